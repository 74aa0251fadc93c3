//! `tessera logs`: the warnings and errors workers reported about a job's units, as the
//! coordinator kept them, and with `--follow` those that come until the job ends.

use std::time::Duration;

use anyhow::Result;
use tessera_proto::v1 as pb;
use tessera_proto::view::{LogEntryView, LogPage};

use super::{connect, rpc_error};
use crate::farm::{runtime, CoordinatorUrl};
use crate::terminal::printable;

/// Arguments of `tessera logs`.
#[derive(Debug, clap::Args)]
pub struct LogsArgs {
    /// Job id (a frame-range job's: every frame's lines).
    job: String,
    /// Only this frame's lines, for a frame-range job.
    #[arg(long)]
    frame: Option<u32>,
    /// Keep printing new lines until the job ends.
    #[arg(long, short)]
    follow: bool,
    #[command(flatten)]
    url: CoordinatorUrl,
}

/// Unix milliseconds as UTC, `2026-11-28T02:50:01Z` (days to a civil date: Howard Hinnant's
/// algorithm, so that a log line needs no time-zone database).
fn utc(unix_ms: i64) -> String {
    let secs = unix_ms.div_euclid(1000);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// One line as printed.
fn line(e: &LogEntryView) -> String {
    let level = e.level.name();
    let frame = e.frame.map(|f| format!(" frame {f}")).unwrap_or_default();
    format!(
        "{} {}{frame} tile {} batch {} {} ({}): {level}: {}",
        utc(e.unix_ms),
        e.job_id,
        e.tile,
        e.batch,
        e.worker_id,
        printable(&e.worker_name),
        printable(&e.message)
    )
}

/// Runs `tessera logs`.
pub fn logs(args: LogsArgs) -> Result<()> {
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let mut after = 0;
        let mut said_dropped = 0;
        loop {
            let r = client
                .get_logs(pb::GetLogsRequest {
                    job_id: args.job.clone(),
                    frame: args.frame,
                    after,
                })
                .await
                .map_err(|e| rpc_error(&url, &args.job, e))?
                .into_inner();
            let r = LogPage::try_from(&r)?;
            if r.dropped > said_dropped {
                errln!(
                    "({} lines were not kept: a job keeps its last 200, and a worker may send 5 a \
                     second)",
                    r.dropped
                );
                said_dropped = r.dropped;
            }
            let page = r.entries.len();
            for e in &r.entries {
                outln!("{}", line(e));
                after = after.max(e.seq);
            }
            // A full page: more are waiting now.
            if page >= 1000 {
                continue;
            }
            if !args.follow || r.ended {
                return Ok(());
            }
            tokio::time::sleep(Duration::from_secs(1)).await;
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_print_as_utc() {
        assert_eq!(utc(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc(1_795_833_001_000), "2026-11-28T02:30:01Z");
        assert_eq!(utc(951_782_400_000), "2000-02-29T00:00:00Z");
    }

    #[test]
    fn a_line_names_the_unit_and_the_worker() {
        let e = LogEntryView {
            seq: 3,
            unix_ms: 0,
            worker_id: "w1-2".into(),
            worker_name: "render\u{1b}[2J".into(),
            job_id: "job-000004".into(),
            frame: Some(7),
            tile: 3,
            batch: 1,
            level: tessera_proto::view::LogLevel::Error,
            message: "out of memory".into(),
        };
        let l = line(&e);
        assert_eq!(
            l,
            "1970-01-01T00:00:00Z job-000004 frame 7 tile 3 batch 1 w1-2 (render\\u{1b}[2J): error: out of memory"
        );
    }
}
