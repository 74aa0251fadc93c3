//! `tessera.v1.Jobs`: what clients call (submit, status, watch, cancel, lists, fetch, and the
//! scene files' uploads).

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_proto::convert::settings_from_wire;
use tessera_proto::ids::JobId;
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_server::Jobs;
use tessera_proto::view::{LogEntryView, LogLevel, LogPage};
use tessera_render::scene::{Format, Scene, SceneCheck, Shot, FIRST_FRAME};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};
use tracing::info;

use super::{asset_status, caller, internal, job_id, may_change, Service, Stream_};
use crate::assets::{check_hash, JobAssets};
use crate::auth::Caller;
use crate::config::Config;
use crate::error::truncate;

/// Most log lines one GetLogs answer carries.
const MAX_LOG_ENTRIES: usize = 1000;
use crate::names::OutputNames;
use crate::scheduler::{add_stored, Admission, AdmissionLimits, Asked, Checked};
use crate::shared::{durable, now_ms};
use crate::store::StoredScene;
use tessera_proto::tags::{check_tags, MAX_REQUIREMENTS};

#[tonic::async_trait]
impl Jobs for Service {
    async fn submit_job(
        &self,
        request: Request<pb::SubmitJobRequest>,
    ) -> Result<Response<pb::SubmitJobResponse>, Status> {
        let caller = caller(&request);
        let mut req = request.into_inner();
        let (checked, after) = check_request(&caller, &req, &self.shared.config)?;
        // Checking a scene reads its meshes: keep it off the async threads, and few at a time.
        let _permit = self
            .parses
            .clone()
            .acquire_owned()
            .await
            .map_err(|_| Status::unavailable("the coordinator is shutting down"))?;
        // Until the job is durable (and its scene names its files), they are not collected.
        let _assets_held = self.shared.asset_gate.read().await;
        let (scene, stored) = self.check_scene(&mut req, &checked).await?;
        let frames = checked.frames;
        let spp = checked.settings.spp;
        let (id, units) = self
            .admit_job(&caller, req, checked, after, &scene, stored)
            .await?;
        let n_frames = frames.map_or(1, |r| r.len()) as u32;
        info!(
            "{id} submitted: {}×{} at {spp} spp, {n_frames} frame(s), {units} units",
            scene.width, scene.height
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
        Ok(Response::new(pb::JobStatus::from(&self.job_view(id)?)))
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
        let first = self.job_view(id)?;
        let (tx, rx) = mpsc::channel(4);
        let shared = Arc::downgrade(&self.shared);
        let mut changed = self.shared.changed.subscribe();
        tokio::spawn(async move {
            let mut msg = first;
            loop {
                let last = msg.state.is_final();
                if tx.send(Ok(pb::JobStatus::from(&msg))).await.is_err() || last {
                    return;
                }
                // Wake on a change, but no more often than every tenth of the interval.
                let _ = tokio::time::timeout(interval, changed.changed()).await;
                tokio::time::sleep(interval / 10).await;
                let Some(shared) = shared.upgrade() else {
                    return;
                };
                let Some(v) = shared.scheduler().job_view(id, Instant::now()) else {
                    return;
                };
                msg = v;
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn cancel_job(
        &self,
        request: Request<pb::CancelJobRequest>,
    ) -> Result<Response<pb::CancelJobResponse>, Status> {
        let caller = caller(&request);
        let id = job_id(&request.into_inner().job_id)?;
        let rx = {
            let mut core = self.shared.scheduler();
            may_change(&core, id, &caller, "cancel")?;
            // A frame-range job is cancelled as a whole: every frame still active.
            let Some(ops) = core.cancel(id, now_ms()) else {
                let v = core
                    .job_view(id, Instant::now())
                    .ok_or_else(|| Status::not_found(format!("unknown job {id}")))?;
                return Ok(Response::new(pb::CancelJobResponse {
                    state: pb::JobState::from(v.state) as i32,
                }));
            };
            self.shared.queue_write(ops)
        };
        durable(rx).await.map_err(internal)?;
        crate::kept::sweep(&self.shared);
        info!("{id} cancelled");
        self.shared.bump_changed();
        Ok(Response::new(pb::CancelJobResponse {
            state: pb::JobState::Cancelled as i32,
        }))
    }

    async fn retry_job(
        &self,
        request: Request<pb::RetryJobRequest>,
    ) -> Result<Response<pb::RetryJobResponse>, Status> {
        let caller = caller(&request);
        let req = request.into_inner();
        let id = job_id(&req.job_id)?;
        let (ids, rx) = {
            let mut core = self.shared.scheduler();
            may_change(&core, id, &caller, "retry")?;
            let (ids, ops) = core.retry(id, req.frame, self.shared.config.max_active_jobs)?;
            (ids, self.shared.queue_write(ops))
        };
        durable(rx).await.map_err(internal)?;
        info!(
            "{id} retried: {}",
            ids.iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        );
        self.shared.bump_changed();
        self.shared.bump_work();
        Ok(Response::new(pb::RetryJobResponse {
            job_ids: ids.iter().map(ToString::to_string).collect(),
        }))
    }

    async fn update_job(
        &self,
        request: Request<pb::UpdateJobRequest>,
    ) -> Result<Response<pb::JobStatus>, Status> {
        let caller = caller(&request);
        let req = request.into_inner();
        let id = job_id(&req.job_id)?;
        if let Some(p) = req.priority {
            caller
                .may_set_priority(p)
                .map_err(Status::permission_denied)?;
        }
        let rx = {
            let mut core = self.shared.scheduler();
            may_change(&core, id, &caller, "pause, resume or reprioritise")?;
            let ops = core.update(id, req.paused, req.priority)?;
            self.shared.queue_write(ops)
        };
        durable(rx).await.map_err(internal)?;
        if let Some(p) = req.paused {
            info!("{id} {}", if p { "paused" } else { "resumed" });
        }
        if let Some(p) = req.priority {
            info!("{id} priority {p}");
        }
        self.shared.bump_changed();
        if req.paused == Some(false) {
            // A resumed job's units wait for workers that may be long-polling already.
            self.shared.bump_work();
        }
        let core = self.shared.scheduler();
        let v = core
            .job_view(id, Instant::now())
            .ok_or_else(|| Status::not_found(format!("unknown job {id}")))?;
        Ok(Response::new(pb::JobStatus::from(&v)))
    }

    async fn list_jobs(
        &self,
        request: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::ListJobsResponse>, Status> {
        let req = request.into_inner();
        let (views, next) = self.job_page(&req.page_token, req.page_size)?;
        Ok(Response::new(pb::ListJobsResponse {
            jobs: views.iter().map(pb::JobStatus::from).collect(),
            next_page_token: next.map(|n| n.to_string()).unwrap_or_default(),
        }))
    }

    async fn list_workers(
        &self,
        _request: Request<pb::ListWorkersRequest>,
    ) -> Result<Response<pb::ListWorkersResponse>, Status> {
        let workers = self
            .worker_views()
            .iter()
            .map(pb::WorkerInfo::from)
            .collect();
        Ok(Response::new(pb::ListWorkersResponse { workers }))
    }

    async fn get_logs(
        &self,
        request: Request<pb::GetLogsRequest>,
    ) -> Result<Response<pb::GetLogsResponse>, Status> {
        let req = request.into_inner();
        let page = self.log_page(&req.job_id, req.frame, req.after).await?;
        Ok(Response::new((&page).into()))
    }

    async fn drain_worker(
        &self,
        request: Request<pb::DrainWorkerRequest>,
    ) -> Result<Response<pb::DrainWorkerResponse>, Status> {
        let who = admins_worker(&caller(&request), "drain", request.into_inner().worker)?;
        let drained = self.shared.scheduler().drain(&who, Instant::now())?;
        for id in &drained {
            info!("worker {id} draining");
        }
        // A drained worker long-polling for work hears it now, not when its poll times out.
        self.shared.bump_work();
        self.shared.bump_changed();
        Ok(Response::new(pb::DrainWorkerResponse {
            drained: drained.iter().map(ToString::to_string).collect(),
        }))
    }

    async fn release_worker(
        &self,
        request: Request<pb::ReleaseWorkerRequest>,
    ) -> Result<Response<pb::ReleaseWorkerResponse>, Status> {
        let who = admins_worker(&caller(&request), "release", request.into_inner().worker)?;
        let released = self.shared.scheduler().release_quarantine(&who)?;
        for id in &released {
            info!("worker {id} released from quarantine");
        }
        self.shared.bump_work();
        self.shared.bump_changed();
        Ok(Response::new(pb::ReleaseWorkerResponse {
            released: released.iter().map(ToString::to_string).collect(),
        }))
    }

    type FetchResultStream = Stream_<pb::ResultChunk>;

    async fn fetch_result(
        &self,
        request: Request<pb::FetchResultRequest>,
    ) -> Result<Response<Self::FetchResultStream>, Status> {
        let req = request.into_inner();
        let id = job_id(&req.job_id)?;
        let (name, data) = self.read_output(id, req.frame).await?;
        let total = data.len() as u64;
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

/// Jobs one listing page holds when the caller does not say.
pub(crate) const DEFAULT_PAGE: usize = 200;

/// Most jobs one listing page holds: a page stays far below the gRPC message limit, however
/// many jobs the coordinator keeps.
pub(crate) const MAX_PAGE: usize = 1000;

/// A submission's settings and wire fields checked, before its scene is read: what
/// [`Admission::check`] decides, and the job it waits for.
fn check_request(
    caller: &Caller,
    req: &pb::SubmitJobRequest,
    config: &Config,
) -> Result<(Checked, Option<JobId>), Status> {
    let settings = settings_from_wire(req.settings.as_ref())
        .map_err(|e| Status::invalid_argument(e.to_string()))?;
    if req.progressive && req.frames.is_none() {
        return Err(Status::invalid_argument(
            "progressive: only a frame range (--frames) is leased progressively",
        ));
    }
    if req.progressive && settings.adaptive.is_some() {
        return Err(Status::invalid_argument(
            "progressive: an adaptive job (a noise target) decides its own batches; it \
             cannot also be leased progressively",
        ));
    }
    check_tags("requirement", &req.require, MAX_REQUIREMENTS)
        .map_err(|e| Status::invalid_argument(format!("require: {e}")))?;
    caller
        .may_set_priority(req.priority)
        .map_err(Status::permission_denied)?;
    let after = match req.after.as_str() {
        "" => None,
        a => Some(
            job_id(a).map_err(|e| Status::invalid_argument(format!("after: {}", e.message())))?,
        ),
    };
    let checked = Admission::check(
        Asked {
            settings,
            tile_size: req.tile_size,
            frames: req.frames.map(|r| (r.first, r.last, r.step)),
            output_name: Some(req.output_name.clone()).filter(|n| !n.is_empty()),
        },
        config.limits.max_spp,
        config.default_tile_size,
    )?;
    Ok((checked, after))
}

impl Service {
    /// A page of job `id`'s log (of its frame `frame`, for a frame range): the lines after
    /// `after`, at most [`MAX_LOG_ENTRIES`]; what `GetLogs` and `/api/jobs/{id}/logs`
    /// answer. An ended job's lines are read from the store.
    pub(crate) async fn log_page(
        &self,
        id: &str,
        frame: Option<u32>,
        after: u64,
    ) -> Result<LogPage, Status> {
        let id = job_id(id)?;
        let mut q = self.shared.scheduler().logs(id, frame, after)?;
        if !q.stored.is_empty() {
            let store = self.shared.store.clone();
            q = tokio::task::spawn_blocking(move || {
                for (job, frame) in std::mem::take(&mut q.stored) {
                    let bytes = store
                        .log(job.0)
                        .map_err(|e| Status::internal(format!("coordinator state store: {e}")))?;
                    if let Some(b) = bytes {
                        add_stored(&mut q, job, frame, &b, after);
                    }
                }
                Ok::<_, Status>(q)
            })
            .await
            .map_err(|e| Status::internal(e.to_string()))??;
        }
        let (mut lines, dropped, ended) = (q.lines, q.dropped, q.ended);
        // A page at a time: a caller asks again after the last line's number.
        lines.truncate(MAX_LOG_ENTRIES);
        let entries = lines
            .into_iter()
            .map(|(job, frame, l)| LogEntryView {
                seq: l.seq,
                unix_ms: l.unix_ms,
                worker_id: l.worker_id,
                worker_name: l.worker_name,
                job_id: job.to_string(),
                frame,
                tile: l.tile,
                batch: l.batch,
                level: LogLevel::from_name(&l.level),
                message: l.message,
            })
            .collect();
        Ok(LogPage {
            entries,
            dropped,
            ended,
        })
    }

    /// A submission's scene, checked as `tessera render` checks it (no image decoded) over the
    /// files the job names, every one uploaded; with the scene as it is stored. Takes the
    /// request's scene text.
    async fn check_scene(
        &self,
        req: &mut pb::SubmitJobRequest,
        checked: &Checked,
    ) -> Result<(SceneCheck, StoredScene), Status> {
        let limits = self.shared.config.limits.clone();
        let json = req.scene_format == pb::SceneFormat::Json as i32;
        let name = if req.scene_name.is_empty() {
            "scene".to_string()
        } else {
            truncate(&req.scene_name)
        };
        let names = asset_names(&req.assets, limits.max_assets)?;
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
        let shot = Shot {
            frame: checked
                .frames
                .map_or(checked.settings.frame.unwrap_or(FIRST_FRAME), |r| r.first),
            resolution: checked.settings.resolution,
        };
        let gauge = self.parsing.clone();
        let assets = self.shared.assets.clone();
        let text = std::mem::take(&mut req.scene_text);
        let (scene, text, name) = tokio::task::spawn_blocking(move || {
            let now = gauge.0.fetch_add(1, Ordering::SeqCst) + 1;
            gauge.1.fetch_max(now, Ordering::SeqCst);
            let format = if json { Format::Json } else { Format::Toml };
            let files = JobAssets {
                store: &assets,
                names,
            };
            let r = Scene::text(&text, format, &name, &limits)
                .at(shot)
                .assets(&files)
                .check();
            gauge.0.fetch_sub(1, Ordering::SeqCst);
            (r, text, name)
        })
        .await
        .map_err(|e| Status::internal(e.to_string()))?;
        let scene = scene.map_err(|e| Status::invalid_argument(e.to_string()))?;
        let stored = StoredScene {
            text,
            json,
            name,
            assets: scene.files.clone(),
        };
        Ok((scene, stored))
    }

    /// Admits a checked submission and waits until it is durable; its id and units.
    async fn admit_job(
        &self,
        caller: &Caller,
        req: pb::SubmitJobRequest,
        checked: Checked,
        after: Option<JobId>,
        scene: &SceneCheck,
        stored: StoredScene,
    ) -> Result<(JobId, u64), Status> {
        let config = &self.shared.config;
        let denoise = denoise_of(req.channels.as_ref(), scene)?;
        let mut settings = checked.settings;
        if denoise.is_some() {
            tessera_denoise::gather_inputs(&mut settings);
        }
        let admission = Admission {
            scene_hash: scene.hash.clone(),
            scene: stored,
            width: scene.width,
            height: scene.height,
            settings,
            tile_size: checked.tile_size,
            output_name: checked.output_name,
            priority: req.priority,
            variance: req.channels.as_ref().is_some_and(|c| c.variance),
            sample_count: req.channels.as_ref().is_some_and(|c| c.sample_count),
            denoise,
            frames: checked.frames,
            after,
            require: req.require,
            min_memory: req.min_memory_bytes,
            progressive: req.progressive,
            guide_bounds: scene.bounds,
            submitter: caller.user.clone(),
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
                .into_iter()
                .filter_map(|m| core.job(m))
                .map(|j| j.units_total())
                .sum::<u64>();
            (id, units, self.shared.queue_write(ops))
        };
        durable(rx).await.map_err(internal)?;
        Ok((id, units))
    }
}

/// A listing page's (offset, size) from its token (empty: the first page) and asked size (0:
/// [`DEFAULT_PAGE`], at most [`MAX_PAGE`]).
pub(crate) fn list_page(token: &str, size: u32) -> Result<(usize, usize), Status> {
    let offset = if token.is_empty() {
        0
    } else {
        token.parse().map_err(|_| {
            Status::invalid_argument(format!(
                "page_token {:?} is not a token a listing gave",
                truncate(token)
            ))
        })?
    };
    let size = match size as usize {
        0 => DEFAULT_PAGE,
        n => n.min(MAX_PAGE),
    };
    Ok((offset, size))
}

/// The worker an admin's verb names (`who`: a name or a public id), or why not: workers are
/// the farm's, not one user's, so only an admin may drain or release one.
fn admins_worker(caller: &crate::auth::Caller, verb: &str, who: String) -> Result<String, Status> {
    if !caller.admin {
        return Err(Status::permission_denied(format!(
            "only an admin (a tokens-file line ending in `admin`) may {verb} workers"
        )));
    }
    if who.is_empty() || who.len() > tessera_proto::MAX_ID_LEN * 4 {
        return Err(Status::invalid_argument(
            "worker: give a worker's name or public id (tessera workers lists them)",
        ));
    }
    Ok(who)
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
        // The same rule every scene reader keeps: a client that skipped it is refused here.
        tessera_render::scene::assets::check_file_name(&r.name)
            .map_err(|e| Status::invalid_argument(format!("the job's files: {}", truncate(&e))))?;
        if names.insert(r.name.clone(), r.sha256.clone()).is_some() {
            return Err(Status::invalid_argument(format!(
                "the job lists `{}` twice",
                truncate(&r.name)
            )));
        }
    }
    Ok(names)
}

/// A submission's denoising, checked: the request's, else the scene file's (`[render]
/// denoise`, checked when it was read), with a known quality. Every coordinator takes it: one
/// started with `--denoise` denoises the frame itself, another lends it to a worker that
/// denoises ([`crate::denoise`]), and the job waits for one, saying so.
fn denoise_of(
    channels: Option<&pb::OutputChannels>,
    scene: &SceneCheck,
) -> Result<Option<crate::store::DenoiseRecord>, Status> {
    let Some(d) = channels.and_then(|c| c.denoise.as_ref()) else {
        return Ok(scene.denoise.as_ref().map(|s| crate::store::DenoiseRecord {
            quality: s.quality.clone(),
            hdr: s.hdr,
        }));
    };
    let quality = match d.quality.as_str() {
        "" => tessera_denoise::Quality::High,
        q => tessera_denoise::Quality::parse(q).ok_or_else(|| {
            Status::invalid_argument(format!(
                "channels.denoise.quality: {q:?} is not fast, balanced or high"
            ))
        })?,
    };
    Ok(Some(crate::store::DenoiseRecord {
        quality: quality.name().to_string(),
        hdr: !d.ldr,
    }))
}
