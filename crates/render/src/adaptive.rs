//! Noise-targeted adaptive sampling: each tile takes batches until the estimated relative
//! error of its pixel means meets a target, or the spp cap.
//!
//! The decision is a pure function of a tile's sums after whole batches (`0..k` merged in
//! index order, exactly the bits every renderer and the farm's merge produce), so the same job
//! stops every tile at the same batch whoever renders it, in whatever order results arrive,
//! and after a coordinator restart rebuilds the sums from its store.
//!
//! **Bias.** Stopping on an estimate computed from the samples themselves makes the estimator
//! consistent rather than unbiased (a tile whose first samples happened to agree stops early,
//! and its mean keeps that luck). [`MIN_SAMPLES`] bounds the effect, and it is opt-in: without
//! a noise target every pixel takes `spp` samples and the estimator is unbiased.

use std::ops::RangeInclusive;

use crate::film::TileSums;
use crate::integrator::RenderSettings;

/// The noise targets accepted: a relative error of 0.01% to 100%.
pub const NOISE_TARGET_RANGE: RangeInclusive<f64> = 1e-4..=1.0;

/// Samples every pixel takes before its tile's noise may stop it: a variance estimated from a
/// handful of samples is often far too low (a dark tile whose rare bright paths have not been
/// found yet looks noiseless).
pub const MIN_SAMPLES: u32 = 64;

/// The adaptive part of a render's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adaptive {
    /// The relative error at which a tile stops: the RMS standard error of its pixel means
    /// divided by their mean (the `noise_relative` that `tessera status` shows for a job).
    pub noise_target: f64,
    /// Edge of the square tiles the decision is made for, in pixels. It is part of the job's
    /// identity: other tiles stop at other batches.
    pub tile: u32,
}

/// A noise target outside [`NOISE_TARGET_RANGE`].
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "noise target {0} must be a relative error between {min} and {max}",
    min = NOISE_TARGET_RANGE.start(),
    max = NOISE_TARGET_RANGE.end()
)]
pub struct BadNoiseTarget(pub f64);

impl Adaptive {
    /// Checks the target (`tile` is the caller's to check against its own tile range).
    pub fn new(noise_target: f64, tile: u32) -> Result<Self, BadNoiseTarget> {
        if !NOISE_TARGET_RANGE.contains(&noise_target) {
            return Err(BadNoiseTarget(noise_target));
        }
        Ok(Self { noise_target, tile })
    }
}

/// The relative error of a tile from its [`TileSums::noise_parts`]: RMS standard error of the
/// pixel means over their mean. A tile without data, or with noise around a zero mean, is
/// infinitely noisy; a tile of exact zeros has none.
pub fn relative_noise((var, mean, n): (f64, f64, u64)) -> f64 {
    if n == 0 {
        return f64::INFINITY;
    }
    let rms = (var.max(0.0) / n as f64).sqrt();
    let mean = mean / n as f64;
    if mean > 0.0 {
        rms / mean
    } else if rms == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}

/// Batches every tile takes before the first decision: [`MIN_SAMPLES`], and at least two so
/// that a batch of any size has a variance to estimate from.
pub fn min_batches(batch: u32) -> u32 {
    MIN_SAMPLES.div_ceil(batch.max(1)).max(2)
}

/// Whether a tile whose sums over batches `0..k` have the noise parts `noise` and end at sample
/// `end` takes batch `k`. Without a noise target, every tile runs to `spp`.
pub fn wants_more(settings: &RenderSettings, end: u32, noise: (f64, f64, u64)) -> bool {
    if end >= settings.spp {
        return false;
    }
    let Some(a) = settings.adaptive else {
        return true;
    };
    let batch = settings.batch.max(1);
    if end < min_batches(batch).saturating_mul(batch) {
        return true;
    }
    relative_noise(noise) > a.noise_target
}

/// [`wants_more`] for a tile's sums.
pub fn tile_wants_more(settings: &RenderSettings, sums: &TileSums) -> bool {
    let end = sums.samples.end;
    // The noise estimate walks every pixel: a render without a target, and sums at the cap,
    // need none.
    end < settings.spp
        && (settings.adaptive.is_none() || wants_more(settings, end, sums.noise_parts()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::PixelRect;

    fn sums(values: &[f64], k: u32) -> TileSums {
        let rect = PixelRect {
            x0: 0,
            y0: 0,
            width: values.len() as u32,
            height: 1,
        };
        let mut t = TileSums::empty(rect, 0);
        t.samples = 0..k;
        for (i, v) in values.iter().enumerate() {
            // k samples: half at 0 and half at 2v, so mean v and sample variance v²·k/(k-1).
            t.sum[i] = [v * k as f64; 3];
            t.sum_sq[i] = [4.0 * v * v * (k / 2) as f64; 3];
            t.count[i] = k;
        }
        t
    }

    fn adaptive(target: f64) -> RenderSettings {
        RenderSettings {
            spp: 1024,
            batch: 16,
            adaptive: Some(Adaptive::new(target, 8).expect("target")),
            ..RenderSettings::default()
        }
    }

    #[test]
    fn the_relative_noise_is_the_standard_error_over_the_mean() {
        // Each pixel: mean v, variance of the mean v²/(k-1)·… = s²/k with s² = v²·k/(k-1).
        let k = 64;
        let t = sums(&[1.0, 3.0], k);
        let s2 = |v: f64| v * v * k as f64 / (k as f64 - 1.0) / k as f64;
        let want = ((s2(1.0) + s2(3.0)) / 2.0).sqrt() / 2.0;
        let got = relative_noise(t.noise_parts());
        assert!((got - want).abs() < 1e-12 * want, "{got} vs {want}");
    }

    #[test]
    fn tiles_stop_at_the_target_and_never_before_the_minimum_or_after_the_cap() {
        let s = adaptive(0.05);
        // Below the minimum, even a noiseless tile goes on.
        let flat = |k| {
            let mut t = sums(&[1.0], k);
            t.sum_sq = vec![[k as f64; 3]];
            t
        };
        assert!(tile_wants_more(&s, &flat(32)));
        assert!(!tile_wants_more(&s, &flat(64)));
        // Relative error 1/√k falls below 0.05 at k = 400.
        assert!(tile_wants_more(&s, &sums(&[2.0], 384)));
        assert!(!tile_wants_more(&s, &sums(&[2.0], 416)));
        // At the cap nothing goes on, however noisy.
        let mut noisy = sums(&[2.0], 1024);
        noisy.sum_sq = vec![[1e9; 3]];
        assert!(!tile_wants_more(&s, &noisy));
        // Without a target, every tile runs to the cap.
        let uniform = RenderSettings {
            adaptive: None,
            ..s
        };
        assert!(tile_wants_more(&uniform, &flat(1000)));
    }

    #[test]
    fn dark_and_empty_tiles() {
        assert_eq!(relative_noise((0.0, 0.0, 4)), 0.0);
        assert_eq!(relative_noise((1.0, 0.0, 4)), f64::INFINITY);
        assert_eq!(relative_noise((0.0, 0.0, 0)), f64::INFINITY);
    }

    #[test]
    fn targets_outside_the_range_are_refused() {
        for bad in [0.0, -0.01, 1.5, f64::NAN, f64::INFINITY] {
            assert!(Adaptive::new(bad, 32).is_err(), "{bad}");
        }
        assert!(Adaptive::new(0.01, 32).is_ok());
    }
}
