//! The worker's settings, and why it stops.

use std::path::PathBuf;
use std::time::Duration;

use tessera_proto::client::ClientOptions;

/// Worker settings.
#[derive(Clone, Debug)]
pub struct Config {
    /// Coordinator URL, e.g. `http://10.0.0.5:7878`.
    pub coordinator: String,
    /// Render threads (default: every core).
    pub threads: Option<usize>,
    /// Name shown in `tessera workers`.
    pub name: String,
    /// Largest gRPC message accepted, in bytes (scenes can be large).
    pub max_message_bytes: usize,
    /// Longest wait between reconnection attempts.
    pub max_backoff: Duration,
    /// How long shutdown waits for the unit in progress before handing it back.
    pub shutdown_grace: Duration,
    /// Token and TLS.
    pub client: ClientOptions,
    /// Where the files scenes name (meshes) are kept by hash, so that each is fetched once;
    /// shared safely by workers on one machine.
    pub cache_dir: PathBuf,
    /// Most bytes the cache keeps: after each new file, the least recently used others are
    /// deleted until it fits (a file a scene needs is fetched again if it was deleted).
    pub cache_bytes: u64,
    /// Operator tags (`--tag`), which jobs' `--require` match (see [`tessera_proto::tags`]).
    pub tags: Vec<String>,
    /// Memory to report, in bytes (default: what the machine, or its container's limit,
    /// allows).
    pub memory_bytes: Option<u64>,
    /// Denoise finished frames for the coordinator too (Open Image Denoise is loaded at start;
    /// without it the worker does not start).
    pub denoise: bool,
}

impl Config {
    /// Defaults for a coordinator URL.
    pub fn new(coordinator: impl Into<String>) -> Self {
        Self {
            coordinator: coordinator.into(),
            threads: None,
            name: "worker".into(),
            max_message_bytes: tessera_proto::MAX_MESSAGE_BYTES,
            max_backoff: Duration::from_secs(10),
            shutdown_grace: Duration::from_secs(30),
            client: ClientOptions::default(),
            cache_dir: std::env::temp_dir().join("tessera-assets"),
            cache_bytes: DEFAULT_CACHE_BYTES,
            tags: Vec::new(),
            memory_bytes: None,
            denoise: false,
        }
    }
}

/// Most bytes the asset cache keeps, unless configured.
pub const DEFAULT_CACHE_BYTES: u64 = 16 << 30;

/// Why the worker stopped.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// The coordinator URL is not usable (the error names it).
    #[error(transparent)]
    Url(#[from] tessera_proto::client::ClientError),
    /// `--denoise`, and the library is not there (the error says how to install it).
    #[error(transparent)]
    Denoise(#[from] tessera_denoise::DenoiseError),
    /// The render threads could not start.
    #[error("starting the render threads: {0}")]
    Threads(String),
    /// The coordinator refused this worker (wrong token, quarantined, another renderer image
    /// revision).
    #[error("the coordinator refused this worker: {0}")]
    Refused(String),
}
