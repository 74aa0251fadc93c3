//! Punctual lights (glTF's point, spot and directional) against their analytic answers over a
//! diffuse plane, whatever the sampling strategy: no ray can hit them, so BSDF-only rendering
//! must still sample them.
//!
//! A point of intensity I at height h over a plane of albedo ρ gives, at horizontal distance r
//! (d² = h² + r²), irradiance E = I cos θ / d² = I h / d³, and the plane's radiance is ρE/π in
//! every direction. A spot multiplies I by its falloff, the square of a linear ramp in the
//! cosine from the outer cone (0) to the inner one (1). A directional light of irradiance E at
//! angle θ from the normal gives ρ E cos θ / π.

mod common;

use common::scene;
use glam::{DVec3, Vec3A};
use tessera_render::integrator::radiance;
use tessera_render::math::Ray;
use tessera_render::sampling::PixelSampler;
use tessera_render::scene::Scene;
use tessera_render::{RenderSettings, Strategy};

const RHO: f64 = 0.5;

fn plane_with(lights: &str) -> Scene {
    scene(&format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1, 1]\ntarget = [0, 0, 0]\nfov = 40\n\
         [film]\nwidth = 4\nheight = 4\n\
         [materials.ground]\ntype = \"diffuse\"\nalbedo = [{RHO}, {RHO}, {RHO}]\n\
         [[objects]]\nshape = \"plane\"\nmaterial = \"ground\"\n{lights}"
    ))
}

/// The radiance the plane sends up from `x` (y = 0), averaged over `n` paths, under
/// `strategy`.
fn at(sc: &Scene, x: [f32; 2], strategy: Strategy, n: u32) -> DVec3 {
    let p = Vec3A::new(x[0], 0.0, x[1]);
    let eye = p + Vec3A::new(0.3, 2.0, 0.1);
    let ray = Ray::new(eye, (p - eye).normalize());
    let settings = RenderSettings {
        strategy,
        ..RenderSettings::default()
    };
    let mut sum = DVec3::ZERO;
    for i in 0..n {
        sum += radiance(sc, &settings, ray, &PixelSampler::new(1, 7, 7, i)).as_dvec3();
    }
    sum / n as f64
}

fn assert_close(got: DVec3, want: [f64; 3], what: &str) {
    for c in 0..3 {
        let (g, w) = (got[c], want[c]);
        assert!(
            (g - w).abs() <= 1e-4 * w.max(1e-6) + 1e-9,
            "{what}, channel {c}: {g} vs {w}"
        );
    }
}

const STRATEGIES: [Strategy; 3] = [Strategy::Mis, Strategy::Nee, Strategy::Bsdf];

#[test]
fn point_light_follows_the_inverse_square_and_cosine_laws() {
    let i = [4.0f64, 2.0, 1.0];
    let h = 1.5f64;
    let sc = plane_with(&format!(
        "[[lights]]\ntype = \"point\"\nposition = [0, {h}, 0]\nintensity = {i:?}\n"
    ));
    for strategy in STRATEGIES {
        for r in [0.0f64, 0.7, 3.0] {
            let d = (h * h + r * r).sqrt();
            let want = i.map(|i| RHO / std::f64::consts::PI * i * h / (d * d * d));
            // The light is the only emitter and the plane cannot see itself: one path is the
            // whole answer.
            assert_close(
                at(&sc, [r as f32, 0.0], strategy, 4),
                want,
                &format!("{strategy:?} r {r}"),
            );
        }
    }
}

#[test]
fn spot_light_is_full_inside_its_inner_cone_and_dark_outside_its_outer() {
    let h = 2.0f64;
    let (inner, outer) = (20.0f64, 40.0f64);
    let sc = plane_with(&format!(
        "[[lights]]\ntype = \"spot\"\nposition = [0, {h}, 0]\ndirection = [0, -1, 0]\n\
         intensity = [3, 3, 3]\ninner_angle = {inner}\nouter_angle = {outer}\n"
    ));
    for strategy in STRATEGIES {
        for deg in [0.0f64, 10.0, 25.0, 30.0, 35.0, 45.0] {
            let r = h * deg.to_radians().tan();
            let d = (h * h + r * r).sqrt();
            let cos = h / d;
            let ramp = ((cos - outer.to_radians().cos())
                / (inner.to_radians().cos() - outer.to_radians().cos()))
            .clamp(0.0, 1.0);
            let want = [RHO / std::f64::consts::PI * 3.0 * ramp * ramp * h / (d * d * d); 3];
            assert_close(
                at(&sc, [r as f32, 0.0], strategy, 4),
                want,
                &format!("{strategy:?} {deg}°"),
            );
        }
    }
}

#[test]
fn directional_light_gives_e_cos_theta_everywhere_and_casts_shadows() {
    let e = [2.0f64, 1.0, 0.5];
    // Light travelling down and along +x, 30° from the vertical, and a box whose shadow falls
    // on the plane beside it.
    let theta = 30.0f64.to_radians();
    let sc = plane_with(&format!(
        "[[lights]]\ntype = \"directional\"\ndirection = [{}, {}, 0]\nirradiance = {e:?}\n\
         [[objects]]\nshape = \"box\"\nmaterial = \"ground\"\nmin = [-0.5, 0, -0.5]\nmax = [0.5, 1, 0.5]\n",
        theta.sin(),
        -theta.cos()
    ));
    for strategy in STRATEGIES {
        let lit = at(&sc, [-3.0, 0.0], strategy, 4);
        let want = e.map(|e| RHO / std::f64::consts::PI * e * theta.cos());
        assert_close(lit, want, &format!("{strategy:?} lit"));
        // Just past the box along the light's travel: in its shadow, lit by nothing but the
        // light the box's lit side sends down (one bounce), so far below the direct value.
        let shade = at(&sc, [0.7, 0.0], strategy, 64);
        assert!(shade.x < 0.3 * want[0], "{strategy:?} shade {shade}");
    }
}

/// Mean and standard error of the radiance the plane sends up from `x` over `n` paths, seen
/// from under 1 m.
fn at_with_error(sc: &Scene, x: [f32; 2], strategy: Strategy, n: u32) -> (DVec3, DVec3) {
    let p = Vec3A::new(x[0], 0.0, x[1]);
    let eye = p + Vec3A::new(0.1, 0.5, 0.4);
    common::estimate(sc, Ray::new(eye, (p - eye).normalize()), strategy, n)
}

/// A sun (a directional light with an angular diameter) is an emitter at infinity: light
/// sampling draws directions in its disk, and a ray that escapes into the disk reads it, so
/// each strategy alone converges to the same answer. A plane tilted `t` from the disk's axis,
/// with the disk wholly above its horizon, receives n·∫ω L dω = L·π·sin²θ·cos t = E cos t (the
/// `irradiance` is what a surface facing it receives). Half a disk hidden by a black roof
/// whose edge passes under the disk's centre gives exactly half that, by the disk's symmetry
/// about the edge's plane: the soft shadow a delta light cannot cast.
#[test]
fn a_sun_gives_e_cos_theta_under_every_strategy_and_a_half_shadow_under_an_edge() {
    let e = [2.0f64, 1.0, 0.5];
    let t = 30.0f64.to_radians();
    for (angle, strategies, n) in [
        // Small as the sun is (0.53°), BSDF sampling alone would hardly ever find it.
        (0.53f64, &STRATEGIES[..2], 20_000u32),
        (20.0, &STRATEGIES[..], 400_000),
    ] {
        let sc = plane_with(&format!(
            "[[lights]]\ntype = \"directional\"\ndirection = [{}, {}, 0]\nirradiance = {e:?}\n\
             angle = {angle}\n",
            t.sin(),
            -t.cos()
        ));
        let lit = e.map(|e| RHO / std::f64::consts::PI * e * t.cos());
        for &strategy in strategies {
            let (got, se) = at_with_error(&sc, [0.0, 0.0], strategy, n);
            for c in 0..3 {
                let z = (got[c] - lit[c]) / se[c].max(1e-12);
                assert!(
                    z.abs() < 5.0 && (got[c] / lit[c] - 1.0).abs() < 0.05,
                    "{angle}° {strategy:?} channel {c}: {} vs {} (z {z:.2})",
                    got[c],
                    lit[c]
                );
            }
        }
    }
    // Overhead, with a black roof over z < 0 at height 1: at the origin the roof's edge runs
    // along x over the point, under the disk's centre.
    let sc = plane_with(&format!(
        "[materials.black]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\n\
         [[lights]]\ntype = \"directional\"\ndirection = [0, -1, 0]\nirradiance = {e:?}\n\
         angle = 10\n\
         [[objects]]\nshape = \"box\"\nmaterial = \"black\"\n\
         min = [-40, 1, -40]\nmax = [40, 1.1, 0]\n"
    ));
    let full = e.map(|e| RHO / std::f64::consts::PI * e);
    for strategy in &STRATEGIES[..2] {
        let (half, se) = at_with_error(&sc, [0.0, 0.0], *strategy, 100_000);
        for c in 0..3 {
            let z = (half[c] - full[c] / 2.0) / se[c].max(1e-12);
            assert!(
                z.abs() < 5.0,
                "{strategy:?} channel {c}: {} under the edge vs half of {} (z {z:.2})",
                half[c],
                full[c]
            );
        }
        // Past the penumbra on either side: all of it, and none.
        let (out, _) = at_with_error(&sc, [0.0, 0.2], *strategy, 1000);
        let (under, _) = at_with_error(&sc, [0.0, -0.2], *strategy, 1000);
        assert!(
            (out.x / full[0] - 1.0).abs() < 0.01,
            "{strategy:?} outside: {out}"
        );
        assert_eq!(under, DVec3::ZERO, "{strategy:?} under the roof");
    }
}
