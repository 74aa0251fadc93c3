//! Chi-square tests of every sampling routine against the density it claims
//! ([`common::chi2`]), Šidák-corrected over this file's tests.

mod common;

use std::f64::consts::PI;

use glam::{Vec2, Vec3A};
use tessera_render::guide::DirTree;
use tessera_render::math::{Frame, Ray};
use tessera_render::sampling::{
    cosine_hemisphere_pdf, square_to_cosine_hemisphere, square_to_uniform_cone,
    square_to_uniform_sphere, HashRng,
};

const TESTS: f64 = 10.0;

/// [`common::chi2::chi_square`] as one of this file's tests.
fn chi_square(
    name: &str,
    sample: impl FnMut(&mut HashRng) -> Option<Vec3A>,
    pdf: &dyn Fn(Vec3A) -> f64,
) {
    common::chi2::chi_square(name, TESTS, sample, pdf)
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
            let s = scene.lights.sample(p, 0, r.next_f32(), u2(r))?;
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

/// A guide trained on a narrow bright lobe (a small light seen through glass) over a dim
/// everywhere, refined `levels` times as Müller et al. train theirs.
fn trained_guide(levels: usize) -> DirTree {
    let lobe = Vec3A::new(0.4, -0.3, 0.6).normalize();
    let mut tree = DirTree::uniform();
    for level in 0..levels {
        let mut next = tree.refined(0.01);
        let mut rng = HashRng::new(100 + level as u64);
        for _ in 0..50_000 {
            let d = square_to_uniform_sphere(u2(&mut rng));
            next.record(d, if d.dot(lobe) > 0.97 { 200.0 } else { 1.0 });
        }
        tree = next;
    }
    tree
}

#[test]
fn guide_directional_tree() {
    let tree = trained_guide(5);
    assert!(tree.len() > 30, "{} nodes", tree.len());
    chi_square("guide-dirtree", |r| Some(tree.sample(u2(r)).0), &|w| {
        tree.pdf(w) as f64
    });
}

#[test]
fn guide_directional_tree_of_garbage() {
    // Whatever it learned, sampling follows its pdf: here energy put where nothing arrives.
    let mut tree = trained_guide(3).refined(0.01);
    let mut rng = HashRng::new(5);
    for i in 0..2_000 {
        let d = square_to_uniform_sphere(u2(&mut rng));
        if d.z < -0.8 {
            tree.record(d, 1e6 * (1 + i % 7) as f64);
        }
    }
    chi_square(
        "guide-dirtree-garbage",
        |r| Some(tree.sample(u2(r)).0),
        &|w| tree.pdf(w) as f64,
    );
}
