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
//! On shutdown the worker stops leasing (taking the answer of a lease call already under way,
//! so that no unit granted in it is lost), finishes and sends the unit it is rendering (units
//! take seconds at most), hands queued units back, and says goodbye.

use std::collections::{HashMap, HashSet};
use std::future::Future;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::time::Duration;

use tessera_proto::client::{endpoint, Bearer, ClientOptions};
use tessera_proto::convert::settings_from_wire;
use tessera_proto::v1 as pb;
use tessera_proto::v1::workers_client::WorkersClient;
use tessera_render::files;
use tessera_render::scene::assets::{sha256_hex, MemAssets};
use tessera_render::scene::{Format, Limits, Scene, FIRST_FRAME};
use tessera_render::{render_tile, PixelRect, RenderSettings, TileSums};
use tokio::sync::{mpsc, watch, OwnedSemaphorePermit, Semaphore};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::{Code, Status};
use tracing::{debug, info, warn};

/// Largest file a worker takes from a coordinator: the renderer's own limit.
const MAX_ASSET_BYTES: u64 = 2 << 30;

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
        }
    }
}

/// Most bytes the asset cache keeps, unless configured.
pub const DEFAULT_CACHE_BYTES: u64 = 16 << 30;

/// Deletes the least recently used (oldest modification time) cached files in `dir`, other
/// than `keep`, until the files named by a hash hold at most `budget` bytes; returns how many
/// files and bytes went. Other files (another worker's download in progress) are left alone.
/// Ties in time go by name, so the order does not depend on the directory's.
pub fn evict(dir: &std::path::Path, budget: u64, keep: &str) -> std::io::Result<(usize, u64)> {
    let mut files = Vec::new();
    for e in std::fs::read_dir(dir)?.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if !tessera_proto::ids::is_sha256(&name) {
            continue;
        }
        if let Ok(m) = e.metadata() {
            let used = m.modified().unwrap_or(std::time::UNIX_EPOCH);
            files.push((name != keep, used, name, m.len()));
        }
    }
    let mut total: u64 = files.iter().map(|f| f.3).sum();
    // `keep` sorts last (false < true, reversed): it is never deleted.
    files.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let (mut n, mut freed) = (0, 0);
    for (evictable, _, name, len) in files {
        if total <= budget || !evictable {
            break;
        }
        match std::fs::remove_file(dir.join(&name)) {
            Ok(()) => {
                n += 1;
                freed += len;
            }
            // Another worker on this machine evicted it first.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e),
        }
        total -= len;
    }
    Ok((n, freed))
}

/// Why the worker stopped.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// The coordinator URL is not usable (the error names it).
    #[error(transparent)]
    Url(#[from] tessera_proto::client::ClientError),
    /// The render threads could not start.
    #[error("starting the render threads: {0}")]
    Threads(String),
    /// The coordinator refused this worker (wrong token, quarantined, another renderer image
    /// revision).
    #[error("the coordinator refused this worker: {0}")]
    Refused(String),
}

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
    /// Texts of animated scenes, for building their other frames without fetching them again.
    texts: Mutex<Texts>,
    /// Held while registering, so that the tasks that all learn at once that the coordinator
    /// forgot this worker register it once, not once each.
    registering: tokio::sync::Mutex<()>,
    stop: watch::Receiver<bool>,
    /// Why the coordinator refused this worker for good, if it did.
    refused: Mutex<Option<String>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

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
                        warn!("cannot reach {}: {}", self.config.coordinator, e.message());
                    }
                    if !self.backoff(&mut attempt).await {
                        return false;
                    }
                }
            }
        }
    }

    /// The scene of a unit at its frame, fetched and built once per hash and frame. A scene
    /// that does not parse here (or breaks this worker's limits) is an `Err(Unrenderable)`,
    /// remembered.
    async fn scene(&self, hash: &str, frame: Option<u32>) -> Result<Arc<Scene>, SceneError> {
        let key = (hash.to_string(), frame);
        if let Some(s) = lock(&self.scenes).get(&key) {
            return Ok(s.clone());
        }
        if let Some(why) = lock(&self.refused_scenes).get(&key) {
            return Err(SceneError::Unrenderable(why.clone()));
        }
        let scene = self.fetch_scene(hash, frame).await;
        match &scene {
            Err(SceneError::Unrenderable(why)) => {
                lock(&self.refused_scenes).insert(key, why.clone());
            }
            Ok(s) => {
                let mut scenes = lock(&self.scenes);
                // Frames come mostly in order: an animation's earlier frames are done with,
                // and each built frame holds its own geometry.
                if scenes.len() >= MAX_CACHED_SCENES {
                    if let Some(old) = scenes.keys().min_by_key(|(_, f)| *f).cloned() {
                        scenes.remove(&old);
                    }
                }
                scenes.insert(key, s.clone());
            }
            Err(SceneError::Unavailable(_)) => {}
        }
        scene
    }

    async fn fetch_scene(&self, hash: &str, frame: Option<u32>) -> Result<Arc<Scene>, SceneError> {
        // A unit with a frame is one frame of an animation: its text builds the others too.
        let kept = frame.and_then(|_| lock(&self.texts).get(hash));
        let resp = match kept {
            Some(text) => text,
            None => {
                let text = Arc::new(self.fetch_text(hash).await?);
                if frame.is_some() {
                    lock(&self.texts).put(hash, text.clone());
                }
                text
            }
        };
        let format = if resp.scene_format == pb::SceneFormat::Json as i32 {
            Format::Json
        } else {
            Format::Toml
        };
        let mut files = MemAssets::default();
        for a in &resp.assets {
            let bytes = self.asset(&a.sha256).await?;
            files.0.insert(a.name.clone(), bytes);
        }
        let scene = tokio::task::spawn_blocking(move || {
            Scene::from_str_with(
                &resp.scene_text,
                format,
                &resp.scene_name,
                &Limits::default(),
                frame.unwrap_or(FIRST_FRAME),
                &files,
            )
        })
        .await
        .map_err(|e| SceneError::Unavailable(e.to_string()))?
        .map_err(|e| SceneError::Unrenderable(e.to_string()))?;
        if scene.hash != hash {
            lock(&self.texts).kept.retain(|(h, _)| h != hash);
            return Err(SceneError::Unavailable(format!(
                "scene {hash} arrived with hash {}",
                scene.hash
            )));
        }
        Ok(Arc::new(scene))
    }

    /// A file a scene names, from this machine's cache or else from the coordinator (and then
    /// cached). Its content is checked against its hash either way: a damaged cache file or a
    /// wrong download is never rendered from.
    async fn asset(&self, hash: &str) -> Result<Vec<u8>, SceneError> {
        if !tessera_proto::ids::is_sha256(hash) {
            return Err(SceneError::Unavailable(format!(
                "the coordinator named a file by {:?}, which is not a SHA-256",
                hash.chars().take(80).collect::<String>()
            )));
        }
        let path = self.config.cache_dir.join(hash);
        let (p, h) = (path.clone(), hash.to_string());
        let cached = tokio::task::spawn_blocking(move || {
            let bytes = std::fs::read(&p).ok()?;
            if sha256_hex(&bytes) == h {
                // Used now: the eviction deletes the least recently used first.
                if let Ok(f) = std::fs::OpenOptions::new().write(true).open(&p) {
                    let _ = f.set_modified(std::time::SystemTime::now());
                }
                Some(bytes)
            } else {
                warn!("cached {} is damaged; fetching it again", p.display());
                None
            }
        })
        .await
        .ok()
        .flatten();
        if let Some(bytes) = cached {
            return Ok(bytes);
        }
        let mut attempt = 0;
        let bytes = loop {
            match self.fetch_asset(hash).await {
                Ok(b) => break b,
                Err(e) if transient(&e) && self.backoff(&mut attempt).await => continue,
                Err(e) => return Err(SceneError::Unavailable(e.message().to_string())),
            }
        };
        let got = sha256_hex(&bytes);
        if got != hash {
            return Err(SceneError::Unavailable(format!(
                "file {hash} arrived with hash {got}"
            )));
        }
        // Written under a fresh random name, then renamed (`files::place`): another worker on
        // this machine may be caching the same file, a reader must never see half of one, and
        // nothing planted in the directory is followed.
        let dir = self.config.cache_dir.clone();
        let budget = self.config.cache_bytes;
        let keep = hash.to_string();
        let (bytes, saved) = tokio::task::spawn_blocking(move || {
            let r = files::private_dir(&dir).and_then(|()| {
                files::place_bytes(&path, files::Place::Replace, files::Access::Private, &bytes)
            });
            if r.is_ok() {
                if let Err(e) = evict(&dir, budget, &keep) {
                    warn!("evicting from the cache {}: {e}", dir.display());
                }
            }
            (bytes, r)
        })
        .await
        .map_err(|e| SceneError::Unavailable(e.to_string()))?;
        if let Err(e) = saved {
            // Rendering goes on; only the next fetch is not saved.
            warn!("caching {hash} in {}: {e}", self.config.cache_dir.display());
        }
        Ok(bytes)
    }

    async fn fetch_asset(&self, hash: &str) -> Result<Vec<u8>, Status> {
        let req = pb::FetchAssetRequest {
            sha256: hash.to_string(),
            offset: 0,
        };
        let mut stream = self.client.clone().fetch_asset(req).await?.into_inner();
        let mut bytes = Vec::new();
        while let Some(chunk) = stream.message().await? {
            if chunk.offset != bytes.len() as u64 || chunk.total_size > MAX_ASSET_BYTES {
                return Err(Status::data_loss(format!(
                    "file {hash}: a chunk at {} of {} bytes after {} bytes",
                    chunk.offset,
                    chunk.total_size,
                    bytes.len()
                )));
            }
            bytes.extend_from_slice(&chunk.data);
        }
        Ok(bytes)
    }

    async fn fetch_text(&self, hash: &str) -> Result<pb::GetSceneResponse, SceneError> {
        let mut attempt = 0;
        loop {
            let req = pb::GetSceneRequest {
                scene_hash: hash.to_string(),
            };
            match self.client.clone().get_scene(req).await {
                Ok(r) => return Ok(r.into_inner()),
                Err(e) if transient(&e) && self.backoff(&mut attempt).await => continue,
                Err(e) => return Err(SceneError::Unavailable(e.message().to_string())),
            }
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

/// Why a unit's scene is not at hand.
enum SceneError {
    /// The coordinator could not send it (it is gone, or the network is): hand the unit back.
    Unavailable(String),
    /// It does not parse here, or breaks this worker's limits: no retry will change that.
    Unrenderable(String),
}

/// A leased unit, ready to render.
struct Ready {
    unit: pb::WorkUnit,
    scene: Arc<Scene>,
    rect: PixelRect,
    settings: RenderSettings,
    _slot: OwnedSemaphorePermit,
}

/// Checks a unit against its scene and turns it into renderer arguments.
fn prepare(unit: &pb::WorkUnit, scene: &Scene) -> Result<(PixelRect, RenderSettings), String> {
    let rect = PixelRect::from(unit.rect.ok_or("unit has no rect")?);
    if !rect.fits(scene.width, scene.height) {
        return Err(format!(
            "unit rect {rect:?} is outside the {}×{} image",
            scene.width, scene.height
        ));
    }
    // An unknown strategy is a coordinator newer than this worker.
    let settings = settings_from_wire(unit.settings.as_ref())
        .map_err(|e| format!("unit settings: {e} (is this worker older than the coordinator?)"))?;
    if unit.sample_start >= unit.sample_end || unit.sample_end > settings.spp {
        return Err(format!(
            "unit samples {}..{} do not fit spp {} in batches of {}",
            unit.sample_start, unit.sample_end, settings.spp, settings.batch
        ));
    }
    Ok((rect, settings))
}

/// A built scene's identity: the scene's hash and the frame it is built at.
type SceneKey = (String, Option<u32>);

/// Built scenes a worker keeps (one per scene and frame).
const MAX_CACHED_SCENES: usize = 4;

/// Scene texts a worker keeps for the frames it has not built yet: a frame-range job's frames
/// share one text (up to the coordinator's scene limit, 32 MiB), which is fetched once rather
/// than once a frame.
#[derive(Default)]
struct Texts {
    /// By hash, the most recently used last.
    kept: Vec<(String, Arc<pb::GetSceneResponse>)>,
}

impl Texts {
    /// Texts kept at most.
    const MAX: usize = 2;

    fn get(&mut self, hash: &str) -> Option<Arc<pb::GetSceneResponse>> {
        let i = self.kept.iter().position(|(h, _)| h == hash)?;
        let entry = self.kept.remove(i);
        let text = entry.1.clone();
        self.kept.push(entry);
        Some(text)
    }

    fn put(&mut self, hash: &str, text: Arc<pb::GetSceneResponse>) {
        self.kept.retain(|(h, _)| h != hash);
        if self.kept.len() >= Self::MAX {
            self.kept.remove(0);
        }
        self.kept.push((hash.to_string(), text));
    }
}

/// The longest a lease call waits at the coordinator for a unit to come free.
const LEASE_WAIT: Duration = Duration::from_secs(2);

/// Leases units while there is room, and queues them for the renderer.
async fn fetcher(ctx: Arc<Ctx>, tx: mpsc::Sender<Ready>) {
    // The units rendering and one queued ahead.
    let slots = Arc::new(Semaphore::new(MAX_HELD_UNITS));
    let mut attempt = 0;
    let mut stop = ctx.stop.clone();
    loop {
        let slot = tokio::select! {
            s = slots.clone().acquire_owned() => match s { Ok(s) => s, Err(_) => return },
            _ = stop.wait_for(|s| *s) => return,
        };
        let req_id = ctx.id();
        let req = pb::LeaseRequest {
            worker_id: req_id.clone(),
            max_units: 1,
            wait_ms: LEASE_WAIT.as_millis() as u32,
        };
        let mut client = ctx.client.clone();
        let call = client.lease(req);
        tokio::pin!(call);
        let answered = tokio::select! {
            r = &mut call => Some(r),
            _ = stop.wait_for(|s| *s) => None,
        };
        let Some(resp) = answered else {
            // The coordinator may have granted units in the answer already on its way: dropping
            // the call would leave them leased to nobody until their leases lapse. The call is
            // a long poll of at most LEASE_WAIT, so take its answer and keep its units as held,
            // for the shutdown to hand back at once.
            let late = tokio::time::timeout(LEASE_WAIT + Duration::from_secs(1), call).await;
            if let Ok(Ok(r)) = late {
                let units = r.into_inner().units;
                lock(&ctx.held).extend(units.into_iter().map(|u| u.lease_id));
            }
            return;
        };
        let units = match resp {
            Ok(r) => {
                attempt = 0;
                r.into_inner().units
            }
            Err(e) if e.code() == Code::NotFound => {
                warn!("{}", e.message());
                if !ctx.reregister(&req_id).await {
                    return;
                }
                continue;
            }
            Err(e) => {
                if attempt == 0 || attempt % 10 == 0 {
                    warn!("leasing from {}: {}", ctx.config.coordinator, e.message());
                }
                if !ctx.backoff(&mut attempt).await {
                    return;
                }
                continue;
            }
        };
        let mut slot = Some(slot);
        for unit in units {
            lock(&ctx.held).insert(unit.lease_id.clone());
            let frame = unit.settings.as_ref().and_then(|s| s.frame);
            let prepared = match ctx.scene(&unit.scene_hash, frame).await {
                Ok(scene) => prepare(&unit, &scene)
                    .map(|p| (scene, p))
                    .map_err(SceneError::Unrenderable),
                Err(e) => Err(e),
            };
            let (scene, (rect, settings)) = match prepared {
                Ok(p) => p,
                Err(SceneError::Unavailable(e)) => {
                    warn!(
                        "unit {} of {}: scene {}: {e}; handing it back",
                        unit.lease_id, unit.job_id, unit.scene_hash
                    );
                    ctx.release(vec![unit.lease_id], false).await;
                    continue;
                }
                Err(SceneError::Unrenderable(e)) => {
                    warn!(
                        "unit {} of {}: this worker cannot render it: {e}",
                        unit.lease_id, unit.job_id
                    );
                    ctx.hand_back(vec![unit.lease_id], false, e).await;
                    continue;
                }
            };
            let Some(s) = slot.take() else { break };
            let ready = Ready {
                unit,
                scene,
                rect,
                settings,
                _slot: s,
            };
            if tx.send(ready).await.is_err() {
                return;
            }
        }
    }
}

/// A rendered unit on its way back. It keeps its fetcher slot until the coordinator has the
/// result: a unit waiting to be sent counts against what the worker may hold, or a worker
/// that renders faster than it can send would lease without bound.
struct Done {
    unit: pb::WorkUnit,
    sums: TileSums,
    _slot: OwnedSemaphorePermit,
}

/// Units rendering at once. Two, so that while one unit's last rows finish on a few threads,
/// the other keeps the rest of the pool busy (rayon steals across both).
const OVERLAP: usize = 2;

/// The most units a worker holds leases for at once: those rendering or waiting for their
/// result to be acknowledged, and one queued ahead. A unit keeps its slot until its result is
/// acknowledged, so results waiting to be sent count too, and a worker whose units render
/// faster than results are committed cannot lease without bound.
pub const MAX_HELD_UNITS: usize = OVERLAP + 1;

/// Renders queued units on the whole pool, [`OVERLAP`] at a time.
async fn renderer(ctx: Arc<Ctx>, mut rx: mpsc::Receiver<Ready>, tx: mpsc::UnboundedSender<Done>) {
    let mut stop = ctx.stop.clone();
    let mut running: tokio::task::JoinSet<Done> = tokio::task::JoinSet::new();
    let mut open = true;
    while open || !running.is_empty() {
        tokio::select! {
            biased;
            // Shutdown: take no new unit, but finish the ones started.
            _ = stop.wait_for(|s| *s), if open => open = false,
            Some(done) = running.join_next(), if !running.is_empty() => match done {
                Ok(done) => {
                    let _ = tx.send(done);
                }
                Err(e) => warn!("render task failed: {e}"),
            },
            r = rx.recv(), if open && running.len() < OVERLAP => {
                let Some(ready) = r else {
                    open = false;
                    continue;
                };
                if lock(&ctx.revoked).remove(&ready.unit.lease_id) {
                    lock(&ctx.held).remove(&ready.unit.lease_id);
                    continue;
                }
                let work = ctx.clone();
                running.spawn_blocking(move || {
                    let samples = ready.unit.sample_start..ready.unit.sample_end;
                    let sums = work.pool.install(|| {
                        render_tile(&ready.scene, &ready.settings, ready.rect, samples)
                    });
                    Done {
                        unit: ready.unit,
                        sums,
                        _slot: ready._slot,
                    }
                });
            }
        }
    }
    // Shutting down: hand back what is queued and not started.
    rx.close();
    let mut back = Vec::new();
    while let Ok(r) = rx.try_recv() {
        back.push(r.unit.lease_id);
    }
    if !back.is_empty() {
        info!("handing back {} queued unit(s)", back.len());
        ctx.release(back, false).await;
    }
}

/// The wait before retry number `attempt` (from 0) of a call the coordinator did not answer:
/// 100 ms, doubling, never above `max`. Every retry loop of the worker waits this long, so a
/// farm of workers whose coordinator restarts reconnects quickly without hammering it.
pub fn backoff_delay(attempt: u32, max: Duration) -> Duration {
    Duration::from_millis(100u64 << attempt.min(10)).min(max)
}

/// Sends results, retrying through network errors.
async fn submitter(ctx: Arc<Ctx>, mut rx: mpsc::UnboundedReceiver<Done>) {
    while let Some(done) = rx.recv().await {
        let result = pb::TileResult::from(&done.sums);
        let mut attempt = 0;
        loop {
            let sent_as = ctx.id();
            let req = pb::SubmitResultRequest {
                worker_id: sent_as.clone(),
                lease_id: done.unit.lease_id.clone(),
                job_id: done.unit.job_id.clone(),
                tile_index: done.unit.tile_index,
                batch_index: done.unit.batch_index,
                result: Some(result.clone()),
            };
            match ctx.client.clone().submit_result(req).await {
                Ok(_) => break,
                Err(e) if e.code() == Code::NotFound && e.message().contains("unknown worker") => {
                    if !ctx.reregister(&sent_as).await {
                        break;
                    }
                }
                Err(e) if transient(&e) => {
                    if attempt == 0 || attempt % 10 == 0 {
                        warn!("sending a result: {}; retrying", e.message());
                    }
                    // Keep retrying during shutdown too, but not past the grace period
                    // (enforced by the caller's timeout).
                    let delay = backoff_delay(attempt, ctx.config.max_backoff);
                    attempt += 1;
                    tokio::time::sleep(delay).await;
                }
                Err(e) => {
                    warn!(
                        "result for {} tile {} batch {} refused: {}",
                        done.unit.job_id,
                        done.unit.tile_index,
                        done.unit.batch_index,
                        e.message()
                    );
                    break;
                }
            }
        }
        lock(&ctx.held).remove(&done.unit.lease_id);
    }
}

/// Renews leases and learns which were revoked.
async fn heartbeat(ctx: Arc<Ctx>) {
    loop {
        let every = Duration::from_millis(ctx.heartbeat_ms.load(Ordering::Relaxed));
        tokio::time::sleep(every).await;
        let lease_ids: Vec<String> = lock(&ctx.held).iter().cloned().collect();
        let req = pb::HeartbeatRequest {
            worker_id: ctx.id(),
            lease_ids,
        };
        match ctx.client.clone().heartbeat(req).await {
            Ok(r) => {
                let revoked = r.into_inner().revoked;
                if !revoked.is_empty() {
                    debug!("{} lease(s) revoked", revoked.len());
                    let mut held = lock(&ctx.held);
                    let mut gone = lock(&ctx.revoked);
                    for l in revoked {
                        held.remove(&l);
                        gone.insert(l);
                    }
                }
            }
            Err(e) => debug!("heartbeat: {}", e.message()),
        }
    }
}

/// A spawned task that is aborted when dropped, so that dropping (aborting) [`run`] stops
/// everything the worker started, as a crash would.
struct Task(tokio::task::JoinHandle<()>);

impl Task {
    fn spawn(f: impl Future<Output = ()> + Send + 'static) -> Self {
        Self(tokio::spawn(f))
    }

    async fn join(&mut self) {
        let _ = (&mut self.0).await;
    }
}

impl Drop for Task {
    fn drop(&mut self) {
        self.0.abort();
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
    let ctx = Arc::new(Ctx {
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
        texts: Mutex::new(Texts::default()),
        registering: tokio::sync::Mutex::new(()),
        stop,
        refused: Mutex::new(None),
    });
    let stop_tx = Arc::new(stop_tx);
    let signal_tx = stop_tx.clone();
    let _signal = Task::spawn(async move {
        shutdown.await;
        let _ = signal_tx.send(true);
    });
    if !ctx.register().await {
        let refused = lock(&ctx.refused).take();
        return match refused {
            Some(why) => Err(WorkerError::Refused(why)),
            None => Ok(()),
        };
    }
    let (ready_tx, ready_rx) = mpsc::channel(1);
    let (done_tx, done_rx) = mpsc::unbounded_channel();
    let _beat = Task::spawn(heartbeat(ctx.clone()));
    let mut fetch = Task::spawn(fetcher(ctx.clone(), ready_tx));
    let mut render = Task::spawn(renderer(ctx.clone(), ready_rx, done_tx));
    let mut submit = Task::spawn(submitter(ctx.clone(), done_rx));
    let mut stop = ctx.stop.clone();
    // The fetcher only ends by itself when the coordinator refused us for good.
    let refused = tokio::select! {
        _ = stop.wait_for(|s| *s) => false,
        _ = fetch.join() => true,
    };
    if refused {
        let _ = stop_tx.send(true);
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

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_render::Strategy;

    /// The cache deletes its least recently used files until it fits its budget, never the
    /// file just cached, and leaves files not named by a hash (downloads in progress) alone.
    #[test]
    fn the_cache_evicts_the_least_recently_used_first() {
        let dir = tempfile::tempdir().expect("tmp");
        let t0 = std::time::SystemTime::now();
        let put = |byte: u8, len: usize, age_s: u64| {
            let data = vec![byte; len];
            let hash = sha256_hex(&data);
            let path = dir.path().join(&hash);
            std::fs::write(&path, &data).expect("write");
            let f = std::fs::OpenOptions::new()
                .write(true)
                .open(&path)
                .expect("open");
            f.set_modified(t0 - Duration::from_secs(age_s))
                .expect("time");
            hash
        };
        let oldest = put(1, 40, 300);
        let middle = put(2, 40, 200);
        let newest = put(3, 40, 100);
        // The file just cached, though the oldest of all, stays.
        let just = put(4, 40, 400);
        std::fs::write(dir.path().join(".partial.1.2"), [0u8; 500]).expect("tmp file");
        let (n, bytes) = evict(dir.path(), 100, &just).expect("evict");
        assert_eq!((n, bytes), (2, 80));
        let here = |h: &str| dir.path().join(h).exists();
        assert!(!here(&oldest) && !here(&middle));
        assert!(here(&newest) && here(&just));
        assert!(dir.path().join(".partial.1.2").exists());
        // Within the budget: nothing goes; over it with only the new file: it stays.
        assert_eq!(evict(dir.path(), 100, &just).expect("evict"), (0, 0));
        assert_eq!(evict(dir.path(), 10, &just).expect("evict"), (1, 40));
        assert!(here(&just) && !here(&newest));
    }

    fn scene() -> Scene {
        let text = include_str!("../../../scenes/cornell-box.toml")
            .replace("width = 256", "width = 8")
            .replace("height = 256", "height = 8");
        Scene::from_str(&text, Format::Toml, "c.toml", &Limits::default()).expect("scene")
    }

    fn unit(rect: pb::Rect, start: u32, end: u32, strategy: i32) -> pb::WorkUnit {
        pb::WorkUnit {
            rect: Some(rect),
            sample_start: start,
            sample_end: end,
            settings: Some(pb::RenderSettings {
                spp: 8,
                seed: 1,
                batch: 4,
                strategy,
                ..Default::default()
            }),
            ..pb::WorkUnit::default()
        }
    }

    #[test]
    fn scene_texts_are_kept_for_the_two_animations_used_last() {
        let text = |name: &str| {
            Arc::new(pb::GetSceneResponse {
                scene_name: name.into(),
                ..Default::default()
            })
        };
        let mut t = Texts::default();
        t.put("a", text("a"));
        t.put("b", text("b"));
        // Using a keeps it: the next text pushes b out, not a.
        assert_eq!(t.get("a").expect("a").scene_name, "a");
        t.put("c", text("c"));
        assert!(t.get("b").is_none());
        assert_eq!(t.get("a").expect("a").scene_name, "a");
        assert_eq!(t.get("c").expect("c").scene_name, "c");
        // Put again, a text is not kept twice.
        t.put("c", text("c2"));
        assert_eq!(t.kept.len(), 2);
        assert_eq!(t.get("c").expect("c").scene_name, "c2");
    }

    #[test]
    fn backoff_doubles_from_a_tenth_of_a_second_up_to_the_cap() {
        let cap = Duration::from_secs(10);
        let waits: Vec<u128> = (0..9).map(|a| backoff_delay(a, cap).as_millis()).collect();
        assert_eq!(
            waits,
            [100, 200, 400, 800, 1600, 3200, 6400, 10_000, 10_000]
        );
        // However long a coordinator stays away, the shift never overflows.
        assert_eq!(backoff_delay(u32::MAX, cap), cap);
        assert_eq!(
            backoff_delay(3, Duration::from_millis(250)).as_millis(),
            250
        );
    }

    #[test]
    fn units_a_worker_cannot_render_as_sent_are_refused_with_the_reason() {
        let scene = scene();
        let inside = pb::Rect {
            x0: 4,
            y0: 4,
            width: 4,
            height: 4,
        };
        let (rect, settings) =
            prepare(&unit(inside, 4, 8, pb::Strategy::Nee as i32), &scene).expect("fits");
        assert_eq!((rect.x0, rect.width), (4, 4));
        assert_eq!(settings.strategy, Strategy::Nee);
        let outside = pb::Rect { x0: 6, ..inside };
        let e = prepare(&unit(outside, 0, 4, 1), &scene).expect_err("outside");
        assert!(e.contains("outside the 8×8 image"), "{e}");
        let e = prepare(&unit(inside, 4, 9, 1), &scene).expect_err("past spp");
        assert!(e.contains("do not fit spp 8"), "{e}");
        let e = prepare(&unit(inside, 0, 4, 99), &scene).expect_err("a strategy from the future");
        assert!(e.contains("unknown strategy 99"), "{e}");
    }
}
