//! `tessera.v1.Workers`: what workers call (register, lease, heartbeat, results, hand-backs,
//! and the scenes and files they render from).

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use tessera_proto::ids::{LeaseId, WorkerCredential};
use tessera_proto::v1 as pb;
use tessera_proto::v1::workers_server::Workers;
use tessera_render::IMAGE_REVISION;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status};
use tracing::info;

use super::{asset_status, credential, internal, job_id, lease_ids, Service, Stream_};
use crate::assets::CHUNK_BYTES;
use crate::error::truncate;
use crate::ingest::{ingest, Arrival, Outcome};
use crate::job::Unit;
use crate::scheduler::{Capabilities, Reported, MAX_LINES_PER_CALL};
use crate::shared::{durable, now_ms};
use tessera_proto::ids::BadId;
use tessera_proto::tags::{check_tags, MAX_CPU_FEATURES, MAX_TAGS};

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
        let bad = |what: &str, e: String| Status::invalid_argument(format!("{what}: {e}"));
        check_tags("tag", &req.tags, MAX_TAGS).map_err(|e| bad("tags", e))?;
        check_tags("CPU feature", &req.cpu_features, MAX_CPU_FEATURES)
            .map_err(|e| bad("cpu_features", e))?;
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
        core.set_host(n, host);
        core.set_capabilities(
            n,
            Capabilities {
                memory_bytes: req.memory_bytes,
                cpu_features: req.cpu_features,
                tags: req.tags.clone(),
                denoise_version: req.denoise_version.max(0),
            },
        );
        if req.draining {
            core.set_draining(n);
        }
        let credential = core
            .worker_credential(n)
            .ok_or_else(|| Status::internal("a registered worker vanished"))?;
        info!(
            "worker {} ({}, {} cores{}{}) registered",
            credential.id,
            truncate(&req.name).escape_debug(),
            req.cores,
            if req.tags.is_empty() { "" } else { ", tags " },
            req.tags.join(" ")
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
            let (units, drain) = {
                let mut core = self.shared.scheduler();
                let now = Instant::now();
                let w = core.touch_worker(&cred, now)?;
                let drain = core.draining(w);
                let granted = core.lease(w, max, now);
                let lease_ms = core.policy().lease_time.as_millis() as u32;
                let units = granted
                    .into_iter()
                    .filter_map(|g| {
                        let job = core.job(g.job)?;
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
                            guide_sha256: job
                                .guiding
                                .as_ref()
                                .and_then(|gd| gd.guide_for(g.unit.batch))
                                .map(|gd| gd.hash.clone())
                                .unwrap_or_default(),
                        })
                    })
                    .collect::<Vec<_>>();
                (units, drain)
            };
            if !units.is_empty() || drain {
                self.shared.bump_changed();
                return Ok(Response::new(pb::LeaseResponse { units, drain }));
            }
            let now = Instant::now();
            if now >= deadline
                || tokio::time::timeout(deadline - now, work.changed())
                    .await
                    .is_err()
            {
                return Ok(Response::new(pb::LeaseResponse {
                    units: Vec::new(),
                    drain: false,
                }));
            }
        }
    }

    async fn report_log(
        &self,
        request: Request<pb::ReportLogRequest>,
    ) -> Result<Response<pb::ReportLogResponse>, Status> {
        let req = request.into_inner();
        let cred = credential(&req.worker_id)?;
        if req.lines.len() > MAX_LINES_PER_CALL {
            return Err(Status::invalid_argument(format!(
                "{} log lines in one call; at most {MAX_LINES_PER_CALL}",
                req.lines.len()
            )));
        }
        let lines = req
            .lines
            .into_iter()
            .enumerate()
            .map(|(i, l)| {
                let lease: LeaseId = l.lease_id.parse().map_err(|e: BadId| {
                    Status::invalid_argument(format!("log line {}: {e}", i + 1))
                })?;
                let level = match pb::LogLevel::try_from(l.level) {
                    Ok(pb::LogLevel::Info) => "info",
                    Ok(pb::LogLevel::Error) => "error",
                    _ => "warn",
                };
                Ok(Reported {
                    lease,
                    level,
                    message: l.message,
                })
            })
            .collect::<Result<Vec<_>, Status>>()?;
        let (kept, dropped) = {
            let mut core = self.shared.scheduler();
            let now = Instant::now();
            let w = core.touch_worker(&cred, now)?;
            let (kept, dropped, ops) = core.report_log(w, lines, now, now_ms());
            if !ops.is_empty() {
                // Kept with the next checkpoint: a line is worth less than a commit of its own.
                self.shared.queue_checkpointed(ops);
            }
            (kept, dropped)
        };
        if kept > 0 {
            self.shared.bump_changed();
        }
        Ok(Response::new(pb::ReportLogResponse { kept, dropped }))
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
            drain: core.draining(w),
            revoked,
            lease_ms: core.policy().lease_time.as_millis() as u32,
        }))
    }

    async fn submit_result(
        &self,
        request: Request<pb::SubmitResultRequest>,
    ) -> Result<Response<pb::SubmitResultResponse>, Status> {
        let req = request.into_inner();
        let arrival = Arrival {
            cred: credential(&req.worker_id)?,
            job: job_id(&req.job_id)?,
            lease: req
                .lease_id
                .parse()
                .map_err(|e: BadId| Status::invalid_argument(e.to_string()))?,
            unit: Unit {
                tile: req.tile_index,
                batch: req.batch_index,
            },
            result: req.result,
        };
        let outcome = match ingest(&self.shared, arrival).await? {
            Outcome::Merged => pb::ResultOutcome::Merged,
            Outcome::Duplicate => pb::ResultOutcome::Duplicate,
            Outcome::Discarded => pb::ResultOutcome::Discarded,
        };
        Ok(Response::new(pb::SubmitResultResponse {
            outcome: outcome as i32,
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
                let ops = core.cannot_render(w, &ids, &req.cannot_render, Instant::now(), now_ms());
                Some(self.shared.queue_write(ops))
            };
            let n = core.release(w, &ids);
            if req.goodbye {
                core.goodbye(w);
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
        let req = request.into_inner();
        let cred = credential(&req.worker_id)?;
        let hash = req.scene_hash;
        {
            let mut core = self.shared.scheduler();
            let w = core.touch_worker(&cred, Instant::now())?;
            if !core
                .jobs_leased_by(w)
                .iter()
                .any(|j| j.rec.scene_hash == hash)
            {
                return Err(not_leased(&cred, "scene", &hash));
            }
        }
        let store = self.shared.store.clone();
        let h = hash.clone();
        let scene = tokio::task::spawn_blocking(move || store.scene(&h))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
            .map_err(|e| Status::internal(format!("coordinator state store: {e}")))?
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

    type DenoiseStream = Stream_<pb::DenoiseDown>;

    async fn denoise(
        &self,
        request: Request<tonic::Streaming<pb::DenoiseUp>>,
    ) -> Result<Response<Self::DenoiseStream>, Status> {
        let mut inbound = request.into_inner();
        let hello = match inbound.message().await? {
            Some(pb::DenoiseUp {
                msg: Some(pb::denoise_up::Msg::Hello(h)),
            }) => h,
            _ => {
                return Err(Status::invalid_argument(
                    "a Denoise stream opens with hello (the worker id)",
                ))
            }
        };
        // An unknown worker, or one that does not denoise, is refused by the call itself
        // rather than later on the stream, so that it learns why at once.
        let cred = credential(&hello.worker_id)?;
        let stream = {
            let mut core = self.shared.scheduler();
            let w = core.touch_worker(&cred, Instant::now())?;
            if core.worker(w).is_none_or(|x| x.caps.denoise_version <= 0) {
                return Err(Status::failed_precondition(
                    "this worker did not register as one that denoises (start it with --denoise)",
                ));
            }
            let Some(token) = core.open_denoise_stream(w) else {
                return Err(Status::resource_exhausted(
                    "this worker has a Denoise stream open already: one at a time",
                ));
            };
            (w, token)
        };
        let (tx, rx) = mpsc::channel(4);
        tokio::spawn(crate::denoise::serve(
            self.shared.clone(),
            (stream, cred, hello.wait_ms),
            inbound,
            tx,
        ));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    type FetchAssetStream = Stream_<pb::AssetChunk>;

    async fn fetch_asset(
        &self,
        request: Request<pb::FetchAssetRequest>,
    ) -> Result<Response<Self::FetchAssetStream>, Status> {
        let req = request.into_inner();
        let cred = credential(&req.worker_id)?;
        let (guide, scenes) = {
            let mut core = self.shared.scheduler();
            let w = core.touch_worker(&cred, Instant::now())?;
            // A guided job's guide, held in memory by its job (and in the store).
            let guide = core.guide_leased_by(w, &req.sha256);
            let scenes: BTreeSet<String> = core
                .jobs_leased_by(w)
                .iter()
                .map(|j| j.rec.scene_hash.clone())
                .collect();
            (guide, scenes)
        };
        if guide.is_none() && !self.scenes_name(scenes, &req.sha256).await? {
            return Err(not_leased(&cred, "file", &req.sha256));
        }
        if let Some(bytes) = guide {
            let total = bytes.len() as u64;
            let chunks: Vec<Result<pb::AssetChunk, Status>> = (req.offset.min(total)..total)
                .step_by(CHUNK_BYTES)
                .map(|at| {
                    let end = (at + CHUNK_BYTES as u64).min(total);
                    Ok(pb::AssetChunk {
                        sha256: req.sha256.clone(),
                        offset: at,
                        total_size: total,
                        data: bytes[at as usize..end as usize].to_vec(),
                    })
                })
                .collect();
            return Ok(Response::new(Box::pin(tokio_stream::iter(chunks))));
        }
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

impl Service {
    /// Whether one of the stored scenes `scenes` names file `sha256`.
    async fn scenes_name(&self, scenes: BTreeSet<String>, sha256: &str) -> Result<bool, Status> {
        let store = self.shared.store.clone();
        let sha = sha256.to_string();
        tokio::task::spawn_blocking(move || {
            for hash in scenes {
                if let Some(scene) = store.scene(&hash)? {
                    if scene.assets.iter().any(|(_, h)| *h == sha) {
                        return Ok(true);
                    }
                }
            }
            Ok(false)
        })
        .await
        .map_err(|e| Status::internal(e.to_string()))?
        .map_err(|e: crate::store::StoreError| {
            Status::internal(format!("coordinator state store: {e}"))
        })
    }
}

/// The refusal of a worker that asks for a scene or file of no job it renders.
fn not_leased(cred: &WorkerCredential, what: &str, hash: &str) -> Status {
    Status::permission_denied(format!(
        "worker {} holds no lease of a live job that reads {what} {}: a worker reads the \
         scenes and files of the jobs it renders only",
        cred.id,
        truncate(hash)
    ))
}
