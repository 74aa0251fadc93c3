//! The gRPC handlers: decode and check each request (the wire's strings become typed ids and
//! settings here, through `tessera_proto`'s conversions), call into the
//! [`Scheduler`] under its lock, and wait for the store before replying where durability
//! matters.

use std::collections::BTreeMap;
use std::pin::Pin;
use std::sync::Arc;
use std::time::{Duration, Instant};

use std::sync::atomic::{AtomicUsize, Ordering};

use tessera_proto::convert::settings_from_wire;
use tessera_proto::ids::{JobId, LeaseId, WorkerCredential};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_server::Jobs;
use tessera_proto::v1::workers_server::Workers;
use tessera_render::scene::{Format, FrameRange, Scene, FIRST_FRAME};
use tessera_render::{TileSums, IMAGE_REVISION, TILE_RANGE};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::Stream;
use tonic::{Request, Response, Status};
use tracing::{info, warn};

use crate::assets::{check_hash, AssetError, JobAssets, CHUNK_BYTES};
use crate::config::{MAX_CONCURRENT_PARSES, MAX_LEASES_PER_CALL};
use crate::error::truncate;
use crate::job::{Job, Unit};
use crate::output::{check_output_name, finish_job, OutputNames};
use crate::scheduler::{Admission, AdmissionLimits, Merged, Scheduler};
use crate::shared::{durable, now_ms, Shared};
use crate::store::{JobPhase, StoredScene};

/// Both services over the same shared state.
#[derive(Clone)]
pub struct Service {
    pub(crate) shared: Arc<Shared>,
    /// Permits to parse a submitted scene ([`MAX_CONCURRENT_PARSES`]).
    parses: Arc<tokio::sync::Semaphore>,
    /// Parses running now, and the most that ever ran at once.
    parsing: Arc<(AtomicUsize, AtomicUsize)>,
}

type Stream_<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send>>;

fn internal(e: String) -> Status {
    Status::internal(format!("coordinator state store: {e}"))
}

fn job_id(s: &str) -> Result<JobId, Status> {
    s.parse()
        .map_err(|e: tessera_proto::ids::BadId| Status::invalid_argument(e.to_string()))
}

/// The credential a worker call quotes. A malformed one is as unknown as a wrong one, and
/// gets the same answer (register again).
fn credential(s: &str) -> Result<WorkerCredential, Status> {
    s.parse().map_err(|e: tessera_proto::ids::BadId| {
        Status::not_found(format!(
            "unknown worker {:?} (the coordinator may have restarted): register again",
            e.text
        ))
    })
}

/// The lease ids a worker call lists: those that parse, and those that do not (which no
/// lease of this coordinator's can be).
fn lease_ids(ids: &[String]) -> Result<(Vec<LeaseId>, Vec<String>), Status> {
    if ids.len() > MAX_LEASES_PER_CALL {
        return Err(Status::invalid_argument(format!(
            "the call lists {} leases; at most {MAX_LEASES_PER_CALL}",
            ids.len()
        )));
    }
    let mut good = Vec::with_capacity(ids.len());
    let mut bad = Vec::new();
    for id in ids {
        match id.parse() {
            Ok(l) => good.push(l),
            Err(_) => bad.push(truncate(id)),
        }
    }
    Ok((good, bad))
}

/// A job's status as sent to clients.
fn status(job: &Job, core: &Scheduler) -> pb::JobStatus {
    let rec = &job.rec;
    let state = match rec.phase {
        JobPhase::Active if job.started => pb::JobState::Running,
        JobPhase::Active => pb::JobState::Queued,
        JobPhase::Done => pb::JobState::Done,
        JobPhase::Cancelled => pb::JobState::Cancelled,
        JobPhase::Failed => pb::JobState::Failed,
    };
    let (units_total, units_done, samples_total, samples_done) = job.progress();
    let rate = job.rate(Instant::now());
    let eta = if rec.phase == JobPhase::Done {
        0.0
    } else if rate > 0.0 && rec.phase == JobPhase::Active {
        samples_total.saturating_sub(samples_done) as f64 / rate
    } else {
        -1.0
    };
    let (noise_rms, noise_relative) = job.noise();
    let units_leased = core.units_leased(job);
    pb::JobStatus {
        job_id: job.id().to_string(),
        state: state as i32,
        priority: rec.priority,
        scene_hash: rec.scene_hash.clone(),
        scene_name: rec.scene_name.clone(),
        output_name: rec.output_name.clone(),
        width: rec.width,
        height: rec.height,
        settings: Some(pb::RenderSettings::from(&job.settings())),
        tile_size: rec.tile_size,
        units_total,
        units_done,
        samples_total,
        samples_done,
        samples_per_second: rate,
        eta_seconds: eta,
        noise_rms,
        noise_relative,
        nonfinite_samples: job.nonfinite,
        error: rec.error.clone(),
        submitted_unix_ms: rec.submitted_ms,
        finished_unix_ms: rec.finished_ms,
        units_leased,
        frames: Vec::new(),
        frame_range: None,
        range_job_id: rec
            .range
            .map(|r| JobId(r.id).to_string())
            .unwrap_or_default(),
    }
}

/// A frame-range job's status: its frames' statuses folded into one, and each frame's own.
fn range_status(id: JobId, members: &[JobId], core: &Scheduler) -> Option<pb::JobStatus> {
    let frames: Vec<pb::JobStatus> = members
        .iter()
        .filter_map(|m| core.jobs.get(m))
        .map(|j| status(j, core))
        .collect();
    let first = frames.first()?;
    let range = core.jobs.get(&members[0])?.rec.range?;
    let state_of = |s: &pb::JobStatus| pb::JobState::try_from(s.state).unwrap_or_default();
    let any = |st: pb::JobState| frames.iter().any(|s| state_of(s) == st);
    let state = if any(pb::JobState::Running) {
        pb::JobState::Running
    } else if any(pb::JobState::Queued) {
        // Some frames done (or failed) and none started since: the range has started.
        if frames.iter().all(|s| state_of(s) == pb::JobState::Queued) {
            pb::JobState::Queued
        } else {
            pb::JobState::Running
        }
    } else if any(pb::JobState::Failed) {
        pb::JobState::Failed
    } else if any(pb::JobState::Cancelled) {
        pb::JobState::Cancelled
    } else {
        pb::JobState::Done
    };
    let failed: Vec<String> = frames
        .iter()
        .filter(|s| state_of(s) == pb::JobState::Failed)
        .map(|s| {
            let frame = s
                .settings
                .as_ref()
                .and_then(|x| x.frame)
                .unwrap_or_default();
            format!("frame {frame} ({}): {}", s.job_id, s.error)
        })
        .collect();
    let error = match failed.len() {
        0 => String::new(),
        n => format!(
            "{n} of {} frames failed; {}",
            frames.len(),
            failed.first().map_or("", |f| f.as_str())
        ),
    };
    let sum = |f: fn(&pb::JobStatus) -> u64| frames.iter().map(f).sum::<u64>();
    let (samples_total, samples_done) = (sum(|s| s.samples_total), sum(|s| s.samples_done));
    // Ended frames keep their last rate for a while; only the frames still going add up.
    let rate: f64 = frames
        .iter()
        .filter(|s| matches!(state_of(s), pb::JobState::Running | pb::JobState::Queued))
        .map(|s| s.samples_per_second)
        .sum();
    let eta = match state {
        pb::JobState::Done => 0.0,
        pb::JobState::Running | pb::JobState::Queued if rate > 0.0 => {
            samples_total.saturating_sub(samples_done) as f64 / rate
        }
        _ => -1.0,
    };
    // The worst frame's noise: the figure a user waiting for the whole range needs.
    let worst = frames
        .iter()
        .max_by(|a, b| a.noise_relative.total_cmp(&b.noise_relative))
        .map_or((0.0, 0.0), |s| (s.noise_rms, s.noise_relative));
    let ended = !matches!(state, pb::JobState::Running | pb::JobState::Queued);
    let mut settings = first.settings;
    if let Some(s) = &mut settings {
        s.frame = None;
    }
    Some(pb::JobStatus {
        job_id: id.to_string(),
        state: state as i32,
        priority: first.priority,
        scene_hash: first.scene_hash.clone(),
        scene_name: first.scene_name.clone(),
        output_name: range_output_pattern(&first.output_name),
        width: first.width,
        height: first.height,
        settings,
        tile_size: first.tile_size,
        units_total: sum(|s| s.units_total),
        units_done: sum(|s| s.units_done),
        samples_total,
        samples_done,
        samples_per_second: rate,
        eta_seconds: eta,
        noise_rms: worst.0,
        noise_relative: worst.1,
        nonfinite_samples: sum(|s| s.nonfinite_samples),
        error,
        submitted_unix_ms: first.submitted_unix_ms,
        finished_unix_ms: if ended {
            frames.iter().map(|s| s.finished_unix_ms).max().unwrap_or(0)
        } else {
            0
        },
        units_leased: sum(|s| s.units_leased),
        frame_range: Some(pb::FrameRange {
            first: range.frames.first,
            last: range.frames.last,
            step: range.frames.step,
        }),
        range_job_id: String::new(),
        frames: frames
            .into_iter()
            .map(|s| pb::FrameStatus {
                frame: s
                    .settings
                    .as_ref()
                    .and_then(|x| x.frame)
                    .unwrap_or_default(),
                job_id: s.job_id,
                state: s.state,
                units_done: s.units_done,
                units_total: s.units_total,
                output_name: s.output_name,
                error: s.error,
            })
            .collect(),
    })
}

/// `shot.0001.exr` → `shot.####.exr`: how a range's output names are shown.
fn range_output_pattern(first_frame_name: &str) -> String {
    let stem = first_frame_name
        .strip_suffix(".exr")
        .unwrap_or(first_frame_name);
    let stem = stem.rsplit_once('.').map_or(stem, |(s, _)| s);
    format!("{stem}.####.exr")
}

/// The status of job `id`, a one-frame job or a frame-range job.
fn status_of(core: &Scheduler, id: JobId) -> Option<pb::JobStatus> {
    match core.ranges.get(&id) {
        Some(members) => range_status(id, members, core),
        None => core.jobs.get(&id).map(|j| status(j, core)),
    }
}

fn final_state(s: &pb::JobStatus) -> bool {
    matches!(
        pb::JobState::try_from(s.state),
        Ok(pb::JobState::Done | pb::JobState::Cancelled | pb::JobState::Failed)
    )
}

/// Converts a result from the wire, checking only what can be checked without the job (the
/// rest is [`Scheduler::submit`]'s). Public for the fuzz target.
pub fn decode_result(r: pb::TileResult) -> Result<TileSums, Status> {
    TileSums::try_from(r).map_err(|e| Status::invalid_argument(e.to_string()))
}

impl Service {
    /// Both services over `shared`.
    pub(crate) fn new(shared: Arc<Shared>) -> Self {
        Self {
            shared,
            parses: Arc::new(tokio::sync::Semaphore::new(MAX_CONCURRENT_PARSES)),
            parsing: Arc::default(),
        }
    }

    /// The most scene parses that have run at once.
    pub(crate) fn peak_parses(&self) -> usize {
        self.parsing.1.load(Ordering::SeqCst)
    }

    fn not_found(id: JobId) -> Status {
        Status::not_found(format!("unknown job {id}"))
    }

    fn job_status(&self, id: JobId) -> Result<pb::JobStatus, Status> {
        let core = self.shared.scheduler();
        status_of(&core, id).ok_or_else(|| Self::not_found(id))
    }
}

#[tonic::async_trait]
impl Jobs for Service {
    async fn submit_job(
        &self,
        request: Request<pb::SubmitJobRequest>,
    ) -> Result<Response<pb::SubmitJobResponse>, Status> {
        let req = request.into_inner();
        let config = &self.shared.config;
        let limits = config.limits.clone();
        let mut settings = settings_from_wire(req.settings.as_ref())
            .map_err(|e| Status::invalid_argument(e.to_string()))?;
        if settings.spp > limits.max_spp {
            return Err(Status::invalid_argument(format!(
                "spp {} must be between 1 and {}",
                settings.spp, limits.max_spp
            )));
        }
        let tile_size = if req.tile_size == 0 {
            config.default_tile_size
        } else {
            req.tile_size
        };
        if !TILE_RANGE.contains(&tile_size) {
            return Err(Status::invalid_argument(format!(
                "tile size {tile_size} must be between {} and {}",
                TILE_RANGE.start(),
                TILE_RANGE.end()
            )));
        }
        if let Some(a) = &mut settings.adaptive {
            // Noise decisions are per unit tile: the job's tiles are the target's.
            a.tile = tile_size;
        }
        let frames = match req.frames {
            Some(_) if settings.frame.is_some() => {
                return Err(Status::invalid_argument(
                    "a job names either one frame or a frame range, not both",
                ))
            }
            Some(r) => Some(
                FrameRange::new(r.first, r.last, r.step)
                    .map_err(|e| Status::invalid_argument(e.to_string()))?,
            ),
            None => None,
        };
        let output_name = Some(req.output_name).filter(|n| !n.is_empty());
        if let Some(name) = &output_name {
            check_output_name(name).map_err(Status::invalid_argument)?;
        }
        let json = req.scene_format == pb::SceneFormat::Json as i32;
        let name = if req.scene_name.is_empty() {
            "scene".to_string()
        } else {
            truncate(&req.scene_name)
        };
        // Parsing builds the BVH: keep it off the async threads, and few at a time.
        let _permit = self
            .parses
            .clone()
            .acquire_owned()
            .await
            .map_err(|_| Status::unavailable("the coordinator is shutting down"))?;
        let text = req.scene_text;
        let names = asset_names(&req.assets, limits.max_assets)?;
        // Until the job is durable (and its scene names its files), they are not collected.
        let _assets_held = self.shared.asset_gate.read().await;
        let missing: Vec<String> = names
            .iter()
            .filter(|(_, hash)| !self.shared.assets.status(hash).is_ok_and(|h| h.complete))
            .map(|(name, hash)| format!("`{}` (sha256 {hash})", truncate(name)))
            .collect();
        if !missing.is_empty() {
            return Err(Status::failed_precondition(format!(
                "not uploaded: {} (tessera submit uploads a scene's files)",
                missing.join(", ")
            )));
        }
        // A range's scene is checked at its first frame; a frame that cannot be built fails
        // alone, when a worker says so.
        let frame = frames.map_or(settings.frame.unwrap_or(FIRST_FRAME), |r| r.first);
        let gauge = self.parsing.clone();
        let assets = self.shared.assets.clone();
        let (scene, text, name) = tokio::task::spawn_blocking(move || {
            let now = gauge.0.fetch_add(1, Ordering::SeqCst) + 1;
            gauge.1.fetch_max(now, Ordering::SeqCst);
            let format = if json { Format::Json } else { Format::Toml };
            let files = JobAssets {
                store: &assets,
                names,
            };
            let r = Scene::from_str_with(&text, format, &name, &limits, frame, &files);
            gauge.0.fetch_sub(1, Ordering::SeqCst);
            (r, text, name)
        })
        .await
        .map_err(|e| Status::internal(e.to_string()))?;
        let scene = scene.map_err(|e| Status::invalid_argument(e.to_string()))?;
        let admission = Admission {
            scene_hash: scene.hash.clone(),
            scene: StoredScene {
                text,
                json,
                name,
                assets: scene.files.clone(),
            },
            width: scene.width,
            height: scene.height,
            settings: settings.clone(),
            tile_size,
            output_name,
            priority: req.priority,
            variance: req.channels.as_ref().is_some_and(|c| c.variance),
            sample_count: req.channels.as_ref().is_some_and(|c| c.sample_count),
            frames,
        };
        let bounds = AdmissionLimits {
            max_active_jobs: config.max_active_jobs,
            max_units_per_job: config.max_units_per_job,
            max_frames_per_job: config.max_frames_per_job,
        };
        let out_dir = config.output_dir();
        let (id, units, rx) = {
            let mut core = self.shared.scheduler();
            let (id, ops) = core.admit(admission, bounds, &OutputNames::new(&out_dir), now_ms())?;
            let units = core
                .members(id)
                .iter()
                .filter_map(|m| core.jobs.get(m))
                .map(|j| j.units_total())
                .sum::<u64>();
            (id, units, self.shared.queue_write(ops))
        };
        durable(rx).await.map_err(internal)?;
        let n_frames = frames.map_or(1, |r| r.len()) as u32;
        info!(
            "{id} submitted: {}×{} at {} spp, {n_frames} frame(s), {units} units",
            scene.width, scene.height, settings.spp
        );
        self.shared.bump_work();
        self.shared.bump_changed();
        Ok(Response::new(pb::SubmitJobResponse {
            job_id: id.to_string(),
            scene_hash: scene.hash,
            units,
            frames: n_frames,
        }))
    }

    async fn get_job(
        &self,
        request: Request<pb::GetJobRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        let id = job_id(&request.into_inner().job_id)?;
        Ok(Response::new(self.job_status(id)?))
    }

    type WatchJobStream = Stream_<pb::JobStatus>;

    async fn watch_job(
        &self,
        request: Request<pb::WatchJobRequest>,
    ) -> Result<Response<Self::WatchJobStream>, Status> {
        let req = request.into_inner();
        let id = job_id(&req.job_id)?;
        let interval = Duration::from_millis(match req.interval_ms {
            0 => 1000,
            ms => ms.clamp(50, 60_000) as u64,
        });
        let first = self.job_status(id)?;
        let (tx, rx) = mpsc::channel(4);
        let shared = Arc::downgrade(&self.shared);
        let mut changed = self.shared.changed.subscribe();
        tokio::spawn(async move {
            let mut msg = first;
            loop {
                let last = final_state(&msg);
                if tx.send(Ok(msg)).await.is_err() || last {
                    return;
                }
                // Wake on a change, but no more often than every tenth of the interval.
                let _ = tokio::time::timeout(interval, changed.changed()).await;
                tokio::time::sleep(interval / 10).await;
                let Some(shared) = shared.upgrade() else {
                    return;
                };
                let core = shared.scheduler();
                let Some(s) = status_of(&core, id) else {
                    return;
                };
                msg = s;
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn cancel_job(
        &self,
        request: Request<pb::CancelJobRequest>,
    ) -> Result<Response<pb::CancelJobResponse>, Status> {
        let id = job_id(&request.into_inner().job_id)?;
        let rx = {
            let mut core = self.shared.scheduler();
            // A frame-range job is cancelled as a whole: every frame still active.
            let live: Vec<JobId> = core
                .members(id)
                .into_iter()
                .filter(|m| {
                    core.jobs
                        .get(m)
                        .is_some_and(|j| j.rec.phase == JobPhase::Active && !j.finishing)
                })
                .collect();
            if live.is_empty() {
                let s = status_of(&core, id).ok_or_else(|| Self::not_found(id))?;
                return Ok(Response::new(pb::CancelJobResponse { state: s.state }));
            }
            let now = now_ms();
            let ops = live
                .into_iter()
                .flat_map(|m| core.end_job(m, JobPhase::Cancelled, String::new(), now))
                .collect();
            self.shared.queue_write(ops)
        };
        durable(rx).await.map_err(internal)?;
        info!("{id} cancelled");
        self.shared.bump_changed();
        Ok(Response::new(pb::CancelJobResponse {
            state: pb::JobState::Cancelled as i32,
        }))
    }

    async fn list_jobs(
        &self,
        _request: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::ListJobsResponse>, Status> {
        let core = self.shared.scheduler();
        // A frame-range job is one row, where its first frame would be.
        let jobs = core
            .schedule_order(false)
            .into_iter()
            .filter_map(|id| match core.jobs.get(&id)?.rec.range {
                None => status_of(&core, id),
                Some(r) if core.ranges.get(&JobId(r.id))?.first() == Some(&id) => {
                    status_of(&core, JobId(r.id))
                }
                Some(_) => None,
            })
            .collect();
        Ok(Response::new(pb::ListJobsResponse { jobs }))
    }

    async fn list_workers(
        &self,
        _request: Request<pb::ListWorkersRequest>,
    ) -> Result<Response<pb::ListWorkersResponse>, Status> {
        let core = self.shared.scheduler();
        let now = Instant::now();
        let workers = core
            .workers
            .iter()
            .map(|(&n, w)| {
                let idle = now.duration_since(w.last_seen);
                pb::WorkerInfo {
                    worker_id: core.worker_id(n).to_string(),
                    name: w.name.clone(),
                    cores: w.cores,
                    version: w.version.clone(),
                    leases: core.leases_of(n) as u32,
                    units_done: w.units_done,
                    samples_done: w.samples_done,
                    last_seen_ms_ago: idle.as_millis() as u64,
                    alive: w.alive(now, core.lease_time),
                    bad_results: w.bad_results,
                    quarantined: w.quarantined,
                    convicted: w.convicted.clone().unwrap_or_default(),
                    audits_passed: w.audits_passed,
                    suspect: !w.disputes.is_empty(),
                    host: w.host.clone(),
                    samples_per_second: w.rate.per_second(now),
                }
            })
            .collect();
        Ok(Response::new(pb::ListWorkersResponse { workers }))
    }

    type FetchResultStream = Stream_<pb::ResultChunk>;

    async fn fetch_result(
        &self,
        request: Request<pb::FetchResultRequest>,
    ) -> Result<Response<Self::FetchResultStream>, Status> {
        let req = request.into_inner();
        let id = job_id(&req.job_id)?;
        let s = self.job_status(id)?;
        let s = match (req.frame, s.frames.is_empty()) {
            (None, false) => {
                return Err(Status::failed_precondition(format!(
                    "{id} is a range of {} frames: fetch them one at a time by frame",
                    s.frames.len()
                )))
            }
            (Some(f), false) => {
                let Some(frame) = s.frames.iter().find(|x| x.frame == f) else {
                    let r = s.frame_range.unwrap_or_default();
                    return Err(Status::not_found(format!(
                        "{id} renders frames {}-{}:{}, which do not include frame {f}",
                        r.first, r.last, r.step
                    )));
                };
                self.job_status(job_id(&frame.job_id)?)?
            }
            (Some(f), true) if s.settings.as_ref().and_then(|x| x.frame) != Some(f) => {
                return Err(Status::not_found(format!("{id} does not render frame {f}")));
            }
            _ => s,
        };
        if s.state != pb::JobState::Done as i32 {
            let state = tessera_proto::convert::job_state_name(s.state);
            // A job that ended without an image never will have one: say so, not "not ready".
            let why = match pb::JobState::try_from(s.state) {
                Ok(pb::JobState::Cancelled) => "it was cancelled, so it has no EXR".to_string(),
                Ok(pb::JobState::Failed) => format!("it has no EXR: {}", s.error),
                _ => "its EXR is not ready".to_string(),
            };
            return Err(Status::failed_precondition(format!(
                "{} is {state} ({}/{} units): {why}",
                s.job_id, s.units_done, s.units_total
            )));
        }
        let path = self.shared.config.output_path(&s.output_name);
        let data = tokio::fs::read(&path).await.map_err(|e| {
            Status::not_found(format!("{}'s output {}: {e}", s.job_id, s.output_name))
        })?;
        let total = data.len() as u64;
        let name = s.output_name;
        let chunks: Vec<Result<pb::ResultChunk, Status>> = data
            .chunks(1 << 20)
            .map(|c| {
                Ok(pb::ResultChunk {
                    data: c.to_vec(),
                    total_bytes: total,
                    output_name: name.clone(),
                })
            })
            .collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }

    async fn upload_asset(
        &self,
        request: Request<tonic::Streaming<pb::AssetChunk>>,
    ) -> Result<Response<pb::AssetStatus>, Status> {
        let mut stream = request.into_inner();
        let mut hash: Option<String> = None;
        let mut held = None;
        while let Some(chunk) = stream.message().await? {
            match &hash {
                Some(h) if *h != chunk.sha256 => {
                    return Err(Status::invalid_argument(format!(
                        "one upload stream carries one file: {h}, then {}",
                        truncate(&chunk.sha256)
                    )))
                }
                Some(_) => {}
                None => hash = Some(chunk.sha256.clone()),
            }
            let assets = self.shared.assets.clone();
            let h = tokio::task::spawn_blocking(move || {
                assets.append(&chunk.sha256, chunk.offset, chunk.total_size, &chunk.data)
            })
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(asset_status)?;
            held = Some(h);
            if h.complete {
                break;
            }
        }
        let held = held.ok_or_else(|| Status::invalid_argument("an upload with no chunks"))?;
        Ok(Response::new(pb::AssetStatus {
            received: held.received,
            complete: held.complete,
        }))
    }

    async fn get_asset_status(
        &self,
        request: Request<pb::GetAssetStatusRequest>,
    ) -> Result<Response<pb::AssetStatus>, Status> {
        let held = self
            .shared
            .assets
            .status(&request.into_inner().sha256)
            .map_err(asset_status)?;
        Ok(Response::new(pb::AssetStatus {
            received: held.received,
            complete: held.complete,
        }))
    }
}

/// 128 bits from the operating system's random source, as hex: a worker's secret.
fn new_secret() -> Result<String, Status> {
    let mut b = [0u8; 16];
    getrandom::getrandom(&mut b)
        .map_err(|e| Status::internal(format!("no random source for a worker secret: {e}")))?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

#[tonic::async_trait]
impl Workers for Service {
    async fn register(
        &self,
        request: Request<pb::RegisterRequest>,
    ) -> Result<Response<pb::RegisterResponse>, Status> {
        let host = request
            .remote_addr()
            .map(|a| a.ip().to_string())
            .unwrap_or_default();
        let req = request.into_inner();
        if req.image_revision != IMAGE_REVISION {
            return Err(Status::failed_precondition(format!(
                "worker {:?} (tessera {}) renders image revision {}, this coordinator revision \
                 {IMAGE_REVISION}: different revisions return different bits for the same \
                 sample, so every worker of a farm must run the coordinator's revision",
                truncate(&req.name),
                truncate(&req.version),
                req.image_revision
            )));
        }
        let lease = self.shared.config.lease_timeout;
        let secret = new_secret()?;
        let mut core = self.shared.scheduler();
        core.host_may_register(&host, Instant::now())?;
        let n = core.register(
            truncate(&req.name),
            req.cores,
            truncate(&req.version),
            secret,
            Instant::now(),
        );
        if let Some(w) = core.workers.get_mut(&n) {
            w.host = host;
        }
        let credential = core
            .worker_credential(n)
            .ok_or_else(|| Status::internal("a registered worker vanished"))?;
        info!(
            "worker {} ({}, {} cores) registered",
            credential.id,
            truncate(&req.name).escape_debug(),
            req.cores
        );
        Ok(Response::new(pb::RegisterResponse {
            worker_id: credential.to_string(),
            lease_ms: lease.as_millis() as u32,
            heartbeat_ms: (lease / 4).as_millis().max(1) as u32,
        }))
    }

    async fn lease(
        &self,
        request: Request<pb::LeaseRequest>,
    ) -> Result<Response<pb::LeaseResponse>, Status> {
        let req = request.into_inner();
        let cred = credential(&req.worker_id)?;
        let max = req.max_units.clamp(1, 64) as usize;
        let deadline = Instant::now() + Duration::from_millis(req.wait_ms.min(30_000) as u64);
        let mut work = self.shared.work.subscribe();
        loop {
            work.borrow_and_update();
            let units = {
                let mut core = self.shared.scheduler();
                let now = Instant::now();
                let w = core.touch_worker(&cred, now)?;
                let granted = core.lease(w, max, now);
                let lease_ms = core.lease_time.as_millis() as u32;
                granted
                    .into_iter()
                    .filter_map(|g| {
                        let job = core.jobs.get(&g.job)?;
                        let range = job.batch_range(g.unit.batch);
                        let rect = job.tiles.get(g.unit.tile)?;
                        Some(pb::WorkUnit {
                            lease_id: g.lease.to_string(),
                            job_id: g.job.to_string(),
                            scene_hash: job.rec.scene_hash.clone(),
                            settings: Some(pb::RenderSettings::from(&job.settings())),
                            rect: Some(rect.into()),
                            tile_index: g.unit.tile,
                            batch_index: g.unit.batch,
                            sample_start: range.start,
                            sample_end: range.end,
                            lease_ms,
                        })
                    })
                    .collect::<Vec<_>>()
            };
            if !units.is_empty() {
                self.shared.bump_changed();
                return Ok(Response::new(pb::LeaseResponse { units }));
            }
            let now = Instant::now();
            if now >= deadline
                || tokio::time::timeout(deadline - now, work.changed())
                    .await
                    .is_err()
            {
                return Ok(Response::new(pb::LeaseResponse { units: Vec::new() }));
            }
        }
    }

    async fn heartbeat(
        &self,
        request: Request<pb::HeartbeatRequest>,
    ) -> Result<Response<pb::HeartbeatResponse>, Status> {
        let req = request.into_inner();
        let cred = credential(&req.worker_id)?;
        let (ids, mut revoked) = lease_ids(&req.lease_ids)?;
        let mut core = self.shared.scheduler();
        let now = Instant::now();
        let w = core.touch_worker(&cred, now)?;
        revoked.extend(core.heartbeat(w, &ids, now).iter().map(LeaseId::to_string));
        Ok(Response::new(pb::HeartbeatResponse {
            revoked,
            lease_ms: core.lease_time.as_millis() as u32,
        }))
    }

    async fn submit_result(
        &self,
        request: Request<pb::SubmitResultRequest>,
    ) -> Result<Response<pb::SubmitResultResponse>, Status> {
        let arrived = Instant::now();
        let req = request.into_inner();
        let cred = credential(&req.worker_id)?;
        let job = job_id(&req.job_id)?;
        let lease: LeaseId = req
            .lease_id
            .parse()
            .map_err(|e: tessera_proto::ids::BadId| Status::invalid_argument(e.to_string()))?;
        let unit = Unit {
            tile: req.tile_index,
            batch: req.batch_index,
        };
        let (merged, rx) = {
            let mut core = self.shared.scheduler();
            let now = Instant::now();
            let w = core.touch_worker(&cred, now)?;
            let decoded = req
                .result
                .ok_or_else(|| Status::invalid_argument("request has no result"))
                .and_then(decode_result);
            let sums = match decoded {
                Ok(s) => s,
                Err(e) => {
                    core.count_bad_result(w);
                    core.counters.results_refused += 1;
                    warn!("result from {} refused: {}", cred.id, e.message());
                    return Err(e);
                }
            };
            match core.submit(w, lease, job, unit, sums, now) {
                Ok(Merged::New { ops, finished }) => {
                    let rx = self.shared.queue_write(ops);
                    (finished, Some(rx))
                }
                Ok(Merged::Duplicate) => {
                    return Ok(Response::new(pb::SubmitResultResponse {
                        outcome: pb::ResultOutcome::Duplicate as i32,
                    }))
                }
                // Told merged, like any accepted result: a worker must not learn which of
                // its units are audited.
                Ok(Merged::Held) => (false, None),
                Ok(Merged::Discarded) => {
                    return Ok(Response::new(pb::SubmitResultResponse {
                        outcome: pb::ResultOutcome::Discarded as i32,
                    }))
                }
                Err(r) => {
                    warn!("result from {} refused: {r:?}", cred.id);
                    return Err(r.into());
                }
            }
        };
        crate::referee::spawn_pending(&self.shared);
        if let Some(rx) = rx {
            durable(rx).await.map_err(internal)?;
            self.shared.metrics.merge.observe(arrived.elapsed());
        }
        if merged {
            tokio::spawn(finish_job(self.shared.clone(), job));
        }
        self.shared.bump_changed();
        Ok(Response::new(pb::SubmitResultResponse {
            outcome: pb::ResultOutcome::Merged as i32,
        }))
    }

    async fn release_leases(
        &self,
        request: Request<pb::ReleaseLeasesRequest>,
    ) -> Result<Response<pb::ReleaseLeasesResponse>, Status> {
        let req = request.into_inner();
        let cred = credential(&req.worker_id)?;
        let (ids, _) = lease_ids(&req.lease_ids)?;
        let (released, failed) = {
            let mut core = self.shared.scheduler();
            let w = core.touch_worker(&cred, Instant::now())?;
            let failed = if req.cannot_render.is_empty() {
                None
            } else {
                let ops = core.cannot_render(w, &ids, &req.cannot_render, now_ms());
                Some(self.shared.queue_write(ops))
            };
            let n = core.release(w, &ids);
            if req.goodbye {
                if let Some(worker) = core.workers.get_mut(&w) {
                    worker.gone = true;
                }
            }
            (n, failed)
        };
        if let Some(rx) = failed {
            durable(rx).await.map_err(internal)?;
            self.shared.bump_changed();
        }
        if released > 0 {
            self.shared.bump_work();
            self.shared.bump_changed();
        }
        Ok(Response::new(pb::ReleaseLeasesResponse { released }))
    }

    async fn get_scene(
        &self,
        request: Request<pb::GetSceneRequest>,
    ) -> Result<Response<pb::GetSceneResponse>, Status> {
        let hash = request.into_inner().scene_hash;
        let store = self.shared.store.clone();
        let h = hash.clone();
        let scene = tokio::task::spawn_blocking(move || store.scene(&h))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(|e| internal(e.to_string()))?
            .ok_or_else(|| Status::not_found(format!("unknown scene {}", truncate(&hash))))?;
        Ok(Response::new(pb::GetSceneResponse {
            scene_text: scene.text,
            scene_format: if scene.json {
                pb::SceneFormat::Json
            } else {
                pb::SceneFormat::Toml
            } as i32,
            scene_name: scene.name,
            assets: scene
                .assets
                .into_iter()
                .map(|(name, sha256)| pb::AssetRef { name, sha256 })
                .collect(),
        }))
    }

    type FetchAssetStream = Stream_<pb::AssetChunk>;

    async fn fetch_asset(
        &self,
        request: Request<pb::FetchAssetRequest>,
    ) -> Result<Response<Self::FetchAssetStream>, Status> {
        let req = request.into_inner();
        let held = self
            .shared
            .assets
            .status(&req.sha256)
            .map_err(asset_status)?;
        if !held.complete {
            return Err(Status::not_found(format!(
                "asset {} is not uploaded",
                req.sha256
            )));
        }
        let (tx, rx) = mpsc::channel(2);
        let assets = self.shared.assets.clone();
        // Read a chunk at a time as the worker takes them: a file may be gigabytes.
        tokio::task::spawn_blocking(move || {
            let mut offset = req.offset;
            while offset < held.received {
                let chunk = assets
                    .read_from(&req.sha256, offset, CHUNK_BYTES as u64)
                    .map_err(asset_status)
                    .map(|data| pb::AssetChunk {
                        sha256: req.sha256.clone(),
                        offset,
                        total_size: held.received,
                        data,
                    });
                let len = chunk.as_ref().map_or(0, |c| c.data.len() as u64);
                let failed = chunk.is_err() || len == 0;
                if tx.blocking_send(chunk).is_err() || failed {
                    return;
                }
                offset += len;
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
}

/// The gRPC status for an asset store error.
fn asset_status(e: AssetError) -> Status {
    match e {
        AssetError::Invalid(m) => Status::invalid_argument(m),
        AssetError::Limit(m) => Status::resource_exhausted(m),
        AssetError::Missing(m) => Status::not_found(m),
        e @ AssetError::Io { .. } => Status::internal(e.to_string()),
    }
}

/// A job's files as name → hash: each hash well formed, each name once, at most `max`.
fn asset_names(refs: &[pb::AssetRef], max: usize) -> Result<BTreeMap<String, String>, Status> {
    if refs.len() > max {
        return Err(Status::resource_exhausted(format!(
            "the job lists {} files; at most {max}",
            refs.len()
        )));
    }
    let mut names = BTreeMap::new();
    for r in refs {
        check_hash(&r.sha256).map_err(asset_status)?;
        if r.name.is_empty() || r.name.len() > 4096 {
            return Err(Status::invalid_argument(format!(
                "a file name of {} bytes; 1 to 4096",
                r.name.len()
            )));
        }
        if names.insert(r.name.clone(), r.sha256.clone()).is_some() {
            return Err(Status::invalid_argument(format!(
                "the job lists `{}` twice",
                truncate(&r.name)
            )));
        }
    }
    Ok(names)
}
