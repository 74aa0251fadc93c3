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

/// No 4×4 block of `img` is brighter than `sky` beyond 4 standard errors (Russian roulette
/// lets single samples exceed it; their mean may not).
fn never_above(img: &tessera_render::Image, sky: [f64; 3], what: &str) {
    for y in (0..32).step_by(4) {
        for x in (0..32).step_by(4) {
            let (mean, se) = common::region_stats(img, x, y, 4, 4);
            for c in 0..3 {
                assert!(
                    mean[c] <= sky[c] + 4.0 * se[c] + 1e-6,
                    "{what}: block ({x},{y}) channel {c}: {} above the sky {} (±{})",
                    mean[c],
                    sky[c],
                    se[c]
                );
            }
        }
    }
}

fn metal_sky_scene(roughness: f32) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 6]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 32\nheight = 32\n\
         [environment]\ntype = \"constant\"\nradiance = [1.0, 0.5, 0.25]\n\
         [materials.m]\ntype = \"conductor\"\nf0 = [1, 1, 1]\nroughness = {roughness}\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\nradius = 1.0\n"
    )
}

/// A smooth metal with F = 1 under a uniform sky reflects the sky exactly: every sample of
/// every pixel is the sky's radiance.
#[test]
fn smooth_white_metal_is_invisible_under_uniform_sky() {
    let img = render(
        &scene(&metal_sky_scene(0.0)),
        &RenderSettings {
            spp: 16,
            seed: 5,
            ..RenderSettings::default()
        },
    );
    for p in &img.rgb {
        assert_eq!(*p, [1.0, 0.5, 0.25]);
    }
}

/// A rough metal with F = 1 under a uniform sky L shows L·E(θo), E the model's directional
/// albedo: no pixel above the sky, and at normal incidence E(0), whose value for r = 0.5 the
/// estimate below recomputes from the BSDF alone.
#[test]
fn rough_white_metal_reflects_its_albedo_and_never_more() {
    let sky = [1.0f64, 0.5, 0.25];
    let img = render(
        &scene(&metal_sky_scene(0.5)),
        &RenderSettings {
            spp: 256,
            seed: 5,
            ..RenderSettings::default()
        },
    );
    never_above(&img, sky, "rough white metal");
    let c = tessera_render::bsdf::Conductor {
        distribution: tessera_render::bsdf::microfacet::TrowbridgeReitz::from_roughness(0.5),
        fresnel: tessera_render::bsdf::Fresnel::Schlick(glam::Vec3A::ONE),
    };
    let mut rng = tessera_render::sampling::HashRng::new(1);
    let n = 400_000;
    let e0: f64 = (0..n)
        .map(|_| {
            let u = glam::Vec2::new(rng.next_f32(), rng.next_f32());
            c.sample(glam::Vec3A::Z, u)
                .map_or(0.0, |s| s.weight.x as f64)
        })
        .sum::<f64>()
        / n as f64;
    let (mean, se) = common::region_stats(&img, 15, 15, 2, 2);
    for ch in 0..3 {
        let expected = e0 * sky[ch];
        assert!(
            (mean[ch] - expected).abs() <= 3.0 * se[ch] + 0.004 * sky[ch],
            "channel {ch}: {} vs E(0)·L = {expected}",
            mean[ch]
        );
    }
}

fn glass_sky_scene(material: &str, object: &str) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 6]\ntarget = [0, 0, 0]\nfov = 30\n[film]\nwidth = 32\nheight = 32\n\
         [environment]\ntype = \"constant\"\nradiance = [1.0, 0.5, 0.25]\n\
         [materials.g]\ntype = \"dielectric\"\n{material}\n\
         [[objects]]\nmaterial = \"g\"\n{object}\n"
    )
}

const SPHERE: &str = "shape = \"sphere\"\nradius = 1.0";

/// Rough glass under a uniform sky reflects and transmits at most what arrives (the light it
/// loses went into the multiple scattering the model leaves out), and a near-smooth one is
/// nearly invisible.
#[test]
fn rough_glass_under_uniform_sky_never_gains() {
    let sky = [1.0f64, 0.5, 0.25];
    for (roughness, least) in [(0.05f32, 0.985f64), (0.6, 0.6)] {
        let img = render(
            &scene(&glass_sky_scene(
                &format!("ior = 1.5\nroughness = {roughness}"),
                SPHERE,
            )),
            &RenderSettings {
                spp: 256,
                seed: 9,
                ..RenderSettings::default()
            },
        );
        assert_eq!(img.nonfinite, 0);
        never_above(&img, sky, &format!("roughness {roughness}"));
        let (mean, _) = common::region_stats(&img, 12, 12, 8, 8);
        assert!(
            mean[0] >= least * sky[0],
            "roughness {roughness}: the sphere's middle keeps {} of the sky",
            mean[0] / sky[0]
        );
    }
}

/// An interface of index 1 is no interface, rough or not: the sphere vanishes, every sample of
/// every pixel the sky's radiance. And a thin sheet of glass under a uniform sky is invisible
/// too: what it does not reflect it lets straight through.
#[test]
fn index_matched_glass_and_thin_sheets_vanish_under_uniform_sky() {
    for (material, object) in [
        ("ior = 1.0\nroughness = 0.7", SPHERE),
        (
            "ior = 1.5\nthin = true",
            "shape = \"rect\"\nsize = [3, 3]\ntransform = { rotate = { axis = [1, 1, 0], degrees = 50 } }",
        ),
    ] {
        let img = render(
            &scene(&glass_sky_scene(material, object)),
            &RenderSettings {
                spp: 16,
                seed: 3,
                ..RenderSettings::default()
            },
        );
        for p in &img.rgb {
            assert_eq!(*p, [1.0, 0.5, 0.25], "{material}");
        }
    }
}

/// Beer–Lambert: a slab of thickness d and absorption σ seen head-on through index-matched
/// glass transmits e^(−σd) of the sky behind it; with index 1.5 the two faces' reflections,
/// summed over every internal bounce, give (1 − R)² e^(−σd) / (1 − R² e^(−2σd)).
#[test]
fn coloured_glass_absorbs_as_beer_lambert_says() {
    let sigma = [0.5f64, 1.0, 2.0];
    let slab = "shape = \"box\"\nmin = [-2, -2, -0.5]\nmax = [2, 2, 0.5]";
    let absorbing = format!("absorption = [{}, {}, {}]", sigma[0], sigma[1], sigma[2]);
    let sky = [1.0f64, 0.5, 0.25];
    let matched = render(
        &scene(&glass_sky_scene(&format!("ior = 1.0\n{absorbing}"), slab)),
        &RenderSettings {
            spp: 4,
            seed: 3,
            ..RenderSettings::default()
        },
    );
    // Rays through these pixels cross the slab at up to 2° from its normal: paths up to
    // 1/cos 2° = 1.0006 long.
    let (mean, _) = common::region_stats(&matched, 14, 14, 4, 4);
    for c in 0..3 {
        let want = sky[c] * (-sigma[c]).exp();
        let longest = sky[c] * (-sigma[c] * 1.001).exp();
        assert!(
            mean[c] <= want * (1.0 + 1e-6) && mean[c] >= longest,
            "index 1, channel {c}: {} vs {want}",
            mean[c]
        );
    }
    let img = render(
        &scene(&glass_sky_scene(&format!("ior = 1.5\n{absorbing}"), slab)),
        &RenderSettings {
            spp: 4096,
            seed: 3,
            ..RenderSettings::default()
        },
    );
    let (mean, se) = common::region_stats(&img, 14, 14, 4, 4);
    let r = 0.04f64; // ((1.5 − 1)/(1.5 + 1))²
    for c in 0..3 {
        let t = (-sigma[c]).exp();
        // The sky behind, through the slab, and the sky in front, reflected by it.
        let through = (1.0 - r).powi(2) * t / (1.0 - r * r * t * t);
        let back = r + (1.0 - r).powi(2) * r * t * t / (1.0 - r * r * t * t);
        let want = sky[c] * (through + back);
        assert!(
            (mean[c] - want).abs() <= 4.0 * se[c] + 1e-4 * want,
            "index 1.5, channel {c}: {} vs {want} (±{})",
            mean[c],
            se[c]
        );
    }
}
