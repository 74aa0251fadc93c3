//! Why the coordinator could not start, and why it refused a call.

use tonic::Status;

use crate::store::StoreError;

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
    /// The asset store cannot be opened.
    #[error(transparent)]
    Assets(#[from] crate::assets::AssetError),
    /// The task serving in-process ([`crate::server::Spawned`]) panicked or was cancelled.
    #[error("coordinator task: {0}")]
    Task(String),
    /// The dashboard could not start (its TLS identity, say).
    #[error("dashboard: {0}")]
    Http(String),
    /// The gRPC server failed.
    #[error("gRPC server: {0}")]
    Transport(#[from] tonic::transport::Error),
    /// Configured to denoise (`--denoise`), without a denoiser to run.
    #[error("--denoise: {0}")]
    Denoise(#[from] tessera_denoise::DenoiseError),
}

/// Why a state change could not be made durable. Cloned to every caller whose change was in
/// the failed commit, hence the `Arc`s.
#[derive(Clone, Debug, thiserror::Error)]
pub enum CommitError {
    /// The writer task has stopped (the coordinator is shutting down).
    #[error("state writer stopped")]
    WriterStopped,
    /// The commit's task panicked or was cancelled.
    #[error("state commit task: {0}")]
    Task(std::sync::Arc<tokio::task::JoinError>),
    /// The store refused the commit.
    #[error(transparent)]
    Store(std::sync::Arc<StoreError>),
}

/// Why the scheduler refused a call. Each kind maps to one gRPC status code, so a client can
/// tell a mistake of its own from a state it must wait out.
#[derive(Debug, PartialEq, Eq)]
pub enum Refusal {
    /// Unknown id (job, scene).
    NotFound(String),
    /// A worker credential this boot did not issue: the worker must register again
    /// ([`tessera_proto::reason::UNKNOWN_WORKER`]).
    UnknownWorker(String),
    /// Malformed or inconsistent.
    Invalid(String),
    /// Not allowed in the current state (unknown lease).
    Precondition(String),
    /// The worker is quarantined.
    Denied(String),
    /// Over a limit of the coordinator's (active jobs, units per job).
    Exhausted(String),
    /// A name that is taken (output names).
    Exists(String),
    /// Not now, for a reason that passes by itself: the caller retries.
    Unavailable(String),
    /// The coordinator failed inside (its store, a task of its own).
    Internal(String),
}

impl From<Refusal> for Status {
    fn from(r: Refusal) -> Self {
        match r {
            Refusal::NotFound(m) => Status::not_found(m),
            Refusal::UnknownWorker(m) => tessera_proto::reason::unknown_worker(m),
            Refusal::Invalid(m) => Status::invalid_argument(m),
            Refusal::Precondition(m) => Status::failed_precondition(m),
            Refusal::Denied(m) => Status::permission_denied(m),
            Refusal::Exhausted(m) => Status::resource_exhausted(m),
            Refusal::Exists(m) => Status::already_exists(m),
            Refusal::Unavailable(m) => Status::unavailable(m),
            Refusal::Internal(m) => Status::internal(m),
        }
    }
}

/// At most 64 characters of a peer-supplied string, for error messages and logs.
pub fn truncate(s: &str) -> String {
    s.chars().take(tessera_proto::MAX_ID_LEN).collect()
}
