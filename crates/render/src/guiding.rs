//! Guided rendering (issue #60): a frame rendered in epochs of doubling sample counts, each
//! sampling directions from the guide ([`crate::guide::SdTree`]) that the epochs before it
//! trained, and training the next.
//!
//! Epoch k renders sample indices [2^k − 1, 2^(k+1) − 1); the last epoch also takes the
//! samples short of a whole further epoch, so it is never smaller than the one before. Epoch
//! 0 samples no guide, and the last trains none. The structure each epoch trains is the last
//! guide's refinement ([`crate::guide::SdTree::refined`]), a pure function of its sums.
//!
//! Turning itself off. From epoch [`FIRST_OFF_EPOCH`] on, a guide that would not pay for
//! itself is not sampled ([`guides`]): one none of whose leaves samples it (each chose α = 0),
//! or whose chosen mixtures measured more than [`OFF_ABOVE`] of the cosine lobe's second
//! moment. Its epoch renders unguided (the many-path tracer where it applies) and records
//! nothing, so the next guide has learned nothing and guiding stays off to the end. A guided
//! sample costs two to three unguided ones (docs/renderer.md), so a guide that cuts the
//! second moment by less than half loses at equal time; the first epochs are never off,
//! because their guides are too crude to judge by (a first guide's leaves choose α = 0 on
//! every scene measured, and better guides follow).
//!
//! The image is the plain mean of every sample of every epoch. Each sample is unbiased
//! whatever guide it drew from (see [`crate::integrator`]'s guided vertex), so the mean is
//! too; weights computed from the epochs' own variances (Müller et al.'s later
//! inverse-variance combination) would correlate the weights with what they weigh and bias the
//! mean, if only slightly. A plain mean is also what the film already sums: the frame's sums
//! are those of samples [0, spp), merged in index order, as any render's.
//!
//! Determinism. Within an epoch, each thread records into its own copy of the structure; the
//! copies' sums are integers ([`crate::guide`]), so adding them gives the same guide whatever
//! thread recorded what, and so the same bits on any number of threads. The same holds across
//! machines: a farm's unit is one rectangle and one of [`units`]' sample ranges, rendered with
//! [`render_tile_guided`] against [`structure`], and its trained tree added to the epoch's in
//! any order. A pixel's sums fold those ranges in index order, here as on a farm, so a farm
//! gives this renderer's bits.

use std::ops::Range;
use std::sync::Mutex;

use rayon::prelude::*;

use crate::film::{assemble_render, PixelRect, TileSums};
use crate::guide::SdTree;
use crate::integrator::{sample_pixel_with, GuidedPath, RenderSettings};
use crate::scene::Scene;
use crate::tile::{aov_sums, render_tile, scalar_row};
use glam::Vec3A;

/// Müller et al.'s spatial split constant: a leaf splits once it counts more than
/// c·√(2^k) vertices in epoch k.
pub const SPLIT_C: f64 = 12_000.0;

/// The share of a directional tree's energy a quadrant needs to be refined (Müller's ρ).
pub const RHO: f64 = 0.01;

/// The first epoch that may render unguided, if the guide it would sample does not pay
/// ([`guides`]): epochs 0–2 are 7 samples, a cost a render of hundreds hardly sees.
pub const FIRST_OFF_EPOCH: usize = 3;

/// The most of the cosine lobe's second moment a guide's chosen mixtures may measure
/// ([`SdTree::second_moment_ratio`]) and still be sampled from [`FIRST_OFF_EPOCH`] on.
pub const OFF_ABOVE: f64 = 0.5;

/// Whether epoch `k` samples `guide` (the one epoch k − 1 trained), or renders unguided and
/// records nothing: a pure function of the guide and `k`, so a farm's workers and a local
/// render decide alike.
pub fn guides(k: usize, guide: Option<&SdTree>) -> bool {
    let Some(g) = guide else { return false };
    k < FIRST_OFF_EPOCH || (g.guides() && g.second_moment_ratio().is_none_or(|r| r <= OFF_ABOVE))
}

/// The tile edge the guided renderer renders by (it cannot change a bit: pixels are
/// independent, and guides' sums do not depend on order).
const TILE: u32 = 32;

/// One epoch of a guided render, as the render reports it.
#[derive(Clone, Debug, PartialEq)]
pub struct Epoch {
    /// Its sample indices.
    pub samples: Range<u32>,
    /// Spatial leaves of the guide it sampled (0: none).
    pub guide_leaves: usize,
    /// Bytes that guide held.
    pub guide_bytes: usize,
    /// Whether it sampled that guide ([`guides`]); false for epoch 0, and for the epochs
    /// after guiding turned itself off.
    pub guided: bool,
}

/// A guided render: the frame's sums and its epochs.
pub struct GuidedFrame {
    /// Sums of samples [0, spp) of every pixel.
    pub sums: TileSums,
    /// The epochs, in order.
    pub epochs: Vec<Epoch>,
    /// The last guide (which the last epoch sampled).
    pub guide: Option<SdTree>,
}

/// The sample ranges of the epochs of a guided render of `spp` samples.
pub fn epochs(spp: u32) -> Vec<Range<u32>> {
    let mut out = Vec::new();
    let mut start = 0u32;
    let mut size = 1u32;
    while start < spp {
        let mut end = start.saturating_add(size).min(spp);
        // Too few left for a whole epoch after this one: they join this one.
        if spp - end < size.saturating_mul(2) {
            end = spp;
        }
        out.push(start..end);
        start = end;
        size = size.saturating_mul(2);
    }
    out
}

/// The sample ranges a guided render of `spp` samples in batches of `batch` is merged by:
/// every epoch cut at each multiple of `batch` inside it. No range crosses an epoch (its samples
/// draw from one guide) or a batch boundary (so none is larger than a batch). A farm's guided
/// job has one unit per tile and range.
pub fn units(spp: u32, batch: u32) -> Vec<Range<u32>> {
    let batch = batch.max(1);
    let mut out = Vec::new();
    for e in epochs(spp) {
        let mut s = e.start;
        while s < e.end {
            let end = (s / batch)
                .saturating_add(1)
                .saturating_mul(batch)
                .min(e.end);
            out.push(s..end);
            s = end;
        }
    }
    out
}

/// The epoch (index into [`epochs`]) that sample `index` of a guided render of `spp` samples
/// belongs to; `None` past `spp`.
pub fn epoch_of(spp: u32, index: u32) -> Option<usize> {
    epochs(spp).iter().position(|e| e.contains(&index))
}

/// The count above which a leaf splits in the structure epoch `k` trains.
fn split_after(k: usize) -> u64 {
    (SPLIT_C * 2f64.powf(k as f64 / 2.0)) as u64
}

/// The structure epoch `k` of a guided render records into: the empty tree over `bounds`
/// ([`guide_bounds`] of the scene) for epoch 0, else the refinement of `guide`, the guide
/// epoch `k` samples (trained by epoch k − 1). A pure function of its arguments, so every
/// machine builds the same one.
pub fn structure(bounds: [[f32; 3]; 2], k: usize, guide: Option<&SdTree>) -> SdTree {
    match guide {
        None => SdTree::new(Vec3A::from(bounds[0]), Vec3A::from(bounds[1])),
        Some(g) => g.refined(split_after(k), RHO),
    }
}

/// The box a guide of `scene` starts from: the one holding every finite object (planes are
/// infinite).
pub fn guide_bounds(scene: &Scene) -> [[f32; 3]; 2] {
    crate::scene::shape_bounds(&scene.prims)
}

/// Renders the whole frame with path guiding, calling `progress` with the number of samples
/// finished after each tile of each epoch. `settings.adaptive` and `settings.tracer` are not
/// read: a guided render takes every sample, one path at a time.
pub fn render_frame_guided(
    scene: &Scene,
    settings: &RenderSettings,
    progress: &(dyn Fn(u64) + Sync),
) -> GuidedFrame {
    let tiles = PixelRect::tiles(scene.width, scene.height, TILE);
    let mut acc: Vec<TileSums> = tiles.iter().map(|&r| TileSums::empty(r, 0)).collect();
    let ranges = epochs(settings.spp);
    let cuts = units(settings.spp, settings.batch);
    let bounds = guide_bounds(scene);
    let mut guide: Option<SdTree> = None;
    let mut report = Vec::new();
    for (k, samples) in ranges.iter().enumerate() {
        let trains = k + 1 < ranges.len();
        let training = trains.then(|| structure(bounds, k, guide.as_ref()));
        let guided = guides(k, guide.as_ref());
        // Epoch 0 samples no guide but trains the first; an epoch after guiding turned off
        // records nothing.
        let records = guided || k == 0;
        let pool = copies(training.as_ref().filter(|_| records));
        report.push(Epoch {
            samples: samples.clone(),
            guide_leaves: guide.as_ref().map_or(0, SdTree::leaves),
            guide_bytes: guide.as_ref().map_or(0, SdTree::memory_bytes),
            guided,
        });
        let mine: Vec<&Range<u32>> = cuts.iter().filter(|r| samples.contains(&r.start)).collect();
        acc.par_iter_mut().for_each(|acc| {
            // Range by range, as a farm merges its units: a pixel's bits depend on where its
            // sums were cut.
            for r in &mine {
                let part = if records {
                    guided_tile(scene, settings, acc.rect, r, guide.as_ref(), &pool)
                } else {
                    render_tile(scene, settings, acc.rect, (*r).clone())
                };
                acc.merge(&part)
                    .expect("same rectangle, contiguous samples");
                progress(acc.rect.area() as u64 * r.len() as u64);
            }
        });
        if let Some(next) = if records {
            summed(pool)
        } else {
            training.map(frozen)
        } {
            guide = Some(next);
        }
    }
    let sums = assemble_render(settings, scene.width, scene.height, &acc)
        .expect("tiles partition the frame and cover samples from 0");
    GuidedFrame {
        sums,
        epochs: report,
        guide,
    }
}

/// Renders `rect` for sample indices `samples`, sampling directions from `guide` (none: the
/// first epoch) and training a copy of `train` (none: the last epoch), which it returns
/// frozen: what a farm's unit of a guided job is. An epoch whose guide does not pay
/// ([`guides`]; its index follows from `samples` and `settings.spp`) renders unguided and
/// returns `train` with nothing recorded. Parallel over rows; the same bits on any number of
/// threads.
pub fn render_tile_guided(
    scene: &Scene,
    settings: &RenderSettings,
    rect: PixelRect,
    samples: Range<u32>,
    guide: Option<&SdTree>,
    train: Option<&SdTree>,
) -> (TileSums, Option<SdTree>) {
    let k = epoch_of(settings.spp, samples.start).unwrap_or(0);
    if k > 0 && !guides(k, guide) {
        let sums = render_tile(scene, settings, rect, samples);
        return (sums, train.cloned().map(frozen));
    }
    let pool = copies(train);
    let sums = guided_tile(scene, settings, rect, &samples, guide, &pool);
    (sums, summed(pool))
}

/// One copy of `structure` for each thread of the current rayon pool.
fn copies(structure: Option<&SdTree>) -> Vec<Mutex<SdTree>> {
    structure
        .map(|t| {
            (0..rayon::current_num_threads())
                .map(|_| Mutex::new(t.clone()))
                .collect()
        })
        .unwrap_or_default()
}

fn frozen(mut tree: SdTree) -> SdTree {
    tree.freeze();
    tree
}

/// The threads' trees added up (in any order: their sums are integers), frozen.
fn summed(pool: Vec<Mutex<SdTree>>) -> Option<SdTree> {
    let mut trees = pool
        .into_iter()
        .map(|m| m.into_inner().unwrap_or_else(|e| e.into_inner()));
    let mut sum = trees.next()?;
    for t in trees {
        sum.add(&t).expect("copies of one structure");
    }
    Some(frozen(sum))
}

/// Renders `rect` for `samples`, sampling `guide` and recording into the calling thread's
/// tree of `pool` (none: nothing recorded). Parallel over rows; a row holds its thread's tree
/// for as long as it runs, and no row waits on another's.
fn guided_tile(
    scene: &Scene,
    settings: &RenderSettings,
    rect: PixelRect,
    samples: &Range<u32>,
    guide: Option<&SdTree>,
    pool: &[Mutex<SdTree>],
) -> TileSums {
    let mut out = TileSums::empty(rect, samples.start);
    out.samples = samples.clone();
    let w = rect.width as usize;
    out.nonfinite = out
        .sum
        .par_chunks_mut(w)
        .zip(out.sum_sq.par_chunks_mut(w))
        .zip(out.count.par_chunks_mut(w))
        .enumerate()
        .map(|(row, ((sum, sum_sq), count))| {
            let y = rect.y0 + row as u32;
            let mut tree = (!pool.is_empty()).then(|| {
                let i = rayon::current_thread_index().unwrap_or(0) % pool.len();
                pool[i].lock().unwrap_or_else(|e| e.into_inner())
            });
            let mut path = GuidedPath::new(guide, tree.as_deref_mut());
            scalar_row(
                settings,
                (rect.x0, y),
                samples,
                (sum, sum_sq, count),
                |x, sampler| sample_pixel_with(scene, settings, x, y, sampler, &mut path),
            )
        })
        .sum();
    if settings.aovs.any() {
        out.aov = Some(Box::new(aov_sums(scene, settings, rect, samples)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_cut_epochs_at_batches() {
        assert_eq!(
            units(64, 16),
            vec![
                0..1,
                1..3,
                3..7,
                7..15,
                15..16,
                16..31,
                31..32,
                32..48,
                48..64
            ]
        );
        for (spp, batch) in [(1, 1), (7, 3), (100, 16), (257, 64), (40, 1000)] {
            let u = units(spp, batch);
            assert_eq!(u[0].start, 0);
            assert_eq!(u.last().map(|r| r.end), Some(spp));
            for w in u.windows(2) {
                assert_eq!(w[0].end, w[1].start);
            }
            for r in &u {
                assert!(r.len() as u32 <= batch, "{r:?}");
                assert_eq!(
                    (r.start / batch),
                    (r.end - 1) / batch,
                    "{r:?} crosses a batch"
                );
                let k = epoch_of(spp, r.start);
                assert_eq!(k, epoch_of(spp, r.end - 1), "{r:?} crosses an epoch");
            }
        }
        assert_eq!(epoch_of(64, 64), None);
    }

    #[test]
    fn epochs_double_and_the_last_takes_the_rest() {
        assert_eq!(epochs(1), vec![0..1]);
        assert_eq!(epochs(2), vec![0..2]);
        assert_eq!(epochs(4), vec![0..1, 1..4]);
        assert_eq!(epochs(64), vec![0..1, 1..3, 3..7, 7..15, 15..31, 31..64]);
        assert_eq!(epochs(0), Vec::<Range<u32>>::new());
        for spp in 1..300 {
            let e = epochs(spp);
            assert_eq!(e[0].start, 0);
            assert_eq!(e.last().map(|r| r.end), Some(spp));
            for w in e.windows(2) {
                assert_eq!(w[0].end, w[1].start);
                assert!(w[1].len() >= w[0].len(), "{spp}: {e:?}");
            }
        }
    }
}
