//! Noise-targeted adaptive sampling: samples go where they lower the image's relative error
//! most, until its expected value meets a target, or the spp cap.
//!
//! **The rule.** The error measured is relMSE: the mean over pixels and channels of
//! (I − R)²/(R² + 0.01), whose expectation for a tile of `n` samples per pixel is `V/n`, with
//! `V` the tile's per-sample relative variance ([`relative_variance`]: each pixel's sample
//! variance over its squared mean plus the same 0.01). For a fixed number of samples, the image's
//! relMSE, the mean of `V_t/n_t` over tiles, is least when `n_t ∝ √V_t` (Neyman allocation;
//! stopping each tile at the same error, `n_t ∝ V_t`, gives exactly uniform sampling's relMSE).
//! So every tile first takes [`MIN_SAMPLES`] (the pilot); the tiles' pilot estimates then fix
//! one scale `k = mean(√V_t) / E²` for the image ([`neyman_scale`]), chosen so that the image's
//! expected relMSE, `mean(√V_t)/k`, is the target `E` squared; and each tile goes on batch by
//! batch while its count is below `k·√V_t`, `V_t` estimated again from all its samples so far
//! ([`wants_more`]). `docs/renderer.md` gives the measured result and its bounds.
//!
//! **Determinism.** Every estimate is a pure function of sums after whole batches (`0..k`
//! merged in index order, exactly the bits every renderer and the farm's merge produce), and
//! the scale is computed once, in tile order, from every tile's pilot sums; so the same job
//! stops every tile at the same batch whoever renders it, in whatever order results arrive,
//! and after a coordinator restart (which keeps the scale in the job's record).
//!
//! **Bias.** Stopping on an estimate computed from the samples themselves makes the estimator
//! consistent rather than unbiased (a tile whose first samples happened to agree stops early,
//! and its mean keeps that luck). [`MIN_SAMPLES`] bounds the effect, and it is opt-in: without
//! a noise target every pixel takes `spp` samples and the estimator is unbiased.

use crate::film::TileSums;
use crate::settings::RenderSettings;
pub use crate::settings::{Adaptive, BadNoiseTarget, MIN_SAMPLES, NOISE_TARGET_RANGE};

/// The floor under a squared pixel value in relMSE (and in [`relative_variance`]): without it a
/// black pixel's relative error is undefined and a nearly black one's dominates the image.
pub const RELATIVE_FLOOR: f64 = 0.01;

/// The relative error of a tile from its [`TileSums::noise_parts`]: RMS standard error of the
/// pixel means over their mean (what `tessera status` and `tessera render` print as noise). A
/// tile without data, or with noise around a zero mean, is infinitely noisy; a tile of exact
/// zeros has none.
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

/// A tile's per-sample relative variance `V`: the mean over its pixels and channels of the
/// sample variance over (mean² + [`RELATIVE_FLOOR`]), so that `V/n` estimates the tile's
/// relMSE at `n` samples per pixel. Pixels with fewer than two samples count as 0.
pub fn relative_variance(sums: &TileSums) -> f64 {
    let mut total = 0.0;
    for ((s, q), &k) in sums.sum.iter().zip(&sums.sum_sq).zip(&sums.count) {
        if k < 2 {
            continue;
        }
        let k = k as f64;
        for c in 0..3 {
            let m = s[c] / k;
            let var = ((q[c] - s[c] * m) / (k - 1.0)).max(0.0);
            total += var / (m * m + RELATIVE_FLOOR);
        }
    }
    let n = sums.sum.len() * 3;
    if n == 0 {
        0.0
    } else {
        total / n as f64
    }
}

/// The image's Neyman scale `k` from every tile's pilot sums, in tile order: tiles go on while
/// their samples per pixel are below `k·√V`. `k = mean(√V)/E²` (weighted by pixels), which
/// makes the image's expected relMSE `E²`.
pub fn neyman_scale<'a>(target: f64, pilots: impl IntoIterator<Item = &'a TileSums>) -> f64 {
    let (mut root, mut pixels) = (0.0, 0.0);
    for t in pilots {
        let area = t.sum.len() as f64;
        root += relative_variance(t).sqrt() * area;
        pixels += area;
    }
    if pixels == 0.0 {
        return 0.0;
    }
    root / pixels / (target * target)
}

/// Batches every tile takes before the first decision: [`MIN_SAMPLES`], and at least two so
/// that a batch of any size has a variance to estimate from.
pub fn min_batches(batch: u32) -> u32 {
    MIN_SAMPLES.div_ceil(batch.max(1)).max(2)
}

/// Samples per pixel in every tile's pilot: [`min_batches`] batches, or `spp` if fewer; all of
/// `spp` without a noise target.
pub fn pilot_samples(settings: &RenderSettings) -> u32 {
    let batch = settings.batch.max(1);
    match settings.adaptive {
        Some(_) => min_batches(batch).saturating_mul(batch).min(settings.spp),
        None => settings.spp,
    }
}

/// Whether a tile whose sums over batches `0..k` end at sample `end` and have the relative
/// variance `v` ([`relative_variance`]) takes batch `k`, under the image's Neyman `scale`
/// ([`neyman_scale`]). Without a noise target, every tile runs to `spp`; with one, every
/// tile takes its pilot.
pub fn wants_more(settings: &RenderSettings, end: u32, v: f64, scale: f64) -> bool {
    if end >= settings.spp {
        return false;
    }
    if settings.adaptive.is_none() || end < pilot_samples(settings) {
        return true;
    }
    (end as f64) < scale * v.sqrt()
}

/// [`wants_more`] for a tile's sums.
pub fn tile_wants_more(settings: &RenderSettings, sums: &TileSums, scale: f64) -> bool {
    let end = sums.samples.end;
    // The variance walks every pixel: a render without a target, and sums at the cap or in
    // the pilot, need none.
    if end >= settings.spp || settings.adaptive.is_none() || end < pilot_samples(settings) {
        return end < settings.spp;
    }
    wants_more(settings, end, relative_variance(sums), scale)
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
    fn the_relative_variance_is_relmse_per_sample() {
        // Each pixel: mean v, sample variance v²·k/(k-1); relMSE per sample var/(v² + 0.01).
        let k = 64;
        let t = sums(&[1.0, 0.05], k);
        let var = |v: f64| v * v * k as f64 / (k as f64 - 1.0);
        let want = (var(1.0) / 1.01 + var(0.05) / (0.0025 + 0.01)) / 2.0;
        let got = relative_variance(&t);
        assert!((got - want).abs() < 1e-12 * want, "{got} vs {want}");
        // The dark pixel counts for less than its relative variance (1.0) alone would say.
        assert!(var(0.05) / (0.0025 + 0.01) < 0.25);
    }

    #[test]
    fn the_scale_makes_the_expected_relmse_the_target_squared() {
        // Tiles of relative variance V₁ and V₂ stopped at n = k·√V have relMSE √V/k each;
        // their mean must be E².
        let e = 0.05;
        let (a, b) = (sums(&[1.0], 64), sums(&[1.0, 0.3, 0.2, 0.1], 64));
        let k = neyman_scale(e, [&a, &b]);
        let (va, vb) = (relative_variance(&a), relative_variance(&b));
        let relmse = (va / (k * va.sqrt()) + 4.0 * vb / (k * vb.sqrt())) / 5.0;
        assert!((relmse - e * e).abs() < 1e-12, "{relmse} vs {}", e * e);
    }

    #[test]
    fn tiles_stop_at_their_neyman_count_and_never_before_the_pilot_or_after_the_cap() {
        let s = adaptive(0.05);
        // In the pilot, even a noiseless tile goes on; after it, a noiseless tile stops.
        let flat = |k| {
            let mut t = sums(&[1.0], k);
            t.sum_sq = vec![[k as f64; 3]];
            t
        };
        assert!(tile_wants_more(&s, &flat(32), 1e9));
        assert!(!tile_wants_more(&s, &flat(64), 1e9));
        // A tile goes on while its count is below k·√V.
        let t = sums(&[2.0], 384);
        let root = relative_variance(&t).sqrt();
        assert!(tile_wants_more(&s, &t, 385.0 / root));
        assert!(!tile_wants_more(&s, &t, 383.0 / root));
        // At the cap nothing goes on, however noisy.
        let mut noisy = sums(&[2.0], 1024);
        noisy.sum_sq = vec![[1e9; 3]];
        assert!(!tile_wants_more(&s, &noisy, 1e9));
        // Without a target, every tile runs to the cap.
        let uniform = RenderSettings {
            adaptive: None,
            ..s
        };
        assert!(tile_wants_more(&uniform, &flat(1000), 0.0));
        assert!(!tile_wants_more(&uniform, &flat(1024), 0.0));
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
