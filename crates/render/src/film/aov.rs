//! The AOVs' part of the film ([`crate::aov`]): per-pixel sums beside a tile's beauty sums
//! ([`AovSums`]), merged and inserted by the same rules, and their finished planes
//! ([`AovPlanes`]).

use super::MergeError;
use crate::aov::FirstHit;

/// Per-pixel AOV sums of a tile over its sample range, summed like the beauty: in index order
/// within a batch, batches added in order. Samples whose AOVs were not finite (which no
/// surface gives, but a future bug might) are left out of `count`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AovSums {
    /// Σ albedo.
    pub albedo: Vec<[f64; 3]>,
    /// Σ shading normal.
    pub normal: Vec<[f64; 3]>,
    /// Σ depth, over the samples that met a surface.
    pub depth: Vec<f64>,
    /// Samples that met a surface.
    pub hits: Vec<u32>,
    /// Samples summed.
    pub count: Vec<u32>,
}

impl AovSums {
    /// Zero sums for `n` pixels.
    pub fn zeros(n: usize) -> Self {
        Self {
            albedo: vec![[0.0; 3]; n],
            normal: vec![[0.0; 3]; n],
            depth: vec![0.0; n],
            hits: vec![0; n],
            count: vec![0; n],
        }
    }

    /// Checks every array's length against `n` pixels.
    pub fn check_shape(&self, n: usize) -> Result<(), MergeError> {
        let lens = [
            self.albedo.len(),
            self.normal.len(),
            self.depth.len(),
            self.hits.len(),
            self.count.len(),
        ];
        match lens.into_iter().find(|&len| len != n) {
            Some(got) => Err(MergeError::Shape { expected: n, got }),
            None => Ok(()),
        }
    }

    /// Adds `next`'s sums pixel by pixel (the shapes are checked by the caller).
    pub(super) fn add(&mut self, next: &AovSums) {
        for i in 0..self.count.len() {
            for c in 0..3 {
                self.albedo[i][c] += next.albedo[i][c];
                self.normal[i][c] += next.normal[i][c];
            }
            self.depth[i] += next.depth[i];
            self.hits[i] += next.hits[i];
            self.count[i] += next.count[i];
        }
    }

    /// Copies `w` pixels of `src` from `from` to this one's `to`.
    pub(crate) fn copy(&mut self, to: usize, src: &AovSums, from: usize, w: usize) {
        self.albedo[to..to + w].copy_from_slice(&src.albedo[from..from + w]);
        self.normal[to..to + w].copy_from_slice(&src.normal[from..from + w]);
        self.depth[to..to + w].copy_from_slice(&src.depth[from..from + w]);
        self.hits[to..to + w].copy_from_slice(&src.hits[from..from + w]);
        self.count[to..to + w].copy_from_slice(&src.count[from..from + w]);
    }

    /// Each pixel's means: albedo and normal over its samples, depth over those that met a
    /// surface (+∞ where none did), black and zero where it has no samples.
    pub fn finalize(&self) -> AovPlanes {
        let n = self.count.len();
        let mut out = AovPlanes::default();
        out.resize(n);
        for i in 0..n {
            let k = f64::from(self.count[i]);
            if k > 0.0 {
                for c in 0..3 {
                    out.albedo[i][c] = (self.albedo[i][c] / k) as f32;
                    out.normal[i][c] = (self.normal[i][c] / k) as f32;
                }
            }
            let h = f64::from(self.hits[i]);
            out.depth[i] = if h > 0.0 {
                (self.depth[i] / h) as f32
            } else {
                f32::INFINITY
            };
        }
        out
    }
}

/// One batch's AOV sums of one pixel, before they are added to the pixel's.
#[derive(Default)]
pub(crate) struct AovBatch {
    albedo: [f64; 3],
    normal: [f64; 3],
    depth: f64,
    hits: u32,
    count: u32,
}

impl AovBatch {
    /// Adds one sample's AOVs (left out if not finite).
    ///
    /// Each sample's albedo is clamped into [0, 1] and each normal component into [−1, 1]
    /// here, the one place every sample enters a sum: a normalised f32 vector can have a
    /// component of 1 + 1 ulp, and a base colour read from a file is whatever it says. So a
    /// pixel's sums keep to the farm's bounds (albedo in [0, count], normal in [−count,
    /// count]) by construction: rounding is monotone and every integer up to 2^53 is an f64,
    /// so a sum of `k` values each at most 1, in any order and grouping, is at most `k`.
    #[inline]
    pub(crate) fn add(&mut self, h: FirstHit) {
        let depth = h.depth.unwrap_or(0.0);
        if !(h.albedo.is_finite() && h.normal.is_finite() && depth.is_finite()) {
            return;
        }
        for c in 0..3 {
            self.albedo[c] += f64::from(h.albedo[c].clamp(0.0, 1.0));
            self.normal[c] += f64::from(h.normal[c].clamp(-1.0, 1.0));
        }
        if h.depth.is_some() {
            self.depth += f64::from(depth);
            self.hits += 1;
        }
        self.count += 1;
    }

    /// Adds this batch to pixel `i` of `sums` and starts the next batch.
    #[inline]
    pub(crate) fn flush_into(&mut self, sums: &mut AovSums, i: usize) {
        for c in 0..3 {
            sums.albedo[i][c] += self.albedo[c];
            sums.normal[i][c] += self.normal[c];
        }
        sums.depth[i] += self.depth;
        sums.hits[i] += self.hits;
        sums.count[i] += self.count;
        *self = Self::default();
    }
}

/// Finished AOV planes, row-major like the [`super::Image`] they belong to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AovPlanes {
    /// Mean albedo.
    pub albedo: Vec<[f32; 3]>,
    /// Mean shading normal (not renormalised: a pixel across an edge averages two).
    pub normal: Vec<[f32; 3]>,
    /// Mean depth of the samples that met a surface; +∞ where none did.
    pub depth: Vec<f32>,
}

impl AovPlanes {
    /// Grows or cuts the planes to `n` pixels (new pixels black, at +∞).
    pub(super) fn resize(&mut self, n: usize) {
        self.albedo.resize(n, [0.0; 3]);
        self.normal.resize(n, [0.0; 3]);
        self.depth.resize(n, f32::INFINITY);
    }

    /// The pixels from `at` on, leaving those before.
    pub(super) fn split_off(&mut self, at: usize) -> Self {
        Self {
            albedo: self.albedo.split_off(at),
            normal: self.normal.split_off(at),
            depth: self.depth.split_off(at),
        }
    }

    /// Copies `w` pixels of `src` from `from` to this one's `to`.
    pub(super) fn copy(&mut self, to: usize, src: &AovPlanes, from: usize, w: usize) {
        self.albedo[to..to + w].copy_from_slice(&src.albedo[from..from + w]);
        self.normal[to..to + w].copy_from_slice(&src.normal[from..from + w]);
        self.depth[to..to + w].copy_from_slice(&src.depth[from..from + w]);
    }

    /// Appends `other`'s pixels.
    pub(super) fn extend(&mut self, other: &AovPlanes) {
        self.albedo.extend_from_slice(&other.albedo);
        self.normal.extend_from_slice(&other.normal);
        self.depth.extend_from_slice(&other.depth);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3A;

    /// A normalised f32 normal can have a component of 1 + 1 ulp, and a base colour can be
    /// above 1: summed as they are, 32 such samples give 32.000000059604645, above the farm's
    /// bound of 32 (`check_aov_sums`), and honest workers were quarantined for it.
    #[test]
    fn sums_of_ulp_high_samples_stay_within_their_counts() {
        let over = f32::from_bits(1.0f32.to_bits() + 1);
        let hit = FirstHit {
            albedo: Vec3A::new(over, 1.5, -0.0),
            normal: Vec3A::new(-over, over, 0.0),
            depth: Some(2.0),
        };
        let mut sums = AovSums::zeros(1);
        for _ in 0..4 {
            let mut batch = AovBatch::default();
            for _ in 0..8 {
                batch.add(hit);
            }
            batch.flush_into(&mut sums, 0);
        }
        assert_eq!(sums.count[0], 32);
        assert_eq!(sums.albedo[0], [32.0, 32.0, 0.0]);
        assert_eq!(sums.normal[0], [-32.0, 32.0, 0.0]);
    }
}
