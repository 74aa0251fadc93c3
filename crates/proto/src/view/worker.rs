//! A worker as people see it ([`WorkerView`]): its state in one word, what it advertises and
//! what it has done; sent as [`pb::WorkerInfo`] and read back by the CLI.

use serde::Serialize;

use super::BadView;
use crate::ids::WorkerId;
use crate::v1 as pb;

/// A worker's state in one word, the most serious first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum WorkerState {
    /// Convicted by an audit: gets no more work, its results taken back.
    Convicted,
    /// Sent too many invalid results: gets no more work.
    Quarantined,
    /// An audit's copies of a unit it rendered disagree, until the referee decides.
    Suspect,
    /// Alive and drained: finishing the units it holds, then leaving.
    Draining,
    /// Called within a lease time.
    Alive,
    /// Said goodbye, or silent for longer than a lease.
    Gone,
}

impl WorkerState {
    /// The most serious of what is true of a worker.
    pub fn of(
        convicted: bool,
        quarantined: bool,
        suspect: bool,
        draining: bool,
        alive: bool,
    ) -> Self {
        if convicted {
            WorkerState::Convicted
        } else if quarantined {
            WorkerState::Quarantined
        } else if suspect {
            WorkerState::Suspect
        } else if alive && draining {
            WorkerState::Draining
        } else if alive {
            WorkerState::Alive
        } else {
            WorkerState::Gone
        }
    }

    /// The word people read.
    pub fn name(self) -> &'static str {
        match self {
            WorkerState::Convicted => "convicted",
            WorkerState::Quarantined => "quarantined",
            WorkerState::Suspect => "suspect",
            WorkerState::Draining => "draining",
            WorkerState::Alive => "alive",
            WorkerState::Gone => "gone",
        }
    }
}

/// A worker, as `tessera workers` and the dashboard show it.
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct WorkerView {
    /// Its public id.
    #[schema(value_type = String)]
    pub worker_id: WorkerId,
    /// The name it gave.
    pub name: String,
    /// The address it registered from, when known.
    pub host: Option<String>,
    /// Render threads it reported.
    pub cores: u32,
    /// Its tessera version.
    pub version: String,
    /// Its state.
    pub state: WorkerState,
    /// Whether it called within a lease time and has not said goodbye (a quarantined worker
    /// may still be calling).
    pub alive: bool,
    /// Leases it holds now.
    pub leases: u32,
    /// Units merged from it.
    pub units_done: u64,
    /// Samples merged from it.
    pub samples_done: u64,
    /// Its merged samples per second, recently.
    pub samples_per_second: f64,
    /// Results refused as invalid.
    pub bad_results: u64,
    /// Its results that another host's copy matched.
    pub audits_passed: u64,
    /// Why an audit convicted it.
    pub convicted: Option<String>,
    /// Seconds since its last call.
    pub last_seen_seconds_ago: f64,
    /// Memory it reported, in bytes (0: unknown).
    pub memory_bytes: u64,
    /// CPU features it reported.
    pub cpu_features: Vec<String>,
    /// Its operator tags.
    pub tags: Vec<String>,
    /// The Open Image Denoise version it denoises finished frames with (20501 for 2.5.1;
    /// 0: it does not denoise).
    pub denoise_version: i32,
}

impl From<&WorkerView> for pb::WorkerInfo {
    fn from(v: &WorkerView) -> Self {
        pb::WorkerInfo {
            worker_id: v.worker_id.to_string(),
            name: v.name.clone(),
            cores: v.cores,
            version: v.version.clone(),
            leases: v.leases,
            units_done: v.units_done,
            samples_done: v.samples_done,
            last_seen_ms_ago: (v.last_seen_seconds_ago * 1000.0).round() as u64,
            alive: v.alive,
            bad_results: v.bad_results,
            quarantined: matches!(v.state, WorkerState::Quarantined | WorkerState::Convicted),
            convicted: v.convicted.clone().unwrap_or_default(),
            audits_passed: v.audits_passed,
            suspect: v.state == WorkerState::Suspect,
            host: v.host.clone().unwrap_or_default(),
            samples_per_second: v.samples_per_second,
            memory_bytes: v.memory_bytes,
            cpu_features: v.cpu_features.clone(),
            tags: v.tags.clone(),
            draining: v.state == WorkerState::Draining,
            denoise_version: v.denoise_version,
        }
    }
}

impl TryFrom<&pb::WorkerInfo> for WorkerView {
    type Error = BadView;

    fn try_from(w: &pb::WorkerInfo) -> Result<Self, BadView> {
        let state = WorkerState::of(
            !w.convicted.is_empty(),
            w.quarantined,
            w.suspect,
            w.draining,
            w.alive,
        );
        Ok(WorkerView {
            worker_id: w.worker_id.parse()?,
            name: w.name.clone(),
            host: (!w.host.is_empty()).then(|| w.host.clone()),
            cores: w.cores,
            version: w.version.clone(),
            state,
            alive: w.alive,
            leases: w.leases,
            units_done: w.units_done,
            samples_done: w.samples_done,
            samples_per_second: w.samples_per_second,
            bad_results: w.bad_results,
            audits_passed: w.audits_passed,
            convicted: (!w.convicted.is_empty()).then(|| w.convicted.clone()),
            last_seen_seconds_ago: w.last_seen_ms_ago as f64 / 1000.0,
            memory_bytes: w.memory_bytes,
            cpu_features: w.cpu_features.clone(),
            tags: w.tags.clone(),
            denoise_version: w.denoise_version,
        })
    }
}
