//! Furnace tests: scenes whose answer is known in closed form.

mod common;

use common::{render, scene};
use tessera_render::{RenderSettings, Strategy};

/// Mean over all pixels and its standard error (pixels are independent: each has its own
/// scrambled sequence).
fn image_mean(img: &tessera_render::Image) -> ([f64; 3], [f64; 3]) {
    common::region_stats(img, 0, 0, img.width, img.height)
}

/// A closed, two-sided diffuse sphere with albedo ρ that emits Le, seen from inside. Every
/// path bounces forever inside, so L = Le + ρL, i.e. L = Le/(1 − ρ): unlimited depth and
/// Russian roulette are both exercised.
#[test]
fn closed_emitting_sphere_gives_le_over_one_minus_albedo() {
    let (rho, le) = ([0.8f64, 0.5, 0.3], [0.5f64, 1.0, 2.0]);
    let s = scene(&common::closed_sphere(rho, le, 24, 16));
    // Both Russian roulette rules: pbrt's (threshold 1) and the default.
    let cases = [Strategy::Bsdf, Strategy::Nee, Strategy::Mis]
        .into_iter()
        .flat_map(|s| [(s, 1.0), (s, RenderSettings::default().rr_threshold)]);
    for (strategy, rr_threshold) in cases {
        let img = render(
            &s,
            &RenderSettings {
                spp: 256,
                seed: 3,
                strategy,
                rr_threshold,
                ..RenderSettings::default()
            },
        );
        let (mean, se) = image_mean(&img);
        eprintln!("{strategy:?}, RR threshold {rr_threshold}: {mean:?} ± {se:?}");
        for c in 0..3 {
            let expected = le[c] / (1.0 - rho[c]);
            let tol = 3.0 * se[c] + 1e-5 * expected;
            assert!(
                (mean[c] - expected).abs() <= tol,
                "{strategy:?}, RR threshold {rr_threshold}, channel {c}: {} vs Le/(1-ρ) = {expected} (3σ = {})",
                mean[c],
                3.0 * se[c]
            );
            assert!(
                se[c] > 0.0,
                "the estimate must carry noise here, else the test is vacuous"
            );
        }
    }
}

fn sky_scene(albedo: f32) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 6]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 32\nheight = 32\n\
         [environment]\ntype = \"constant\"\nradiance = [1.0, 0.5, 0.25]\n\
         [materials.m]\ntype = \"diffuse\"\nalbedo = [{albedo}, {albedo}, {albedo}]\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\nradius = 1.0\n\
         [[objects]]\nshape = \"box\"\nmaterial = \"m\"\nmin = [-0.5, -0.5, -0.5]\nmax = [0.5, 0.5, 0.5]\n\
         transform = {{ translate = [0.0, 0.0, 1.2], rotate = {{ axis = [1, 1, 0], degrees = 35 }} }}\n"
    )
}

/// A convex diffuse object under a uniform sky L: every bounce leaves to the sky, so the
/// object shows ρ·L; with ρ = 1 it is invisible (every pixel is L).
#[test]
fn convex_object_under_uniform_sky() {
    let sky = [1.0f64, 0.5, 0.25];
    let invisible = render(
        &scene(&sky_scene(1.0)),
        &RenderSettings {
            spp: 64,
            seed: 5,
            ..RenderSettings::default()
        },
    );
    for (i, p) in invisible.rgb.iter().enumerate() {
        for c in 0..3 {
            let se = (invisible.variance[i][c] as f64).sqrt();
            assert!(
                (p[c] as f64 - sky[c]).abs() <= 3.0 * se + 1e-5,
                "pixel {i} channel {c}: {} should equal the sky {}",
                p[c],
                sky[c]
            );
        }
    }
    let rho = 0.6f64;
    let img = render(
        &scene(&sky_scene(rho as f32)),
        &RenderSettings {
            spp: 64,
            seed: 5,
            ..RenderSettings::default()
        },
    );
    // The central 6×6 pixels see the sphere/box only (no silhouette).
    let (mean, se) = common::region_stats(&img, 13, 13, 6, 6);
    for c in 0..3 {
        let expected = rho * sky[c];
        assert!(
            (mean[c] - expected).abs() <= 3.0 * se[c] + 1e-5 * expected,
            "channel {c}: {} vs ρL = {expected}",
            mean[c]
        );
    }
    // And the corners see the sky.
    let (corner, se) = common::region_stats(&img, 0, 0, 3, 3);
    for c in 0..3 {
        assert!((corner[c] - sky[c]).abs() <= 3.0 * se[c] + 1e-5);
    }
}

/// With `render.max_depth = k`, the closed sphere sums only the first k + 1 terms of the
/// series: L = Le·(1 + ρ + … + ρᵏ).
#[test]
fn max_depth_truncates_the_neumann_series() {
    let (rho, le) = (0.7f64, 1.0f64);
    for k in [0u32, 1, 3] {
        let text = format!(
            "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 0]\ntarget = [1, 0, 0]\nfov = 90\n[film]\nwidth = 16\nheight = 16\n\
             [render]\nmax_depth = {k}\n\
             [materials.shell]\ntype = \"diffuse\"\nalbedo = [{rho}, {rho}, {rho}]\nemission = [{le}, {le}, {le}]\ntwo_sided = true\n\
             [[objects]]\nshape = \"sphere\"\nmaterial = \"shell\"\nradius = 1.0\n"
        );
        for strategy in [Strategy::Mis, Strategy::Bsdf, Strategy::Nee] {
            let img = render(
                &scene(&text),
                &RenderSettings {
                    spp: 128,
                    seed: 8,
                    strategy,
                    ..RenderSettings::default()
                },
            );
            let (mean, se) = image_mean(&img);
            let expected: f64 = (0..=k).map(|i| le * rho.powi(i as i32)).sum();
            assert!(
                (mean[0] - expected).abs() <= 3.0 * se[0] + 1e-5 * expected,
                "max_depth {k}, {strategy:?}: {} vs {expected}",
                mean[0]
            );
        }
    }
}
