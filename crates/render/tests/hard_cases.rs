//! Numerical robustness on hard cases (pbrt-v4's style: analytic answers, re-intersection
//! sweeps, degenerate inputs). Each test has a pass criterion that a plausible bug fails:
//! a fixed epsilon in scene units, f32 cancellation in the sphere test, NaN from the slab test,
//! an infinite pdf, or f32 accumulation all break one of them.

mod common;

use std::f64::consts::PI;

use common::{load, render, repo_root, scene};
use glam::{DVec3, Vec2, Vec3A};
use tessera_render::integrator::radiance;
use tessera_render::math::{offset_ray_origin, Aabb, Frame, Ray};
use tessera_render::output::read_exr_rgb;
use tessera_render::sampling::{
    square_to_cosine_hemisphere, square_to_uniform_cone, square_to_uniform_sphere, HashRng,
    PixelSampler, ONE_MINUS_EPSILON,
};
use tessera_render::scene::Scene;
use tessera_render::shape::{slab, sphere_roots, Shape, Transformed};
use tessera_render::{render_tile, PixelRect, RenderSettings, TileSums};

fn seeded(spp: u32, seed: u64) -> RenderSettings {
    RenderSettings {
        spp,
        seed,
        ..RenderSettings::default()
    }
}

fn rand3(rng: &mut HashRng) -> Vec3A {
    Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32())
}

fn unit(rng: &mut HashRng) -> Vec3A {
    square_to_uniform_sphere(Vec2::new(rng.next_f32(), rng.next_f32()))
}

// ---------------------------------------------------------------------------------------------
// 1. Sphere precision
// ---------------------------------------------------------------------------------------------

/// Independent f64 reference: project the centre onto the line, then step back and forth by
/// the half chord. With f64 and these magnitudes the cancellation error is ~1e-12 of the
/// distance, far below an f32 ULP of anything compared.
fn reference_roots(o: Vec3A, d: Vec3A, c: Vec3A, r: f32) -> Option<(f64, f64, f64)> {
    let (o, d, c, r) = (o.as_dvec3(), d.as_dvec3(), c.as_dvec3(), r as f64);
    let tc = (c - o).dot(d) / d.dot(d);
    let foot = o + d * tc;
    let dist = (foot - c).length();
    if dist > r {
        return None;
    }
    let half = (r * r - dist * dist).sqrt() / d.length();
    Some((tc - half, tc + half, dist))
}

const SPHERE_RAYS: u32 = 20_000;

fn ulp(x: f32) -> f64 {
    let x = x.abs();
    (x.next_up() - x) as f64
}

/// Checks hit/miss and both roots for rays from `eye` aimed around a sphere; returns the
/// number of rays compared, hits among them, and disagreements outside the silhouette band.
fn sweep_sphere(c: Vec3A, r: f32, aim: impl Fn(&mut HashRng) -> (Vec3A, Vec3A)) -> (u32, u32) {
    let mut rng = HashRng::new(11);
    let mut hits = 0;
    for i in 0..SPHERE_RAYS {
        let (o, d) = aim(&mut rng);
        let got = sphere_roots(o, d, c, r);
        let want = reference_roots(o, d, c, r);
        let (_, _, dist) =
            reference_roots(o, d, c, f32::MAX).expect("any line meets a huge sphere");
        // Within a few ULPs of the radius, the f32 inputs themselves cannot say hit or miss.
        let band = 8.0 * ulp(r);
        if (dist - r as f64).abs() <= band {
            continue;
        }
        match (got, want) {
            (None, None) => {}
            (Some((t0, t1)), Some((w0, w1, _))) => {
                hits += 1;
                // Near the silhouette the roots are ill-conditioned: dt/dr = r/half-chord.
                let half = ((r as f64).powi(2) - dist * dist).sqrt();
                let cond = (r as f64 / half).min(1e6);
                for (t, w) in [(t0, w0), (t1, w1)] {
                    let tol = 4.0 * ulp(w as f32) + cond * 4.0 * ulp(r) / d.length() as f64;
                    assert!(
                        (t as f64 - w).abs() <= tol,
                        "ray {i}: t = {t} vs f64 {w} (tolerance {tol}) for o {o:?} d {d:?}"
                    );
                }
            }
            (g, w) => panic!(
                "ray {i}: hit/miss disagrees, got {g:?}, f64 {w:?}, distance from centre {dist} vs r {r}"
            ),
        }
    }
    (SPHERE_RAYS, hits)
}

#[test]
fn tiny_distant_sphere_matches_f64() {
    let (c, r) = (Vec3A::new(0.3, -0.2, 0.1), 1e-4f32);
    let (n, hits) = sweep_sphere(c, r, |rng| {
        let o = c + unit(rng) * 1e4;
        let target = c + (rand3(rng) * 2.0 - Vec3A::ONE) * (1.5 * r);
        (o, (target - o).normalize())
    });
    assert!(
        hits > n / 10 && hits < n - n / 10,
        "the sweep must straddle the silhouette: {hits} hits of {n}"
    );
    // The surface point is re-projected onto the sphere and its normal is unit length, although
    // o + t·d in f32 is off by ~1e-3 (ten radii) this far away.
    let o = c + Vec3A::new(0.0, 0.0, 1e4);
    let d = (c - o).normalize();
    let s = Shape::Sphere {
        center: c,
        radius: r,
    };
    let ray = Ray::new(o, d);
    let (t, part) = s.intersect(&ray, f32::INFINITY).expect("hit");
    let sp = s.surface(&ray, t, part);
    assert!(((sp.p - c).length() - r).abs() < 1e-3 * r, "{sp:?}");
    assert!(
        (sp.n.length() - 1.0).abs() < 1e-6 && sp.n.dot(d) < -0.999,
        "{sp:?}"
    );
}

#[test]
fn huge_ground_sphere_matches_f64() {
    // An r = 1e5 sphere used as ground, seen from 1.7 units above its top.
    let (c, r) = (Vec3A::new(0.0, -1e5, 0.0), 1e5f32);
    let eye = Vec3A::new(0.2, 1.7, -0.4);
    let (n, hits) = sweep_sphere(c, r, |rng| {
        // Down to the horizon and a little above it: grazing and near-silhouette rays.
        let u = Vec2::new(rng.next_f32(), rng.next_f32());
        let local = square_to_uniform_cone(u, 1.01); // the lower hemisphere and 0.6° above
        let d = Frame::from_normal(-Vec3A::Y).to_world(local).normalize();
        (eye, d)
    });
    assert!(hits > n / 2 && hits < n, "{hits} of {n}");
}

// ---------------------------------------------------------------------------------------------
// 2. Re-intersection sweep
// ---------------------------------------------------------------------------------------------

/// The shapes of the sweep, as scene-file objects at centre `c`, size `s`: (name, TOML, closed).
fn sweep_shapes(c: [f64; 3], s: f64) -> Vec<(&'static str, String, bool)> {
    let t = format!("translate = [{}, {}, {}]", c[0], c[1], c[2]);
    let rot = "rotate = { axis = [1, 1, 0.3], degrees = 37 }";
    vec![
        (
            "sphere",
            format!(
                "shape = \"sphere\"\ncenter = [{}, {}, {}]\nradius = {s}\n",
                c[0], c[1], c[2]
            ),
            true,
        ),
        (
            "box",
            format!(
                "shape = \"box\"\nmin = [{}, {}, {}]\nmax = [{}, {}, {}]\n",
                c[0] - s,
                c[1] - 0.6 * s,
                c[2] - 0.8 * s,
                c[0] + s,
                c[1] + 0.6 * s,
                c[2] + 0.8 * s
            ),
            true,
        ),
        (
            "rect",
            format!(
                "shape = \"rect\"\nsize = [{}, {}]\ntransform = {{ {t} }}\n",
                2.0 * s,
                1.4 * s
            ),
            false,
        ),
        (
            "rotated rect",
            format!(
                "shape = \"rect\"\nsize = [{}, {}]\ntransform = {{ {rot}, {t} }}\n",
                2.0 * s,
                1.4 * s
            ),
            false,
        ),
        (
            "rotated box",
            format!(
                "shape = \"box\"\ntransform = {{ scale = [{s}, {}, {}], {rot}, {t} }}\n",
                0.6 * s,
                0.8 * s
            ),
            true,
        ),
        (
            "ellipsoid",
            format!(
                "shape = \"sphere\"\ntransform = {{ scale = [{s}, {}, {}], {rot}, {t} }}\n",
                0.5 * s,
                0.8 * s
            ),
            true,
        ),
        // Meshes: the wide BVH and the four-lane watertight test, with their error bounds
        // carried through the instance's transform.
        (
            "mesh box",
            format!(
                "shape = \"mesh\"\nfile = \"cube.obj\"\ntransform = {{ scale = [{s}, {}, {}], {rot}, {t} }}\n",
                0.6 * s,
                0.8 * s
            ),
            true,
        ),
        (
            "mesh sphere",
            format!(
                "shape = \"mesh\"\nfile = \"icosphere.ply\"\ntransform = {{ scale = [{s}, {s}, {s}], {rot}, {t} }}\n"
            ),
            true,
        ),
    ]
}

fn one_object_scene(object: &str, c: [f64; 3], s: f64, material: &str) -> Scene {
    let meshes = repo_root().join("scenes/meshes");
    let cube = std::fs::read(meshes.join("cube.obj")).expect("cube.obj");
    let sphere = std::fs::read(meshes.join("icosphere.ply")).expect("icosphere.ply");
    let files: &[(&str, &[u8])] = &[("cube.obj", &cube), ("icosphere.ply", &sphere)];
    common::scene_with_files(&format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [{}, {}, {}]\ntarget = [{}, {}, {}]\nfov = 40\n\
         [film]\nwidth = 4\nheight = 4\n[materials.m]\n{material}\n[[objects]]\nmaterial = \"m\"\n{object}",
        c[0],
        c[1],
        c[2] + 10.0 * s,
        c[0],
        c[1],
        c[2]
    ), files)
}

#[derive(Default, Debug)]
struct SweepCounts {
    spawned: u32,
    self_hits: u32,
    false_occlusions: u32,
    inside_misses: u32,
}

/// Shoots rays at the shape from outside; at each hit, spawns (a) a ray leaving the surface
/// into the hemisphere it was hit from, which must hit nothing (each shape is convex and alone),
/// (b) a shadow ray from there to a far point on that side, and (c) a shadow ray from the
/// outside origin to the hit point moved off the surface towards it (the light-sample case),
/// neither of which may be occluded, and for closed shapes (d) a ray into the inside, which must
/// hit the same shape again at a distinct point.
fn reintersection(sc: &Scene, c: Vec3A, s: f32, closed: bool, seed: u64) -> SweepCounts {
    let mut rng = HashRng::new(seed);
    let mut k = SweepCounts::default();
    while k.spawned < 16_384 {
        let q = c + unit(&mut rng) * (4.0 * s);
        let target = c + (rand3(&mut rng) * 2.4 - Vec3A::splat(1.2)) * s;
        let ray = Ray::new(q, (target - q).normalize());
        let Some(hit) = sc.intersect(&ray, f32::INFINITY) else {
            continue;
        };
        let sp = sc.prims[hit.prim as usize]
            .shape
            .surface(&ray, hit.t, hit.part);
        assert!((sp.n.length() - 1.0).abs() < 1e-5, "{sp:?}");
        let n = if sp.n.dot(ray.d) < 0.0 { sp.n } else { -sp.n };
        let u = Vec2::new(rng.next_f32(), rng.next_f32());
        let frame = Frame::from_normal(n);
        let out = frame.to_world(square_to_cosine_hemisphere(u));
        k.spawned += 1;
        let o = offset_ray_origin(sp.p, sp.err, n);
        if sc.intersect(&Ray::new(o, out), f32::INFINITY).is_some() {
            k.self_hits += 1;
        }
        let far = o + out * (8.0 * s);
        if sc.occluded(&Ray::new(o, far - o), 1.0 - 1e-4) {
            k.false_occlusions += 1;
        }
        let x = offset_ray_origin(sp.p, sp.err, n);
        if sc.occluded(&Ray::new(q, x - q), 1.0 - 1e-4) {
            k.false_occlusions += 1;
        }
        if closed {
            let inward = -frame.to_world(square_to_cosine_hemisphere(u));
            let oi = offset_ray_origin(sp.p, sp.err, -n);
            let inner = Ray::new(oi, inward);
            match sc.intersect(&inner, f32::INFINITY) {
                Some(h) => {
                    // Re-hitting the surface just left is a hit at (almost) the same point on
                    // the same face; a short chord near a box edge exits through another face.
                    let sp2 = sc.prims[h.prim as usize].shape.surface(&inner, h.t, h.part);
                    if (sp2.p - sp.p).length() < 1e-3 * s && sp2.n.dot(sp.n) > 0.999 {
                        k.inside_misses += 1;
                    }
                }
                // Within rounding of a box edge, an inward ray may leave through the adjacent
                // face at t = 0: the chord is genuinely empty, not a miss.
                None if on_box_edge(&sc.prims[hit.prim as usize].shape, sp.p, sp.err) => {}
                None => k.inside_misses += 1,
            }
        }
    }
    k
}

/// Whether `p` (with rounding-error bound `err`) lies within its error, or 1e-5 of the box's
/// size, of two faces of a box (analytic, or the mesh of one).
fn on_box_edge(shape: &Shape, p: Vec3A, err: Vec3A) -> bool {
    let (min, max, xf) = match shape {
        Shape::Cuboid { min, max, xf } => (min, max, xf),
        // The mesh box's bounds are its faces (for the sphere mesh, no point is near two).
        Shape::Mesh(m) => (&m.mesh.bounds().min, &m.mesh.bounds().max, &m.xf),
        _ => return false,
    };
    let pl = xf.to_object.transform_point3a(p);
    let m = xf.to_object.matrix3;
    let abs = glam::Mat3A::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
    let tol = (*max - *min) * 1e-5 + abs * err * 8.0;
    let near = ((pl - *min).abs().cmplt(tol)) | ((*max - pl).abs().cmplt(tol));
    near.bitmask().count_ones() >= 2
}

#[test]
fn spawned_rays_never_re_hit_their_surface_at_any_scale() {
    let configs: [(f64, f64); 6] = [
        (0.0, 1.0),
        (1e3, 1.0),
        (0.0, 1e-3),
        (1e4, 1e3),
        (1e6, 1e2),
        (1e8, 1e5),
    ];
    for (offset, scale) in configs {
        let c = [offset, offset * 0.5, -offset * 0.25];
        let cv = Vec3A::new(c[0] as f32, c[1] as f32, c[2] as f32);
        for (name, object, closed) in sweep_shapes(c, scale) {
            for material in [
                "type = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\ntwo_sided = true",
                "type = \"dielectric\"\nior = 1.5",
            ] {
                let sc = one_object_scene(&object, c, scale, material);
                let k = reintersection(&sc, cv, scale as f32, closed, 5);
                assert!(
                    k.self_hits == 0 && k.false_occlusions == 0 && k.inside_misses == 0,
                    "{name} at offset {offset}, scale {scale}: {k:?}"
                );
            }
        }
    }
}

/// The sweep can fail: the same sweep with a fixed scene-unit epsilon (1e-4, a common choice)
/// instead of error bounds self-intersects at scale 1e3 and offset 1e4.
#[test]
fn a_fixed_epsilon_fails_the_same_sweep() {
    let (offset, scale) = (1e4, 1e3);
    let c = [offset, offset * 0.5, -offset * 0.25];
    let cv = Vec3A::new(c[0] as f32, c[1] as f32, c[2] as f32);
    let sc = one_object_scene(
        &sweep_shapes(c, scale)[0].1,
        c,
        scale,
        "type = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]",
    );
    let mut rng = HashRng::new(9);
    let mut self_hits = 0;
    for _ in 0..4096 {
        let q = cv + unit(&mut rng) * (4.0 * scale as f32);
        let ray = Ray::new(q, (cv - q).normalize());
        let Some(hit) = sc.intersect(&ray, f32::INFINITY) else {
            continue;
        };
        let sp = sc.prims[0].shape.surface(&ray, hit.t, hit.part);
        let out = Frame::from_normal(sp.n).to_world(square_to_cosine_hemisphere(Vec2::new(
            rng.next_f32(),
            rng.next_f32(),
        )));
        if sc
            .intersect(&Ray::new(sp.p + sp.n * 1e-4, out), f32::INFINITY)
            .is_some()
        {
            self_hits += 1;
        }
    }
    assert!(self_hits > 100, "{self_hits}");
}

// ---------------------------------------------------------------------------------------------
// 3. Slab degeneracies
// ---------------------------------------------------------------------------------------------

/// Exact reference for the slab test on small integers: the parameter interval where the line
/// is inside the closed box, with the entry and exit faces under the lowest-axis tie rule.
fn slab_reference(
    o: [f64; 3],
    d: [f64; 3],
    lo: [f64; 3],
    hi: [f64; 3],
) -> Option<(f64, u32, f64, u32)> {
    let (mut tn, mut tf) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut fnear, mut ffar) = (0, 0);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        let (f0, f1) = if d[a] > 0.0 {
            (2 * a as u32, 2 * a as u32 + 1)
        } else {
            (2 * a as u32 + 1, 2 * a as u32)
        };
        let (t0, t1) = (t0.min(t1), t0.max(t1));
        if t0 > tn {
            (tn, fnear) = (t0, f0);
        }
        if t1 < tf {
            (tf, ffar) = (t1, f1);
        }
    }
    (tn <= tf).then_some((tn, fnear, tf, ffar))
}

#[test]
fn slab_degeneracies_have_no_nan_and_a_fixed_tie_rule() {
    let comps = [-1.0f32, -0.0, 0.0, 1.0, 0.5];
    let coords = [-2.0f32, -1.0, -0.5, 0.0, 1.0, 2.0];
    let boxes = [
        (Vec3A::splat(-1.0), Vec3A::ONE),
        // Zero thickness in y, and in y and z.
        (Vec3A::new(-1.0, 0.0, -1.0), Vec3A::new(1.0, 0.0, 1.0)),
        (Vec3A::new(-1.0, 0.0, 0.0), Vec3A::new(1.0, 0.0, 0.0)),
    ];
    let mut checked = 0;
    for (lo, hi) in boxes {
        let shape = Shape::Cuboid {
            min: lo,
            max: hi,
            xf: Transformed::new(glam::Affine3A::IDENTITY),
        };
        let aabb = Aabb { min: lo, max: hi };
        for &dx in &comps {
            for &dy in &comps {
                for &dz in &comps {
                    let d = Vec3A::new(dx, dy, dz);
                    if d == Vec3A::ZERO {
                        continue;
                    }
                    for &ox in &coords {
                        for &oy in &coords {
                            for &oz in &coords {
                                let o = Vec3A::new(ox, oy, oz);
                                let f = |v: Vec3A| [v.x as f64, v.y as f64, v.z as f64];
                                let want = slab_reference(f(o), f(d), f(lo), f(hi));
                                let got = slab(o, d, lo, hi);
                                checked += 1;
                                match (got, want) {
                                    (None, None) => {}
                                    (Some((tn, fnr, tf, ffr)), Some((wn, wfn, wf, wff))) => {
                                        assert!(!tn.is_nan() && !tf.is_nan());
                                        assert_eq!(
                                            (tn as f64, fnr, tf as f64, ffr),
                                            (wn, wfn, wf, wff),
                                            "o {o:?} d {d:?} box {lo:?}..{hi:?}"
                                        );
                                    }
                                    (g, w) => {
                                        panic!("o {o:?} d {d:?} box {lo:?}..{hi:?}: {g:?} vs {w:?}")
                                    }
                                }
                                // The BVH's box test is conservative: it never misses a box
                                // the ray meets at some t ≥ 0.
                                if want.is_some_and(|(_, _, tf, _)| tf >= 0.0) {
                                    assert!(
                                        aabb.hit(o, d.recip(), f32::INFINITY),
                                        "o {o:?} d {d:?}"
                                    );
                                }
                                let ray = Ray::new(o, d);
                                if let Some((t, part)) = shape.intersect(&ray, f32::INFINITY) {
                                    assert!(t > 0.0 && t.is_finite());
                                    let sp = shape.surface(&ray, t, part);
                                    assert!(sp.p.is_finite() && sp.err.is_finite());
                                    assert_eq!(sp.n.length(), 1.0, "unit normal, o {o:?} d {d:?}");
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    assert!(checked > 20_000);
}

// ---------------------------------------------------------------------------------------------
// 4. Nested and touching surfaces
// ---------------------------------------------------------------------------------------------

fn nested_scene(ior: Option<f64>) -> Scene {
    let shell = match ior {
        Some(ior) => format!(
            "[materials.glass]\ntype = \"dielectric\"\nior = {ior}\n\
             [[objects]]\nshape = \"sphere\"\nmaterial = \"glass\"\nradius = 1.00004\n"
        ),
        None => String::new(),
    };
    scene(&format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0.3, 4]\ntarget = [0, 0, 0]\nfov = 40\n\
         [film]\nwidth = 32\nheight = 32\n\
         [environment]\ntype = \"gradient\"\ntop = [1.0, 1.0, 1.0]\nbottom = [0.2, 0.3, 0.5]\n\
         [materials.red]\ntype = \"diffuse\"\nalbedo = [0.8, 0.1, 0.1]\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"red\"\nradius = 1.0\n{shell}"
    ))
}

#[test]
fn sphere_inside_a_glass_sphere_4e5_larger_stays_visible() {
    let settings = |seed| seeded(64, seed);
    // Index-matched glass (η = 1) is invisible: the image must equal the bare sphere's.
    let bare = render(&nested_scene(None), &settings(1));
    let matched = render(&nested_scene(Some(1.0)), &settings(2));
    let (frac, worst) = common::z_test(&bare, &matched);
    assert!(
        frac < 0.005 && worst < 5.0,
        "index-matched shell changed the image: {frac} {worst}"
    );
    // Real glass: the red sphere still shows through the 4e-5 gap (a fixed 1e-4 epsilon would
    // start the refracted ray inside the red sphere and lose it).
    let glass = render(&nested_scene(Some(1.5)), &settings(3));
    let (m, _) = common::region_stats(&glass, 12, 12, 8, 8);
    let (mb, _) = common::region_stats(&bare, 12, 12, 8, 8);
    assert!(
        m[0] > 4.0 * m[2] && m[0] > 0.5 * mb[0],
        "centre {m:?} vs bare {mb:?}"
    );
}

#[test]
fn a_room_of_flush_boxes_leaks_no_light() {
    // Six slabs meet flush at their faces and edges around a closed room; the camera is inside,
    // a bright sphere light and the sky outside. Every pixel must be exactly black.
    let slab = |min: [f64; 3], max: [f64; 3]| {
        format!("[[objects]]\nshape = \"box\"\nmaterial = \"wall\"\nmin = {min:?}\nmax = {max:?}\n")
    };
    let mut text = String::from(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0.1, 0.2, 0.3]\ntarget = [1, 0.5, -1]\nfov = 100\n\
         [film]\nwidth = 24\nheight = 24\n\
         [environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\
         [materials.wall]\ntype = \"diffuse\"\nalbedo = [0.9, 0.9, 0.9]\ntwo_sided = true\n\
         [materials.lamp]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [100, 100, 100]\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = [3, 3, 3]\nradius = 0.5\n",
    );
    let (a, b) = (1.0, 1.25);
    text += &slab([-b, -b, -b], [b, -a, b]); // floor
    text += &slab([-b, a, -b], [b, b, b]); // ceiling
    text += &slab([-b, -a, -b], [-a, a, b]); // x walls
    text += &slab([a, -a, -b], [b, a, b]);
    text += &slab([-a, -a, -b], [a, a, -a]); // z walls
    text += &slab([-a, -a, a], [a, a, b]);
    let img = render(&scene(&text), &seeded(64, 0));
    let lit = img
        .rgb
        .iter()
        .filter(|p| p.iter().any(|&v| v != 0.0))
        .count();
    assert_eq!(lit, 0, "light leaked into the closed room at {lit} pixels");
    // The same room with one wall removed is lit, so the test can fail.
    let open = text.rsplit_once("[[objects]]").expect("walls").0;
    let img = render(
        &scene(open),
        &RenderSettings {
            spp: 16,
            ..RenderSettings::default()
        },
    );
    assert!(img.rgb.iter().filter(|p| p[0] > 0.0).count() > 100);
}

// ---------------------------------------------------------------------------------------------
// 5. Non-finite guard
// ---------------------------------------------------------------------------------------------

#[test]
fn samplers_at_the_domain_edges_stay_finite() {
    let sc = load("spheres.toml");
    let edges = [0.0, 0.5, ONE_MINUS_EPSILON, 1.0 - f32::EPSILON * 0.5];
    let points = [
        Vec3A::new(0.0, 0.0, 0.0),
        Vec3A::new(1.0, 3.5, 2.5), // the sphere light's centre
        Vec3A::new(1.0, 4.0, 2.5), // on the sphere light
        Vec3A::new(0.0, 2.0, 0.0),
    ];
    let mut samples = 0;
    for p in points {
        for &s in &edges {
            for &a in &edges {
                for &b in &edges {
                    if let Some(ls) = sc.lights.sample(p, 0, s, Vec2::new(a, b)) {
                        assert!(
                            ls.p.is_finite() && ls.wi.is_finite() && ls.le().is_finite(),
                            "{p:?} {ls:?}"
                        );
                        assert!(ls.pdf > 0.0 && ls.pdf.is_finite(), "{p:?} {ls:?}");
                        assert!((ls.wi.length() - 1.0).abs() < 1e-5);
                        samples += 1;
                    }
                }
            }
        }
    }
    assert!(samples > 100);
    // Zero-length and degenerate inputs: the light point itself gives no sample, not a NaN.
    let c = Vec3A::new(1.0, 4.0, 2.5);
    let got = sc.lights.sample(c, 0, 0.0, Vec2::new(0.5, 0.0));
    assert!(got.is_none_or(|ls| ls.pdf.is_finite() && ls.wi.is_finite()));
    for omc in [0.0f32, 1e-30, 2.0] {
        let w = square_to_uniform_cone(Vec2::new(0.0, ONE_MINUS_EPSILON), omc);
        assert!(w.is_finite(), "{omc}: {w:?}");
    }
    // Total internal reflection and grazing Fresnel.
    for cos in [0.0f32, 1e-8, 0.1, 1.0] {
        for eta in [1.5f32, 1.0 / 1.5] {
            let (f, ct) = tessera_render::bsdf::fresnel_dielectric(cos, eta);
            assert!(
                (0.0..=1.0).contains(&f) && ct.is_finite(),
                "{cos} {eta}: {f} {ct}"
            );
        }
    }
}

/// At least 10⁷ paths through the hard cases together (glass in glass, total internal
/// reflection, a tiny bright light, mirrors at grazing angles, flush boxes) give no non-finite
/// sample at all. (The accumulator's guard, which counts and drops one if it ever occurs, is
/// tested in `tile.rs`.)
#[test]
fn ten_million_hard_paths_are_all_finite() {
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1.2, 4.5]\ntarget = [0, 0.5, 0]\nfov = 50\n\
         [film]\nwidth = 160\nheight = 125\n\
         [environment]\ntype = \"gradient\"\ntop = [0.5, 0.6, 1.0]\nbottom = [0.1, 0.1, 0.1]\n\
         [materials.glass]\ntype = \"dielectric\"\nior = 1.5\n\
         [materials.dense]\ntype = \"dielectric\"\nior = 2.4\n\
         [materials.mirror]\ntype = \"mirror\"\n\
         [materials.white]\ntype = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
         [materials.tiny]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [1e7, 1e7, 1e7]\n\
         [[objects]]\nshape = \"plane\"\nmaterial = \"white\"\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"glass\"\ncenter = [0, 1, 0]\nradius = 1.00004\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"dense\"\ncenter = [0, 1, 0]\nradius = 1\n\
         [[objects]]\nshape = \"box\"\nmaterial = \"mirror\"\nmin = [1.2, 0, -1]\nmax = [2, 0.8, 1]\n\
         [[objects]]\nshape = \"box\"\nmaterial = \"white\"\nmin = [2, 0, -1]\nmax = [2.5, 0.8, 1]\n\
         [[objects]]\nshape = \"box\"\nmaterial = \"glass\"\nmin = [-2, 0, -1]\nmax = [-1.2, 0.8, 1]\ntransform = { rotate = { axis = [0, 1, 0], degrees = 20 } }\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"tiny\"\ncenter = [0.5, 2.5, 1]\nradius = 0.001\n\
         [[objects]]\nshape = \"rect\"\nmaterial = \"mirror\"\nsize = [8, 8]\ntransform = { rotate = { axis = [1, 0, 0], degrees = -89.9 }, translate = [0, 0.001, -3] }\n";
    let sc = scene(text);
    let spp = 500;
    let img = render(
        &sc,
        &RenderSettings {
            spp,
            ..RenderSettings::default()
        },
    );
    let paths = img.count.iter().map(|&c| c as u64).sum::<u64>() + img.nonfinite;
    assert!(paths >= 10_000_000, "{paths}");
    assert_eq!(img.nonfinite, 0, "non-finite samples over {paths} paths");
    assert!(img.rgb.iter().flatten().all(|v| v.is_finite()));
}

/// Metals at the edges of their parameters: roughness 0 (the mirror), just under and over the
/// width where the microfacet lobe becomes a mirror (α = 10⁻³), 1, a smooth-shaded mesh sphere
/// (whose shading normals tilt away from the geometric ones), an 89.9° rough metal floor, and
/// a 10⁻³ light of radiance 10⁷: two million paths, none non-finite.
#[test]
fn rough_metals_at_their_limits_stay_finite() {
    let ply = std::fs::read(common::repo_root().join("scenes/meshes/icosphere.ply")).expect("ply");
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1.2, 4.5]\ntarget = [0, 0.5, 0]\nfov = 50\n\
         [film]\nwidth = 100\nheight = 80\n\
         [environment]\ntype = \"gradient\"\ntop = [0.5, 0.6, 1.0]\nbottom = [0.1, 0.1, 0.1]\n\
         [materials.mirror]\ntype = \"conductor\"\nmetal = \"silver\"\n\
         [materials.under]\ntype = \"conductor\"\nmetal = \"gold\"\nroughness = 0.0316\n\
         [materials.over]\ntype = \"conductor\"\nmetal = \"copper\"\nroughness = 0.0317\n\
         [materials.rough]\ntype = \"conductor\"\nf0 = [1, 1, 1]\nroughness = 1\n\
         [materials.white]\ntype = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
         [materials.tiny]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [1e7, 1e7, 1e7]\n\
         [[objects]]\nshape = \"plane\"\nmaterial = \"white\"\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"mirror\"\ncenter = [-1.6, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"under\"\ncenter = [-0.5, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"over\"\ncenter = [0.6, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"ico.ply\"\nmaterial = \"rough\"\nsmooth = true\n\
         transform = { scale = [0.5, 0.5, 0.5], translate = [1.7, 0.5, 0] }\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"tiny\"\ncenter = [0.5, 2.5, 1]\nradius = 0.001\n\
         [[objects]]\nshape = \"rect\"\nmaterial = \"rough\"\nsize = [8, 8]\ntransform = { rotate = { axis = [1, 0, 0], degrees = -89.9 }, translate = [0, 0.001, -3] }\n";
    let sc = common::scene_with_files(text, &[("ico.ply", &ply)]);
    let img = render(&sc, &seeded(256, 3));
    let paths = img.count.iter().map(|&c| c as u64).sum::<u64>() + img.nonfinite;
    assert!(paths >= 2_000_000, "{paths}");
    assert_eq!(img.nonfinite, 0, "non-finite samples over {paths} paths");
    assert!(img.rgb.iter().flatten().all(|v| v.is_finite()));
}

/// Rough glass at its limits: a dense rough sphere (index 2.4, total internal reflection past
/// 24.6°) inside a rough one, roughness 1, an index-1 rough sphere (no interface), coloured
/// glass that absorbs strongly, a thin sheet at 89.9°, and a 10⁻³ light of radiance 10⁷: two
/// million paths, none non-finite.
#[test]
fn rough_glass_at_its_limits_stays_finite() {
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1.2, 4.5]\ntarget = [0, 0.5, 0]\nfov = 50\n\
         [film]\nwidth = 100\nheight = 80\n\
         [environment]\ntype = \"gradient\"\ntop = [0.5, 0.6, 1.0]\nbottom = [0.1, 0.1, 0.1]\n\
         [materials.outer]\ntype = \"dielectric\"\nior = 1.5\nroughness = 0.3\n\
         [materials.dense]\ntype = \"dielectric\"\nior = 2.4\nroughness = 0.1\n\
         [materials.roughest]\ntype = \"dielectric\"\nior = 1.5\nroughness = 1\n\
         [materials.matched]\ntype = \"dielectric\"\nior = 1.0\nroughness = 0.5\n\
         [materials.ink]\ntype = \"dielectric\"\nior = 1.33\nroughness = 0.2\nabsorption = [50, 200, 1000]\n\
         [materials.sheet]\ntype = \"dielectric\"\nior = 1.5\nthin = true\n\
         [materials.white]\ntype = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
         [materials.tiny]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [1e7, 1e7, 1e7]\n\
         [[objects]]\nshape = \"plane\"\nmaterial = \"white\"\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"outer\"\ncenter = [-1.5, 0.6, 0]\nradius = 0.6\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"dense\"\ncenter = [-1.5, 0.6, 0]\nradius = 0.4\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"roughest\"\ncenter = [-0.2, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"matched\"\ncenter = [0.9, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"box\"\nmaterial = \"ink\"\nmin = [1.5, 0, -0.5]\nmax = [2.3, 0.8, 0.5]\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"tiny\"\ncenter = [0.5, 2.5, 1]\nradius = 0.001\n\
         [[objects]]\nshape = \"rect\"\nmaterial = \"sheet\"\nsize = [8, 8]\ntransform = { rotate = { axis = [1, 0, 0], degrees = -89.9 }, translate = [0, 0.001, -3] }\n";
    let img = render(&scene(text), &seeded(256, 4));
    let paths = img.count.iter().map(|&c| c as u64).sum::<u64>() + img.nonfinite;
    assert!(paths >= 2_000_000, "{paths}");
    assert_eq!(img.nonfinite, 0, "non-finite samples over {paths} paths");
    assert!(img.rgb.iter().flatten().all(|v| v.is_finite()));
}

/// glTF's material at its limits: smooth and roughness-1 metal and dielectric, index 1 (no
/// coat) and 2.4, a transmitting sheet at 89.9°, a quad whose normal map tips the normal 80°
/// (nearly under the surface), and a 10⁻³ light of radiance 10⁷: two million paths, none
/// non-finite.
#[test]
fn pbr_at_its_limits_stays_finite() {
    let quad = std::fs::read(common::repo_root().join("scenes/meshes/quad.obj")).expect("quad");
    // A 2 × 2 normal map of one texel 80° from the normal, along u.
    let (s, c) = (80f64.to_radians().sin(), 80f64.to_radians().cos());
    let code = |x: f64| (127.5 * (1.0 + x)).round() as u8;
    let png = common::png_rgb(2, 2, &[code(s), 128, code(c)].repeat(4));
    let text = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1.2, 4.5]\ntarget = [0, 0.5, 0]\nfov = 50\n\
         [film]\nwidth = 100\nheight = 80\n\
         [environment]\ntype = \"gradient\"\ntop = [0.5, 0.6, 1.0]\nbottom = [0.1, 0.1, 0.1]\n\
         [materials.mirror]\ntype = \"pbr\"\nbase_color = [0.9, 0.8, 0.5]\nmetallic = 1\nroughness = 0\n\
         [materials.glaze]\ntype = \"pbr\"\nbase_color = [0.2, 0.5, 0.8]\nmetallic = 0\nroughness = 0\nior = 2.4\n\
         [materials.chalk]\ntype = \"pbr\"\nbase_color = [1, 1, 1]\nmetallic = 0\nroughness = 1\nior = 1\n\
         [materials.rough-metal]\ntype = \"pbr\"\nbase_color = [1, 1, 1]\nroughness = 1\n\
         [materials.sheet]\ntype = \"pbr\"\nbase_color = [1, 1, 1]\nmetallic = 0\nroughness = 0.3\ntransmission = 1\n\
         [materials.bent]\ntype = \"pbr\"\nbase_color = [0.8, 0.8, 0.8]\nmetallic = 0.5\nroughness = 0.2\ntransmission = 0.5\nnormal_map = { texture = \"n.png\" }\n\
         [materials.white]\ntype = \"diffuse\"\nalbedo = [0.8, 0.8, 0.8]\n\
         [materials.tiny]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [1e7, 1e7, 1e7]\n\
         [[objects]]\nshape = \"plane\"\nmaterial = \"white\"\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"mirror\"\ncenter = [-1.5, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"glaze\"\ncenter = [-0.5, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"chalk\"\ncenter = [0.5, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"rough-metal\"\ncenter = [1.5, 0.5, 0]\nradius = 0.5\n\
         [[objects]]\nshape = \"mesh\"\nfile = \"quad.obj\"\nmaterial = \"bent\"\ntransform = { scale = [0.6, 0.6, 1], translate = [0, 1.6, -0.5] }\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"tiny\"\ncenter = [0.5, 2.5, 1]\nradius = 0.001\n\
         [[objects]]\nshape = \"rect\"\nmaterial = \"sheet\"\nsize = [8, 8]\ntransform = { rotate = { axis = [1, 0, 0], degrees = -89.9 }, translate = [0, 0.001, -3] }\n";
    let sc = common::scene_with_files(text, &[("quad.obj", &quad), ("n.png", &png)]);
    let img = render(&sc, &seeded(256, 5));
    let paths = img.count.iter().map(|&c| c as u64).sum::<u64>() + img.nonfinite;
    assert!(paths >= 2_000_000, "{paths}");
    assert_eq!(img.nonfinite, 0, "non-finite samples over {paths} paths");
    assert!(img.rgb.iter().flatten().all(|v| v.is_finite()));
}

// ---------------------------------------------------------------------------------------------
// 6, 7. A tiny bright light, and grazing incidence
// ---------------------------------------------------------------------------------------------

/// Mean radiance of `n` paths of the camera ray `ray`, averaged over sample indices.
fn point_radiance(sc: &Scene, ray: Ray, n: u32) -> DVec3 {
    let settings = RenderSettings::default();
    let mut sum = DVec3::ZERO;
    for i in 0..n {
        let l = radiance(sc, &settings, ray, &PixelSampler::new(1, 7, 7, i));
        sum += l.as_dvec3();
    }
    sum / n as f64
}

/// A diffuse plane y = 0 (albedo ρ) lit only by a black-bodied emitting sphere (radiance L,
/// radius r, centre c): a fully visible sphere is exactly a point source of intensity
/// L·πr², so the irradiance at x is E = πL·(r/D)²·cos θ with D the centre distance, and the
/// plane's radiance is ρE/π.
fn sphere_lit_plane(c: [f64; 3], r: f64, l: f64) -> Scene {
    scene(&format!(
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 1, 1]\ntarget = [0, 0, 0]\nfov = 40\n\
         [film]\nwidth = 4\nheight = 4\n\
         [materials.ground]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [materials.lamp]\ntype = \"diffuse\"\nalbedo = [0, 0, 0]\nemission = [{l:e}, {l:e}, {l:e}]\n\
         [[objects]]\nshape = \"plane\"\nmaterial = \"ground\"\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"lamp\"\ncenter = {c:?}\nradius = {r:e}\n"
    ))
}

fn expected_plane_radiance(c: [f64; 3], r: f64, l: f64, x: [f64; 3]) -> f64 {
    let d = DVec3::from(c) - DVec3::from(x);
    let sin2 = r * r / d.length_squared();
    let cos = d.y / d.length();
    0.5 * (PI * l * sin2 * cos) / PI
}

fn look_down_at(x: [f64; 3]) -> Ray {
    let p = DVec3::from(x).as_vec3a();
    let eye = p + Vec3A::new(0.3, 2.0, 0.1);
    Ray::new(eye, (p - eye).normalize())
}

#[test]
fn tiny_bright_light_gives_the_analytic_irradiance() {
    // r = 1e-3 at height 1 with L = 1e6: πr²L ≈ 3 W/sr, a near-point light of huge radiance.
    let (c, r, l) = ([0.0, 1.0, 0.0], 1e-3, 1e6);
    let sc = sphere_lit_plane(c, r, l);
    for x in [
        [0.0, 0.0, 0.0],
        [0.7, 0.0, -0.2],
        [2.0, 0.0, 1.5],
        [-5.0, 0.0, 0.0],
    ] {
        let want = expected_plane_radiance(c, r, l, x);
        let got = point_radiance(&sc, look_down_at(x), 4096).x;
        assert!(got.is_finite());
        assert!(
            (got / want - 1.0).abs() < 0.01,
            "at {x:?}: {got} vs analytic {want} ({:+.3}%)",
            100.0 * (got / want - 1.0)
        );
    }
}

#[test]
fn grazing_light_at_89_9_degrees_follows_the_cosine_law() {
    // A distant sphere light whose centre is 89.9° from the plane's normal (0.1° above the
    // horizon) and wholly above it: E = E₀·cos θ with E₀ = πL·sin²α.
    let theta = 89.9f64.to_radians();
    let dist = 1e3;
    let c = [dist * theta.sin(), dist * theta.cos(), 0.0];
    let (r, l) = (1.0, 1e6);
    assert!(c[1] - r > 0.0, "the light must be wholly above the horizon");
    let sc = sphere_lit_plane(c, r, l);
    let e0 = PI * l * (r / dist).powi(2);
    for x in [[0.0, 0.0, 0.0], [-3.0, 0.0, 2.0]] {
        let want = expected_plane_radiance(c, r, l, x);
        let d = DVec3::from(c) - DVec3::from(x);
        assert!((want / (0.5 * e0 / PI * d.y / d.length()) - 1.0).abs() < 1e-2);
        let got = point_radiance(&sc, look_down_at(x), 4096).x;
        assert!(
            (got / want - 1.0).abs() < 0.01,
            "at {x:?}: {got} vs E0·cosθ·ρ/π = {want} ({:+.3}%)",
            100.0 * (got / want - 1.0)
        );
    }
}

// ---------------------------------------------------------------------------------------------
// 8. Scale invariance
// ---------------------------------------------------------------------------------------------

/// The Cornell box with every object's matrix and the camera mapped by p ↦ k·p + t.
fn cornell_scaled(k: f64, t: f64) -> Scene {
    let text = std::fs::read_to_string(repo_root().join("scenes/cornell-box.toml")).expect("scene");
    let mut doc: toml::Table = text.parse().expect("toml");
    let map = |v: &toml::Value| -> f64 {
        v.as_float()
            .or(v.as_integer().map(|i| i as f64))
            .expect("number")
    };
    let cam = doc["camera"].as_table_mut().expect("camera");
    for key in ["eye", "target"] {
        let p: Vec<toml::Value> = cam[key]
            .as_array()
            .expect("point")
            .iter()
            .map(|v| toml::Value::Float(map(v) * k + t))
            .collect();
        cam.insert(key.into(), toml::Value::Array(p));
    }
    for obj in doc["objects"].as_array_mut().expect("objects") {
        let m = obj["transform"]["matrix"]
            .as_array()
            .expect("matrix")
            .clone();
        let rows: Vec<toml::Value> = m
            .iter()
            .enumerate()
            .map(|(i, row)| {
                let row = row.as_array().expect("row");
                toml::Value::Array(
                    (0..4)
                        .map(|j| {
                            let v = map(&row[j]);
                            let v = if i < 3 {
                                if j < 3 {
                                    v * k
                                } else {
                                    v * k + t
                                }
                            } else {
                                v
                            };
                            toml::Value::Float(v)
                        })
                        .collect(),
                )
            })
            .collect();
        obj["transform"]
            .as_table_mut()
            .expect("transform")
            .insert("matrix".into(), toml::Value::Array(rows));
    }
    doc["film"]["width"] = toml::Value::Integer(64);
    doc["film"]["height"] = toml::Value::Integer(64);
    scene(&toml::to_string(&doc).expect("serialise"))
}

#[test]
fn cornell_box_is_invariant_to_scale_and_translation() {
    let settings = |seed| seeded(128, seed);
    let base = render(&cornell_scaled(1.0, 0.0), &settings(10));
    for (i, (k, t)) in [(1e-3, 0.0), (1.0, 0.0), (1e3, 0.0), (1.0, 1e4)]
        .into_iter()
        .enumerate()
    {
        let img = render(&cornell_scaled(k, t), &settings(20 + i as u64));
        assert_eq!(img.nonfinite, 0);
        let (frac, worst) = common::z_test(&base, &img);
        eprintln!("scale {k}, translate {t}: {:.3}% of pixel-channels beyond 4σ, worst block z {worst:.2}", 100.0 * frac);
        assert!(
            frac < 0.003 && worst < 5.0,
            "scale {k}, translate {t}: {frac} of pixel-channels beyond 4σ, worst 4×4 block z {worst}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// 9. Convergence
// ---------------------------------------------------------------------------------------------

/// relMSE against the independent Mitsuba reference over a 32×32 crop, at 2⁴ … 2¹² spp,
/// extending one render (samples are nested, sums merged in order). The reference's own noise
/// (its 16384 spp against our N) is subtracted as its expected share, N/16384 of our variance.
/// The fitted log–log slope must be −1 or steeper, and the last octave must still fall: a
/// plateau would mean bias, or f32 accumulation.
#[test]
fn relmse_falls_as_one_over_n_without_a_plateau() {
    let sc = load("cornell-box.toml");
    let reference =
        read_exr_rgb(&repo_root().join("tests/data/cornell-box-reference.exr")).expect("reference");
    let rect = PixelRect {
        x0: 96,
        y0: 136,
        width: 32,
        height: 32,
    };
    let settings = RenderSettings::default();
    let mut sums = TileSums::empty(rect, 0);
    let mut points = Vec::new();
    for e in 4..=12u32 {
        let n = 1u32 << e;
        let more = render_tile(&sc, &settings, rect, sums.samples.end..n);
        sums.merge(&more).expect("in order");
        let img = sums.finalize();
        let mut rel = 0f64;
        for y in 0..rect.height {
            for x in 0..rect.width {
                let i = (y * rect.width + x) as usize;
                let r = reference.rgb
                    [(rect.y0 + y) as usize * reference.width + (rect.x0 + x) as usize];
                for (c, &rv) in r.iter().enumerate() {
                    let (v, rv) = (img.rgb[i][c] as f64, rv as f64);
                    let ref_var = img.variance[i][c] as f64 * n as f64 / 16384.0;
                    rel += ((v - rv).powi(2) - ref_var) / (rv * rv + 0.01);
                }
            }
        }
        rel /= (3 * rect.area()) as f64;
        points.push(((n as f64).ln(), rel.ln()));
        eprintln!("spp {n:5}: relMSE {rel:.3e}");
    }
    let k = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / k, b + p.1 / k));
    let slope = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>()
        / points.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>();
    let last = (points[8].1 - points[7].1) / (points[8].0 - points[7].0);
    eprintln!("slope {slope:.3}, last octave {last:.3}");
    assert!(
        slope <= -1.0,
        "log-log slope {slope:.3} is shallower than -1"
    );
    assert!(
        last < -0.7,
        "the last octave is flat ({last:.3}): a plateau"
    );
}
