//! The statistics of a benchmark: relMSE against a reference, means over seeds, the
//! relMSE·seconds summary of each renderer, and the reference's own noise taken off both sides.

use std::collections::BTreeMap;

use tessera_render::output::{tone_map, Preview, RgbImage};
use tessera_render::Image;

use super::peer::Row;

/// relMSE of `img` against `reference`: mean over pixels and channels of (I−R)²/(R²+0.01).
pub(super) fn rel_mse(img: &Image, reference: &RgbImage) -> f64 {
    let mut sum = 0f64;
    for (p, r) in img.rgb.iter().zip(&reference.rgb) {
        for c in 0..3 {
            let (i, r) = (p[c] as f64, r[c] as f64);
            sum += (i - r) * (i - r) / (r * r + 0.01);
        }
    }
    sum / (3 * img.rgb.len()) as f64
}

/// Mean FLIP (NVIDIA's perceptual difference, LDR, Andersson et al. 2020) of `img` against
/// `reference` as both are seen on a display: each tone-mapped as `tessera render --preview`
/// maps it (ACES, then sRGB, 8 bits), at FLIP's default 67 pixels per degree (a 0.7 m
/// viewing distance from a 4K monitor 0.7 m wide). 0 is identical; relMSE weighs every
/// pixel's error, FLIP what a viewer sees of it (blur, lost texture, noise), which is what
/// denoising trades.
pub(super) fn flip(img: &Image, reference: &RgbImage) -> f64 {
    let (w, h) = (img.width, img.height);
    debug_assert_eq!(
        (w as usize, h as usize),
        (reference.width, reference.height)
    );
    let shown = |rgb: &[[f32; 3]]| {
        let codes = tone_map(rgb, Preview { exposure: 0.0 });
        nv_flip::FlipImageRgb8::with_data(w, h, &codes)
    };
    let map = nv_flip::flip(
        shown(&reference.rgb),
        shown(&img.rgb),
        nv_flip::DEFAULT_PIXELS_PER_DEGREE,
    );
    let errors = map.to_vec();
    errors.iter().map(|&e| f64::from(e)).sum::<f64>() / errors.len().max(1) as f64
}

/// [`rel_mse`] and [`flip`] of `img` against `reference`, for a row.
pub(super) fn errors(img: &Image, reference: &RgbImage) -> (f64, f64) {
    (rel_mse(img, reference), flip(img, reference))
}

/// Per (scene, renderer, spp): mean seconds, mean relMSE, mean Msamples/s over seeds.
pub(super) type Series = BTreeMap<(String, String), BTreeMap<u32, (f64, f64, f64)>>;

pub(super) fn series(rows: &[Row]) -> Series {
    let mut acc: BTreeMap<(String, String), BTreeMap<u32, Vec<&Row>>> = BTreeMap::new();
    for r in rows {
        acc.entry((r.scene.clone(), r.renderer.clone()))
            .or_default()
            .entry(r.spp)
            .or_default()
            .push(r);
    }
    acc.into_iter()
        .map(|(k, by_spp)| {
            let v = by_spp
                .into_iter()
                .map(|(spp, rs)| {
                    let n = rs.len() as f64;
                    let mean = |f: &dyn Fn(&Row) -> f64| rs.iter().map(|r| f(r)).sum::<f64>() / n;
                    (
                        spp,
                        (
                            mean(&|r| r.seconds),
                            mean(&|r| r.relmse),
                            mean(&|r| r.msamples_per_s),
                        ),
                    )
                })
                .collect();
            (k, v)
        })
        .collect()
}

/// relMSE·seconds (geometric mean over spp ≥ 64, where error falls as 1/time and fixed costs
/// no longer dominate) and throughput (all samples over all time) of one series.
pub(super) fn summary(points: &BTreeMap<u32, (f64, f64, f64)>) -> (f64, f64) {
    let fit: Vec<f64> = points
        .iter()
        .filter(|(spp, _)| **spp >= 64)
        .map(|(_, (s, e, _))| (s * e).ln())
        .collect();
    let err_time = if fit.is_empty() {
        f64::NAN
    } else {
        (fit.iter().sum::<f64>() / fit.len() as f64).exp()
    };
    let (samples, secs) = points
        .values()
        .fold((0.0, 0.0), |(n, t), (s, _, m)| (n + m * s, t + s));
    (err_time, samples / secs)
}

/// The expected share of the reference's own noise in every relMSE of `scene`, estimated from
/// the renderers' top octave.
///
/// A render I and a reference R are independent, so E[(I − R)²] = E[(I − μ)²] + E[(R − μ)²]:
/// the reference adds the same ρ to every point of a scene, whichever renderer made it, and at
/// high spp it is a large part of a good render's error (docs/renderer.md gives its share on
/// the Cornell box). Where a renderer's own error falls as 1/spp over its last octave (e at 4N
/// is e/4), its points e₁ at N and e₄ at 4N give ρ = (4·e₄ − e₁)/3. A renderer whose error
/// falls faster there (quasi-Monte Carlo) makes the estimate smaller, never larger, so the
/// correction leans towards too little. The mean over
/// the scene's renderers, `None` without a top octave or where the estimate is not positive.
pub(super) fn reference_noise(all: &Series, scene: &str) -> Option<f64> {
    let of_scene: Vec<_> = all
        .iter()
        .filter(|((s, _), _)| s == scene)
        .map(|(_, points)| points)
        .collect();
    let estimates: Vec<f64> = of_scene
        .iter()
        .filter_map(|points| {
            let mut top = points.iter().rev();
            let (&n4, &(_, e4, _)) = top.next()?;
            let (&n1, &(_, e1, _)) = top.next()?;
            (n4 == 4 * n1).then_some((4.0 * e4 - e1) / 3.0)
        })
        .collect();
    let rho = estimates.iter().sum::<f64>() / estimates.len() as f64;
    // Below every point's error, or the "corrected" error of some point would be 0 or less.
    let floor = of_scene
        .iter()
        .flat_map(|p| p.values().map(|v| v.1))
        .fold(f64::INFINITY, f64::min);
    (rho > 0.0 && rho < floor).then_some(rho)
}

/// [`reference_noise`] of every scene of `all`, estimated once for the table and its notes.
pub(super) fn reference_noises(all: &Series) -> BTreeMap<String, Option<f64>> {
    all.keys()
        .map(|(scene, _)| (scene.clone(), reference_noise(all, scene)))
        .collect()
}

/// Rows of the by-spp table: for each peer of each scene and each spp both measured, tessera's
/// relMSE·s over the peer's as measured and with the scene's estimated reference noise `rho`
/// taken off both.
pub(super) fn by_spp(
    all: &Series,
    rho: &BTreeMap<String, Option<f64>>,
) -> Vec<(String, String, u32, f64, Option<f64>)> {
    let mut out = Vec::new();
    for ((scene, renderer), points) in all {
        let Some(t) = all.get(&(scene.clone(), "tessera".to_string())) else {
            continue;
        };
        if renderer == "tessera" {
            continue;
        }
        let rho = rho.get(scene).copied().flatten();
        for (spp, &(ps, pe, _)) in points {
            let Some(&(ts, te, _)) = t.get(spp) else {
                continue;
            };
            let raw = (ts * te) / (ps * pe);
            let corrected = rho.map(|r| (ts * (te - r)) / (ps * (pe - r)));
            out.push((scene.clone(), renderer.clone(), *spp, raw, corrected));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summary_is_relmse_times_seconds_over_the_1_over_n_range() {
        let mut p = BTreeMap::new();
        p.insert(4, (0.1, 1.0, 2.0)); // excluded: below 64 spp
        p.insert(64, (1.0, 0.01, 2.0));
        p.insert(256, (4.0, 0.0025, 2.0));
        let (et, ms) = summary(&p);
        assert!((et - 0.01).abs() < 1e-12, "{et}");
        assert!((ms - 2.0).abs() < 1e-12);
    }

    /// Two renderers whose own errors fall as 1/spp, against a reference that adds ρ to every
    /// point: the estimate finds ρ, and the corrected ratio is the ratio of the own errors.

    #[test]
    fn reference_noise_is_found_and_taken_off_both_sides() {
        let rho = 2e-5;
        let series = |c: f64, ms: f64| -> BTreeMap<u32, (f64, f64, f64)> {
            [64u32, 256, 1024, 4096]
                .into_iter()
                .map(|spp| {
                    let secs = 65536.0 * f64::from(spp) / (ms * 1e6);
                    (spp, (secs, c / f64::from(spp) + rho, ms))
                })
                .collect()
        };
        let mut all = Series::new();
        all.insert(("box".into(), "tessera".into()), series(0.1, 3.0));
        all.insert(("box".into(), "peer".into()), series(0.3, 2.0));
        let est = reference_noise(&all, "box").expect("estimated");
        assert!((est - rho).abs() < 1e-12, "{est}");
        let rows = by_spp(&all, &reference_noises(&all));
        assert_eq!(rows.len(), 4);
        // Own errors 0.1 against 0.3 per sample, and tessera 1.5x as fast: 1/4.5 at every spp.
        for (_, peer, spp, raw, corrected) in rows {
            assert_eq!(peer, "peer");
            let c = corrected.expect("corrected");
            assert!((c - 1.0 / 4.5).abs() < 1e-9, "{spp}: {c}");
            // The measured ratio is pulled towards 1 by the shared ρ, most at high spp.
            assert!(raw > c, "{spp}: {raw} vs {c}");
        }
        // Without a top octave (one spp), nothing is estimated.
        let mut one = Series::new();
        one.insert(
            ("box".into(), "tessera".into()),
            [(64, (1.0, 0.01, 2.0))].into(),
        );
        assert_eq!(reference_noise(&one, "box"), None);
        // An estimate at or above some point's error is refused rather than giving a negative
        // error: here the last octave does not fall at all.
        let mut flat = Series::new();
        flat.insert(
            ("box".into(), "tessera".into()),
            [(1024, (1.0, 1e-4, 2.0)), (4096, (4.0, 1e-4, 2.0))].into(),
        );
        assert_eq!(reference_noise(&flat, "box"), None);
    }
}
