//! A guided job's epochs and guides (issue #60; the renderer's side is
//! [`tessera_render::guiding`]).
//!
//! A guided job's batches are [`units`]: its epochs' sample ranges cut at multiples of the
//! batch, so a tile folds them in the same order `tessera render --guiding` does. Epoch k's
//! units are leased only once every unit of epoch k − 1 is merged (the barrier), because they
//! sample the guide epoch k − 1 trained. Each unit of a training epoch returns the tree it
//! recorded into; the coordinator adds it to the epoch's tree when it accepts the result (its
//! sums merged or kept for their turn), and never again for the same unit (a duplicate is
//! dropped before). Counts and energies are integers, so the sum is the same bits whatever
//! order results arrive in, on any number of workers: that is why no merge order is needed.
//!
//! When the last tile passes the epoch's end, its tree is frozen into the next guide, named by
//! the SHA-256 of its encoding, kept in the store (`guides` table, in the same commit as the
//! merge that finished it, with the record that lists its hash) and served to workers by
//! FetchAsset from memory. The epoch's tree as merged so far is written with each checkpoint,
//! beside the tiles it came with, so a restart resumes it with exactly the results the store
//! holds; a restart that finds an epoch's every tile in but not its guide (no such commit can
//! be written, but the rule costs nothing) finishes it again from the same sums.

use std::ops::Range;
use std::sync::Arc;

use sha2::{Digest, Sha256};
use tessera_render::guide::SdTree;
use tessera_render::guiding::{epochs, structure, units};
use tessera_render::integrator::MAX_VERTICES;

use crate::store::Op;

/// A guide an epoch trained, as workers fetch it.
#[derive(Debug)]
pub struct Guide {
    /// SHA-256 of `bytes`, lower-case hex.
    pub hash: String,
    /// Its encoding ([`SdTree::encode`]).
    pub bytes: Arc<Vec<u8>>,
}

impl Guide {
    fn of(tree: &SdTree) -> Self {
        let bytes = tree.encode();
        Self {
            hash: hex(&Sha256::digest(&bytes)),
            bytes: Arc::new(bytes),
        }
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// A guided job's epochs: its batches, the guides trained so far and the tree being trained.
#[derive(Debug)]
pub struct Guiding {
    /// The box epoch 0's structure spans (the scene's, from admission).
    bounds: [[f32; 3]; 2],
    /// Sample ranges of its batches.
    ranges: Vec<Range<u32>>,
    /// For each epoch, the batch one past its last.
    ends: Vec<u32>,
    /// `guides[k]`: what epoch k trained, which epoch k + 1 samples.
    guides: Vec<Guide>,
    /// The training epoch's tree, as merged so far; none in the last epoch. Shared with a
    /// checkpoint's snapshot, copied on write.
    train: Option<Arc<SdTree>>,
    /// `train` changed since the last checkpoint.
    dirty: bool,
    /// Tiles whose merged batches reach the end of the training epoch.
    through: u64,
}

impl Guiding {
    /// A guided job of `spp` samples in batches of `batch`, over `bounds`, at its start.
    pub fn new(spp: u32, batch: u32, bounds: [[f32; 3]; 2]) -> Self {
        let ranges = units(spp, batch);
        let ends = epochs(spp)
            .iter()
            .map(|e| ranges.iter().filter(|r| r.end <= e.end).count() as u32)
            .collect::<Vec<_>>();
        let train = (ends.len() > 1).then(|| Arc::new(structure(bounds, 0, None)));
        Self {
            bounds,
            ranges,
            ends,
            guides: Vec::new(),
            train,
            dirty: false,
            through: 0,
        }
    }

    /// The sample ranges of the job's batches, in order.
    pub fn ranges(&self) -> &[Range<u32>] {
        &self.ranges
    }

    /// The epoch batch `b` belongs to.
    pub fn epoch_of(&self, b: u32) -> usize {
        self.ends.partition_point(|&e| e <= b)
    }

    /// Batches that may be leased: those of the epochs whose guide exists.
    pub fn released(&self) -> u32 {
        let k = self.guides.len().min(self.ends.len().saturating_sub(1));
        self.ends.get(k).copied().unwrap_or(0)
    }

    /// The guide batch `b` samples, if its epoch samples one.
    pub fn guide_for(&self, b: u32) -> Option<&Guide> {
        self.epoch_of(b)
            .checked_sub(1)
            .and_then(|k| self.guides.get(k))
    }

    /// The first batch of epoch `k`.
    pub fn first_batch(&self, k: usize) -> u32 {
        k.checked_sub(1)
            .and_then(|p| self.ends.get(p))
            .copied()
            .unwrap_or(0)
    }

    /// Whether epoch `k` trains a guide (every epoch but the last).
    pub fn trains(&self, k: usize) -> bool {
        k + 1 < self.ends.len()
    }

    /// What rendering batch `b` takes besides the scene: the guide its epoch samples (decoded)
    /// and the empty structure it records into (none in the last epoch), as a worker builds
    /// them. For the coordinator's own render of a unit (the referee).
    pub fn unit_inputs(&self, b: u32) -> Result<(Option<SdTree>, Option<SdTree>), String> {
        let k = self.epoch_of(b);
        let guide = match k.checked_sub(1) {
            None => None,
            Some(p) => {
                let g = self
                    .guides
                    .get(p)
                    .ok_or_else(|| format!("batch {b}'s guide (epoch {p}'s) is not trained"))?;
                Some(SdTree::decode(&g.bytes).map_err(|e| format!("guide {p}: {e}"))?)
            }
        };
        let train = self
            .trains(k)
            .then(|| structure(self.bounds, k, guide.as_ref()));
        Ok((guide, train))
    }

    /// Rewinds to the start of epoch `k` (no later than the training one): the guides of
    /// epochs `k` on are dropped and epoch `k` trains afresh, from no results. An audit that
    /// convicts a worker whose training shaped guide `k` calls it (with the job's tiles taken
    /// back to the epoch's start, [`crate::job::Job::take_back`]), since every epoch after
    /// `k` sampled what the liar's training made. Returns the store change that replaces
    /// what the store holds for epoch `k` (a guide, or a training tree) with the empty tree.
    pub fn rewind(&mut self, id: u64, k: usize) -> Result<Vec<Op>, String> {
        if k > self.guides.len() {
            return Err(format!(
                "epoch {k} is past the training one ({})",
                self.guides.len()
            ));
        }
        let before = match k.checked_sub(1) {
            None => None,
            Some(p) => {
                Some(SdTree::decode(&self.guides[p].bytes).map_err(|e| format!("guide {p}: {e}"))?)
            }
        };
        self.guides.truncate(k);
        self.train = self
            .trains(k)
            .then(|| Arc::new(structure(self.bounds, k, before.as_ref())));
        self.dirty = false;
        self.through = 0;
        Ok(self
            .train
            .iter()
            .map(|t| Op::PutGuide(id, k as u32, t.encode()))
            .collect())
    }

    /// The encoding of the guide named `hash`, if this job has it.
    pub fn by_hash(&self, hash: &str) -> Option<Arc<Vec<u8>>> {
        self.guides
            .iter()
            .find(|g| g.hash == hash)
            .map(|g| g.bytes.clone())
    }

    /// The guides' hashes, epoch by epoch (kept in the job's record).
    pub fn hashes(&self) -> Vec<String> {
        self.guides.iter().map(|g| g.hash.clone()).collect()
    }

    /// Checks what a result of batch `b` over `pixels` pixels trained: a tree of the training
    /// epoch's structure, counting no more vertices than its paths can have, where its epoch
    /// trains; nothing where it does not.
    pub fn check(&self, b: u32, pixels: u64, train: Option<&SdTree>) -> Result<(), String> {
        let k = self.epoch_of(b);
        let trains = k + 1 < self.ends.len();
        match (train, trains) {
            (None, false) => Ok(()),
            (Some(_), false) => Err(format!(
                "batch {b} is of the last epoch ({k}), which trains no guide, but the result \
                 has a training tree"
            )),
            (None, true) => Err(format!(
                "batch {b} is of epoch {k}, which trains a guide, and the result has no \
                 training tree"
            )),
            (Some(t), true) => {
                if k != self.guides.len() {
                    return Err(format!(
                        "batch {b} is of epoch {k}, but epoch {} is training",
                        self.guides.len()
                    ));
                }
                let samples = self.ranges.get(b as usize).map_or(0, |r| r.len() as u64);
                let most = pixels * samples * MAX_VERTICES as u64;
                if t.records() > most {
                    return Err(format!(
                        "the training tree counts {} vertices; {pixels} pixels of {samples} \
                         samples have at most {most}",
                        t.records()
                    ));
                }
                let train = self.train.as_deref().ok_or("no tree is training")?;
                if train.same_shape(t) {
                    Ok(())
                } else {
                    Err(format!(
                        "the training tree is not epoch {k}'s structure ({} spatial leaves, \
                         {} expected, or their directional trees differ)",
                        t.leaves(),
                        train.leaves()
                    ))
                }
            }
        }
    }

    /// Adds a checked result's training tree to the epoch's.
    pub fn add(&mut self, train: &SdTree) {
        if let Some(t) = &mut self.train {
            // Checked against this structure by `check`, under the same lock.
            if Arc::make_mut(t).add(train).is_ok() {
                self.dirty = true;
            }
        }
    }

    /// A tile's merged batches went from `before` to `after`; `tiles` is the job's count. When
    /// that completes the training epoch, freezes its tree into the next guide and starts the
    /// next epoch's structure; returns the store change for the guide (job `id`).
    pub fn advanced(&mut self, id: u64, before: u32, after: u32, tiles: u64) -> Vec<Op> {
        let k = self.guides.len();
        let Some(&end) = self.ends.get(k) else {
            return Vec::new();
        };
        if before < end && after >= end {
            self.through += 1;
        }
        self.finish_epochs(id, tiles)
    }

    /// Finishes the training epoch while every tile is through it.
    fn finish_epochs(&mut self, id: u64, tiles: u64) -> Vec<Op> {
        let mut ops = Vec::new();
        while self.through >= tiles && self.train.is_some() {
            let Some(t) = self.train.take() else { break };
            let mut tree = Arc::unwrap_or_clone(t);
            tree.freeze();
            let k = self.guides.len();
            let guide = Guide::of(&tree);
            ops.push(Op::PutGuide(id, k as u32, guide.bytes.to_vec()));
            self.guides.push(guide);
            self.train = self.next_train(&tree);
            self.dirty = false;
            // No unit of the new epoch was leased before its guide existed.
            self.through = 0;
        }
        ops
    }

    /// The structure the epoch after the guides so far records into, given the last guide
    /// (`guide`); none when that epoch is the last.
    fn next_train(&self, guide: &SdTree) -> Option<Arc<SdTree>> {
        let k = self.guides.len();
        (k + 1 < self.ends.len()).then(|| Arc::new(structure(self.bounds, k, Some(guide))))
    }

    /// The training tree to write, if it changed since the last checkpoint: (epoch, tree).
    pub fn take_dirty(&mut self) -> Option<(u32, Arc<SdTree>)> {
        if !std::mem::take(&mut self.dirty) {
            return None;
        }
        self.train.clone().map(|t| (self.guides.len() as u32, t))
    }

    /// Rebuilds the epochs after a restart: `hashes` are the guides the record lists, `stored`
    /// the store's trees by epoch, `next` each tile's merged batch count. Refuses a guide that
    /// is missing or not its hash's, and a training tree of another structure.
    pub fn restore(
        &mut self,
        id: u64,
        hashes: &[String],
        stored: Vec<(u32, Vec<u8>)>,
        next: impl Iterator<Item = u32>,
        tiles: u64,
    ) -> Result<Vec<Op>, String> {
        let mut stored: std::collections::BTreeMap<u32, Vec<u8>> = stored.into_iter().collect();
        for (k, hash) in hashes.iter().enumerate() {
            let bytes = stored
                .remove(&(k as u32))
                .ok_or_else(|| format!("guide {k} ({hash}) is not in the store"))?;
            let got = hex(&Sha256::digest(&bytes));
            if &got != hash {
                return Err(format!("guide {k} is {got}, the record says {hash}"));
            }
            self.guides.push(Guide {
                hash: hash.clone(),
                bytes: Arc::new(bytes),
            });
        }
        // Only the last guide's refinement is the structure the current epoch trains.
        if let Some(last) = self.guides.last() {
            let tree = SdTree::decode(&last.bytes)
                .map_err(|e| format!("guide {}: {e}", self.guides.len() - 1))?;
            self.train = self.next_train(&tree);
        }
        let k = self.guides.len();
        if let Some(bytes) = stored.remove(&(k as u32)) {
            let tree = SdTree::decode(&bytes).map_err(|e| format!("epoch {k}'s tree: {e}"))?;
            if let Some(t) = &mut self.train {
                Arc::make_mut(t)
                    .add(&tree)
                    .map_err(|e| format!("epoch {k}'s tree: {e}"))?;
            }
        }
        let end = self.ends.get(k).copied().unwrap_or(u32::MAX);
        self.through = next.filter(|&n| n >= end).count() as u64;
        Ok(self.finish_epochs(id, tiles))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BOX: [[f32; 3]; 2] = [[-1.0; 3], [1.0; 3]];

    /// Epochs are released one at a time, each once every tile is through the one before,
    /// and each guide is named by its encoding's hash.
    #[test]
    fn an_epoch_is_released_when_every_tile_is_through_the_last() {
        let mut g = Guiding::new(16, 4, BOX);
        // Epochs [0,1) [1,3) [3,7) [7,16); batches 0..1 1..3 3..4 4..7 7..8 8..12 12..16.
        assert_eq!(g.ranges().len(), 7);
        assert_eq!(g.released(), 1);
        assert_eq!(g.epoch_of(3), 2);
        assert!(g.guide_for(0).is_none());
        // Two tiles: the first through epoch 0 releases nothing.
        assert!(g.advanced(9, 0, 1, 2).is_empty());
        assert_eq!(g.released(), 1);
        let ops = g.advanced(9, 0, 1, 2);
        assert!(matches!(ops.as_slice(), [Op::PutGuide(9, 0, _)]));
        assert_eq!(g.released(), 2);
        let hash = g.guide_for(1).map(|x| x.hash.clone()).expect("a guide");
        assert!(g.by_hash(&hash).is_some());
        assert_eq!(
            g.guide_for(1)
                .map(|x| hex(&Sha256::digest(x.bytes.as_slice()))),
            Some(hash)
        );
        // The last epoch releases everything and trains nothing.
        for (b, e) in [(1, 2), (2, 4)] {
            g.advanced(9, b, e, 2);
            g.advanced(9, b, e, 2);
        }
        assert_eq!(g.released(), 7);
        assert!(g.take_dirty().is_none());
        assert!(g.check(5, 4, None).is_ok());
    }

    /// A training tree is refused when it is missing, of another structure, or counts more
    /// vertices than the unit's paths can have.
    #[test]
    fn training_trees_are_checked() {
        let g = Guiding::new(16, 4, BOX);
        let mut t = structure(BOX, 0, None);
        assert!(g.check(0, 4, Some(&t)).is_ok());
        let refused = |t: Option<&SdTree>| g.check(0, 4, t).err().unwrap_or_default();
        assert!(refused(None).contains("no training tree"));
        let mut trained = structure(BOX, 0, None);
        trained.record(glam::Vec3A::ZERO, glam::Vec3A::Z, 1.0);
        trained.freeze();
        let other = trained.refined(0, 0.01);
        assert!(g.check(0, 4, Some(&other)).is_err());
        for _ in 0..=4 * MAX_VERTICES {
            t.record(glam::Vec3A::ZERO, glam::Vec3A::Z, 1.0);
        }
        assert!(refused(Some(&t)).contains("vertices"));
    }
}
