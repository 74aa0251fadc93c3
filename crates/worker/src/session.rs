//! The worker's session with its coordinator: the connection, the id it registered under
//! (registering again when the coordinator forgets it), the leases it holds and those revoked,
//! the lines it reports, and the shutdown signal every task watches. What the pipeline's tasks
//! share besides (scenes, guides, the render pool) is theirs ([`crate::pipeline::Worker`]).

use std::collections::HashSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, RwLock};
use std::time::Duration;

use tessera_proto::client::Bearer;
use tessera_proto::v1 as pb;
use tessera_proto::v1::workers_client::WorkersClient;
use tokio::sync::watch;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::{Code, Status};
use tracing::{debug, info, warn};

use crate::config::Config;

/// The worker's side of its session with the coordinator.
pub(crate) struct Session {
    pub(crate) client: WorkersClient<InterceptedService<Channel, Bearer>>,
    pub(crate) config: Config,
    pub(crate) cores: u32,
    pub(crate) worker_id: RwLock<String>,
    /// Heartbeat period the coordinator asked for.
    pub(crate) heartbeat_ms: AtomicU64,
    /// Leases held: queued, rendering or being sent.
    pub(crate) held: Mutex<HashSet<String>>,
    /// Leases the coordinator no longer wants.
    pub(crate) revoked: Mutex<HashSet<String>>,
    /// Held while registering, so that the tasks that all learn at once that the coordinator
    /// forgot this worker register it once, not once each.
    pub(crate) registering: tokio::sync::Mutex<()>,
    pub(crate) stop: watch::Receiver<bool>,
    /// Starts the shutdown: a signal, or the coordinator's drain.
    pub(crate) stop_tx: watch::Sender<bool>,
    /// Drained by the coordinator: said when registering again, so that a coordinator that
    /// restarted meanwhile leases nothing more to this worker.
    pub(crate) draining: std::sync::atomic::AtomicBool,
    /// Lines about units for the coordinator, sent with the next heartbeat (at most
    /// [`MAX_QUEUED_LOG_LINES`]; the oldest go first).
    pub(crate) log_lines: Mutex<std::collections::VecDeque<pb::WorkerLogLine>>,
    /// What it tells the coordinator it has.
    pub(crate) memory_bytes: u64,
    pub(crate) cpu_features: Vec<String>,
    /// The Open Image Denoise version it loaded (0: it does not denoise).
    pub(crate) denoise_version: i32,
    /// Why the coordinator refused this worker for good, if it did.
    pub(crate) refused: Mutex<Option<String>>,
}

impl Session {
    /// A session over `client`, not registered yet; `stop`, from `stop_tx`, ends it.
    pub(crate) fn new(
        client: WorkersClient<InterceptedService<Channel, Bearer>>,
        config: Config,
        cores: u32,
        (memory_bytes, denoise_version): (u64, i32),
        (stop_tx, stop): (watch::Sender<bool>, watch::Receiver<bool>),
    ) -> Self {
        Self {
            client,
            config,
            cores,
            worker_id: RwLock::new(String::new()),
            heartbeat_ms: AtomicU64::new(2000),
            held: Mutex::new(HashSet::new()),
            revoked: Mutex::new(HashSet::new()),
            registering: tokio::sync::Mutex::new(()),
            stop,
            stop_tx,
            draining: AtomicBool::new(false),
            log_lines: Mutex::new(std::collections::VecDeque::new()),
            memory_bytes,
            cpu_features: tessera_proto::tags::cpu_features(),
            denoise_version,
            refused: Mutex::new(None),
        }
    }
}

pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Log lines a worker keeps queued for the coordinator.
const MAX_QUEUED_LOG_LINES: usize = 64;

/// Log lines in one call (the coordinator takes at most 32).
const LOG_LINES_PER_CALL: usize = 32;

/// Errors worth retrying: the coordinator is down, restarting or overloaded.
pub(crate) fn transient(s: &Status) -> bool {
    matches!(
        s.code(),
        Code::Unavailable | Code::Unknown | Code::DeadlineExceeded | Code::Aborted | Code::Internal
    )
}

impl Session {
    pub(crate) fn id(&self) -> String {
        self.worker_id
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    pub(crate) fn stopping(&self) -> bool {
        *self.stop.borrow()
    }

    /// The coordinator drained this worker: stop as on SIGTERM (finish what is rendering,
    /// hand back what is not started, say goodbye, exit).
    pub(crate) fn drain(&self) {
        if !self.draining.swap(true, Ordering::Relaxed) {
            info!(
                "drained by the coordinator: finishing the units in hand, then leaving ({} held)",
                lock(&self.held).len()
            );
        }
        let _ = self.stop_tx.send(true);
    }

    /// Sleeps for a backoff step; false if shutdown began meanwhile.
    pub(crate) async fn backoff(&self, attempt: &mut u32) -> bool {
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
    pub(crate) async fn reregister(&self, stale: &str) -> bool {
        let _one = self.registering.lock().await;
        if self.id() != stale {
            return true;
        }
        self.register_locked().await
    }

    /// Registers, retrying until it works or shutdown begins. A refusal that retrying cannot
    /// fix (a wrong token, another image revision) is kept in `refused` and stops the worker.
    pub(crate) async fn register(&self) -> bool {
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
                denoise_version: self.denoise_version,
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
    pub(crate) fn log(&self, lease: &str, level: pb::LogLevel, message: String) {
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
    pub(crate) async fn send_logs(&self) {
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

    pub(crate) async fn release(&self, leases: Vec<String>, goodbye: bool) {
        self.hand_back(leases, goodbye, String::new()).await;
    }

    /// Hands leases back; with a reason in `cannot_render`, their units are ones this worker
    /// will never be able to render, and the coordinator fails their jobs with it.
    pub(crate) async fn hand_back(
        &self,
        leases: Vec<String>,
        goodbye: bool,
        cannot_render: String,
    ) {
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

/// The wait before retry number `attempt` (from 0) of a call the coordinator did not answer:
/// 100 ms, doubling, never above `max`. Every retry loop of the worker waits this long, so a
/// farm of workers whose coordinator restarts reconnects quickly without hammering it.
pub fn backoff_delay(attempt: u32, max: Duration) -> Duration {
    Duration::from_millis(100u64 << attempt.min(10)).min(max)
}
