//! The state every handler and background task shares: the scheduler behind one mutex, the
//! store, and the commit writer that makes changes durable in groups, in the order they were
//! made.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{SystemTime, UNIX_EPOCH};

use tokio::sync::{mpsc, oneshot, watch};
use tracing::{error, info};

use crate::assets::{AssetStore, Collected};
use crate::config::Config;
use crate::error::{CommitError, CoordinatorError};
use crate::metrics::Metrics;
use crate::scheduler::{Policy, Scheduler};
use crate::store::{JobPhase, Op, Store};
use tessera_proto::ids::JobId;

/// A batch of store changes and who waits for them to be durable.
pub(crate) struct Write {
    ops: Vec<Op>,
    done: oneshot::Sender<Result<(), CommitError>>,
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
            metrics: Arc::default(),
            asset_gate: tokio::sync::RwLock::new(()),
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

    /// Queues store changes. Called with the scheduler's lock held, so commits follow merge
    /// order.
    pub(crate) fn queue_write(&self, ops: Vec<Op>) -> oneshot::Receiver<Result<(), CommitError>> {
        let (done, rx) = oneshot::channel();
        if self.writes.send(Write { ops, done }).is_err() {
            error!("state writer has stopped");
        }
        rx
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

/// Commits queued writes in groups: one fsync covers every result that arrived meanwhile.
pub(crate) async fn writer(
    store: Arc<Store>,
    mut rx: mpsc::UnboundedReceiver<Write>,
    metrics: Arc<Metrics>,
) {
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
        let bytes: u64 = ops.iter().map(Op::payload_len).sum();
        let start = std::time::Instant::now();
        let result = tokio::task::spawn_blocking(move || store.apply(&ops))
            .await
            .map_err(|e| CommitError::Task(Arc::new(e)))
            .and_then(|r| r.map_err(|e| CommitError::Store(Arc::new(e))));
        metrics.commit.observe(start.elapsed());
        metrics
            .written_bytes
            .fetch_add(bytes, std::sync::atomic::Ordering::Relaxed);
        if let Err(e) = &result {
            error!("state commit failed: {e}");
        }
        for w in waiters {
            let _ = w.send(result.clone());
        }
    }
}
