//! A page of a job's log ([`LogPage`]): the warnings and errors workers reported about its
//! units, as `tessera logs` prints them and `/api/jobs/{id}/logs` answers them; sent as
//! [`pb::GetLogsResponse`] and read back by the CLI.

use serde::Serialize;

use super::BadView;
use crate::v1 as pb;

/// How serious a line is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum LogLevel {
    /// For information.
    Info,
    /// Something the user may want to fix (the default: a line without a level).
    Warn,
    /// A unit failed.
    Error,
}

impl LogLevel {
    /// The level a worker or the store gave in words (`info`, `error`; anything else warns).
    pub fn from_name(name: &str) -> Self {
        match name {
            "info" => LogLevel::Info,
            "error" => LogLevel::Error,
            _ => LogLevel::Warn,
        }
    }

    /// Its name, as printed and stored.
    pub fn name(self) -> &'static str {
        match self {
            LogLevel::Info => "info",
            LogLevel::Warn => "warn",
            LogLevel::Error => "error",
        }
    }
}

impl From<LogLevel> for pb::LogLevel {
    fn from(l: LogLevel) -> Self {
        match l {
            LogLevel::Info => pb::LogLevel::Info,
            LogLevel::Warn => pb::LogLevel::Warn,
            LogLevel::Error => pb::LogLevel::Error,
        }
    }
}

impl From<i32> for LogLevel {
    /// A wire level; an unknown or unset one reads as a warning, as the protocol says.
    fn from(l: i32) -> Self {
        match pb::LogLevel::try_from(l) {
            Ok(pb::LogLevel::Info) => LogLevel::Info,
            Ok(pb::LogLevel::Error) => LogLevel::Error,
            _ => LogLevel::Warn,
        }
    }
}

/// One line of a job's log.
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct LogEntryView {
    /// Increases with every line the coordinator keeps, across restarts: ask for the lines
    /// after the last one seen to follow.
    pub seq: u64,
    /// When the coordinator received it, Unix milliseconds.
    pub unix_ms: i64,
    /// The worker's public id.
    pub worker_id: String,
    /// The worker's name.
    pub worker_name: String,
    /// The job.
    pub job_id: String,
    /// The frame, for a frame-range job.
    pub frame: Option<u32>,
    /// The unit's tile.
    pub tile: u32,
    /// The unit's batch.
    pub batch: u32,
    /// How serious.
    pub level: LogLevel,
    /// The text.
    pub message: String,
}

/// A page of a job's log, oldest line first.
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct LogPage {
    /// The lines.
    pub entries: Vec<LogEntryView>,
    /// Lines dropped (rate, size, the job's cap).
    pub dropped: u64,
    /// The job has ended: no more lines will come.
    pub ended: bool,
}

impl From<&LogPage> for pb::GetLogsResponse {
    fn from(p: &LogPage) -> Self {
        pb::GetLogsResponse {
            entries: p
                .entries
                .iter()
                .map(|e| pb::LogEntry {
                    seq: e.seq,
                    unix_ms: e.unix_ms,
                    worker_id: e.worker_id.clone(),
                    worker_name: e.worker_name.clone(),
                    job_id: e.job_id.clone(),
                    frame: e.frame,
                    tile_index: e.tile,
                    batch_index: e.batch,
                    level: pb::LogLevel::from(e.level) as i32,
                    message: e.message.clone(),
                })
                .collect(),
            dropped: p.dropped,
            ended: p.ended,
        }
    }
}

impl TryFrom<&pb::GetLogsResponse> for LogPage {
    type Error = BadView;

    /// Infallible today (every wire value has a reading); fallible like the other views so
    /// that a field that must be checked can be.
    fn try_from(r: &pb::GetLogsResponse) -> Result<Self, BadView> {
        Ok(LogPage {
            entries: r
                .entries
                .iter()
                .map(|e| LogEntryView {
                    seq: e.seq,
                    unix_ms: e.unix_ms,
                    worker_id: e.worker_id.clone(),
                    worker_name: e.worker_name.clone(),
                    job_id: e.job_id.clone(),
                    frame: e.frame,
                    tile: e.tile_index,
                    batch: e.batch_index,
                    level: LogLevel::from(e.level),
                    message: e.message.clone(),
                })
                .collect(),
            dropped: r.dropped,
            ended: r.ended,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_page_survives_the_wire_and_reads_unknown_levels_as_warnings() {
        let page = LogPage {
            entries: [LogLevel::Info, LogLevel::Warn, LogLevel::Error]
                .into_iter()
                .enumerate()
                .map(|(i, level)| LogEntryView {
                    seq: i as u64 + 1,
                    unix_ms: 7,
                    worker_id: "w1-2".into(),
                    worker_name: "render".into(),
                    job_id: "job-000004".into(),
                    frame: (i == 1).then_some(3),
                    tile: 5,
                    batch: 6,
                    level,
                    message: format!("line {i}"),
                })
                .collect(),
            dropped: 2,
            ended: true,
        };
        let wire = pb::GetLogsResponse::from(&page);
        assert_eq!(LogPage::try_from(&wire).unwrap(), page);
        let mut odd = wire.clone();
        odd.entries[0].level = 99;
        assert_eq!(
            LogPage::try_from(&odd).unwrap().entries[0].level,
            LogLevel::Warn
        );
        let json = serde_json::to_value(&page).unwrap();
        assert_eq!(json["entries"][2]["level"], "error");
        assert_eq!(json["entries"][1]["frame"], 3);
    }
}
