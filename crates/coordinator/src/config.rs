//! The coordinator's settings, and the fixed bounds that are not settings.

use std::path::PathBuf;
use std::time::Duration;

use tessera_proto::Secret;
use tessera_render::scene::Limits;

use crate::auth::Tokens;

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
    /// Most work units one job may have (each frame of a frame-range job).
    pub max_units_per_job: u64,
    /// Most frames one frame-range job may have.
    pub max_frames_per_job: u64,
    /// When set, every RPC must carry `authorization: Bearer <token>`.
    pub token: Option<Secret>,
    /// When set (instead of `token`), every RPC must carry one of these tokens, and a job
    /// records the user its token names ([`crate::auth`]).
    pub tokens: Option<Tokens>,
    /// Most units the jobs of one user may have leased at once (0: no cap).
    pub max_leases_per_user: usize,
    /// When set, serve TLS only.
    pub tls: Option<ServerTls>,
    /// Refused results after which a worker is quarantined (no more leases or results).
    pub quarantine_after: u64,
    /// Failures of one job's units on one worker after which it is blocklisted for the job.
    pub blocklist_after: u32,
    /// Failures after which a frame fails, with every reason.
    pub fail_frame_after: u32,
    /// Distinct machines on which one unit's lease may lapse (each worker died or stopped
    /// answering while it held the unit) before its frame fails; 0: never.
    pub fail_unit_after_lapses: u32,
    /// How long a failed job's scene (and so its assets) is kept for `tessera retry`.
    pub retry_window: Duration,
    /// The slowest an HTTP upload may arrive, in bytes a second on average, once
    /// [`Config::upload_grace`] has passed: a trickle that holds a connection for hours is cut
    /// off (the bytes it sent are kept, and it may resume).
    pub upload_min_rate: u64,
    /// How long an HTTP upload may take before its rate is judged.
    pub upload_grace: Duration,
    /// Most HTTP uploads one user (or, without named tokens, one address) may have under way
    /// at once.
    pub max_uploads_per_user: usize,
    /// Host names the dashboard is served as, besides IP addresses and `localhost`: on a farm
    /// without a token, a request naming another host is refused (DNS rebinding).
    pub http_hosts: Vec<String>,
    /// How long an ended job's workers' log is kept (in the store; memory holds active jobs'
    /// logs only).
    pub log_retention: Duration,
    /// Most bytes of ended jobs' logs kept in all; past it the oldest go first.
    pub max_log_bytes: u64,
    /// How long an ended job's record is kept (listings, status, fetch by id); its output
    /// files stay where they were written.
    pub job_retention: Duration,
    /// Most ended jobs kept in all (a frame range counts its frames); past it the oldest go
    /// first.
    pub max_ended_jobs: usize,
    /// Most leases one worker registration may hold at once.
    pub max_leases_per_worker: usize,
    /// Most live worker registrations from one host (the address it registers from).
    pub max_workers_per_host: usize,
    /// Fraction (0 to 1) of units rendered a second time by another worker and compared bit
    /// for bit; 0 audits nothing, and jobs pay nothing for it (docs/farm.md, "Audits").
    pub audit: f64,
    /// Most client connections open at once; more wait to be accepted until one closes.
    pub max_connections: usize,
    /// A connection that sends nothing (not even an answer to a keepalive ping) for this long
    /// is closed.
    pub idle_connection: Duration,
    /// Most bytes the asset store holds (complete files and unfinished uploads' declared
    /// sizes); an upload that would pass it is refused.
    pub asset_store_bytes: u64,
    /// How long an asset file is kept after the last active job naming it ended (or after its
    /// upload, if no job has named it).
    pub asset_retention: Duration,
    /// How often merged results are made durable (a checkpoint of the tiles merged since the
    /// last one). A crash loses at most the units merged since the last checkpoint, which are
    /// rendered again; zero makes every merge durable before it is acknowledged.
    pub checkpoint_interval: Duration,
    /// Bytes of a job's whole frame of sums (52 a pixel) above which its open tiles leave
    /// memory once a checkpoint stored them, and are read back for their next batch: memory
    /// that does not grow with the frame, for a tile read per merge.
    pub evict_open_over: u64,
    /// Bytes of merged sums not yet in the store at which results are deferred (workers
    /// retry them) until a checkpoint commits: bounds the coordinator's memory when results
    /// arrive faster than its disk and CPU can store them.
    pub max_unstored_bytes: u64,
    /// Denoise the frames of jobs that ask for it, here, after their last merge (the library
    /// is loaded when the coordinator starts); off, they are lent to workers that denoise
    /// (the coordinator's `denoise` module), and wait for one.
    pub denoise: bool,
}

/// Checkpoint interval unless configured: a crash costs at most this much of the farm's time
/// in re-rendering, and the store writes each merged tile at most once in this time.
pub const DEFAULT_CHECKPOINT_INTERVAL: Duration = Duration::from_secs(5);

/// [`Config::evict_open_over`]'s default: 64 MiB of sums, a frame of about 1.3 Mpixels (1160²),
/// above which the memory of open tiles is worth a tile read per merge.
pub const DEFAULT_EVICT_OPEN_OVER: u64 = 64 << 20;

/// [`Config::max_unstored_bytes`]'s default: three early checkpoints' worth
/// ([`crate::job::MAX_DIRTY_BYTES`]), so one can be written while the next fills.
pub const DEFAULT_MAX_UNSTORED_BYTES: u64 = 3 * crate::job::MAX_DIRTY_BYTES;

/// Most live worker registrations from one host, unless configured: enough for a host running
/// many worker containers behind one address, few enough that one token holder cannot fill
/// the coordinator with registrations.
pub const DEFAULT_MAX_WORKERS_PER_HOST: usize = 256;

/// How long a lease lasts without a heartbeat, unless configured.
pub const DEFAULT_LEASE_TIMEOUT: Duration = Duration::from_secs(30);

/// The largest scene accepted, in bytes, unless configured.
pub const DEFAULT_MAX_SCENE_BYTES: usize = 32 << 20;

/// Refused results after which a worker is quarantined, unless configured.
pub const DEFAULT_QUARANTINE_AFTER: u64 = 5;

/// Failures of one job's units on one worker after which the worker is blocklisted for the job
/// (Flamenco's default).
pub const DEFAULT_BLOCKLIST_AFTER: u32 = 3;

/// Failures after which a frame fails.
pub const DEFAULT_FAIL_FRAME_AFTER: u32 = 5;

/// Distinct machines one unit's lease may lapse on before its frame fails: a unit that crashes
/// or stalls every worker that takes it stops after this many rather than going round the farm.
pub const DEFAULT_FAIL_UNIT_AFTER_LAPSES: u32 = 3;

/// How long a failed job stays retryable (its scene and assets kept), unless configured: three
/// days, so that a frame that failed on Friday night can be retried on Monday.
pub const DEFAULT_RETRY_WINDOW: Duration = Duration::from_secs(3 * 24 * 3600);

/// How long an ended job's workers' log is kept by default: two weeks.
pub const DEFAULT_LOG_RETENTION: Duration = Duration::from_secs(14 * 86_400);

/// Bytes of ended jobs' logs kept by default, in all.
pub const DEFAULT_MAX_LOG_BYTES: u64 = 256 << 20;

/// How long an ended job's record is kept by default: thirty days, past the retry window and
/// the logs' retention, so that a job's record outlives everything that hangs on it.
pub const DEFAULT_JOB_RETENTION: Duration = Duration::from_secs(30 * 86_400);

/// Ended jobs kept by default, in all: each is a record of a few hundred bytes in memory and
/// in the store, and a line in every listing.
pub const DEFAULT_MAX_ENDED_JOBS: usize = 10_000;

/// Most leases one worker registration may hold, unless configured.
pub const DEFAULT_MAX_LEASES_PER_WORKER: usize = 8;

/// Most bytes the asset store holds, unless configured.
pub const DEFAULT_ASSET_STORE_BYTES: u64 = 64 << 30;

/// How long an asset no active job uses is kept, unless configured: a day, so that the next
/// day's jobs of a shot find yesterday's meshes without uploading them again.
pub const DEFAULT_ASSET_RETENTION: Duration = Duration::from_secs(24 * 3600);

/// Most client connections open at once, unless configured.
pub const DEFAULT_MAX_CONNECTIONS: usize = 1024;

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
            lease_timeout: DEFAULT_LEASE_TIMEOUT,
            default_tile_size: tessera_render::DEFAULT_TILE,
            limits: Limits {
                max_bytes: DEFAULT_MAX_SCENE_BYTES,
                ..Limits::default()
            },
            max_message_bytes: tessera_proto::MAX_MESSAGE_BYTES,
            max_active_jobs: 1000,
            max_units_per_job: 1 << 24,
            max_frames_per_job: 10_000,
            token: None,
            tokens: None,
            max_leases_per_user: 0,
            tls: None,
            quarantine_after: DEFAULT_QUARANTINE_AFTER,
            blocklist_after: DEFAULT_BLOCKLIST_AFTER,
            fail_frame_after: DEFAULT_FAIL_FRAME_AFTER,
            fail_unit_after_lapses: DEFAULT_FAIL_UNIT_AFTER_LAPSES,
            retry_window: DEFAULT_RETRY_WINDOW,
            http_hosts: Vec::new(),
            upload_min_rate: 16 << 10,
            upload_grace: Duration::from_secs(10),
            max_uploads_per_user: 8,
            log_retention: DEFAULT_LOG_RETENTION,
            max_log_bytes: DEFAULT_MAX_LOG_BYTES,
            job_retention: DEFAULT_JOB_RETENTION,
            max_ended_jobs: DEFAULT_MAX_ENDED_JOBS,
            max_leases_per_worker: DEFAULT_MAX_LEASES_PER_WORKER,
            max_workers_per_host: DEFAULT_MAX_WORKERS_PER_HOST,
            audit: 0.0,
            max_connections: DEFAULT_MAX_CONNECTIONS,
            idle_connection: Duration::from_secs(60),
            asset_store_bytes: DEFAULT_ASSET_STORE_BYTES,
            asset_retention: DEFAULT_ASSET_RETENTION,
            checkpoint_interval: DEFAULT_CHECKPOINT_INTERVAL,
            evict_open_over: DEFAULT_EVICT_OPEN_OVER,
            max_unstored_bytes: DEFAULT_MAX_UNSTORED_BYTES,
            denoise: false,
        }
    }

    /// The tokens every call must carry one of, if any: the tokens file's, or the lone token.
    pub fn auth(&self) -> Option<Tokens> {
        self.tokens
            .clone()
            .or_else(|| self.token.as_ref().map(Tokens::one))
    }

    /// The directory finished EXRs go to.
    pub fn output_dir(&self) -> PathBuf {
        self.output_dir
            .clone()
            .unwrap_or_else(|| self.data_dir.join("output"))
    }

    /// Where finished frames wait for a worker to denoise them (`DATA_DIR/denoise`).
    pub fn kept_frames_dir(&self) -> PathBuf {
        self.data_dir.join("denoise")
    }

    /// Where the output named `name` is (or will be) written.
    pub fn output_path(&self, name: &str) -> PathBuf {
        self.output_dir().join(name)
    }
}

/// Most leases one heartbeat or release may list: a worker holds at most its pipeline's few,
/// so a longer list is a broken or hostile peer.
pub const MAX_LEASES_PER_CALL: usize = 4096;
