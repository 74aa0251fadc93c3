//! Chi-square tests of every sampling routine against the density it claims (pbrt-v4 style):
//! directions are binned over the sphere, each bin's expected count is the claimed pdf
//! integrated over the bin by quadrature, and Pearson's statistic must not reject at 1%
//! (Šidák-corrected over the tests). Every sample must also land where the pdf is positive.

mod common;

use std::f64::consts::PI;

use glam::{Vec2, Vec3A};
use tessera_render::math::{Frame, Ray};
use tessera_render::sampling::{
    cosine_hemisphere_pdf, square_to_cosine_hemisphere, square_to_uniform_cone,
    square_to_uniform_sphere, HashRng,
};

const THETA_BINS: usize = 24;
const PHI_BINS: usize = 48;
const SAMPLES: usize = 200_000;
const TESTS: f64 = 8.0;

fn bin_of(w: Vec3A) -> usize {
    let z = (w.z as f64).clamp(-1.0, 1.0);
    let t = (((1.0 - z) / 2.0 * THETA_BINS as f64) as usize).min(THETA_BINS - 1);
    let mut phi = (w.y as f64).atan2(w.x as f64);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let p = ((phi / (2.0 * PI) * PHI_BINS as f64) as usize).min(PHI_BINS - 1);
    t * PHI_BINS + p
}

/// ∫ pdf over each bin, by a midpoint rule on (cos θ, φ), where dω = d(cos θ) dφ.
fn expected(pdf: &dyn Fn(Vec3A) -> f64, n: usize) -> Vec<f64> {
    const SUB: usize = 32;
    let mut e = vec![0f64; THETA_BINS * PHI_BINS];
    let dz = 2.0 / (THETA_BINS * SUB) as f64;
    let dphi = 2.0 * PI / (PHI_BINS * SUB) as f64;
    for i in 0..THETA_BINS * SUB {
        let z = 1.0 - (i as f64 + 0.5) * dz;
        let r = (1.0 - z * z).max(0.0).sqrt();
        for j in 0..PHI_BINS * SUB {
            let phi = (j as f64 + 0.5) * dphi;
            let w = Vec3A::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
            e[(i / SUB) * PHI_BINS + j / SUB] += pdf(w) * dz * dphi * n as f64;
        }
    }
    e
}

/// Regularised upper incomplete gamma Q(a, x) (Numerical Recipes: series or continued fraction).
fn gamma_q(a: f64, x: f64) -> f64 {
    let ln_gamma_a = ln_gamma(a);
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * (-x + a * x.ln() - ln_gamma_a).exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (-x + a * x.ln() - ln_gamma_a).exp() * h
    }
}

fn ln_gamma(x: f64) -> f64 {
    // Lanczos approximation (g = 7, n = 9).
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Samples `SAMPLES` directions and runs the chi-square test against `pdf`.
fn chi_square(
    name: &str,
    mut sample: impl FnMut(&mut HashRng) -> Option<Vec3A>,
    pdf: &dyn Fn(Vec3A) -> f64,
) {
    let mut rng = HashRng::new(0x5eed ^ name.len() as u64);
    let mut observed = vec![0f64; THETA_BINS * PHI_BINS];
    let mut taken = 0usize;
    for _ in 0..SAMPLES {
        let Some(w) = sample(&mut rng) else { continue };
        assert!(
            w.is_finite() && (w.length() - 1.0).abs() < 1e-4,
            "{name}: bad direction {w:?}"
        );
        assert!(pdf(w) > 0.0, "{name}: sample {w:?} where the pdf is zero");
        observed[bin_of(w)] += 1.0;
        taken += 1;
    }
    let exp = expected(pdf, taken);
    let total_exp: f64 = exp.iter().sum();
    assert!(
        (total_exp / taken as f64 - 1.0).abs() < 0.01,
        "{name}: pdf integrates to {}",
        total_exp / taken as f64
    );
    // Pool bins with fewer than 5 expected samples.
    let mut order: Vec<usize> = (0..exp.len()).collect();
    order.sort_by(|&a, &b| exp[a].total_cmp(&exp[b]));
    let (mut chi2, mut dof) = (0f64, 0usize);
    let (mut pool_o, mut pool_e) = (0f64, 0f64);
    for &i in &order {
        if exp[i] < 5.0 {
            pool_o += observed[i];
            pool_e += exp[i];
            if pool_e >= 5.0 {
                chi2 += (pool_o - pool_e).powi(2) / pool_e;
                dof += 1;
                pool_o = 0.0;
                pool_e = 0.0;
            }
            continue;
        }
        chi2 += (observed[i] - exp[i]).powi(2) / exp[i];
        dof += 1;
    }
    if pool_e > 0.0 {
        chi2 += (pool_o - pool_e).powi(2) / pool_e.max(1e-9);
        dof += 1;
    }
    let dof = dof.saturating_sub(1).max(1);
    let p = gamma_q(dof as f64 / 2.0, chi2 / 2.0);
    let alpha = 1.0 - (1.0 - 0.01f64).powf(1.0 / TESTS);
    eprintln!("{name}: χ² = {chi2:.1}, dof = {dof}, p = {p:.4}");
    assert!(
        p > alpha,
        "{name}: rejected, χ² = {chi2:.1} with {dof} dof, p = {p:.2e} < {alpha:.2e}"
    );
}

fn u2(rng: &mut HashRng) -> Vec2 {
    Vec2::new(rng.next_f32(), rng.next_f32())
}

#[test]
fn chi_square_harness_rejects_a_wrong_pdf() {
    // Guard against a test that cannot fail: uniform hemisphere samples against the cosine pdf.
    let result = std::panic::catch_unwind(|| {
        chi_square(
            "uniform-vs-cosine",
            |r| {
                let w = square_to_uniform_sphere(u2(r));
                Some(Vec3A::new(w.x, w.y, w.z.abs()))
            },
            &|w| cosine_hemisphere_pdf(w.z) as f64,
        )
    });
    assert!(result.is_err(), "the harness accepted a wrong density");
    // And the seed notes' biased recipe: (rand, rand, rand) normalised covers one octant.
    let result = std::panic::catch_unwind(|| {
        chi_square(
            "course-octant",
            |r| Some(Vec3A::new(r.next_f32(), r.next_f32(), r.next_f32()).normalize()),
            &|w| if w.z > 0.0 { 1.0 / (2.0 * PI) } else { 0.0 },
        )
    });
    assert!(
        result.is_err(),
        "the harness accepted the one-octant recipe"
    );
}

#[test]
fn cosine_hemisphere() {
    chi_square(
        "cosine-hemisphere",
        |r| Some(square_to_cosine_hemisphere(u2(r))),
        &|w| cosine_hemisphere_pdf(w.z) as f64,
    );
}

#[test]
fn uniform_sphere() {
    chi_square(
        "uniform-sphere",
        |r| Some(square_to_uniform_sphere(u2(r))),
        &|_| 1.0 / (4.0 * PI),
    );
}

#[test]
fn uniform_cone() {
    // On a bin boundary (1 − 4/12), so the quadrature is exact at the cone's edge.
    let cos_max = 2.0f64 / 3.0;
    chi_square(
        "uniform-cone",
        |r| Some(square_to_uniform_cone(u2(r), (1.0 - cos_max) as f32)),
        &|w| {
            if (w.z as f64) >= cos_max {
                1.0 / (2.0 * PI * (1.0 - cos_max))
            } else {
                0.0
            }
        },
    );
}

/// Light sampling from `p` against the sampler's exact direction density. Where no light hides
/// another (`first_hit_too`), the density MIS uses — that of the light point a ray in that
/// direction hits first — must agree with it at every sample.
fn light_test(name: &str, scene_text: &str, p: Vec3A, first_hit_too: bool) {
    light_test_scene(name, &common::scene(scene_text), p, first_hit_too);
}

/// [`light_test`] for a built scene (one with mesh files).
fn light_test_scene(
    name: &str,
    scene: &tessera_render::scene::Scene,
    p: Vec3A,
    first_hit_too: bool,
) {
    let first_hit_pdf = |w: Vec3A| -> f64 {
        let ray = Ray::new(p, w);
        match scene.intersect(&ray, f32::INFINITY) {
            Some(hit) => {
                let prim = &scene.prims[hit.prim as usize];
                if prim.light == u32::MAX {
                    return 0.0;
                }
                let sp = prim.shape.surface(&ray, hit.t, hit.part);
                scene.lights.pdf(
                    (prim.light + hit.part * prim.light_stride) as usize,
                    p,
                    sp.p,
                    sp.n,
                ) as f64
            }
            None => 0.0,
        }
    };
    chi_square(
        name,
        |r| {
            let s = scene.lights.sample(p, r.next_f32(), u2(r))?;
            let exact = scene.lights.pdf_direction(p, s.wi) as f64;
            assert!(
                (s.pdf as f64 - exact).abs() <= 1e-3 * exact || !first_hit_too,
                "{name}: sample pdf {} vs {exact}",
                s.pdf
            );
            if first_hit_too {
                let fh = first_hit_pdf(s.wi);
                assert!(
                    (fh - exact).abs() <= 1e-3 * exact,
                    "{name}: first-hit pdf {fh} vs {exact}"
                );
            }
            Some(s.wi)
        },
        &|w| scene.lights.pdf_direction(p, w) as f64,
    );
}

fn light_scene(objects: &str) -> String {
    format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 40\n[film]\nwidth = 4\nheight = 4\n\
         [materials.lamp]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\nemission = [1, 2, 3]\ntwo_sided = true\n{objects}"
    )
}

#[test]
fn area_light_quad() {
    let text = light_scene(
        "[[objects]]\nshape = \"rect\"\nmaterial = \"lamp\"\nsize = [3, 2]\ntransform = { translate = [0.3, 0, 0.6], rotate = { axis = [1, 1, 0], degrees = 25 } }\n",
    );
    light_test("area-light-quad", &text, Vec3A::ZERO, true);
}

#[test]
fn area_light_sphere_outside_and_two_lights() {
    let text = light_scene(
        "[[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = [0, 0, 2]\nradius = 1.2\n\
         [[objects]]\nshape = \"rect\"\nmaterial = \"lamp\"\ntransform = { translate = [0, 0, -1] }\n",
    );
    light_test("area-light-sphere-outside", &text, Vec3A::ZERO, true);
}

#[test]
fn area_light_sphere_inside() {
    let text = light_scene("[[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = [0.2, 0.1, 0]\nradius = 1.0\n");
    light_test("area-light-sphere-inside", &text, Vec3A::ZERO, true);
}

#[test]
fn area_light_box_faces() {
    let text = light_scene(
        "[[objects]]\nshape = \"box\"\nmaterial = \"lamp\"\nmin = [-0.5, -0.4, 0.5]\nmax = [0.6, 0.5, 1.5]\ntransform = { rotate = { axis = [0, 1, 1], degrees = 20 } }\n",
    );
    light_test("area-light-box", &text, Vec3A::new(0.0, 0.0, -0.5), false);
}

/// An emissive mesh: a triangle is picked by its share of the area and a point uniformly on
/// it (one number does both: `Distribution1D::sample_remap`). Triangles of very different
/// sizes, a fold, and one apart, none hiding another from `p`.
#[test]
fn area_light_mesh_triangles() {
    let obj = "v 0 0 0\nv 2 0 0\nv 0 1 0\nv 2 1 0.6\nv -1 -1 0.2\nv -0.8 -1 0.2\nv -1 -0.5 0.3\n\
               f 1 2 3\nf 2 4 3\nf 5 6 7\n";
    let text = light_scene(
        "[[objects]]\nshape = \"mesh\"\nfile = \"lamp.obj\"\nmaterial = \"lamp\"\ntransform = { translate = [0, 0, 1.5], rotate = { axis = [1, 0, 0], degrees = 10 } }\n",
    );
    let scene = common::scene_with_files(&text, &[("lamp.obj", obj.as_bytes())]);
    light_test_scene("area-light-mesh", &scene, Vec3A::new(0.2, 0.1, 0.0), true);
}

/// A closed emissive mesh (a cube of 12 triangles) seen from outside: directions through it
/// cross two triangles, each a way of drawing them.
#[test]
fn area_light_mesh_cube() {
    let obj = std::fs::read(common::repo_root().join("scenes/meshes/cube.obj")).expect("cube.obj");
    let text = light_scene(
        "[[objects]]\nshape = \"mesh\"\nfile = \"cube.obj\"\nmaterial = \"lamp\"\ntransform = { translate = [0, 0, 2], scale = [0.5, 0.7, 0.4] }\n",
    );
    let scene = common::scene_with_files(&text, &[("cube.obj", &obj)]);
    light_test_scene("area-light-mesh-cube", &scene, Vec3A::ZERO, false);
}

#[test]
fn cosine_hemisphere_in_a_frame() {
    // The frame used to orient samples must keep the density (a rotation).
    let n = Vec3A::new(0.3, -0.5, -0.8).normalize();
    let f = Frame::from_normal(n);
    chi_square(
        "cosine-in-frame",
        |r| Some(f.to_world(square_to_cosine_hemisphere(u2(r)))),
        &|w| cosine_hemisphere_pdf(w.dot(n)) as f64,
    );
}
