//! The rough BSDFs' sampling, density and value agree with each other (pbrt-v4 and Mitsuba 3
//! test theirs this way): a chi-square test of the directions `sample` draws against `pdf`
//! at several roughnesses and incident angles, `sample`'s weight and density against
//! `eval` and `pdf` at every draw, reciprocity, and white furnaces (a metal with F = 1 reflects
//! at most what arrives, and what it loses is exactly what the model's own integral says).

mod common;

use glam::{Vec2, Vec3A};
use tessera_render::bsdf::microfacet::{half_vector, reflect_about, TrowbridgeReitz};
use tessera_render::bsdf::{Conductor, Fresnel};
use tessera_render::sampling::HashRng;

/// Roughnesses (α = r²) and incident angles every test here sweeps.
const ROUGHNESS: [f32; 4] = [0.3, 0.5, 0.8, 1.0];
const THETA_O_DEG: [f32; 3] = [0.0, 45.0, 80.0];

fn incident(deg: f32) -> Vec3A {
    let t = deg.to_radians();
    Vec3A::new(t.sin(), 0.0, t.cos())
}

fn u2(rng: &mut HashRng) -> Vec2 {
    Vec2::new(rng.next_f32(), rng.next_f32())
}

fn white(roughness: f32) -> Conductor {
    Conductor {
        distribution: TrowbridgeReitz::from_roughness(roughness),
        fresnel: Fresnel::Schlick(Vec3A::ONE),
    }
}

fn gold(roughness: f32) -> Conductor {
    let (eta, k) = tessera_render::bsdf::conductor::metal("gold").expect("known");
    Conductor {
        distribution: TrowbridgeReitz::from_roughness(roughness),
        fresnel: Fresnel::Complex { eta, k },
    }
}

#[test]
fn visible_normal_reflections_follow_their_density() {
    let tests = (ROUGHNESS.len() * THETA_O_DEG.len()) as f64;
    for r in ROUGHNESS {
        let d = TrowbridgeReitz::from_roughness(r);
        for deg in THETA_O_DEG {
            let o = incident(deg);
            // Every reflection about a drawn visible normal, those that go under the surface
            // included, against D_o(m)/(4 o·m) over the whole sphere.
            common::chi2::chi_square(
                &format!("ggx r={r} θo={deg}°"),
                tests,
                |rng| Some(reflect_about(o, d.sample_visible(o, u2(rng)))),
                &|i| {
                    let Some(m) = half_vector(o, i) else {
                        return 0.0;
                    };
                    let om = o.dot(m);
                    if om > 0.0 {
                        (d.d_visible(o, m) / (4.0 * om)) as f64
                    } else {
                        0.0
                    }
                },
            );
        }
    }
}

#[test]
fn conductor_sample_agrees_with_eval_and_pdf() {
    let mut rng = HashRng::new(7);
    for r in [0.05f32, 0.3, 0.6, 1.0] {
        for c in [white(r), gold(r)] {
            for deg in [0.0f32, 30.0, 60.0, 85.0, 89.9] {
                let o = incident(deg);
                for _ in 0..2000 {
                    let Some(s) = c.sample(o, u2(&mut rng)) else {
                        continue;
                    };
                    assert!(s.wi.z > 0.0 && (s.wi.length() - 1.0).abs() < 1e-4);
                    let pdf = c.pdf(o, s.wi);
                    assert!(
                        (pdf - s.pdf).abs() <= 1e-3 * pdf,
                        "r {r} θo {deg}: sampled pdf {} vs pdf() {pdf}",
                        s.pdf
                    );
                    let want = c.eval(o, s.wi) / s.pdf;
                    let err = (want - s.weight).abs().max_element();
                    assert!(
                        err <= 2e-3 * want.max_element().max(1e-3),
                        "r {r} θo {deg}: weight {} vs eval/pdf {want}",
                        s.weight
                    );
                    // F G/G1 ≤ F ≤ 1.
                    assert!(s.weight.max_element() <= 1.0 + 1e-5, "gain: {}", s.weight);
                }
            }
        }
    }
}

#[test]
fn conductor_reflection_is_reciprocal() {
    let mut rng = HashRng::new(3);
    for r in [0.2f32, 0.7] {
        let c = gold(r);
        for _ in 0..5000 {
            let a = tessera_render::sampling::square_to_cosine_hemisphere(u2(&mut rng));
            let b = tessera_render::sampling::square_to_cosine_hemisphere(u2(&mut rng));
            if a.z < 1e-3 || b.z < 1e-3 {
                continue;
            }
            // eval is f·cos θi.
            let fab = c.eval(a, b) / b.z;
            let fba = c.eval(b, a) / a.z;
            let err = (fab - fba).abs().max_element();
            assert!(err <= 1e-4 * fab.max_element().max(1e-6), "{fab} vs {fba}");
        }
    }
}

/// The directional albedo ∫ f cos θi dωi by quadrature over the hemisphere.
fn albedo_quadrature(c: &Conductor, o: Vec3A, n: usize) -> f64 {
    let mut sum = 0.0;
    let dz = 1.0 / n as f64;
    let dp = 2.0 * std::f64::consts::PI / (4 * n) as f64;
    for i in 0..n {
        let z = 1.0 - (i as f64 + 0.5) * dz;
        let s = (1.0 - z * z).sqrt();
        for j in 0..4 * n {
            let p = (j as f64 + 0.5) * dp;
            let w = Vec3A::new((s * p.cos()) as f32, (s * p.sin()) as f32, z as f32);
            sum += c.eval(o, w).x as f64 * dz * dp;
        }
    }
    sum
}

#[test]
fn white_furnace_loses_exactly_the_models_multiple_scattering() {
    let mut rng = HashRng::new(11);
    let mut table = Vec::new();
    for r in [0.1f32, 0.3, 0.5, 0.8, 1.0] {
        let c = white(r);
        for deg in [0.0f32, 45.0, 80.0] {
            let o = incident(deg);
            let n = 200_000;
            let mc: f64 = (0..n)
                .map(|_| c.sample(o, u2(&mut rng)).map_or(0.0, |s| s.weight.x as f64))
                .sum::<f64>()
                / n as f64;
            table.push(format!("r {r} θo {deg}°: {mc:.4}"));
            assert!(mc <= 1.0, "r {r} θo {deg}: gain {mc}");
            if r < 0.3 {
                // A lobe a degree wide: too narrow for the quadrature, and nearly a mirror.
                assert!(mc > 0.99, "a near mirror keeps its light: {mc}");
                continue;
            }
            let quad = albedo_quadrature(&c, o, 800);
            assert!(quad <= 1.0 + 1e-3, "r {r} θo {deg}: gain {quad}");
            assert!(
                (mc - quad).abs() < 0.004,
                "r {r} θo {deg}: sampled albedo {mc} vs quadrature {quad}"
            );
        }
    }
    eprintln!("white GGX conductor's albedo:\n{}", table.join("\n"));
    // At α = 1 D is 1/π, Λ(o) = 0 at normal incidence and G = 2μ/(1 + μ) (μ = cos θi), so
    // the albedo is ∫₀¹ μ/(1 + μ) dμ = 1 − ln 2: 69% of the light a white metal this rough
    // reflects, and the rest, scattered between facets more than once, is what this model
    // loses.
    let o = incident(0.0);
    let quad = albedo_quadrature(&white(1.0), o, 800);
    let exact = 1.0 - std::f64::consts::LN_2;
    assert!(
        (quad - exact).abs() < 1e-3,
        "α = 1: {quad} vs 1 − ln 2 = {exact}"
    );
}

#[test]
fn grazing_and_extreme_inputs_stay_finite() {
    let mut rng = HashRng::new(5);
    for r in [0.0f32, 0.032, 0.1, 1.0] {
        let c = gold(r);
        for z in [0.0f32, 1e-8, 1e-4, 1.0] {
            let o = Vec3A::new((1.0 - z * z).sqrt(), 0.0, z);
            for _ in 0..1000 {
                if let Some(s) = c.sample(o, u2(&mut rng)) {
                    assert!(s.weight.is_finite() && s.pdf.is_finite() && s.pdf > 0.0);
                    assert!(s.wi.is_finite());
                }
                let i = tessera_render::sampling::square_to_cosine_hemisphere(u2(&mut rng));
                assert!(c.eval(o, i).is_finite() && c.pdf(o, i).is_finite());
            }
        }
    }
}
