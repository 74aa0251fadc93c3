//! The render driver: a pixel rectangle for a range of sample indices into partial sums
//! ([`TileSums`], defined with the rest of the film in [`crate::film`]), parallel over rows
//! with rayon, and the whole frame tile by tile.
//!
//! Accumulation order is fixed per pixel: samples are summed in index order within each batch
//! (samples `[k·batch, (k+1)·batch)`), starting from zero, and batch sums are added in batch
//! order. Pixels are independent, so neither the tile shape nor the thread count can change a
//! bit; and two sample ranges cut at a batch boundary merge to exactly the bits of rendering
//! their union in one call.

use std::ops::Range;

use rayon::prelude::*;

use crate::adaptive::{neyman_scale, pilot_samples, tile_wants_more};
use crate::aov::first_hit;
use crate::film::{assemble_render, AovBatch, AovSums, PixelRect, TileSums};
use crate::integrator::{sample_pixel, RenderSettings, Tracer};
use crate::scene::Scene;
use crate::util::sampling::PixelSampler;

/// One pixel's sums over one batch: the only place a sample enters the image. A non-finite
/// sample (which no test scene has produced, but a future bug might) is counted and dropped,
/// so it is reported instead of poisoning the pixel and every merge after it.
#[derive(Default)]
struct BatchSums {
    sum: [f64; 3],
    sum_sq: [f64; 3],
    count: u32,
    nonfinite: u64,
}

impl BatchSums {
    #[inline]
    fn add(&mut self, v: glam::Vec3A) {
        if !v.is_finite() {
            self.nonfinite += 1;
            return;
        }
        for c in 0..3 {
            let f = v[c] as f64;
            self.sum[c] += f;
            self.sum_sq[c] += f * f;
        }
        self.count += 1;
    }

    /// Adds this batch to its pixel's sums, sample count and non-finite count, in the one
    /// order every path through `render_tile` merges batches in, and starts the next batch.
    #[inline]
    fn flush_into(
        &mut self,
        sum: &mut [f64; 3],
        sum_sq: &mut [f64; 3],
        count: &mut u32,
        nonfinite: &mut u64,
    ) {
        for c in 0..3 {
            sum[c] += self.sum[c];
            sum_sq[c] += self.sum_sq[c];
        }
        *count += self.count;
        *nonfinite += self.nonfinite;
        *self = Self::default();
    }
}

/// How many samples the many-path tracer takes at a time (from one pixel or from several of a
/// row): their values are kept until all are done, to be summed in index order.
const STREAM_CHUNK: u32 = 2048;

/// Renders `rect` for sample indices `samples` (parallel over rows with rayon).
pub fn render_tile(
    scene: &Scene,
    settings: &RenderSettings,
    rect: PixelRect,
    samples: Range<u32>,
) -> TileSums {
    let mut out = TileSums::empty(rect, samples.start);
    out.samples = samples.clone();
    let w = rect.width as usize;
    // Scenes whose bounce the many-path tracer models take it: the same bits, and more
    // samples a second than the scalar trace (docs/renderer.md).
    let wide = match settings.tracer {
        Tracer::Scalar => None,
        Tracer::Auto => crate::wide::Wide::new(scene, settings),
        Tracer::Lanes(n) => {
            crate::wide::Wide::anywhere(scene, settings).and_then(|w| w.with_lanes(n))
        }
    };
    let nonfinite: u64 = out
        .sum
        .par_chunks_mut(w)
        .zip(out.sum_sq.par_chunks_mut(w))
        .zip(out.count.par_chunks_mut(w))
        .enumerate()
        .map(|(row, ((sum, sum_sq), count))| {
            let y = rect.y0 + row as u32;
            if let Some(wide) = &wide {
                return wide_row(wide, settings, (rect.x0, y), &samples, sum, sum_sq, count);
            }
            scalar_row(
                settings,
                (rect.x0, y),
                &samples,
                (sum, sum_sq, count),
                |x, sampler| sample_pixel(scene, settings, x, y, sampler),
            )
        })
        .sum();
    out.nonfinite = nonfinite;
    if settings.aovs.any() {
        out.aov = Some(Box::new(aov_sums(scene, settings, rect, &samples)));
    }
    out
}

/// One row of pixels from column `x0`, one path at a time: each pixel's samples `samples`
/// from `sample` (given the column and the sampler set to each index in turn) into its sums.
/// Returns the non-finite samples.
#[inline]
pub(crate) fn scalar_row(
    settings: &RenderSettings,
    (x0, y): (u32, u32),
    samples: &Range<u32>,
    (sum, sum_sq, count): (&mut [[f64; 3]], &mut [[f64; 3]], &mut [u32]),
    mut sample: impl FnMut(u32, &PixelSampler) -> glam::Vec3A,
) -> u64 {
    let mut bad = 0u64;
    for (col, sums) in sum
        .iter_mut()
        .zip(sum_sq.iter_mut())
        .zip(count.iter_mut())
        .enumerate()
    {
        let x = x0 + col as u32;
        pixel_sums(settings, (x, y), samples, sums, &mut bad, |sampler| {
            sample(x, sampler)
        });
    }
    bad
}

/// One pixel's samples `samples` from `sample` (given the sampler set to each index in turn),
/// summed batch by batch in index order into its sums (sum, sum of squares, count); `bad`
/// counts the non-finite ones.
#[inline]
fn pixel_sums(
    settings: &RenderSettings,
    (x, y): (u32, u32),
    samples: &Range<u32>,
    ((s, sq), k): ((&mut [f64; 3], &mut [f64; 3]), &mut u32),
    bad: &mut u64,
    mut sample: impl FnMut(&PixelSampler) -> glam::Vec3A,
) {
    let batch = settings.batch.max(1);
    let mut sampler = PixelSampler::new(settings.seed, x, y, samples.start);
    let mut i = samples.start;
    while i < samples.end {
        let end = ((i / batch).saturating_add(1))
            .saturating_mul(batch)
            .min(samples.end);
        let mut b = BatchSums::default();
        for index in i..end {
            sampler.set_index(index);
            b.add(sample(&sampler));
        }
        b.flush_into(s, sq, k, bad);
        i = end;
    }
}

/// The AOVs' sums of `rect` over `samples` ([`crate::aov`]): their own pass over the tile,
/// parallel over rows, each pixel's samples summed by batch in index order as the beauty's are.
pub(crate) fn aov_sums(
    scene: &Scene,
    settings: &RenderSettings,
    rect: PixelRect,
    samples: &Range<u32>,
) -> AovSums {
    let w = rect.width as usize;
    let batch = settings.batch.max(1);
    let rows: Vec<AovSums> = (0..rect.height)
        .into_par_iter()
        .map(|row| {
            let y = rect.y0 + row;
            let mut sums = AovSums::zeros(w);
            for col in 0..w {
                let x = rect.x0 + col as u32;
                let mut sampler = PixelSampler::new(settings.seed, x, y, samples.start);
                let mut b = AovBatch::default();
                for index in samples.clone() {
                    sampler.set_index(index);
                    b.add(first_hit(scene, x, y, &sampler));
                    if (index + 1) % batch == 0 || index + 1 == samples.end {
                        b.flush_into(&mut sums, col);
                    }
                }
            }
            sums
        })
        .collect();
    let mut all = AovSums::zeros(rect.area());
    for (row, sums) in rows.iter().enumerate() {
        all.copy(row * w, sums, 0, w);
    }
    all
}

/// One row of a tile through the many-path tracer: the row's pixels and samples cut into runs
/// of at most [`STREAM_CHUNK`] samples in all, so that the lanes go on from one pixel to the
/// next, and each value folded into its pixel's sums in index order, batch by batch. Returns
/// the non-finite samples.
fn wide_row(
    wide: &crate::wide::Wide<'_>,
    settings: &RenderSettings,
    (x0, y): (u32, u32),
    samples: &Range<u32>,
    sum: &mut [[f64; 3]],
    sum_sq: &mut [[f64; 3]],
    count: &mut [u32],
) -> u64 {
    let batch = settings.batch.max(1);
    let mut bad = 0u64;
    let mut runs = Vec::new();
    let mut cols = Vec::new();
    let mut values = Vec::new();
    let mut b = BatchSums::default();
    let (mut col, mut start) = (0, samples.start);
    while col < sum.len() {
        runs.clear();
        cols.clear();
        let mut room = STREAM_CHUNK;
        while col < sum.len() && room > 0 {
            let x = x0 + col as u32;
            let end = start.saturating_add(room).min(samples.end);
            runs.push(crate::wide::PixelRun {
                x,
                y,
                sampler: PixelSampler::new(settings.seed, x, y, start),
                samples: start..end,
            });
            cols.push(col);
            room -= end - start;
            if end == samples.end {
                col += 1;
                start = samples.start;
            } else {
                start = end;
            }
        }
        wide.trace(&runs, &mut values);
        let mut v = values.iter();
        for (run, &c) in runs.iter().zip(&cols) {
            for (index, value) in run.samples.clone().zip(&mut v) {
                b.add(*value);
                // Batches end at multiples of `batch` and at the end of the range.
                if (index + 1) % batch == 0 || index + 1 == samples.end {
                    b.flush_into(&mut sum[c], &mut sum_sq[c], &mut count[c], &mut bad);
                }
            }
        }
    }
    bad
}

/// Renders the whole frame, tile by tile and batch by batch, calling `progress` with the number
/// of samples finished after each tile batch. Each tile takes `settings.spp` samples, or, with
/// a noise target, its pilot, and then batches until [`crate::adaptive::tile_wants_more`] says
/// it has enough under the scale every tile's pilot gives: the decisions the farm's coordinator
/// makes from the same sums, so both stop every tile at the same batch.
pub fn render_frame(
    scene: &Scene,
    settings: &RenderSettings,
    progress: &(dyn Fn(u64) + Sync),
) -> TileSums {
    let batch = settings.batch.max(1);
    // Without a noise target the tiles' shape cannot change a bit; with one it decides where
    // samples go, and must be the job's.
    let size = settings.adaptive.map_or(32, |a| a.tile.max(1));
    let tiles = PixelRect::tiles(scene.width, scene.height, size);
    // Batch by batch up to `until` (each batch merged in index order, as the farm merges).
    let step = |acc: &mut TileSums, until: u32| {
        let s = acc.samples.end;
        let e = s.saturating_add(batch).min(until);
        let part = render_tile(scene, settings, acc.rect, s..e);
        acc.merge(&part)
            .expect("same rectangle, contiguous samples");
        progress(acc.rect.area() as u64 * (e - s) as u64);
    };
    let pilot = pilot_samples(settings);
    let mut done: Vec<TileSums> = tiles
        .par_iter()
        .map(|&rect| {
            let mut acc = TileSums::empty(rect, 0);
            while acc.samples.end < pilot {
                step(&mut acc, pilot);
            }
            acc
        })
        .collect();
    if let Some(a) = settings.adaptive {
        let scale = neyman_scale(a.noise_target, &done);
        done.par_iter_mut().for_each(|acc| {
            while tile_wants_more(settings, acc, scale) {
                step(acc, settings.spp);
            }
        });
    }
    assemble_render(settings, scene.width, scene.height, &done)
        .expect("tiles partition the frame and cover samples from 0")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_samples_are_counted_and_never_merged() {
        let mut b = BatchSums::default();
        b.add(glam::Vec3A::new(1.0, 2.0, 3.0));
        b.add(glam::Vec3A::new(f32::NAN, 0.0, 0.0));
        b.add(glam::Vec3A::new(0.0, f32::INFINITY, 0.0));
        b.add(glam::Vec3A::new(0.0, 0.0, f32::NEG_INFINITY));
        b.add(glam::Vec3A::new(3.0, 2.0, 1.0));
        assert_eq!(b.nonfinite, 3);
        assert_eq!(b.count, 2);
        assert_eq!(b.sum, [4.0, 4.0, 4.0]);
        assert_eq!(b.sum_sq, [10.0, 8.0, 10.0]);
    }
}
