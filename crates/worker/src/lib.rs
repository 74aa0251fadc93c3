//! # tessera-worker
//!
//! A render worker. It registers with a coordinator, leases work units (one tile for one batch
//! of samples), renders each on every core with rayon, and returns the partial sums.
//!
//! Three tasks form a pipeline so that the cores never wait for the network:
//! - the *fetcher* leases the next unit (and fetches its scene once, by hash) while the current
//!   one renders, holding at most one unit queued ahead;
//! - the *renderer* runs each unit through [`tessera_render::render_tile`] inside
//!   `spawn_blocking` + the worker's rayon pool (the renderer itself knows nothing of tokio);
//! - the *submitter* sends results, retrying through network errors.
//!
//! A heartbeat renews the leases held and learns which ones the coordinator revoked (cancelled
//! jobs). The gRPC channel reconnects by itself; calls that fail because the coordinator is
//! unreachable are retried with capped exponential backoff, and a worker that the coordinator
//! no longer knows (after a restart) registers again.
//!
//! The crate, by concept: [`Config`] and [`WorkerError`] (`config.rs`); what a worker keeps
//! between units, built scenes and the asset cache on disk (`cache.rs`, [`evict`]); the
//! pipeline's tasks (`pipeline.rs`); and here the state they share, registration, and [`run`].
//!
//! On shutdown (Ctrl-C, SIGTERM, or the coordinator's drain, which a heartbeat or a lease call
//! brings) the worker stops leasing, hands back at once the unit it had queued (and any granted
//! in a lease call already under way), finishes and sends the units it is rendering (units take
//! seconds at most), and says goodbye. It reports what it registers with: memory, CPU features
//! and its operator's tags, which jobs' requirements match; and sends its warnings about units
//! to the coordinator with its heartbeats (`tessera logs`).

mod cache;
mod config;
mod guides;
mod memory;
mod pipeline;

use std::collections::{HashMap, HashSet};
use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};

use tessera_proto::client::{endpoint, Bearer};
use tessera_proto::v1 as pb;
use tessera_proto::v1::workers_client::WorkersClient;
use tessera_render::scene::Scene;
use tokio::sync::watch;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::{Code, Status};
use tracing::{debug, info, warn};

pub use cache::evict;
use cache::{SceneKey, Texts, MAX_TEXTS};
pub use config::{Config, WorkerError, DEFAULT_CACHE_BYTES};
pub use pipeline::{backoff_delay, MAX_HELD_UNITS};
use pipeline::{Pipeline, Task};

/// What the tasks share.
struct Ctx {
    client: WorkersClient<InterceptedService<Channel, Bearer>>,
    config: Config,
    cores: u32,
    pool: rayon::ThreadPool,
    worker_id: RwLock<String>,
    /// Heartbeat period the coordinator asked for.
    heartbeat_ms: AtomicU64,
    /// Leases held: queued, rendering or being sent.
    held: Mutex<HashSet<String>>,
    /// Leases the coordinator no longer wants.
    revoked: Mutex<HashSet<String>>,
    /// Scenes built, by hash and frame (at most [`MAX_CACHED_SCENES`]).
    scenes: Mutex<HashMap<SceneKey, Arc<Scene>>>,
    /// Scenes this worker cannot render, by hash and frame, with the reason: fetched and
    /// refused once, not again for every unit.
    refused_scenes: Mutex<HashMap<SceneKey, String>>,
    /// Guided units' guides and structures, built once each.
    guides: Mutex<guides::Kept>,
    /// Texts of animated scenes, for building their other frames without fetching them again.
    texts: Mutex<Texts>,
    /// Held while registering, so that the tasks that all learn at once that the coordinator
    /// forgot this worker register it once, not once each.
    registering: tokio::sync::Mutex<()>,
    stop: watch::Receiver<bool>,
    /// Starts the shutdown: a signal, or the coordinator's drain.
    stop_tx: watch::Sender<bool>,
    /// Drained by the coordinator: said when registering again, so that a coordinator that
    /// restarted meanwhile leases nothing more to this worker.
    draining: std::sync::atomic::AtomicBool,
    /// Lines about units for the coordinator, sent with the next heartbeat (at most
    /// [`MAX_QUEUED_LOG_LINES`]; the oldest go first).
    log_lines: Mutex<std::collections::VecDeque<pb::WorkerLogLine>>,
    /// What it tells the coordinator it has.
    memory_bytes: u64,
    cpu_features: Vec<String>,
    /// Why the coordinator refused this worker for good, if it did.
    refused: Mutex<Option<String>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Log lines a worker keeps queued for the coordinator.
const MAX_QUEUED_LOG_LINES: usize = 64;

/// Log lines in one call (the coordinator takes at most 32).
const LOG_LINES_PER_CALL: usize = 32;

/// Errors worth retrying: the coordinator is down, restarting or overloaded.
fn transient(s: &Status) -> bool {
    matches!(
        s.code(),
        Code::Unavailable | Code::Unknown | Code::DeadlineExceeded | Code::Aborted | Code::Internal
    )
}

impl Ctx {
    fn id(&self) -> String {
        self.worker_id
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    fn stopping(&self) -> bool {
        *self.stop.borrow()
    }

    /// The coordinator drained this worker: stop as on SIGTERM (finish what is rendering,
    /// hand back what is not started, say goodbye, exit).
    fn drain(&self) {
        if !self.draining.swap(true, Ordering::Relaxed) {
            info!(
                "drained by the coordinator: finishing the units in hand, then leaving ({} held)",
                lock(&self.held).len()
            );
        }
        let _ = self.stop_tx.send(true);
    }

    /// Sleeps for a backoff step; false if shutdown began meanwhile.
    async fn backoff(&self, attempt: &mut u32) -> bool {
        let delay = backoff_delay(*attempt, self.config.max_backoff);
        *attempt += 1;
        let mut stop = self.stop.clone();
        tokio::select! {
            _ = tokio::time::sleep(delay) => !self.stopping(),
            _ = stop.wait_for(|s| *s) => false,
        }
    }

    /// Registers again after the coordinator said it does not know `stale` (it restarted),
    /// unless another task already did.
    async fn reregister(&self, stale: &str) -> bool {
        let _one = self.registering.lock().await;
        if self.id() != stale {
            return true;
        }
        self.register_locked().await
    }

    /// Registers, retrying until it works or shutdown begins. A refusal that retrying cannot
    /// fix (a wrong token, another image revision) is kept in `refused` and stops the worker.
    async fn register(&self) -> bool {
        let _one = self.registering.lock().await;
        self.register_locked().await
    }

    async fn register_locked(&self) -> bool {
        let mut attempt = 0;
        loop {
            let req = pb::RegisterRequest {
                name: self.config.name.clone(),
                cores: self.cores,
                version: env!("CARGO_PKG_VERSION").into(),
                image_revision: tessera_render::IMAGE_REVISION,
                memory_bytes: self.memory_bytes,
                cpu_features: self.cpu_features.clone(),
                tags: self.config.tags.clone(),
                draining: self.draining.load(Ordering::Relaxed),
            };
            match self.client.clone().register(req).await {
                Ok(r) => {
                    let r = r.into_inner();
                    // The id's secret half stays out of the log.
                    let public = r.worker_id.split('.').next().unwrap_or_default();
                    info!(
                        "registered with {} as {public} ({} render threads)",
                        self.config.coordinator, self.cores
                    );
                    self.heartbeat_ms
                        .store(r.heartbeat_ms.clamp(50, 60_000) as u64, Ordering::Relaxed);
                    *self.worker_id.write().unwrap_or_else(|p| p.into_inner()) = r.worker_id;
                    return true;
                }
                // A wrong token, or a renderer of another image revision: retrying cannot help.
                Err(e)
                    if matches!(
                        e.code(),
                        Code::Unauthenticated | Code::PermissionDenied | Code::FailedPrecondition
                    ) =>
                {
                    *lock(&self.refused) = Some(e.message().to_string());
                    return false;
                }
                Err(e) => {
                    if attempt == 0 || attempt % 10 == 0 {
                        warn!(
                            "{}",
                            tessera_proto::client::unreachable(&self.config.coordinator, &e)
                        );
                    }
                    if !self.backoff(&mut attempt).await {
                        return false;
                    }
                }
            }
        }
    }

    /// Queues a line about the unit of `lease` for the coordinator (`tessera logs`).
    fn log(&self, lease: &str, level: pb::LogLevel, message: String) {
        let mut q = lock(&self.log_lines);
        if q.len() >= MAX_QUEUED_LOG_LINES {
            q.pop_front();
        }
        q.push_back(pb::WorkerLogLine {
            lease_id: lease.to_string(),
            level: level as i32,
            message,
        });
    }

    /// Sends the queued lines (best effort: a line lost to a network error is only a line).
    async fn send_logs(&self) {
        let lines: Vec<pb::WorkerLogLine> = {
            let mut q = lock(&self.log_lines);
            let n = q.len().min(LOG_LINES_PER_CALL);
            q.drain(..n).collect()
        };
        if lines.is_empty() {
            return;
        }
        let req = pb::ReportLogRequest {
            worker_id: self.id(),
            lines,
        };
        if let Err(e) = self.client.clone().report_log(req).await {
            debug!("sending log lines: {}", e.message());
        }
    }

    async fn release(&self, leases: Vec<String>, goodbye: bool) {
        self.hand_back(leases, goodbye, String::new()).await;
    }

    /// Hands leases back; with a reason in `cannot_render`, their units are ones this worker
    /// will never be able to render, and the coordinator fails their jobs with it.
    async fn hand_back(&self, leases: Vec<String>, goodbye: bool, cannot_render: String) {
        if leases.is_empty() && !goodbye {
            return;
        }
        // The lines about these units go first, while their leases are still this worker's.
        self.send_logs().await;
        for l in &leases {
            lock(&self.held).remove(l);
        }
        let req = pb::ReleaseLeasesRequest {
            worker_id: self.id(),
            lease_ids: leases,
            goodbye,
            cannot_render,
        };
        if let Err(e) = self.client.clone().release_leases(req).await {
            debug!("releasing leases: {}", e.message());
        }
    }
}

/// The rayon pool units render on (kept out of `run` because the builder is not `Send`).
fn render_pool(threads: Option<usize>) -> Result<rayon::ThreadPool, WorkerError> {
    let mut pool = rayon::ThreadPoolBuilder::new().thread_name(|i| format!("render-{i}"));
    if let Some(t) = threads {
        pool = pool.num_threads(t);
    }
    pool.build()
        .map_err(|e| WorkerError::Threads(e.to_string()))
}

/// Runs a worker until `shutdown` completes (then drains as described in the crate docs).
pub async fn run(
    config: Config,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), WorkerError> {
    let endpoint = endpoint(&config.coordinator, &config.client)?;
    let client =
        WorkersClient::with_interceptor(endpoint.connect_lazy(), Bearer::new(&config.client))
            .max_decoding_message_size(config.max_message_bytes)
            .max_encoding_message_size(config.max_message_bytes);
    let pool = render_pool(config.threads)?;
    let (stop_tx, stop) = watch::channel(false);
    let memory_bytes = config.memory_bytes.unwrap_or_else(memory::available);
    let ctx = Arc::new(Ctx {
        memory_bytes,
        cpu_features: tessera_proto::tags::cpu_features(),
        draining: std::sync::atomic::AtomicBool::new(false),
        log_lines: Mutex::new(std::collections::VecDeque::new()),
        stop_tx,
        client,
        cores: pool.current_num_threads() as u32,
        pool,
        config: config.clone(),
        worker_id: RwLock::new(String::new()),
        heartbeat_ms: AtomicU64::new(2000),
        held: Mutex::new(HashSet::new()),
        revoked: Mutex::new(HashSet::new()),
        scenes: Mutex::new(HashMap::new()),
        refused_scenes: Mutex::new(HashMap::new()),
        guides: Mutex::new(guides::Kept::new(guides::MAX_KEPT)),
        texts: Mutex::new(Texts::new(MAX_TEXTS)),
        registering: tokio::sync::Mutex::new(()),
        stop,
        refused: Mutex::new(None),
    });
    let signal = ctx.clone();
    let _signal = Task::spawn(async move {
        shutdown.await;
        let _ = signal.stop_tx.send(true);
    });
    if !ctx.register().await {
        let refused = lock(&ctx.refused).take();
        return match refused {
            Some(why) => Err(WorkerError::Refused(why)),
            None => Ok(()),
        };
    }
    let Pipeline {
        heartbeat: _beat,
        mut fetch,
        mut render,
        mut submit,
    } = Pipeline::start(&ctx);
    let mut stop = ctx.stop.clone();
    // The fetcher only ends by itself when the coordinator refused us for good.
    let refused = tokio::select! {
        _ = stop.wait_for(|s| *s) => false,
        _ = fetch.join() => true,
    };
    if refused {
        let _ = ctx.stop_tx.send(true);
    } else {
        fetch.join().await;
    }
    info!("shutting down: finishing the unit in progress");
    let drained = async {
        render.join().await;
        submit.join().await;
    };
    if tokio::time::timeout(config.shutdown_grace, drained)
        .await
        .is_err()
    {
        warn!("unit in progress did not finish within the grace period; handing it back");
    }
    let left: Vec<String> = lock(&ctx.held).iter().cloned().collect();
    ctx.release(left, true).await;
    info!("worker stopped");
    let refused = lock(&ctx.refused).take();
    match refused {
        Some(why) => Err(WorkerError::Refused(why)),
        None => Ok(()),
    }
}
