//! `tessera loadtest --guiding`: the training trees a guided job's simulated workers send
//! (issue #60). A unit of a training epoch must return a tree of its epoch's structure, which
//! the coordinator checks, adds to the epoch's and freezes into the next guide, and that cost
//! is what the guided runs measure. So each simulated worker does what a worker does for the
//! structure: it fetches the epoch's guide by hash (FetchAsset) and refines it. The records
//! are synthetic (rendering every unit for real would make the load generator the bottleneck,
//! as for the sums): [`RECORDS`] fixed points and directions spread over the scene's box, the
//! same for every unit, so the trees grow epoch by epoch as real ones do, from the counts the
//! coordinator sums. One tree per epoch is made and shared by every simulated worker.

use std::collections::HashMap;
use std::sync::Arc;

use anyhow::{anyhow, Result};
use glam::{Vec2, Vec3A};
use tessera_proto::v1 as pb;
use tessera_proto::v1::workers_client::WorkersClient;
use tessera_render::guide::{from_square, SdTree};
use tessera_render::guiding::{epoch_of, epochs, structure};
use tonic::transport::Channel;

/// Vertices each unit's training tree records: fewer than any unit's paths can have (a 128²
/// tile of one sample, 16 vertices a path, allows 262,144).
pub(super) const RECORDS: u32 = 4096;

/// Encoded training trees by (guide hash, epoch).
type Kept = HashMap<(String, usize), Arc<Vec<u8>>>;

/// The training trees of a guided load test's epochs, made once each.
pub(super) struct Trains {
    /// The scene's box (what epoch 0's structure spans).
    pub bounds: [[f32; 3]; 2],
    /// The job's spp.
    pub spp: u32,
    /// The trees made so far.
    kept: tokio::sync::Mutex<Kept>,
}

/// A low-discrepancy point in [0, 1)² (the golden-ratio sequence): the `i`th of a fixed set.
fn point(i: u32, salt: f32) -> Vec2 {
    let g = 0.618_034_f32;
    Vec2::new(
        (i as f32 * g + salt).fract(),
        ((i as f32 + 0.5) / RECORDS as f32 + salt * 0.37).fract(),
    )
}

impl Trains {
    /// Trains for a job of `spp` samples over `bounds`.
    pub fn new(bounds: [[f32; 3]; 2], spp: u32) -> Self {
        Self {
            bounds,
            spp,
            kept: tokio::sync::Mutex::new(HashMap::new()),
        }
    }

    /// The epochs whose trees were made, and the largest tree's bytes.
    pub fn reached(&self) -> (usize, usize) {
        self.kept.try_lock().map_or((0, 0), |k| {
            (
                k.keys().map(|(_, e)| e + 1).max().unwrap_or(0),
                k.values().map(|t| t.len()).max().unwrap_or(0),
            )
        })
    }

    /// The training tree to send with `unit`'s result (empty for an epoch that trains none),
    /// fetching the unit's guide as `worker_id`, which holds its lease.
    pub async fn tree(
        &self,
        client: &mut WorkersClient<Channel>,
        worker_id: &str,
        unit: &pb::WorkUnit,
    ) -> Result<Arc<Vec<u8>>> {
        let k = epoch_of(self.spp, unit.sample_start)
            .ok_or_else(|| anyhow!("samples {} past spp", unit.sample_start))?;
        if k + 1 >= epochs(self.spp).len() {
            return Ok(Arc::new(Vec::new()));
        }
        let key = (unit.guide_sha256.clone(), k);
        // Held across the fetch: the first worker of an epoch makes its tree, the rest wait.
        let mut kept = self.kept.lock().await;
        if let Some(t) = kept.get(&key) {
            return Ok(t.clone());
        }
        let guide = if unit.guide_sha256.is_empty() {
            None
        } else {
            let mut stream = client
                .fetch_asset(pb::FetchAssetRequest {
                    sha256: unit.guide_sha256.clone(),
                    offset: 0,
                    worker_id: worker_id.to_string(),
                })
                .await?
                .into_inner();
            let mut bytes = Vec::new();
            while let Some(c) = stream.message().await? {
                bytes.extend_from_slice(&c.data);
            }
            Some(SdTree::decode(&bytes)?)
        };
        let mut tree = structure(self.bounds, k, guide.as_ref());
        let (lo, hi) = (Vec3A::from(self.bounds[0]), Vec3A::from(self.bounds[1]));
        for i in 0..RECORDS {
            let (a, b) = (point(i, 0.1), point(i, 0.7));
            let p = lo + (hi - lo) * Vec3A::new(a.x, a.y, b.x);
            tree.record(p, from_square(point(i, 0.3)), 1.0 + b.y as f64);
        }
        let t = Arc::new(tree.encode());
        kept.insert(key, t.clone());
        Ok(t)
    }
}
