//! What a worker keeps between units: built scenes (by hash and frame), the texts of animated
//! scenes for their other frames, and the asset files scenes read, in a content-addressed
//! cache on disk bounded by `--cache-bytes` (least recently used out first).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use tessera_proto::v1 as pb;
use tessera_render::files;
use tessera_render::scene::assets::{sha256_hex, MemAssets};
use tessera_render::scene::{Format, Limits, Scene, Shot, FIRST_FRAME};
use tonic::Status;
use tracing::warn;

use crate::session::{lock, transient, Session};

/// Largest file a worker takes from a coordinator: the renderer's own limit.
const MAX_ASSET_BYTES: u64 = 2 << 30;

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

/// Why a unit's scene is not at hand.
pub(crate) enum SceneError {
    /// The coordinator could not send it (it is gone, or the network is): hand the unit back.
    Unavailable(String),
    /// It does not parse here, or breaks this worker's limits: no retry will change that.
    Unrenderable(String),
}

/// A built scene's identity: the scene's hash and the frame it is built at.
type SceneKey = (String, Option<u32>, Option<(u32, u32)>);

/// Built scenes a worker keeps (one per scene and frame).
const MAX_CACHED_SCENES: usize = 4;

/// A few values a worker keeps by key, the least recently used going first when one more
/// comes: scene texts, guides.
pub(crate) struct Recent<K, V> {
    max: usize,
    /// The most recently used last.
    kept: Vec<(K, V)>,
}

impl<K: PartialEq, V: Clone> Recent<K, V> {
    /// Keeps at most `max`.
    pub(crate) fn new(max: usize) -> Self {
        Self {
            max,
            kept: Vec::new(),
        }
    }

    /// The value of `key`, now the most recently used.
    pub(crate) fn get<Q: PartialEq + ?Sized>(&mut self, key: &Q) -> Option<V>
    where
        K: std::borrow::Borrow<Q>,
    {
        let i = self.kept.iter().position(|(k, _)| k.borrow() == key)?;
        let entry = self.kept.remove(i);
        let v = entry.1.clone();
        self.kept.push(entry);
        Some(v)
    }

    /// Keeps `v` under `key` (replacing what it held), dropping the least recently used if
    /// full.
    pub(crate) fn put(&mut self, key: K, v: V) {
        self.forget(&key);
        if self.kept.len() >= self.max {
            self.kept.remove(0);
        }
        self.kept.push((key, v));
    }

    /// Drops `key`'s value.
    pub(crate) fn forget<Q: PartialEq + ?Sized>(&mut self, key: &Q)
    where
        K: std::borrow::Borrow<Q>,
    {
        self.kept.retain(|(k, _)| k.borrow() != key);
    }

    #[cfg(test)]
    fn len(&self) -> usize {
        self.kept.len()
    }
}

/// Scene texts a worker keeps for the frames it has not built yet: a frame-range job's frames
/// share one text (up to the coordinator's scene limit, 32 MiB), which is fetched once rather
/// than once a frame.
type Texts = Recent<String, Arc<pb::GetSceneResponse>>;

/// Texts kept at most (two animations at once).
const MAX_TEXTS: usize = 2;

/// The scenes a worker has built for its units (by hash, frame and size), those it could not
/// build and why, and animated scenes' texts; their files are in the cache on disk.
pub(crate) struct SceneCache {
    /// Scenes built, by hash and frame (at most [`MAX_CACHED_SCENES`]).
    scenes: Mutex<HashMap<SceneKey, Arc<Scene>>>,
    /// Scenes this worker cannot render, by hash and frame, with the reason: fetched and
    /// refused once, not again for every unit.
    refused: Mutex<HashMap<SceneKey, String>>,
    /// Texts of animated scenes, for building their other frames without fetching them again.
    texts: Mutex<Texts>,
}

impl SceneCache {
    /// Nothing built yet.
    pub(crate) fn new() -> Self {
        Self {
            scenes: Mutex::new(HashMap::new()),
            refused: Mutex::new(HashMap::new()),
            texts: Mutex::new(Texts::new(MAX_TEXTS)),
        }
    }

    /// The scene of a unit at its frame, fetched and built once per hash and frame. A scene
    /// that does not parse here (or breaks this worker's limits) is an `Err(Unrenderable)`,
    /// remembered.
    pub(crate) async fn scene(
        &self,
        session: &Session,
        hash: &str,
        frame: Option<u32>,
        resolution: Option<(u32, u32)>,
    ) -> Result<Arc<Scene>, SceneError> {
        let key = (hash.to_string(), frame, resolution);
        if let Some(s) = lock(&self.scenes).get(&key) {
            return Ok(s.clone());
        }
        if let Some(why) = lock(&self.refused).get(&key) {
            return Err(SceneError::Unrenderable(why.clone()));
        }
        let scene = self.fetch_scene(session, hash, frame, resolution).await;
        match &scene {
            Err(SceneError::Unrenderable(why)) => {
                lock(&self.refused).insert(key, why.clone());
            }
            Ok(s) => {
                let mut scenes = lock(&self.scenes);
                // Frames come mostly in order: an animation's earlier frames are done with,
                // and each built frame holds its own geometry.
                if scenes.len() >= MAX_CACHED_SCENES {
                    if let Some(old) = scenes.keys().min_by_key(|(_, f, _)| *f).cloned() {
                        scenes.remove(&old);
                    }
                }
                scenes.insert(key, s.clone());
            }
            Err(SceneError::Unavailable(_)) => {}
        }
        scene
    }

    async fn fetch_scene(
        &self,
        session: &Session,
        hash: &str,
        frame: Option<u32>,
        resolution: Option<(u32, u32)>,
    ) -> Result<Arc<Scene>, SceneError> {
        // A unit with a frame is one frame of an animation: its text builds the others too.
        let kept = frame.and_then(|_| lock(&self.texts).get(hash));
        let resp = match kept {
            Some(text) => text,
            None => {
                let text = Arc::new(self.fetch_text(session, hash).await?);
                if frame.is_some() {
                    lock(&self.texts).put(hash.to_string(), text.clone());
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
            let bytes = self.asset(session, &a.sha256).await?;
            files.0.insert(a.name.clone(), bytes);
        }
        let scene = tokio::task::spawn_blocking(move || {
            Scene::text(
                &resp.scene_text,
                format,
                &resp.scene_name,
                &Limits::default(),
            )
            .at(Shot {
                frame: frame.unwrap_or(FIRST_FRAME),
                resolution,
            })
            .assets(&files)
            .load()
        })
        .await
        .map_err(|e| SceneError::Unavailable(e.to_string()))?
        .map_err(|e| SceneError::Unrenderable(e.to_string()))?;
        if scene.hash != hash {
            lock(&self.texts).forget(hash);
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
    pub(crate) async fn asset(&self, session: &Session, hash: &str) -> Result<Vec<u8>, SceneError> {
        if !tessera_proto::ids::is_sha256(hash) {
            return Err(SceneError::Unavailable(format!(
                "the coordinator named a file by {:?}, which is not a SHA-256",
                hash.chars().take(80).collect::<String>()
            )));
        }
        let path = session.config.cache_dir.join(hash);
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
            match self.fetch_asset(session, hash).await {
                Ok(b) => break b,
                Err(e) if transient(&e) && session.backoff(&mut attempt).await => continue,
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
        let dir = session.config.cache_dir.clone();
        let budget = session.config.cache_bytes;
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
            warn!(
                "caching {hash} in {}: {e}",
                session.config.cache_dir.display()
            );
        }
        Ok(bytes)
    }

    async fn fetch_asset(&self, session: &Session, hash: &str) -> Result<Vec<u8>, Status> {
        let req = pb::FetchAssetRequest {
            sha256: hash.to_string(),
            offset: 0,
            worker_id: session.id(),
        };
        let mut stream = session.client.clone().fetch_asset(req).await?.into_inner();
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

    async fn fetch_text(
        &self,
        session: &Session,
        hash: &str,
    ) -> Result<pb::GetSceneResponse, SceneError> {
        let mut attempt = 0;
        loop {
            let req = pb::GetSceneRequest {
                scene_hash: hash.to_string(),
                worker_id: session.id(),
            };
            match session.client.clone().get_scene(req).await {
                Ok(r) => return Ok(r.into_inner()),
                Err(e) if transient(&e) && session.backoff(&mut attempt).await => continue,
                Err(e) => return Err(SceneError::Unavailable(e.message().to_string())),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

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

    #[test]
    fn scene_texts_are_kept_for_the_two_animations_used_last() {
        let text = |name: &str| {
            Arc::new(pb::GetSceneResponse {
                scene_name: name.into(),
                ..Default::default()
            })
        };
        let mut t = Texts::new(MAX_TEXTS);
        t.put("a".into(), text("a"));
        t.put("b".into(), text("b"));
        // Using a keeps it: the next text pushes b out, not a.
        assert_eq!(t.get("a").expect("a").scene_name, "a");
        t.put("c".into(), text("c"));
        assert!(t.get("b").is_none());
        assert_eq!(t.get("a").expect("a").scene_name, "a");
        assert_eq!(t.get("c").expect("c").scene_name, "c");
        // Put again, a text is not kept twice.
        t.put("c".into(), text("c2"));
        assert_eq!(t.len(), 2);
        assert_eq!(t.get("c").expect("c").scene_name, "c2");
    }
}
