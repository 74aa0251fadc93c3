//! What a guided unit renders with (issue #60): the guide its epoch samples, fetched once per
//! hash, and the structure its epoch records into, built once per guide. Both are pure
//! functions of the scene, the sample range and the guide, so every worker builds the same.

use std::sync::{Arc, Mutex};

use tessera_proto::v1 as pb;
use tessera_render::guide::SdTree;
use tessera_render::guiding::{epoch_of, epochs, guide_bounds, structure};
use tessera_render::scene::Scene;
use tessera_render::RenderSettings;

use crate::cache::{Recent, SceneCache, SceneError};
use crate::session::{lock, Session};

/// A guided unit's guide and training structure.
pub(crate) struct Guided {
    /// The guide its epoch samples (none in epoch 0).
    pub guide: Option<SdTree>,
    /// The structure its epoch records into (none in the last epoch).
    pub train: Option<SdTree>,
}

/// (scene hash, frame, guide hash, epoch): what a [`Guided`] is built from.
type Key = (String, Option<u32>, String, usize);

/// Guides kept: a job's epochs come one after another, and a worker rarely serves more than a
/// couple of guided jobs at once.
const MAX_KEPT: usize = 4;

/// The guides a worker has built.
pub(crate) struct GuideCache(Mutex<Recent<Key, Arc<Guided>>>);

impl GuideCache {
    /// None built yet.
    pub(crate) fn new() -> Self {
        Self(Mutex::new(Recent::new(MAX_KEPT)))
    }

    /// What guided unit `unit` of `scene` renders with. A unit whose guide does not match its
    /// epoch (one named in epoch 0, or none later) cannot be rendered as sent; a guide that does
    /// not decode is refused the same way (its hash was checked, so the coordinator made it).
    pub(crate) async fn guided(
        &self,
        session: &Session,
        scenes: &SceneCache,
        unit: &pb::WorkUnit,
        scene: &Arc<Scene>,
        settings: &RenderSettings,
    ) -> Result<Arc<Guided>, SceneError> {
        let spp = settings.spp;
        let k = epoch_of(spp, unit.sample_start)
            .filter(|&k| epoch_of(spp, unit.sample_end - 1) == Some(k))
            .ok_or_else(|| {
                SceneError::Unrenderable(format!(
                    "samples {}..{} are not inside one epoch of a guided render of {spp}",
                    unit.sample_start, unit.sample_end
                ))
            })?;
        let hash = unit.guide_sha256.clone();
        if (k == 0) != hash.is_empty() {
            return Err(SceneError::Unrenderable(format!(
                "a unit of epoch {k} came {}",
                if k == 0 {
                    "with a guide"
                } else {
                    "without a guide"
                }
            )));
        }
        let key: Key = (unit.scene_hash.clone(), settings.frame, hash.clone(), k);
        if let Some(g) = lock(&self.0).get(&key) {
            return Ok(g);
        }
        let bytes = if hash.is_empty() {
            None
        } else {
            Some(scenes.asset(session, &hash).await?)
        };
        let trains = k + 1 < epochs(spp).len();
        let scene = scene.clone();
        let built = tokio::task::spawn_blocking(move || {
            let guide = bytes
                .map(|b| SdTree::decode(&b))
                .transpose()
                .map_err(|e| format!("guide {hash}: {e}"))?;
            let train = trains.then(|| structure(guide_bounds(&scene), k, guide.as_ref()));
            Ok::<_, String>(Guided { guide, train })
        })
        .await
        .map_err(|e| SceneError::Unavailable(e.to_string()))?
        .map_err(SceneError::Unrenderable)?;
        let g = Arc::new(built);
        lock(&self.0).put(key, g.clone());
        Ok(g)
    }
}
