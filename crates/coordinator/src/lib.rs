//! # tessera-coordinator
//!
//! The farm's coordinator. It takes render jobs over gRPC (`tessera.v1.Jobs`), splits each
//! frame into work units (tile × sample batch), leases them to workers (`tessera.v1.Workers`)
//! with a deadline that heartbeats renew, merges returned partial sums per tile in batch order
//! (whatever order they arrive in), and writes the finished frame as OpenEXR, atomically.
//!
//! Because the renderer's partial sums are a pure function of (seed, pixel, sample index) and
//! each tile's batches are folded in index order starting from zero, the EXR is bit-identical
//! to `tessera render` with the same seed, spp and batch size, however many workers took part.
//!
//! State lives in a redb database under the data directory; every merged result is committed
//! before it is acknowledged, so a restarted coordinator resumes its jobs. Leases are not
//! stored: after a restart, units that were in flight are simply handed out again.
//!
//! [`serve`] runs the server on a listener the caller binds (port 0 in tests) until the
//! `shutdown` future completes.

use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tessera_proto::v1::jobs_server::JobsServer;
use tessera_proto::v1::workers_server::WorkersServer;
use tessera_proto::Secret;
use tessera_render::output::{render_metadata, write_new_exr, ExrChannels};
use tessera_render::scene::Limits;
use tessera_render::{assemble_frame, TileSums, IMAGE_REVISION};
use tokio::sync::{mpsc, oneshot, watch};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Certificate, Identity, ServerTlsConfig};
use tracing::{error, info, warn};

mod conn;
mod service;
pub use service::{decode_result, Service};
pub mod state;
pub mod store;

use state::{job_name, Core, Job};
use store::{JobPhase, Op, Store, StoreError};

/// Coordinator settings.
#[derive(Clone, Debug)]
pub struct Config {
    /// Where the state database lives.
    pub data_dir: PathBuf,
    /// Where finished EXRs are written (default: `data_dir/output`).
    pub output_dir: Option<PathBuf>,
    /// How long a lease lasts without a heartbeat.
    pub lease_timeout: Duration,
    /// Tile edge when a job does not choose one.
    pub default_tile_size: u32,
    /// Bounds on submitted scenes and spp.
    pub limits: Limits,
    /// Largest gRPC message accepted, in bytes.
    pub max_message_bytes: usize,
    /// Most jobs that may be active (queued or running) at once.
    pub max_active_jobs: usize,
    /// Most work units one job may have.
    pub max_units_per_job: u64,
    /// When set, every RPC must carry `authorization: Bearer <token>`.
    pub token: Option<Secret>,
    /// When set, serve TLS only.
    pub tls: Option<ServerTls>,
    /// Refused results after which a worker is quarantined (no more leases or results).
    pub quarantine_after: u64,
    /// Most leases one worker registration may hold at once.
    pub max_leases_per_worker: usize,
    /// Most client connections open at once; more wait to be accepted until one closes.
    pub max_connections: usize,
    /// A connection that sends nothing (not even an answer to a keepalive ping) for this long
    /// is closed.
    pub idle_connection: Duration,
}

/// Scenes parsed at once by submissions: parsing a large scene takes many times its size in
/// memory, so concurrent submissions of large scenes queue rather than all parse together.
pub const MAX_CONCURRENT_PARSES: usize = 2;

/// Streams one connection may have open at once.
pub const MAX_STREAMS_PER_CONNECTION: u32 = 64;

/// The coordinator's TLS identity, and optionally the CA its clients' certificates must chain to.
#[derive(Clone, Debug)]
pub struct ServerTls {
    /// PEM certificate chain.
    pub cert_pem: Vec<u8>,
    /// PEM private key.
    pub key_pem: Secret,
    /// PEM CA: when set, clients must present a certificate it signed (mutual TLS).
    pub client_ca_pem: Option<Vec<u8>>,
}

impl Config {
    /// Defaults for a data directory.
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        Self {
            data_dir: data_dir.into(),
            output_dir: None,
            lease_timeout: Duration::from_secs(30),
            default_tile_size: tessera_render::DEFAULT_TILE,
            limits: Limits {
                max_bytes: 32 << 20,
                ..Limits::default()
            },
            max_message_bytes: tessera_proto::MAX_MESSAGE_BYTES,
            max_active_jobs: 1000,
            max_units_per_job: 1 << 24,
            token: None,
            tls: None,
            quarantine_after: 5,
            max_leases_per_worker: 8,
            max_connections: 1024,
            idle_connection: Duration::from_secs(60),
        }
    }

    /// The directory finished EXRs go to.
    pub fn output_dir(&self) -> PathBuf {
        self.output_dir
            .clone()
            .unwrap_or_else(|| self.data_dir.join("output"))
    }
}

/// Why the coordinator could not start or keep running.
#[derive(Debug, thiserror::Error)]
pub enum CoordinatorError {
    /// The state store failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// A stored job could not be restored.
    #[error("state store: {0}")]
    Restore(String),
    /// The output directory cannot be created.
    #[error("output directory {path}: {source}")]
    Output {
        /// The directory.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The gRPC server failed.
    #[error("gRPC server: {0}")]
    Transport(#[from] tonic::transport::Error),
}

/// A batch of store changes and who waits for them to be durable.
struct Write {
    ops: Vec<Op>,
    done: oneshot::Sender<Result<(), String>>,
}

/// State shared by the RPC handlers and background tasks.
pub(crate) struct Shared {
    core: Mutex<Core>,
    store: Arc<Store>,
    writes: mpsc::UnboundedSender<Write>,
    /// Bumped whenever a job's status changes (watchers wake on it).
    changed: watch::Sender<u64>,
    /// Bumped whenever units become available (long-polling leases wake on it).
    work: watch::Sender<u64>,
    config: Config,
}

impl Shared {
    /// Locks the scheduling state. A panic while holding the lock is a bug; the state it left
    /// is still consistent enough to serve (every mutation is a sequence of plain assignments),
    /// so poisoning is ignored rather than turned into a crash loop.
    fn core(&self) -> MutexGuard<'_, Core> {
        self.core.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn bump_changed(&self) {
        self.changed.send_modify(|v| *v = v.wrapping_add(1));
    }

    fn bump_work(&self) {
        self.work.send_modify(|v| *v = v.wrapping_add(1));
    }

    /// Queues store changes. Called with the core lock held, so commits follow merge order.
    fn queue_write(&self, ops: Vec<Op>) -> oneshot::Receiver<Result<(), String>> {
        let (done, rx) = oneshot::channel();
        if self.writes.send(Write { ops, done }).is_err() {
            error!("state writer has stopped");
        }
        rx
    }
}

/// Waits for a queued write to be durable.
async fn durable(rx: oneshot::Receiver<Result<(), String>>) -> Result<(), String> {
    rx.await
        .map_err(|_| "state writer stopped".to_string())
        .and_then(|r| r)
}

/// Unix time in milliseconds.
pub(crate) fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

/// Commits queued writes in groups: one fsync covers every result that arrived meanwhile.
async fn writer(store: Arc<Store>, mut rx: mpsc::UnboundedReceiver<Write>) {
    while let Some(first) = rx.recv().await {
        let mut group = vec![first];
        while group.len() < 256 {
            match rx.try_recv() {
                Ok(w) => group.push(w),
                Err(_) => break,
            }
        }
        let mut ops = Vec::new();
        let mut waiters = Vec::new();
        for w in group {
            ops.extend(w.ops);
            waiters.push(w.done);
        }
        let store = store.clone();
        let result = tokio::task::spawn_blocking(move || store.apply(&ops))
            .await
            .map_err(|e| e.to_string())
            .and_then(|r| r.map_err(|e| e.to_string()));
        if let Err(e) = &result {
            error!("state commit failed: {e}");
        }
        for w in waiters {
            let _ = w.send(result.clone());
        }
    }
}

/// Writes a finished job's EXR, then records it as done (or failed).
async fn finish_job(shared: Arc<Shared>, id: u64) {
    let gathered = {
        let core = shared.core();
        core.jobs.get(&id).map(|job| {
            // Every tile has sums by now; a tile without (which would be a bug) is written
            // black rather than left out of the frame.
            let tiles: Vec<TileSums> = (0..job.tiles.len() as u32)
                .filter_map(|t| {
                    let rect = job.tiles.get(t)?;
                    Some(
                        job.acc
                            .get(&t)
                            .and_then(|a| a.sums.clone())
                            .unwrap_or_else(|| TileSums::empty(rect, 0)),
                    )
                })
                .collect();
            (job.rec.clone(), job.settings(), tiles)
        })
    };
    let Some((rec, settings, tiles)) = gathered else {
        return;
    };
    let dir = shared.config.output_dir();
    let path = dir.join(&rec.output_name);
    let written = tokio::task::spawn_blocking(move || {
        let image = assemble_frame(rec.width, rec.height, rec.spp, &tiles)
            .map_err(|e| e.to_string())?
            .finalize();
        let channels = ExrChannels {
            variance: rec.variance,
            samples: rec.sample_count,
        };
        // Never over another file: output names are unique among the coordinator's jobs, so a
        // file already there was put there by someone else, and is theirs.
        write_new_exr(
            &path,
            &image,
            channels,
            &render_metadata(&rec.scene_hash, &settings),
        )
        .map_err(|e| e.to_string())
    })
    .await
    .map_err(|e| e.to_string())
    .and_then(|r| r);
    let rx = {
        let mut core = shared.core();
        let ops = match &written {
            Ok(()) => core.end_job(id, JobPhase::Done, String::new(), now_ms()),
            Err(e) => core.end_job(
                id,
                JobPhase::Failed,
                format!("writing the EXR: {e}"),
                now_ms(),
            ),
        };
        shared.queue_write(ops)
    };
    match (&written, durable(rx).await) {
        (Ok(()), Ok(())) => info!("{} done → {}", job_name(id), dir.display()),
        (Err(e), _) => warn!("{} failed: {e}", job_name(id)),
        (_, Err(e)) => error!("{}: recording completion: {e}", job_name(id)),
    }
    shared.bump_changed();
}

/// The shared state, the writer's queue, and jobs whose units were all in at the last stop.
type Opened = (Arc<Shared>, mpsc::UnboundedReceiver<Write>, Vec<u64>);

/// Opens the store under `config.data_dir`, restores its jobs, and builds the shared state.
fn open(config: Config) -> Result<Opened, CoordinatorError> {
    let out = config.output_dir();
    std::fs::create_dir_all(&out).map_err(|source| CoordinatorError::Output {
        path: out.display().to_string(),
        source,
    })?;
    let store = Arc::new(Store::open(&config.data_dir)?);
    let epoch = store.next_epoch()?;
    let mut core = Core::new(epoch, config.lease_timeout);
    core.quarantine_after = config.quarantine_after.max(1);
    core.max_leases_per_worker = config.max_leases_per_worker.max(1);
    let mut to_finish = Vec::new();
    // Start-up changes to job records, written in one transaction.
    let mut ops = Vec::new();
    let mut failing = Vec::new();
    for loaded in store.load()? {
        let id = loaded.record.id;
        let mut job = Job::restore(loaded)
            .map_err(|e| CoordinatorError::Restore(format!("{}: {e}", job_name(id))))?;
        let mut stale = None;
        if job.rec.phase == JobPhase::Active && job.units_done == job.units_total() {
            job.finishing = true;
            to_finish.push(id);
        } else if job.rec.phase == JobPhase::Active && job.rec.image_revision != IMAGE_REVISION {
            // Accepted by a coordinator of another renderer revision. Its merged sums are that
            // revision's bits; adding this revision's would give an image neither renders.
            if job.started {
                stale = Some(format!(
                    "rendered in part by renderer image revision {}, and this coordinator \
                     renders revision {IMAGE_REVISION}: its results cannot be mixed; resubmit \
                     the job",
                    job.rec.image_revision
                ));
            } else {
                job.rec.image_revision = IMAGE_REVISION;
                ops.push(Op::PutJob(job.rec.clone()));
            }
        }
        core.next_job = core.next_job.max(id + 1);
        core.jobs.insert(id, job);
        if let Some(why) = stale {
            failing.push((id, why));
        }
    }
    // Failed once every job is in, so that a scene another job still needs is kept.
    for (id, why) in failing {
        warn!("{}: {why}", job_name(id));
        ops.extend(core.end_job(id, JobPhase::Failed, why, now_ms()));
    }
    // Scenes that no live job needs (left by a coordinator that kept them all) go.
    for hash in store.scene_hashes()? {
        let live = core
            .jobs
            .values()
            .any(|j| j.rec.phase == JobPhase::Active && j.rec.scene_hash == hash);
        if !live {
            ops.push(Op::DropScene(hash));
        }
    }
    if !ops.is_empty() {
        store.apply(&ops)?;
    }
    let active = core
        .jobs
        .values()
        .filter(|j| j.rec.phase == JobPhase::Active)
        .count();
    info!(
        "state at {}: boot {epoch}, {} jobs ({active} active)",
        config.data_dir.display(),
        core.jobs.len()
    );
    let (writes, rx) = mpsc::unbounded_channel();
    let shared = Arc::new(Shared {
        core: Mutex::new(core),
        store,
        writes,
        changed: watch::channel(0).0,
        work: watch::channel(0).0,
        config,
    });
    Ok((shared, rx, to_finish))
}

/// Runs the coordinator on `listener` until `shutdown` completes. Returns once in-flight
/// requests have drained and queued state writes are durable.
pub async fn serve(
    config: Config,
    listener: tokio::net::TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), CoordinatorError> {
    serve_when_ready(config, listener, shutdown, || {}).await
}

/// [`serve`], calling `ready` once the TLS identity is loaded and the store is open and
/// restored: the moment to tell a person or a script that the coordinator is up. Any error
/// before that (a bad key, a damaged store) comes back instead, and `ready` is not called.
pub async fn serve_when_ready(
    config: Config,
    listener: tokio::net::TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
    ready: impl FnOnce(),
) -> Result<(), CoordinatorError> {
    let max_msg = config.max_message_bytes;
    let lease_timeout = config.lease_timeout;
    let auth = AuthCheck::new(config.token.as_ref());
    let mut builder = tonic::transport::Server::builder()
        // A connection that sends nothing is closed rather than kept for ever, and one
        // connection cannot open unbounded streams.
        .http2_keepalive_interval(Some(Duration::from_secs(30)))
        .http2_keepalive_timeout(Some(Duration::from_secs(20)))
        .max_concurrent_streams(Some(MAX_STREAMS_PER_CONNECTION));
    if let Some(tls) = &config.tls {
        let mut cfg = ServerTlsConfig::new()
            .identity(Identity::from_pem(&tls.cert_pem, tls.key_pem.expose()));
        if let Some(ca) = &tls.client_ca_pem {
            cfg = cfg.client_ca_root(Certificate::from_pem(ca));
        }
        builder = builder.tls_config(cfg)?;
    }
    let (max_connections, idle) = (config.max_connections, config.idle_connection);
    let (shared, rx, to_finish) = open(config)?;
    let writer = tokio::spawn(writer(shared.store.clone(), rx));
    for id in to_finish {
        tokio::spawn(finish_job(shared.clone(), id));
    }
    // Lapsed leases are noticed here as well as on each lease call, so that a long-polling
    // worker wakes up for a unit whose holder died.
    let ticker = {
        let shared = Arc::downgrade(&shared);
        let period = (lease_timeout / 8).clamp(Duration::from_millis(50), Duration::from_secs(1));
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            loop {
                tick.tick().await;
                let Some(shared) = shared.upgrade() else {
                    return;
                };
                let any = shared.core().expire(std::time::Instant::now());
                if any {
                    shared.bump_work();
                }
            }
        })
    };
    let svc = service::Service {
        shared: shared.clone(),
        parses: Arc::new(tokio::sync::Semaphore::new(MAX_CONCURRENT_PARSES)),
        parsing: Arc::default(),
    };
    let incoming = conn::Limited::new(listener, max_connections, idle);
    ready();
    let result = builder
        .add_service(InterceptedService::new(
            JobsServer::new(svc.clone())
                .max_decoding_message_size(max_msg)
                .max_encoding_message_size(max_msg),
            auth.clone(),
        ))
        .add_service(InterceptedService::new(
            WorkersServer::new(svc)
                .max_decoding_message_size(max_msg)
                .max_encoding_message_size(max_msg),
            auth,
        ))
        .serve_with_incoming_shutdown(incoming, shutdown)
        .await;
    ticker.abort();
    drop(shared);
    // The writer ends when the last sender (inside Shared) is gone; give stragglers (watch
    // streams finishing their last message) a moment, then stop waiting.
    let _ = tokio::time::timeout(Duration::from_secs(5), writer).await;
    result?;
    Ok(())
}

/// Both services over a store, with no network, transport or auth in between: what
/// [`serve`] runs, for driving sequences of calls in-process (the `rpc_surface` fuzz target).
/// Made inside a tokio runtime, which runs its state writer.
#[doc(hidden)]
pub struct InProcess {
    service: Service,
    writer: tokio::task::JoinHandle<()>,
}

impl InProcess {
    /// Opens the store under `config.data_dir` and restores its jobs, as [`serve`] does.
    pub fn open(config: Config) -> Result<Self, CoordinatorError> {
        let (shared, rx, to_finish) = open(config)?;
        let writer = tokio::spawn(writer(shared.store.clone(), rx));
        for id in to_finish {
            tokio::spawn(finish_job(shared.clone(), id));
        }
        let service = Service {
            shared,
            parses: Arc::new(tokio::sync::Semaphore::new(MAX_CONCURRENT_PARSES)),
            parsing: Arc::default(),
        };
        Ok(Self { service, writer })
    }

    /// The `Jobs` and `Workers` services.
    pub fn service(&self) -> &Service {
        &self.service
    }

    /// The most scene parses that have run at once.
    pub fn peak_parses(&self) -> usize {
        self.service
            .parsing
            .1
            .load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Lapses overdue leases, as the server's ticker does.
    pub fn expire(&self) {
        if self.service.shared.core().expire(std::time::Instant::now()) {
            self.service.shared.bump_work();
        }
    }

    /// Stops, once every queued write is durable and the store is closed.
    pub async fn close(self) {
        drop(self.service);
        let _ = self.writer.await;
    }
}

/// Checks the bearer token of every call, in constant time: both sides are hashed first, so
/// neither the comparison's time nor its length depends on how much of the token matched.
#[derive(Clone)]
struct AuthCheck(Option<[u8; 32]>);

impl AuthCheck {
    fn new(token: Option<&Secret>) -> Self {
        Self(token.map(|t| sha256(t.expose().as_bytes())))
    }
}

fn sha256(b: &[u8]) -> [u8; 32] {
    use sha2::Digest;
    sha2::Sha256::digest(b).into()
}

impl tonic::service::Interceptor for AuthCheck {
    fn call(&mut self, request: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        use subtle::ConstantTimeEq;
        let Some(want) = &self.0 else {
            return Ok(request);
        };
        let presented = request
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        match presented {
            None => Err(tonic::Status::unauthenticated(
                "this coordinator requires a token (--token-file or TESSERA_TOKEN)",
            )),
            Some(t) if bool::from(sha256(t.as_bytes()).ct_eq(want)) => Ok(request),
            Some(_) => Err(tonic::Status::unauthenticated("wrong token")),
        }
    }
}

/// Whether `name` is the default output name of some job (`job-NNNNNN.exr`): such names are
/// kept for the jobs they name, so that nobody can take a later job's name in advance.
pub(crate) fn is_default_output_name(name: &str) -> bool {
    name.strip_suffix(".exr")
        .and_then(state::parse_job)
        .is_some()
}

/// Whether `name` is an acceptable output file name.
pub(crate) fn check_output_name(name: &str) -> Result<(), String> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name.ends_with(".exr")
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'.' || b == b'_' || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(format!(
            "output name {:?} must be 1–128 letters, digits, '.', '_' or '-', not start with '.', and end in \".exr\"",
            state::truncate(name)
        ))
    }
}

/// The EXR path of a job, if it is done.
pub(crate) fn output_path(config: &Config, name: &str) -> PathBuf {
    Path::new(&config.output_dir()).join(name)
}
