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
//! State lives in a redb database under the data directory. Merged results are committed at
//! checkpoints (every few seconds, each tile merged since the last written once), changes a
//! reply waits on at once, so a restarted coordinator resumes its jobs from the last commit and
//! renders again at most the units merged after it. Leases are not stored: after a restart,
//! units that were in flight are simply handed out again. A tile's sums stay in memory only
//! while results still merge into it.
//!
//! [`serve`] runs the server on a listener the caller binds (port 0 in tests) until the
//! `shutdown` future completes.
//!
//! The crate, by concept, lowest first:
//! - [`config`]: settings and fixed bounds; [`error`]: why it stops or refuses a call;
//!   [`auth`]: the tokens and the users they name.
//! - [`store`]: the redb store, checksummed; the only durable state.
//! - [`job`]: a job's tiles, accumulators and the in-order merge.
//! - [`scheduler`]: workers, leases, queues, speculation, quarantine and admission.
//! - [`output`]: output names, and the EXR written when a job's last unit is in.
//! - `shared` (the scheduler behind its lock, and the commit writer), `ingest` (a worker's
//!   result from its arrival to its merge), `kept` (finished frames kept for a denoising
//!   worker) and `denoise` (the stream that lends them), `service` (the gRPC handlers, which parse the
//!   wire into typed values and call the scheduler or `ingest`), `conn`
//!   (connection limits) and [`server`] (TLS, auth, wiring: [`serve`]).
//! - [`metrics`] (timings and the Prometheus text) and `http` (the dashboard and `/metrics`,
//!   served when [`Listeners::http`] is given: `tessera coordinator --http ADDR`).

mod conn;
mod denoise;
mod http;
mod ingest;
mod kept;
mod referee;
mod service;
mod shared;

pub mod assets;
pub mod auth;
pub mod config;
pub mod error;
pub mod job;
pub mod metrics;
pub mod names;
pub mod output;
pub mod scheduler;
pub mod server;
pub mod store;

pub use auth::Tokens;
pub use config::{Config, ServerTls, MAX_CONCURRENT_PARSES, MAX_STREAMS_PER_CONNECTION};
pub use error::CoordinatorError;
pub use server::{serve, serve_when_ready, InProcess, Listeners, Spawned};
pub use service::{decode_result, Service};
