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
//! between units, built scenes and the asset cache on disk (`cache.rs`, [`evict`]), and guided
//! units' guides (`guide_cache.rs`); the session with the coordinator: registration, leases held,
//! log lines, the shutdown signal (`session.rs`); the pipeline's tasks and what they share
//! (`pipeline.rs`); and here [`run`].
//!
//! On shutdown (Ctrl-C, SIGTERM, or the coordinator's drain, which a heartbeat or a lease call
//! brings) the worker stops leasing, hands back at once the unit it had queued (and any granted
//! in a lease call already under way), finishes and sends the units it is rendering (units take
//! seconds at most), and says goodbye. It reports what it registers with: memory, CPU features
//! and its operator's tags, which jobs' requirements match; and sends its warnings about units
//! to the coordinator with its heartbeats (`tessera logs`).
//!
//! Started with `--denoise` ([`Config::denoise`]), it loads Open Image Denoise first and also
//! denoises finished frames the coordinator lends it, one at a time beside its rendering
//! (`denoise.rs`).

mod cache;
mod config;
mod denoise;
mod guide_cache;
mod memory;
mod pipeline;
mod session;

use std::future::Future;
use std::sync::Arc;

use tessera_proto::client::{endpoint, Bearer};
use tessera_proto::v1::workers_client::WorkersClient;
use tokio::sync::watch;
use tracing::{info, warn};

pub use cache::evict;
pub use config::{Config, WorkerError, DEFAULT_CACHE_BYTES};
pub use pipeline::MAX_HELD_UNITS;
use pipeline::{Pipeline, Task, Worker};
pub use session::backoff_delay;
use session::{lock, Session};

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
    let memory_bytes = config.memory_bytes.unwrap_or_else(memory::available);
    // Loaded before registering: a worker that says it denoises can.
    let denoise_version = if config.denoise {
        tessera_denoise::library_version()?
    } else {
        0
    };
    let session = Session::new(
        client,
        config.clone(),
        pool.current_num_threads() as u32,
        (memory_bytes, denoise_version),
        watch::channel(false),
    );
    let worker = Arc::new(Worker::new(session, pool));
    let session = worker.session();
    let signal = worker.clone();
    let _signal = Task::spawn(async move {
        shutdown.await;
        let _ = signal.session().stop_tx.send(true);
    });
    if !session.register().await {
        let refused = lock(&session.refused).take();
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
    } = Pipeline::start(&worker);
    let _denoise = config
        .denoise
        .then(|| Task::spawn(denoise::run(worker.clone())));
    let mut stop = session.stop.clone();
    // The fetcher only ends by itself when the coordinator refused us for good.
    let refused = tokio::select! {
        _ = stop.wait_for(|s| *s) => false,
        _ = fetch.join() => true,
    };
    if refused {
        let _ = session.stop_tx.send(true);
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
    let left: Vec<String> = lock(&session.held).iter().cloned().collect();
    session.release(left, true).await;
    info!("worker stopped");
    let refused = lock(&session.refused).take();
    match refused {
        Some(why) => Err(WorkerError::Refused(why)),
        None => Ok(()),
    }
}
