//! The state every handler and background task shares: the scheduler behind one mutex, the
//! store, and the commit writer that makes changes durable in the order they were made: at
//! once for the changes a reply waits on (a job's admission, its end), and at the next
//! checkpoint for merged results, so that the store's write rate is bounded by the checkpoint
//! interval rather than by the farm's speed (docs/reliability.md states the bound on what a
//! crash costs).

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{SystemTime, UNIX_EPOCH};

use tokio::sync::{mpsc, oneshot, watch};
use tracing::{debug, error, info};

use crate::assets::{AssetStore, Collected};
use crate::config::Config;
use crate::error::{CommitError, CoordinatorError};
use crate::metrics::Metrics;
use crate::scheduler::{Policy, Scheduler};
use crate::store::{Coalesced, JobPhase, Op, Store};
use tessera_proto::ids::JobId;

/// A batch of store changes and who waits for them to be durable (no one: the next
/// checkpoint makes them so).
pub(crate) struct Write {
    ops: Vec<Op>,
    done: Option<oneshot::Sender<Result<(), CommitError>>>,
    /// Commit now rather than at the interval: the tiles merged since the last checkpoint
    /// have reached their memory budget.
    now: bool,
}

/// State shared by the RPC handlers and background tasks.
pub(crate) struct Shared {
    scheduler: Mutex<Scheduler>,
    pub(crate) store: Arc<Store>,
    /// The files scenes name, by hash.
    pub(crate) assets: Arc<AssetStore>,
    writes: mpsc::UnboundedSender<Write>,
    /// Bumped whenever a job's status changes (watchers wake on it).
    pub(crate) changed: watch::Sender<u64>,
    /// Bumped whenever units become available (long-polling leases wake on it).
    pub(crate) work: watch::Sender<u64>,
    pub(crate) config: Config,
    /// Timings recorded outside the scheduler's lock (the writer holds it too).
    pub(crate) metrics: Arc<Metrics>,
    /// Held (shared) by each submission from its check that the scene's files are uploaded
    /// until its job is durable, and (alone) by the asset collection, which could otherwise
    /// delete a file between a submission's check and its job's admission.
    pub(crate) asset_gate: tokio::sync::RwLock<()>,
    /// Held while a finished job's frame is assembled and written: one at a time, since a
    /// frame's image and its EXR encoding take memory in proportion to its pixels, and jobs
    /// that finish together must not add theirs up.
    pub(crate) finishing: tokio::sync::Semaphore,
}

/// The shared state, the writer's queue, and jobs whose units were all in at the last stop.
pub(crate) type Opened = (Arc<Shared>, mpsc::UnboundedReceiver<Write>, Vec<JobId>);

impl Shared {
    /// Opens the store under `config.data_dir`, restores its jobs, and builds the shared state.
    pub(crate) fn open(config: Config) -> Result<Opened, CoordinatorError> {
        // The store first: it makes the data directory private, and the output directory
        // (inside it by default) must not create it first with the umask's mode.
        let store = Arc::new(Store::open(&config.data_dir)?);
        let out = config.output_dir();
        std::fs::create_dir_all(&out).map_err(|source| CoordinatorError::Output {
            path: out.display().to_string(),
            source,
        })?;
        let assets = Arc::new(AssetStore::open(
            &config.data_dir,
            config.limits.max_asset_bytes,
            config.asset_store_bytes,
        )?);
        // Frames kept for denoising workers are gathered again from the store by the jobs
        // restored as finishing; what a crash left is stale.
        let _ = std::fs::remove_dir_all(config.kept_frames_dir());
        let epoch = store.next_epoch()?;
        let mut scheduler = Scheduler::new(
            epoch,
            Policy {
                lease_time: config.lease_timeout,
                quarantine_after: config.quarantine_after.max(1),
                max_leases_per_worker: config.max_leases_per_worker.max(1),
                max_workers_per_host: config.max_workers_per_host.max(1),
                audit: if config.audit.is_finite() {
                    config.audit.clamp(0.0, 1.0)
                } else {
                    0.0
                },
                evict_open_over: config.evict_open_over,
                max_unstored_bytes: config.max_unstored_bytes.max(1),
                blocklist_after: config.blocklist_after.max(1),
                fail_frame_after: config.fail_frame_after.max(1),
                fail_unit_after_lapses: config.fail_unit_after_lapses,
                retry_window: config.retry_window,
                max_leases_per_user: config.max_leases_per_user,
                log_retention: config.log_retention,
                max_log_bytes: config.max_log_bytes,
                job_retention: config.job_retention,
                max_ended_jobs: config.max_ended_jobs,
            },
        );
        let mut seed = [0u8; 8];
        // Without a random source the audit still runs, on a sequence a worker could
        // reproduce only by knowing the boot number and this code.
        if getrandom::getrandom(&mut seed).is_ok() {
            scheduler.seed_audits(u64::from_le_bytes(seed));
        }
        let (ops, to_finish) = scheduler
            .restore(store.load()?, store.scene_hashes()?, now_ms())
            .map_err(CoordinatorError::Restore)?;
        if !ops.is_empty() {
            store.apply(&ops)?;
        }
        let evicted = scheduler.evict_restored();
        let active = scheduler
            .jobs()
            .filter(|j| j.rec.phase == JobPhase::Active)
            .count();
        info!(
            "state at {}: boot {epoch}, {} jobs ({active} active)",
            config.data_dir.display(),
            scheduler.jobs().count()
        );
        let (writes, rx) = mpsc::unbounded_channel();
        let shared = Arc::new(Shared {
            scheduler: Mutex::new(scheduler),
            store,
            assets,
            writes,
            changed: watch::channel(0).0,
            work: watch::channel(0).0,
            config,
            metrics: Arc::new(Metrics {
                evicted_bytes: evicted.into(),
                ..Metrics::default()
            }),
            asset_gate: tokio::sync::RwLock::new(()),
            finishing: tokio::sync::Semaphore::new(1),
        });
        Ok((shared, rx, to_finish))
    }

    /// Locks the scheduling state. A panic while holding the lock is a bug; the state it left
    /// is still consistent enough to serve (every mutation is a sequence of plain assignments),
    /// so poisoning is ignored rather than turned into a crash loop.
    pub(crate) fn scheduler(&self) -> MutexGuard<'_, Scheduler> {
        self.scheduler.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Wakes status watchers.
    pub(crate) fn bump_changed(&self) {
        self.changed.send_modify(|v| *v = v.wrapping_add(1));
    }

    /// Wakes workers waiting for units.
    pub(crate) fn bump_work(&self) {
        self.work.send_modify(|v| *v = v.wrapping_add(1));
    }

    /// Queues store changes to be durable now: they and every change queued before them are
    /// committed at once. Called with the scheduler's lock held, so commits follow merge order.
    pub(crate) fn queue_write(&self, ops: Vec<Op>) -> oneshot::Receiver<Result<(), CommitError>> {
        let (done, rx) = oneshot::channel();
        self.send_write(Write {
            ops,
            done: Some(done),
            now: false,
        });
        rx
    }

    /// Makes every change so far durable, the tiles merged since the last checkpoint with
    /// them: what a clean stop does last.
    pub(crate) async fn flush(&self) -> Result<(), CommitError> {
        durable(self.queue_write(Vec::new())).await
    }

    /// Queues store changes for the next checkpoint: what a merged result costs the store.
    /// Called with the scheduler's lock held, like [`queue_write`](Self::queue_write).
    pub(crate) fn queue_checkpointed(&self, ops: Vec<Op>) {
        self.send_write(Write {
            ops,
            done: None,
            now: false,
        });
    }

    /// Asks for a checkpoint before the interval is up
    /// ([`Scheduler::wants_checkpoint`](crate::scheduler::Scheduler::wants_checkpoint)).
    pub(crate) fn request_checkpoint(&self) {
        self.send_write(Write {
            ops: Vec::new(),
            done: None,
            now: true,
        });
    }

    fn send_write(&self, w: Write) {
        if self.writes.send(w).is_err() {
            error!("state writer has stopped");
        }
    }

    /// Deletes the asset files that no stored scene names (the stored scenes are the active
    /// jobs') and that have not been used for `config.asset_retention`. `None` when a
    /// submission is in progress: the next collection gets them. Blocking (disk and store).
    pub(crate) fn collect_assets(&self) -> Result<Option<Collected>, CoordinatorError> {
        let Ok(_gate) = self.asset_gate.try_write() else {
            return Ok(None);
        };
        let mut keep = std::collections::BTreeSet::new();
        for hash in self.store.scene_hashes()? {
            if let Some(scene) = self.store.scene(&hash)? {
                keep.extend(scene.assets.into_iter().map(|(_, sha)| sha));
            }
        }
        let done = self
            .assets
            .collect(&keep, self.config.asset_retention, SystemTime::now())?;
        if done != Collected::default() {
            info!(
                "asset store: deleted {} file(s) and {} unfinished upload(s) no active job uses ({} bytes)",
                done.files, done.uploads, done.bytes
            );
        }
        Ok(Some(done))
    }
}

/// Waits for a queued write to be durable.
pub(crate) async fn durable(
    rx: oneshot::Receiver<Result<(), CommitError>>,
) -> Result<(), CommitError> {
    rx.await
        .map_err(|_| CommitError::WriterStopped)
        .and_then(|r| r)
}

/// Unix time in milliseconds.
pub(crate) fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

/// Queued changes are committed early, before the checkpoint is due, once they hold this
/// many bytes: it bounds the memory they take between checkpoints.
pub(crate) const MAX_QUEUED_BYTES: u64 = 256 << 20;

/// Commits queued writes, with the tiles merged since the last commit: at once (with
/// everything queued before them) when someone waits on them, else at the next checkpoint,
/// every `interval` (a zero interval commits every group at once, as a farm without
/// checkpoints would), or sooner when [`MAX_QUEUED_BYTES`] are queued. A clean stop ends with
/// a commit ([`Shared::flush`]); what is still queued when the last sender goes is committed
/// before the writer ends.
/// A commit that fails is told to those waiting on it, and its changes stay queued for the
/// next: a later commit never lands without the changes before it.
pub(crate) async fn writer(
    shared: std::sync::Weak<Shared>,
    mut rx: mpsc::UnboundedReceiver<Write>,
    interval: std::time::Duration,
) {
    let Some((store, metrics)) = shared
        .upgrade()
        .map(|s| (s.store.clone(), s.metrics.clone()))
    else {
        return;
    };
    let mut queued = Coalesced::default();
    let mut waiters = Vec::new();
    let mut asked = false;
    let mut checkpoint = tokio::time::Instant::now() + interval;
    loop {
        let open = tokio::select! {
            w = rx.recv() => match w {
                Some(w) => {
                    asked |= take(&mut queued, &mut waiters, w);
                    // Everything queued meanwhile joins the same commit.
                    while let Ok(w) = rx.try_recv() {
                        asked |= take(&mut queued, &mut waiters, w);
                    }
                    true
                }
                None => false,
            },
            _ = tokio::time::sleep_until(checkpoint) => true,
        };
        let now = tokio::time::Instant::now();
        let due = !open
            || !waiters.is_empty()
            || asked
            || now >= checkpoint
            || queued.bytes() >= MAX_QUEUED_BYTES;
        if due {
            // The tiles merged since the last checkpoint, encoded as they are now, with every
            // change queued before now: under the scheduler's lock, so that the commit is the
            // state after one moment's changes, never half of one.
            if let Some(shared) = shared.upgrade() {
                let snapshot = {
                    let mut core = shared.scheduler();
                    while let Ok(w) = rx.try_recv() {
                        take(&mut queued, &mut waiters, w);
                    }
                    core.checkpoint()
                };
                // Encoded with the lock released: leases and merges go on meanwhile (a tile
                // merged into now is copied first, and the snapshot keeps the moment's sums).
                // On the blocking pool (not `block_in_place`, which a current-thread runtime,
                // as the fuzz targets run, does not allow).
                match tokio::task::spawn_blocking(move || snapshot.ops()).await {
                    Ok(ops) => {
                        for op in ops {
                            queued.push(op);
                        }
                    }
                    Err(e) => error!("encoding a checkpoint failed: {e}"),
                }
            }
            let waiting = std::mem::take(&mut waiters);
            if queued.is_empty() {
                for w in waiting {
                    let _ = w.send(Ok(()));
                }
            } else if let Some(written) = commit(&store, &metrics, &mut queued, waiting).await {
                // What the store now holds and no result will change leaves memory.
                if let Some(shared) = shared.upgrade() {
                    let freed = shared.scheduler().evict(&written);
                    debug!(
                        "checkpoint: {} tiles written, {freed} bytes of sums left memory, {:.3} s after it was due",
                        written.len(),
                        now.elapsed().as_secs_f64()
                    );
                    metrics
                        .evicted_bytes
                        .fetch_add(freed, std::sync::atomic::Ordering::Relaxed);
                }
            }
            asked = false;
            checkpoint = tokio::time::Instant::now() + interval;
        }
        if !open {
            return;
        }
    }
}

/// Queues a write's changes and its waiter; whether it asks for a commit now.
fn take(
    queued: &mut Coalesced,
    waiters: &mut Vec<oneshot::Sender<Result<(), CommitError>>>,
    w: Write,
) -> bool {
    for op in w.ops {
        queued.push(op);
    }
    waiters.extend(w.done);
    w.now
}

/// Commits what is queued as one transaction and tells those waiting how it went; on failure
/// the changes go back in the queue. Returns the tiles written, (job, tile), if it succeeded.
async fn commit(
    store: &Arc<Store>,
    metrics: &Metrics,
    queued: &mut Coalesced,
    waiters: Vec<oneshot::Sender<Result<(), CommitError>>>,
) -> Option<Vec<(u64, u32)>> {
    let bytes = queued.bytes();
    let ops = queued.take();
    let store = store.clone();
    let start = std::time::Instant::now();
    let (result, ops) = match tokio::task::spawn_blocking(move || (store.apply(&ops), ops)).await {
        Ok((r, ops)) => (r.map_err(|e| CommitError::Store(Arc::new(e))), ops),
        Err(e) => (Err(CommitError::Task(Arc::new(e))), Vec::new()),
    };
    metrics.commit.observe(start.elapsed());
    let written = match &result {
        Ok(()) => {
            metrics
                .written_bytes
                .fetch_add(bytes, std::sync::atomic::Ordering::Relaxed);
            Some(ops.iter().filter_map(Op::written_tile).collect())
        }
        Err(e) => {
            error!("state commit failed (its changes stay queued for the next): {e}");
            for op in ops {
                queued.push(op);
            }
            None
        }
    };
    for w in waiters {
        let _ = w.send(result.clone());
    }
    written
}
