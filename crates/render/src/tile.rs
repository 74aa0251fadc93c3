//! The tile API: render a pixel rectangle for a range of sample indices into partial sums,
//! merge partial sums, and finalise them into an image.
//!
//! Accumulation order is fixed per pixel: samples are summed in index order within each batch
//! (samples `[k·batch, (k+1)·batch)`), starting from zero, and batch sums are added in batch
//! order. Pixels are independent, so neither the tile shape nor the thread count can change a
//! bit; and two sample ranges cut at a batch boundary merge to exactly the bits of rendering
//! their union in one call.

use std::ops::Range;

use rayon::prelude::*;

use crate::integrator::{sample_pixel, RenderSettings};
use crate::sampling::PixelSampler;
use crate::scene::Scene;

/// A rectangle of pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PixelRect {
    /// Left column.
    pub x0: u32,
    /// Top row.
    pub y0: u32,
    /// Width (> 0).
    pub width: u32,
    /// Height (> 0).
    pub height: u32,
}

impl PixelRect {
    /// Number of pixels.
    pub fn area(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether it lies inside a `width` × `height` image.
    pub fn fits(&self, width: u32, height: u32) -> bool {
        self.width > 0
            && self.height > 0
            && self.x0.checked_add(self.width).is_some_and(|r| r <= width)
            && self
                .y0
                .checked_add(self.height)
                .is_some_and(|b| b <= height)
    }

    /// Cuts a `width` × `height` image into tiles of at most `size` × `size`, row-major.
    pub fn tiles(width: u32, height: u32, size: u32) -> Vec<PixelRect> {
        let size = size.max(1);
        let mut v = Vec::new();
        for y0 in (0..height).step_by(size as usize) {
            for x0 in (0..width).step_by(size as usize) {
                v.push(PixelRect {
                    x0,
                    y0,
                    width: size.min(width - x0),
                    height: size.min(height - y0),
                });
            }
        }
        v
    }
}

/// Per-pixel partial sums of a rectangle over a contiguous range of sample indices.
#[derive(Clone, Debug, PartialEq)]
pub struct TileSums {
    /// The pixels covered.
    pub rect: PixelRect,
    /// The sample indices covered.
    pub samples: Range<u32>,
    /// Σ radiance, row-major.
    pub sum: Vec<[f64; 3]>,
    /// Σ radiance², row-major.
    pub sum_sq: Vec<[f64; 3]>,
    /// Samples accumulated per pixel (fewer than the range only if some were non-finite).
    pub count: Vec<u32>,
    /// Non-finite samples that were counted and left out of the sums.
    pub nonfinite: u64,
}

/// Why two partial sums cannot be merged.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MergeError {
    /// Different rectangles.
    #[error("tile {got:?} does not match {expected:?}")]
    Rect {
        /// The accumulator's rectangle.
        expected: PixelRect,
        /// The other's.
        got: PixelRect,
    },
    /// Merging out of order would change the bits.
    #[error("samples {got:?} do not continue {have:?}: merges must follow sample order")]
    Order {
        /// The accumulator's range.
        have: Range<u32>,
        /// The other's.
        got: Range<u32>,
    },
    /// Arrays of the wrong length.
    #[error("partial sums hold {got} pixels where the tile has {expected}")]
    Shape {
        /// Pixels in the rectangle.
        expected: usize,
        /// Entries present.
        got: usize,
    },
}

impl TileSums {
    /// Empty sums (sample range `start..start`).
    pub fn empty(rect: PixelRect, start: u32) -> Self {
        let n = rect.area();
        Self {
            rect,
            samples: start..start,
            sum: vec![[0.0; 3]; n],
            sum_sq: vec![[0.0; 3]; n],
            count: vec![0; n],
            nonfinite: 0,
        }
    }

    /// Checks the array lengths against the rectangle.
    pub fn check_shape(&self) -> Result<(), MergeError> {
        let n = self.rect.area();
        for len in [self.sum.len(), self.sum_sq.len(), self.count.len()] {
            if len != n {
                return Err(MergeError::Shape {
                    expected: n,
                    got: len,
                });
            }
        }
        Ok(())
    }

    /// Adds `next`, which must cover the same rectangle and the samples right after ours.
    pub fn merge(&mut self, next: &TileSums) -> Result<(), MergeError> {
        if next.rect != self.rect {
            return Err(MergeError::Rect {
                expected: self.rect,
                got: next.rect,
            });
        }
        next.check_shape()?;
        if next.samples.start != self.samples.end {
            return Err(MergeError::Order {
                have: self.samples.clone(),
                got: next.samples.clone(),
            });
        }
        for i in 0..self.sum.len() {
            for c in 0..3 {
                self.sum[i][c] += next.sum[i][c];
                self.sum_sq[i][c] += next.sum_sq[i][c];
            }
            self.count[i] += next.count[i];
        }
        self.samples.end = next.samples.end;
        self.nonfinite += next.nonfinite;
        Ok(())
    }

    /// Copies a tile's sums into this larger accumulator (which must contain its rectangle and
    /// cover the same samples).
    pub fn insert(&mut self, tile: &TileSums) -> Result<(), MergeError> {
        let (r, t) = (self.rect, tile.rect);
        if t.x0 < r.x0
            || t.y0 < r.y0
            || t.x0 + t.width > r.x0 + r.width
            || t.y0 + t.height > r.y0 + r.height
        {
            return Err(MergeError::Rect {
                expected: r,
                got: t,
            });
        }
        if tile.samples != self.samples {
            return Err(MergeError::Order {
                have: self.samples.clone(),
                got: tile.samples.clone(),
            });
        }
        tile.check_shape()?;
        for row in 0..t.height {
            let src = (row * t.width) as usize;
            let dst = ((t.y0 - r.y0 + row) * r.width + (t.x0 - r.x0)) as usize;
            let w = t.width as usize;
            self.sum[dst..dst + w].copy_from_slice(&tile.sum[src..src + w]);
            self.sum_sq[dst..dst + w].copy_from_slice(&tile.sum_sq[src..src + w]);
            self.count[dst..dst + w].copy_from_slice(&tile.count[src..src + w]);
        }
        self.nonfinite += tile.nonfinite;
        Ok(())
    }

    /// (Σ variance of the mean, Σ mean, pixels with data), each pixel's channels averaged: the
    /// parts of [`Image::noise`], so a merger can add them up tile by tile without building
    /// the image.
    pub fn noise_parts(&self) -> (f64, f64, u64) {
        let (mut var, mut mean, mut n) = (0.0, 0.0, 0u64);
        for i in 0..self.sum.len() {
            let k = self.count[i] as f64;
            if k < 1.0 {
                continue;
            }
            n += 1;
            for c in 0..3 {
                let m = self.sum[i][c] / k;
                mean += m / 3.0;
                if k > 1.0 {
                    var +=
                        ((self.sum_sq[i][c] - self.sum[i][c] * m) / (k - 1.0)).max(0.0) / k / 3.0;
                }
            }
        }
        (var, mean, n)
    }

    /// Mean radiance, variance of the mean and sample count per pixel.
    pub fn finalize(&self) -> Image {
        let n = self.sum.len();
        let mut rgb = Vec::with_capacity(n);
        let mut variance = Vec::with_capacity(n);
        for i in 0..n {
            let k = self.count[i] as f64;
            let mut m = [0f32; 3];
            let mut v = [0f32; 3];
            if k > 0.0 {
                for c in 0..3 {
                    let mean = self.sum[i][c] / k;
                    m[c] = mean as f32;
                    if k > 1.0 {
                        // Unbiased sample variance over k, clamped at 0 against cancellation.
                        let s2 = ((self.sum_sq[i][c] - self.sum[i][c] * mean) / (k - 1.0)).max(0.0);
                        v[c] = (s2 / k) as f32;
                    }
                }
            }
            rgb.push(m);
            variance.push(v);
        }
        Image {
            width: self.rect.width,
            height: self.rect.height,
            rgb,
            variance,
            count: self.count.clone(),
            nonfinite: self.nonfinite,
        }
    }
}

/// A finished image.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Mean radiance per pixel, row-major, row 0 at the top.
    pub rgb: Vec<[f32; 3]>,
    /// Variance of each pixel's mean (sample variance / count).
    pub variance: Vec<[f32; 3]>,
    /// Samples per pixel.
    pub count: Vec<u32>,
    /// Non-finite samples left out.
    pub nonfinite: u64,
}

impl Image {
    /// Noise summary: root-mean-square standard error of pixel means (luminance-weighted
    /// channels averaged), and the same relative to the mean pixel value.
    pub fn noise(&self) -> (f64, f64) {
        let n = self.rgb.len().max(1) as f64;
        let var: f64 = self
            .variance
            .iter()
            .map(|v| (v[0] + v[1] + v[2]) as f64 / 3.0)
            .sum::<f64>()
            / n;
        let mean: f64 = self
            .rgb
            .iter()
            .map(|c| (c[0] + c[1] + c[2]) as f64 / 3.0)
            .sum::<f64>()
            / n;
        let rms = var.sqrt();
        (rms, if mean > 0.0 { rms / mean } else { 0.0 })
    }
}

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
    let batch = settings.batch.max(1);
    // Scenes whose bounce the many-path tracer models take it: the same bits, and more
    // samples a second than the scalar trace (docs/renderer.md). `TESSERA_SCALAR`
    // forces one path at a time and `TESSERA_LANES` (4, 8 or 16) the lane count, for timing them
    // against each other; neither can change a bit of the output.
    let wide = if std::env::var_os("TESSERA_SCALAR").is_some() {
        None
    } else {
        let lanes = std::env::var("TESSERA_LANES")
            .ok()
            .and_then(|v| v.parse().ok());
        crate::wide::Wide::new(scene, settings).and_then(|w| match lanes {
            Some(n) => w.with_lanes(n),
            None => Some(w),
        })
    };
    let nonfinite: u64 = out
        .sum
        .par_chunks_mut(w)
        .zip(out.sum_sq.par_chunks_mut(w))
        .zip(out.count.par_chunks_mut(w))
        .enumerate()
        .map(|(row, ((sum, sum_sq), count))| {
            let y = rect.y0 + row as u32;
            let mut bad = 0u64;
            if let Some(wide) = &wide {
                return wide_row(wide, settings, (rect.x0, y), &samples, sum, sum_sq, count);
            }
            for (col, ((s, sq), k)) in sum
                .iter_mut()
                .zip(sum_sq.iter_mut())
                .zip(count.iter_mut())
                .enumerate()
            {
                let x = rect.x0 + col as u32;
                let mut sampler = PixelSampler::new(settings.seed, x, y, samples.start);
                let mut i = samples.start;
                while i < samples.end {
                    let end = ((i / batch).saturating_add(1))
                        .saturating_mul(batch)
                        .min(samples.end);
                    let mut b = BatchSums::default();
                    for index in i..end {
                        sampler.set_index(index);
                        b.add(sample_pixel(scene, settings, x, y, &sampler));
                    }
                    b.flush_into(s, sq, k, &mut bad);
                    i = end;
                }
            }
            bad
        })
        .sum();
    out.nonfinite = nonfinite;
    out
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

/// Assembles a `width` × `height` frame from tiles that each cover samples `0..spp` and
/// together partition it (the local renderer's last step, and the farm coordinator's).
pub fn assemble_frame(
    width: u32,
    height: u32,
    spp: u32,
    tiles: &[TileSums],
) -> Result<TileSums, MergeError> {
    let full = PixelRect {
        x0: 0,
        y0: 0,
        width,
        height,
    };
    let mut frame = TileSums::empty(full, 0);
    frame.samples = 0..spp;
    for t in tiles {
        frame.insert(t)?;
    }
    Ok(frame)
}

/// Renders the whole frame for `settings.spp` samples, tile by tile and batch by batch, calling
/// `progress` with the number of samples finished after each tile batch.
pub fn render_frame(
    scene: &Scene,
    settings: &RenderSettings,
    progress: &(dyn Fn(u64) + Sync),
) -> TileSums {
    let batch = settings.batch.max(1);
    let tiles = PixelRect::tiles(scene.width, scene.height, 32);
    let done: Vec<TileSums> = tiles
        .par_iter()
        .map(|&rect| {
            let mut acc = TileSums::empty(rect, 0);
            let mut s = 0;
            while s < settings.spp {
                let e = s.saturating_add(batch).min(settings.spp);
                let part = render_tile(scene, settings, rect, s..e);
                acc.merge(&part)
                    .expect("same rectangle, contiguous samples");
                progress(rect.area() as u64 * (e - s) as u64);
                s = e;
            }
            acc
        })
        .collect();
    assemble_frame(scene.width, scene.height, settings.spp, &done)
        .expect("tiles partition the frame and cover 0..spp")
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
