//! The film: pixel rectangles, the partial sums a render returns for one ([`TileSums`]: f64
//! sum of RGB, f64 sum of squares, sample count per pixel), their merging, and the finished
//! [`Image`] they assemble into. Rendering them is [`crate::tile`]'s.
//!
//! Sums are f64 and merged in a fixed order: two sample ranges cut at a batch boundary merge to
//! exactly the bits of rendering their union in one call, and tiles are inserted into a frame
//! without arithmetic, so the frame's bits are its tiles' bits.

use std::ops::Range;

mod aov;
mod strips;

pub(crate) use aov::AovBatch;
pub use aov::{AovPlanes, AovSums};
pub use strips::{assemble_image, Strips};

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
    /// The AOVs' sums, when the render asked for any ([`crate::settings::Aovs`]); boxed, so
    /// that sums without them stay small where they are moved and kept.
    pub aov: Option<Box<AovSums>>,
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
    /// One has AOV sums and the other none.
    #[error("one of the partial sums has AOV sums and the other has none")]
    Aov,
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
            aov: None,
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
        match &self.aov {
            Some(a) => a.check_shape(n),
            None => Ok(()),
        }
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
        match (&mut self.aov, &next.aov) {
            (Some(a), Some(b)) => a.add(b),
            (None, None) => {}
            // An accumulator with no samples yet takes the AOVs' shape from its first part.
            (None, Some(b)) if self.samples.is_empty() => self.aov = Some(b.clone()),
            _ => return Err(MergeError::Aov),
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
        if tile.samples != self.samples {
            return Err(MergeError::Order {
                have: self.samples.clone(),
                got: tile.samples.clone(),
            });
        }
        self.insert_any(tile)
    }

    /// [`TileSums::insert`] for a tile that may cover fewer samples than this accumulator's
    /// range (as long as it starts where the range does and ends inside it): an adaptive
    /// render's tiles stop at different batches.
    pub fn insert_upto(&mut self, tile: &TileSums) -> Result<(), MergeError> {
        if tile.samples.start != self.samples.start || tile.samples.end > self.samples.end {
            return Err(MergeError::Order {
                have: self.samples.clone(),
                got: tile.samples.clone(),
            });
        }
        self.insert_any(tile)
    }

    fn insert_any(&mut self, tile: &TileSums) -> Result<(), MergeError> {
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
        tile.check_shape()?;
        if let (None, Some(_)) = (&self.aov, &tile.aov) {
            self.aov = Some(Box::new(AovSums::zeros(r.area())));
        }
        for row in 0..t.height {
            let src = (row * t.width) as usize;
            let dst = ((t.y0 - r.y0 + row) * r.width + (t.x0 - r.x0)) as usize;
            let w = t.width as usize;
            if let (Some(to), Some(from)) = (&mut self.aov, &tile.aov) {
                to.copy(dst, from, src, w);
            }
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
            aov: self.aov.as_ref().map(|a| a.finalize()),
        }
    }
}

/// A finished image.
#[derive(Clone, Debug, Default, PartialEq)]
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
    /// The AOVs' planes, when the render asked for any.
    pub aov: Option<AovPlanes>,
}

impl Image {
    /// Appends `strip`'s rows below this image's (of the same width): a frame put together
    /// from the strips its writer takes.
    pub fn append(&mut self, strip: &Image) {
        self.rgb.extend_from_slice(&strip.rgb);
        self.variance.extend_from_slice(&strip.variance);
        self.count.extend_from_slice(&strip.count);
        if let (Some(to), Some(from)) = (&mut self.aov, &strip.aov) {
            to.extend(from);
        }
        self.nonfinite += strip.nonfinite;
        self.height += strip.height;
    }

    /// Noise summary: root-mean-square standard error of pixel means (luminance-weighted
    /// channels averaged), and the same relative to the mean pixel value.
    pub fn noise(&self) -> (f64, f64) {
        let mut sum = NoiseSum::default();
        sum.add(self);
        sum.noise()
    }

    /// What the finished image is flagged for ([`OutputChecks`]).
    pub fn checks(&self) -> OutputChecks {
        OutputChecks {
            black: !self.rgb.is_empty() && !any_lit(&self.rgb),
            nonfinite: self.nonfinite,
        }
    }
}

/// Whether any pixel has a channel above zero (negative values are not light).
fn any_lit(rgb: &[[f32; 3]]) -> bool {
    rgb.iter().any(|c| c.iter().any(|&x| x > 0.0))
}

/// What a finished image is flagged for, as render farms check their frames (Royal Render's
/// "job checking"): the image is delivered as rendered, but a frame that is entirely black (no
/// light reached the camera: a missing light, a camera inside an object) or that left out
/// non-finite samples (NaN or infinite radiance, which the merge drops) is not delivered
/// silently. Stored with a farm job's record, so it survives restarts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct OutputChecks {
    /// No pixel has a channel above zero.
    #[serde(default)]
    pub black: bool,
    /// Samples left out for being non-finite.
    #[serde(default)]
    pub nonfinite: u64,
}

impl OutputChecks {
    /// Stable code of the black check.
    pub const BLACK: &'static str = "black";
    /// Stable code of the non-finite check.
    pub const NONFINITE: &'static str = "nonfinite";

    /// The checks the image failed, as (stable code, one line for people); empty when it
    /// passed them all.
    pub fn failed(&self) -> Vec<(&'static str, String)> {
        let mut out = Vec::new();
        if self.black {
            out.push((
                Self::BLACK,
                "the image is entirely black: no light reached the camera (check the lights, \
                 the environment and where the camera is)"
                    .to_string(),
            ));
        }
        if self.nonfinite > 0 {
            out.push((
                Self::NONFINITE,
                format!(
                    "{} non-finite samples (NaN or infinite) were left out of the image",
                    self.nonfinite
                ),
            ));
        }
        out
    }
}

/// [`Image::noise`] of an image taken a strip of rows at a time: the same bits as the whole
/// image's, when the strips are added top to bottom, since each total is a running sum over
/// the pixels in row-major order either way. It also notes whether any pixel is lit, for
/// [`OutputChecks`].
#[derive(Clone, Copy, Debug, Default)]
pub struct NoiseSum {
    var: f64,
    mean: f64,
    pixels: usize,
    lit: bool,
}

impl NoiseSum {
    /// Adds the next strip's pixels.
    pub fn add(&mut self, strip: &Image) {
        for v in &strip.variance {
            self.var += (v[0] + v[1] + v[2]) as f64 / 3.0;
        }
        for c in &strip.rgb {
            self.mean += (c[0] + c[1] + c[2]) as f64 / 3.0;
        }
        self.lit |= any_lit(&strip.rgb);
        self.pixels += strip.rgb.len();
    }

    /// Whether every pixel added so far is black: no channel of any pixel above zero.
    pub fn black(&self) -> bool {
        self.pixels > 0 && !self.lit
    }

    /// The noise of the pixels added so far, as [`Image::noise`] gives it.
    pub fn noise(&self) -> (f64, f64) {
        let n = self.pixels.max(1) as f64;
        let (var, mean) = (self.var / n, self.mean / n);
        let rms = var.sqrt();
        (rms, if mean > 0.0 { rms / mean } else { 0.0 })
    }
}

/// Assembles a `width` × `height` frame from tiles that each cover samples `0..spp` and
/// together partition it ([`assemble_render`] for a render without a noise target).
pub fn assemble_frame(
    width: u32,
    height: u32,
    spp: u32,
    tiles: &[TileSums],
) -> Result<TileSums, MergeError> {
    assemble(width, height, spp, tiles, TileSums::insert)
}

/// The frame of a render with `settings`: [`assemble_frame`] at `settings.spp`, or for an
/// adaptive render, whose tiles stop at different batches, tiles that each cover samples `0..k`
/// for their own `k` of at most `spp` (the cap; the `count` per pixel says how many each took).
pub fn assemble_render(
    settings: &crate::RenderSettings,
    width: u32,
    height: u32,
    tiles: &[TileSums],
) -> Result<TileSums, MergeError> {
    let insert = if settings.adaptive.is_some() {
        TileSums::insert_upto
    } else {
        TileSums::insert
    };
    assemble(width, height, settings.spp, tiles, insert)
}

fn assemble(
    width: u32,
    height: u32,
    spp: u32,
    tiles: &[TileSums],
    insert: fn(&mut TileSums, &TileSums) -> Result<(), MergeError>,
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
        insert(&mut frame, t)?;
    }
    Ok(frame)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(rgb: Vec<[f32; 3]>, nonfinite: u64) -> Image {
        let n = rgb.len();
        Image {
            width: n as u32,
            height: 1,
            rgb,
            variance: vec![[0.0; 3]; n],
            count: vec![4; n],
            nonfinite,
            aov: None,
        }
    }

    #[test]
    fn a_black_image_and_dropped_samples_are_flagged_and_a_lit_pixel_is_not_black() {
        let black = image(vec![[0.0; 3]; 6], 0);
        assert_eq!(
            black.checks(),
            OutputChecks {
                black: true,
                nonfinite: 0
            }
        );
        let codes: Vec<&str> = black.checks().failed().iter().map(|c| c.0).collect();
        assert_eq!(codes, [OutputChecks::BLACK]);
        // One channel of one pixel lit is not black; negative values (which no render
        // makes) are not light either.
        let mut rgb = vec![[0.0, -1.0, 0.0]; 6];
        assert!(image(rgb.clone(), 0).checks().black);
        rgb[5][2] = 1e-30;
        let lit = image(rgb, 3);
        assert!(!lit.checks().black);
        let failed = lit.checks().failed();
        assert_eq!(failed.len(), 1);
        assert_eq!(failed[0].0, OutputChecks::NONFINITE);
        assert!(
            failed[0].1.starts_with("3 non-finite samples"),
            "{}",
            failed[0].1
        );
        // Strip by strip, as the farm writes a frame: lit once any strip is.
        let mut sum = NoiseSum::default();
        assert!(!sum.black(), "nothing added is not a black image");
        sum.add(&black);
        assert!(sum.black());
        sum.add(&lit);
        assert!(!sum.black());
        assert!(image(vec![[0.5; 3]], 0).checks().failed().is_empty());
    }
}
