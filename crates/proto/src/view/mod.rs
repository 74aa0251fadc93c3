//! The farm's read model: what a job or a worker looks like to the people watching it. The
//! coordinator builds these under its lock in one place; its gRPC API sends them as
//! protobuf ([`pb::JobStatus`], [`pb::WorkerInfo`]) and its dashboard as JSON (serde); the
//! CLI turns the protobuf back into the same views and prints them, or serialises them for
//! `--json`. So `tessera status --json` and the dashboard's `/api/jobs/JOB` are one document,
//! and the two cannot disagree.
//!
//! Figures that do not exist yet are `None` (`null` in JSON): the ETA of a job with no rate,
//! the noise of a job with no samples, the finish time of a job still going.

use serde::Serialize;
use tessera_render::scene::FrameRange;
use tessera_render::{RenderSettings, Strategy};

use crate::convert::strategy_from_wire;
use crate::ids::{BadId, JobId};
use crate::v1 as pb;

mod logs;
mod worker;

pub use logs::{LogEntryView, LogLevel, LogPage};
pub use worker::{WorkerState, WorkerView};

/// Where a job is in its life. A frame range's state is its frames' ([`JobState::of_range`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    /// Admitted; no unit leased yet.
    Queued,
    /// Some unit has been leased.
    Running,
    /// Every unit merged and the EXR written.
    Done,
    /// Cancelled by a client.
    Cancelled,
    /// Failed (a worker cannot render it, or its EXR could not be written).
    Failed,
}

impl JobState {
    /// The word people read (`tessera status`, the dashboard, error messages).
    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Cancelled => "cancelled",
            JobState::Failed => "failed",
        }
    }

    /// Whether the job has ended: it will not change again.
    pub fn is_final(self) -> bool {
        !matches!(self, JobState::Queued | JobState::Running)
    }

    /// A frame range's state from its frames': running while any frame runs, or once some
    /// have ended while others wait; queued only if none has started; else failed if any
    /// failed, cancelled if any was cancelled, and done.
    pub fn of_range(frames: impl IntoIterator<Item = JobState> + Clone) -> JobState {
        let any = |s: JobState| frames.clone().into_iter().any(|f| f == s);
        if any(JobState::Running) {
            JobState::Running
        } else if any(JobState::Queued) {
            if frames.into_iter().all(|f| f == JobState::Queued) {
                JobState::Queued
            } else {
                JobState::Running
            }
        } else if any(JobState::Failed) {
            JobState::Failed
        } else if any(JobState::Cancelled) {
            JobState::Cancelled
        } else {
            JobState::Done
        }
    }
}

/// A job state on the wire as people read it (`tessera status`, error messages), or `unknown`
/// for a value this build does not know.
pub fn job_state_name(state: i32) -> &'static str {
    JobState::try_from(state).map_or("unknown", JobState::name)
}

impl From<JobState> for pb::JobState {
    fn from(s: JobState) -> Self {
        match s {
            JobState::Queued => pb::JobState::Queued,
            JobState::Running => pb::JobState::Running,
            JobState::Done => pb::JobState::Done,
            JobState::Cancelled => pb::JobState::Cancelled,
            JobState::Failed => pb::JobState::Failed,
        }
    }
}

/// Why a message cannot be a view: a value this build does not know, or a malformed id.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BadView {
    /// A job state this build does not know.
    #[error("unknown job state {0}")]
    State(i32),
    /// A direct-lighting strategy this build does not know.
    #[error("unknown strategy {0}")]
    Strategy(i32),
    /// A malformed id.
    #[error(transparent)]
    Id(#[from] BadId),
    /// A frame range that is not one.
    #[error("frame range: {0}")]
    Frames(String),
    /// An AOV list naming something that is not one.
    #[error("aovs: {0}")]
    Aovs(String),
}

impl TryFrom<i32> for JobState {
    type Error = BadView;

    fn try_from(v: i32) -> Result<Self, BadView> {
        match pb::JobState::try_from(v) {
            Ok(pb::JobState::Queued) => Ok(JobState::Queued),
            Ok(pb::JobState::Running) => Ok(JobState::Running),
            Ok(pb::JobState::Done) => Ok(JobState::Done),
            Ok(pb::JobState::Cancelled) => Ok(JobState::Cancelled),
            Ok(pb::JobState::Failed) => Ok(JobState::Failed),
            Ok(pb::JobState::Unspecified) | Err(_) => Err(BadView::State(v)),
        }
    }
}

/// The settings of a job that people read: those on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct SettingsView {
    /// Samples per pixel (the cap, for an adaptive job).
    pub spp: u32,
    /// Job seed.
    pub seed: u64,
    /// Samples per batch.
    pub batch: u32,
    /// Direct-lighting strategy.
    #[schema(value_type = String)]
    pub strategy: Strategy,
    /// The frame of a one-frame job that names one.
    pub frame: Option<u32>,
    /// The noise target of an adaptive job.
    pub noise_target: Option<f64>,
    /// The AOVs rendered beside the beauty.
    #[schema(value_type = Object)]
    pub aovs: tessera_render::Aovs,
    /// Path guiding.
    pub guiding: bool,
    /// The film's size when it is not the scene file's (`--resolution`): [width, height].
    pub resolution: Option<[u32; 2]>,
}

impl From<&RenderSettings> for SettingsView {
    fn from(s: &RenderSettings) -> Self {
        Self {
            spp: s.spp,
            seed: s.seed,
            batch: s.batch,
            strategy: s.strategy,
            frame: s.frame,
            noise_target: s.adaptive.map(|a| a.noise_target),
            aovs: s.aovs,
            guiding: s.guiding,
            resolution: s.resolution.map(|(w, h)| [w, h]),
        }
    }
}

impl From<&SettingsView> for pb::RenderSettings {
    fn from(s: &SettingsView) -> Self {
        Self {
            spp: s.spp,
            seed: s.seed,
            batch: s.batch,
            strategy: pb::Strategy::from(s.strategy) as i32,
            noise_target: s.noise_target.unwrap_or(0.0),
            frame: s.frame,
            aovs: s.aovs.list(),
            guiding: s.guiding,
            resolution: s
                .resolution
                .map(|[width, height]| pb::Resolution { width, height }),
        }
    }
}

impl TryFrom<&pb::RenderSettings> for SettingsView {
    type Error = BadView;

    fn try_from(s: &pb::RenderSettings) -> Result<Self, BadView> {
        Ok(Self {
            spp: s.spp,
            seed: s.seed,
            batch: s.batch,
            strategy: strategy_from_wire(s.strategy).map_err(|e| BadView::Strategy(e.0))?,
            frame: s.frame,
            noise_target: (s.noise_target > 0.0).then_some(s.noise_target),
            aovs: tessera_render::Aovs::parse(&s.aovs).map_err(BadView::Aovs)?,
            guiding: s.guiding,
            resolution: s.resolution.map(|r| [r.width, r.height]),
        })
    }
}

/// One frame of a frame-range job, as its range lists it.
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct FrameView {
    /// The frame.
    pub frame: u32,
    /// The frame's own job.
    #[schema(value_type = String)]
    pub job_id: JobId,
    /// Its state.
    pub state: JobState,
    /// Units merged.
    pub units_done: u64,
    /// Units in all.
    pub units_total: u64,
    /// Its EXR's name.
    pub output: String,
    /// Why it failed, or empty.
    pub error: String,
    /// The checks its finished image failed.
    pub checks: Vec<CheckView>,
}

/// A check a finished image failed ([`tessera_render::OutputChecks`]).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct CheckView {
    /// Stable code (`black`, `nonfinite`).
    pub code: String,
    /// One line for people.
    pub message: String,
}

impl CheckView {
    /// The checks `checks` failed, each message after `prefix`.
    pub fn failed(checks: &tessera_render::OutputChecks, prefix: &str) -> Vec<Self> {
        checks
            .failed()
            .into_iter()
            .map(|(code, message)| CheckView {
                code: code.to_string(),
                message: format!("{prefix}{message}"),
            })
            .collect()
    }
}

impl From<&CheckView> for pb::OutputCheck {
    fn from(c: &CheckView) -> Self {
        pb::OutputCheck {
            code: c.code.clone(),
            message: c.message.clone(),
        }
    }
}

impl From<&pb::OutputCheck> for CheckView {
    fn from(c: &pb::OutputCheck) -> Self {
        CheckView {
            code: c.code.clone(),
            message: c.message.clone(),
        }
    }
}

/// A job, or a frame-range job folded into one, as `tessera status` and the dashboard show it.
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct JobView {
    /// The job's id (a range's own id for a range).
    #[schema(value_type = String)]
    pub job_id: JobId,
    /// Its state.
    pub state: JobState,
    /// Why it failed, or empty.
    pub error: String,
    /// The scene's name.
    pub scene: String,
    /// The scene's content hash.
    pub scene_sha256: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Its render settings.
    #[serde(flatten)]
    pub settings: SettingsView,
    /// Tile edge in pixels.
    pub tile_size: u32,
    /// Priority (higher first).
    pub priority: i32,
    /// Units merged.
    pub units_done: u64,
    /// Units in all (so far, for an adaptive job).
    pub units_total: u64,
    /// Units out on a live lease now.
    pub units_leased: u64,
    /// Samples merged.
    pub samples_done: u64,
    /// Samples in all (the cap, for an adaptive job).
    pub samples_total: u64,
    /// Merged samples per second, recently.
    pub samples_per_second: f64,
    /// Seconds left at that rate; `None` while there is no rate.
    pub eta_seconds: Option<f64>,
    /// The image's root-mean-square noise; `None` before any sample.
    pub noise_rms: Option<f64>,
    /// The noise relative to the image's brightness; `None` before any sample.
    pub noise_relative: Option<f64>,
    /// Non-finite samples the workers dropped.
    pub nonfinite_samples: u64,
    /// The EXR's name (`STEM.####.exr` for a range).
    pub output: String,
    /// When it was submitted, Unix milliseconds.
    pub submitted_unix_ms: i64,
    /// When it ended, Unix milliseconds; `None` while it goes on.
    pub finished_unix_ms: Option<i64>,
    /// The range it is a frame of.
    #[schema(value_type = Option<String>)]
    pub range_job_id: Option<JobId>,
    /// A range's frames.
    #[schema(value_type = Option<Object>)]
    pub frame_range: Option<FrameRange>,
    /// A range's frames, each with its own state.
    pub frames: Vec<FrameView>,
    /// The checks the finished image failed (a range's: every frame's, named).
    pub checks: Vec<CheckView>,
    /// The job it starts after (`submit --after`), if any.
    #[schema(value_type = Option<String>)]
    pub after: Option<JobId>,
    /// Paused: leased nothing new until resumed.
    pub paused: bool,
    /// Tags a worker needs for it (`submit --require`).
    pub require: Vec<String>,
    /// Memory a worker needs for it, in bytes (0: any).
    pub min_memory_bytes: u64,
    /// Why it has work to hand out and no connected worker can take it.
    pub waiting: Option<String>,
    /// A frame range leased progressively (`submit --progressive`).
    pub progressive: bool,
    /// Units that failed on workers (each went to another worker).
    pub failures: u32,
    /// Workers blocklisted for it after failing its units, by name.
    pub blocklist: Vec<String>,
    /// Times `tessera retry` put it back after it failed.
    pub retries: u32,
    /// Failed, with its scene still kept: `tessera retry` can put it back.
    pub retryable: bool,
    /// The user whose token submitted it; empty without named tokens.
    pub submitter: String,
}

impl From<&JobView> for pb::JobStatus {
    fn from(v: &JobView) -> Self {
        pb::JobStatus {
            job_id: v.job_id.to_string(),
            state: pb::JobState::from(v.state) as i32,
            priority: v.priority,
            scene_hash: v.scene_sha256.clone(),
            scene_name: v.scene.clone(),
            output_name: v.output.clone(),
            width: v.width,
            height: v.height,
            settings: Some(pb::RenderSettings::from(&v.settings)),
            tile_size: v.tile_size,
            units_total: v.units_total,
            units_done: v.units_done,
            samples_total: v.samples_total,
            samples_done: v.samples_done,
            samples_per_second: v.samples_per_second,
            eta_seconds: v.eta_seconds.unwrap_or(-1.0),
            noise_rms: v.noise_rms.unwrap_or(0.0),
            noise_relative: v.noise_relative.unwrap_or(0.0),
            nonfinite_samples: v.nonfinite_samples,
            error: v.error.clone(),
            submitted_unix_ms: v.submitted_unix_ms,
            finished_unix_ms: v.finished_unix_ms.unwrap_or(0),
            units_leased: v.units_leased,
            frames: v
                .frames
                .iter()
                .map(|f| pb::FrameStatus {
                    frame: f.frame,
                    job_id: f.job_id.to_string(),
                    state: pb::JobState::from(f.state) as i32,
                    units_done: f.units_done,
                    units_total: f.units_total,
                    output_name: f.output.clone(),
                    error: f.error.clone(),
                    checks: f.checks.iter().map(pb::OutputCheck::from).collect(),
                })
                .collect(),
            frame_range: v.frame_range.map(|r| pb::FrameRange {
                first: r.first,
                last: r.last,
                step: r.step,
            }),
            range_job_id: v.range_job_id.map(|r| r.to_string()).unwrap_or_default(),
            checks: v.checks.iter().map(pb::OutputCheck::from).collect(),
            after: v.after.map(|a| a.to_string()).unwrap_or_default(),
            require: v.require.clone(),
            min_memory_bytes: v.min_memory_bytes,
            waiting: v.waiting.clone().unwrap_or_default(),
            progressive: v.progressive,
            failures: v.failures,
            blocklist: v.blocklist.clone(),
            retries: v.retries,
            retryable: v.retryable,
            submitter: v.submitter.clone(),
            paused: v.paused,
        }
    }
}

impl TryFrom<&pb::JobStatus> for JobView {
    type Error = BadView;

    fn try_from(s: &pb::JobStatus) -> Result<Self, BadView> {
        let started = s.samples_done > 0;
        Ok(JobView {
            job_id: s.job_id.parse()?,
            state: JobState::try_from(s.state)?,
            error: s.error.clone(),
            scene: s.scene_name.clone(),
            scene_sha256: s.scene_hash.clone(),
            width: s.width,
            height: s.height,
            settings: SettingsView::try_from(&s.settings.clone().unwrap_or_default())?,
            tile_size: s.tile_size,
            priority: s.priority,
            units_done: s.units_done,
            units_total: s.units_total,
            units_leased: s.units_leased,
            samples_done: s.samples_done,
            samples_total: s.samples_total,
            samples_per_second: s.samples_per_second,
            eta_seconds: (s.eta_seconds >= 0.0 && s.eta_seconds.is_finite())
                .then_some(s.eta_seconds),
            noise_rms: (started && s.noise_rms.is_finite()).then_some(s.noise_rms),
            noise_relative: (started && s.noise_relative.is_finite()).then_some(s.noise_relative),
            nonfinite_samples: s.nonfinite_samples,
            output: s.output_name.clone(),
            submitted_unix_ms: s.submitted_unix_ms,
            finished_unix_ms: (s.finished_unix_ms != 0).then_some(s.finished_unix_ms),
            range_job_id: match s.range_job_id.as_str() {
                "" => None,
                r => Some(r.parse()?),
            },
            frame_range: s
                .frame_range
                .map(|r| FrameRange::new(r.first, r.last, r.step))
                .transpose()
                .map_err(|e| BadView::Frames(e.to_string()))?,
            frames: s
                .frames
                .iter()
                .map(|f| {
                    Ok(FrameView {
                        frame: f.frame,
                        job_id: f.job_id.parse()?,
                        state: JobState::try_from(f.state)?,
                        units_done: f.units_done,
                        units_total: f.units_total,
                        output: f.output_name.clone(),
                        error: f.error.clone(),
                        checks: f.checks.iter().map(CheckView::from).collect(),
                    })
                })
                .collect::<Result<_, BadView>>()?,
            checks: s.checks.iter().map(CheckView::from).collect(),
            after: match s.after.as_str() {
                "" => None,
                a => Some(a.parse()?),
            },
            paused: s.paused,
            require: s.require.clone(),
            min_memory_bytes: s.min_memory_bytes,
            waiting: (!s.waiting.is_empty()).then(|| s.waiting.clone()),
            progressive: s.progressive,
            failures: s.failures,
            blocklist: s.blocklist.clone(),
            retries: s.retries,
            retryable: s.retryable,
            submitter: s.submitter.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status() -> pb::JobStatus {
        pb::JobStatus {
            job_id: "job-000007".into(),
            state: pb::JobState::Running as i32,
            priority: 3,
            scene_hash: "ab".repeat(32),
            scene_name: "shot.toml".into(),
            output_name: "shot.####.exr".into(),
            width: 64,
            height: 32,
            settings: Some(pb::RenderSettings {
                spp: 64,
                seed: 9,
                batch: 16,
                strategy: pb::Strategy::Nee as i32,
                noise_target: 0.02,
                frame: None,
                aovs: "normal,depth".into(),
                guiding: false,
                resolution: None,
            }),
            tile_size: 32,
            units_total: 20,
            units_done: 7,
            samples_total: 1000,
            samples_done: 300,
            samples_per_second: 12.5,
            eta_seconds: 56.0,
            noise_rms: 0.25,
            noise_relative: 0.125,
            nonfinite_samples: 1,
            error: String::new(),
            submitted_unix_ms: 1_700_000_000_000,
            finished_unix_ms: 0,
            units_leased: 2,
            frames: vec![pb::FrameStatus {
                frame: 4,
                job_id: "job-000008".into(),
                state: pb::JobState::Done as i32,
                units_done: 5,
                units_total: 5,
                output_name: "shot.0004.exr".into(),
                error: String::new(),
                checks: vec![pb::OutputCheck {
                    code: "black".into(),
                    message: "the image is entirely black".into(),
                }],
            }],
            frame_range: Some(pb::FrameRange {
                first: 4,
                last: 8,
                step: 4,
            }),
            range_job_id: String::new(),
            checks: vec![pb::OutputCheck {
                code: "black".into(),
                message: "frame 4: the image is entirely black".into(),
            }],
            after: "job-000003".into(),
            paused: true,
            require: vec!["pool=fast".into(), "cpu:avx2".into()],
            min_memory_bytes: 16 << 30,
            waiting: "no worker has tag pool=fast".into(),
            progressive: true,
            failures: 2,
            blocklist: vec!["render-07".into()],
            retries: 1,
            retryable: true,
            submitter: "alice".into(),
        }
    }

    /// The CLI reads the view back from the protobuf the coordinator made of it: the round
    /// trip loses nothing, so the two sides print one document.
    #[test]
    fn a_view_survives_the_wire() {
        let wire = status();
        let view = JobView::try_from(&wire).expect("a view");
        assert_eq!(pb::JobStatus::from(&view), wire);
        assert_eq!(view.eta_seconds, Some(56.0));
        assert_eq!(view.settings.noise_target, Some(0.02));
        let json = serde_json::to_value(&view).expect("JSON");
        assert_eq!(json["state"], "running");
        assert_eq!(json["strategy"], "nee");
        assert_eq!(json["frames"][0]["job_id"], "job-000008");
        assert_eq!(json["frames"][0]["checks"][0]["code"], "black");
        assert_eq!(
            json["checks"][0]["message"],
            "frame 4: the image is entirely black"
        );
        assert_eq!(json["finished_unix_ms"], serde_json::Value::Null);
        // Figures that do not exist yet are null, not a sentinel.
        let fresh = pb::JobStatus {
            eta_seconds: -1.0,
            samples_done: 0,
            noise_rms: 0.0,
            ..status()
        };
        let v = JobView::try_from(&fresh).expect("a view");
        assert_eq!((v.eta_seconds, v.noise_rms), (None, None));
        assert_eq!(pb::JobStatus::from(&v).eta_seconds, -1.0);
    }

    #[test]
    fn what_a_build_does_not_know_is_refused_not_guessed() {
        let bad_state = pb::JobStatus {
            state: 99,
            ..status()
        };
        assert_eq!(JobView::try_from(&bad_state), Err(BadView::State(99)));
        let bad_id = pb::JobStatus {
            job_id: "job-x".into(),
            ..status()
        };
        assert!(matches!(JobView::try_from(&bad_id), Err(BadView::Id(_))));
        assert_eq!(job_state_name(0), "unknown");
        assert_eq!(job_state_name(pb::JobState::Failed as i32), "failed");
    }

    #[test]
    fn a_range_runs_while_any_frame_runs_or_some_have_ended_and_others_wait() {
        use JobState::*;
        assert_eq!(JobState::of_range([Queued, Queued]), Queued);
        assert_eq!(JobState::of_range([Done, Queued]), Running);
        assert_eq!(JobState::of_range([Done, Running, Failed]), Running);
        assert_eq!(JobState::of_range([Done, Failed, Cancelled]), Failed);
        assert_eq!(JobState::of_range([Done, Cancelled]), Cancelled);
        assert_eq!(JobState::of_range([Done, Done]), Done);
    }

    #[test]
    fn a_worker_view_survives_the_wire() {
        let wire = pb::WorkerInfo {
            worker_id: "w3-4".into(),
            name: "node".into(),
            cores: 16,
            version: "0.1.0".into(),
            leases: 2,
            units_done: 10,
            samples_done: 1000,
            last_seen_ms_ago: 1234,
            alive: true,
            bad_results: 1,
            quarantined: false,
            convicted: String::new(),
            audits_passed: 3,
            suspect: true,
            host: "10.0.0.5".into(),
            samples_per_second: 5.5,
            memory_bytes: 64 << 30,
            cpu_features: vec!["avx2".into()],
            tags: vec!["pool=fast".into()],
            draining: false,
            denoise_version: 20501,
        };
        let v = WorkerView::try_from(&wire).expect("a view");
        assert_eq!(v.state, WorkerState::Suspect);
        assert_eq!(pb::WorkerInfo::from(&v), wire);
        // Draining shows for a live worker that nothing worse is true of.
        let draining = pb::WorkerInfo {
            suspect: false,
            draining: true,
            ..wire.clone()
        };
        let d = WorkerView::try_from(&draining).expect("a view");
        assert_eq!(d.state, WorkerState::Draining);
        assert_eq!(pb::WorkerInfo::from(&d), draining);
        let gone = pb::WorkerInfo {
            alive: false,
            ..draining
        };
        assert_eq!(
            WorkerView::try_from(&gone).expect("view").state,
            WorkerState::Gone
        );
        let json = serde_json::to_value(&v).expect("JSON");
        assert_eq!(json["state"], "suspect");
        assert_eq!(json["convicted"], serde_json::Value::Null);
    }
}
