//! The shapes' ray tests for many rays at once, for the many-path tracer's packet queries
//! ([`crate::aggregate::Accel::intersect_lanes`]): boxes and spheres, each lane doing the
//! one-ray test's arithmetic in its order, so that its answer is that test's, bit for bit.

use glam::Vec3A;

use crate::interaction::Transformed;
use crate::util::lanes::{v3, F, V3};

/// [`Shape::intersect`] of a sphere for `N` rays in lanes, as the bits of the lanes with a hit,
/// each lane's t and the f64 root it rounds from, the one [`super::sphere_surface`] takes
/// (meaningful where its bit is set), with a t_max per lane. Every lane does
/// [`super::sphere_roots_f64`]'s arithmetic and the pick of the nearer root in (0, t_max) in their
/// order, one operation across the lanes at a time, so that the compiler can run them in
/// vector registers: each t is the one-ray test's bits, and each root the one
/// [`Shape::surface`] finds again (a unit test compares both).
#[inline(always)]
pub(crate) fn sphere_lanes<const N: usize>(
    center: Vec3A,
    radius: f32,
    o: &V3<N>,
    d: &V3<N>,
    t_max: &[f32; N],
) -> (u32, [f32; N], [f64; N]) {
    let each = |f: &dyn Fn(usize) -> f64| -> [f64; N] { std::array::from_fn(f) };
    let r = radius as f64;
    let f: [[f64; N]; 3] = std::array::from_fn(|c| each(&|i| o[c].0[i] as f64 - center[c] as f64));
    let d: [[f64; N]; 3] = std::array::from_fn(|c| each(&|i| d[c].0[i] as f64));
    let dot = |a: &[[f64; N]; 3], b: &[[f64; N]; 3]| {
        each(&|i| (a[0][i] * b[0][i]) + (a[1][i] * b[1][i]) + (a[2][i] * b[2][i]))
    };
    let a = dot(&d, &d);
    let b = each(&|i| -dot(&f, &d)[i]);
    let cross: [[f64; N]; 3] = [
        each(&|i| f[1][i] * d[2][i] - d[1][i] * f[2][i]),
        each(&|i| f[2][i] * d[0][i] - d[2][i] * f[0][i]),
        each(&|i| f[0][i] * d[1][i] - d[0][i] * f[1][i]),
    ];
    let cross2 = dot(&cross, &cross);
    let perp = each(&|i| (cross2[i] / a[i]).sqrt());
    let disc = each(&|i| (r - perp[i]) * (r + perp[i]));
    let ff = dot(&f, &f);
    let cc = each(&|i| {
        let fl = ff[i].sqrt();
        (fl - r) * (fl + r)
    });
    let q = each(&|i| b[i] + b[i].signum() * (a[i] * disc[i]).sqrt());
    let (mut hit, mut t, mut root) = (0u32, [0.0f32; N], [0.0f64; N]);
    for i in 0..N {
        if !(disc[i] >= 0.0) {
            continue;
        }
        let (t0, t1) = if q[i] == 0.0 {
            (b[i] / a[i], b[i] / a[i])
        } else {
            let (t0, t1) = (cc[i] / q[i], q[i] / a[i]);
            if t0 <= t1 {
                (t0, t1)
            } else {
                (t1, t0)
            }
        };
        let (t0f, t1f) = (t0 as f32, t1 as f32);
        if t0f > 0.0 && t0f < t_max[i] {
            (hit, t[i]) = (hit | 1 << i, t0f);
        } else if t1f > 0.0 && t1f < t_max[i] {
            (hit, t[i]) = (hit | 1 << i, t1f);
        }
        root[i] = super::hit_root(t0, t1, t[i]);
    }
    (hit, t, root)
}

/// A box's test for `N` rays in lanes (origins `o`, directions `d`, each with its own t_max):
/// [`Shape::intersect`]'s answer for each lane, as the bits of the lanes with a hit, each
/// lane's t and each lane's face (meaningful where the bit is set). Every lane does the one-ray
/// test's arithmetic in its order (glam's matrix product, `min_element` and `max_element`
/// orders included), so t and the face are its bits; a unit test compares them.
#[inline(always)]
pub(crate) fn cuboid_lanes<const N: usize>(
    min: Vec3A,
    max: Vec3A,
    xf: &Transformed,
    o: &V3<N>,
    d: &V3<N>,
    t_max: F<N>,
) -> (u32, F<N>, [u32; N]) {
    let (o, d) = if xf.identity {
        (*o, *d)
    } else {
        let m = &xf.to_object.matrix3;
        let xform = |v: &V3<N>| -> V3<N> {
            v3(|c| {
                (F::splat(m.x_axis[c]) * v[0] + F::splat(m.y_axis[c]) * v[1])
                    + F::splat(m.z_axis[c]) * v[2]
            })
        };
        let tr = xf.to_object.translation;
        let p = xform(o);
        (v3(|c| p[c] + tr[c]), xform(d))
    };
    let inv: V3<N> = v3(|c| d[c].recip());
    let mut near = [F::ZERO; 3];
    let mut far = [F::ZERO; 3];
    for c in 0..3 {
        let t_lo = (F::splat(min[c]) - o[c]) * inv[c];
        let t_hi = (F::splat(max[c]) - o[c]) * inv[c];
        let nan = t_lo.is_nan_mask() | t_hi.is_nan_mask();
        near[c] = F::select(nan, F::NEG_INFINITY, t_lo.min(t_hi));
        far[c] = F::select(nan, F::INFINITY, t_lo.max(t_hi));
    }
    // `max_element` and `min_element`: (x ∨ z) ∨ (y ∨ z).
    let tn = near[0].max(near[2]).max(near[1].max(near[2]));
    let tf = far[0].min(far[2]).min(far[1].min(far[2]));
    let near_ok = tn.cmpgt(F::ZERO) & tn.cmplt(t_max);
    let far_ok = tf.cmpgt(F::ZERO) & tf.cmplt(t_max);
    let hit = (tn.cmple(tf) & (near_ok | far_ok)).bits();
    let t = F::select(near_ok, tn, tf);
    let eq_near = v3(|c| near[c].cmpeq(tn).bits());
    let eq_far = v3(|c| far[c].cmpeq(tf).bits());
    let pos = v3(|c| inv[c].cmpgt(F::ZERO).bits());
    let near_ok = near_ok.bits();
    let mut face = [0; N];
    for (lane, f) in face.iter_mut().enumerate() {
        if hit >> lane & 1 == 0 {
            continue;
        }
        // `slab_unchecked`'s faces: the lowest axis holding the extreme distance, and its sign.
        let axis = |eq: &[u32; 3]| (0..3).find(|&a| eq[a] >> lane & 1 == 1).unwrap_or(2);
        *f = if near_ok >> lane & 1 == 1 {
            let a = axis(&eq_near);
            a as u32 * 2 + (!(pos[a] >> lane) & 1)
        } else {
            let a = axis(&eq_far);
            a as u32 * 2 + ((pos[a] >> lane) & 1)
        };
    }
    (hit, t, face)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::Shape;
    use crate::util::math::Ray;
    use glam::Affine3A;

    /// The lanes' sphere test gives the one-ray test's hit and t, bit for bit: rays from
    /// inside, outside and far away, grazing and missing, towards and away from the centre,
    /// with zero components, and a t_max per lane.
    #[test]
    fn sphere_lanes_match_the_one_ray_test() {
        use crate::util::sampling::HashRng;
        let mut rng = HashRng::new(11);
        let mut u = move || rng.next_f32();
        let spheres = [
            (Vec3A::ZERO, 1.0f32),
            (Vec3A::new(0.42, -0.68, 0.3), 0.32),
            (Vec3A::new(1e4, -3.0, 2.0), 1e-3),
        ];
        let (mut hits, mut misses) = (0, 0);
        for (center, radius) in spheres {
            for round in 0..2_000 {
                let mut o = [Vec3A::ZERO; 8];
                let mut d = [Vec3A::ZERO; 8];
                let mut t_max = [f32::INFINITY; 8];
                for lane in 0..8 {
                    let scale = [0.5, 2.0, 1e4][(round + lane) % 3] * radius.max(1.0);
                    o[lane] = center + Vec3A::new(u() - 0.5, u() - 0.5, u() - 0.5) * (2.0 * scale);
                    if (round + lane) % 4 == 1 {
                        // On the surface, as a ray leaving it after a bounce: one root near 0,
                        // where the root formula's sign choice matters.
                        let n = Vec3A::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
                        o[lane] = center + n * (radius * (1.0 + (u() - 0.5) * 1e-5));
                    }
                    let towards = center + Vec3A::new(u() - 0.5, u() - 0.5, u() - 0.5) * radius;
                    d[lane] = match lane % 4 {
                        0 => towards - o[lane],
                        1 => (towards - o[lane]).normalize(),
                        2 => Vec3A::new(u() - 0.5, 0.0, u() - 0.5),
                        _ => Vec3A::new(u() - 0.5, u() - 0.5, u() - 0.5),
                    };
                    if lane % 3 == 0 {
                        t_max[lane] = u() * 3.0 * scale;
                    }
                }
                let lanes =
                    |v: &[Vec3A; 8]| -> V3<8> { v3(|c| F(std::array::from_fn(|i| v[i][c]))) };
                let (hit, t, root) = sphere_lanes(center, radius, &lanes(&o), &lanes(&d), &t_max);
                for lane in 0..8 {
                    let shape = Shape::Sphere { center, radius };
                    let ray = Ray::new(o[lane], d[lane]);
                    let one = shape.intersect(&ray, t_max[lane]);
                    if let Some((t, part)) = one {
                        // The point from the handed-over root is the one-ray surface's.
                        let (want, got) = (
                            shape.surface(&ray, t, part),
                            crate::shape::sphere_surface(&ray, center, radius, root[lane]),
                        );
                        assert_eq!(
                            [got.p, got.n, got.err].map(|v| v.to_array().map(f32::to_bits)),
                            [want.p, want.n, want.err].map(|v| v.to_array().map(f32::to_bits)),
                            "surface: sphere {center} r {radius}, o {} d {}",
                            o[lane],
                            d[lane]
                        );
                    }
                    let got = (hit >> lane & 1 == 1).then(|| (t[lane], 0));
                    assert_eq!(
                        got.map(|(t, p)| (t.to_bits(), p)),
                        one.map(|(t, p)| (t.to_bits(), p)),
                        "sphere {center} r {radius}, o {} d {} t_max {}",
                        o[lane],
                        d[lane],
                        t_max[lane]
                    );
                    if one.is_some() {
                        hits += 1;
                    } else {
                        misses += 1;
                    }
                }
            }
        }
        assert!(
            hits > 10_000 && misses > 10_000,
            "{hits} hits, {misses} misses"
        );
    }

    /// The lanes' box test gives the one-ray test's hit, t and face, bit for bit: rotated and
    /// axis-aligned boxes, rays from inside and outside, directions with zero components,
    /// origins on faces, edges and corners, and a t_max per lane.
    #[test]
    fn cuboid_lanes_match_the_one_ray_test() {
        use crate::util::lanes::F;
        use crate::util::sampling::HashRng;
        let mut rng = HashRng::new(7);
        let mut u = move || rng.next_f32();
        let boxes = [
            (Vec3A::splat(-1.0), Vec3A::ONE, Affine3A::IDENTITY),
            (
                Vec3A::splat(-0.5),
                Vec3A::splat(0.5),
                Affine3A::from_scale_rotation_translation(
                    glam::Vec3::new(0.3, 0.6, 0.3),
                    glam::Quat::from_rotation_y(0.31),
                    glam::Vec3::new(-0.3, -0.4, -0.28),
                ),
            ),
        ];
        let (mut compared, mut hits) = (0, 0);
        for (min, max, to_world) in boxes {
            let xf = Transformed::new(to_world);
            let shape = Shape::Cuboid {
                min,
                max,
                xf: xf.clone(),
            };
            let mut rays = Vec::new();
            for i in 0..4000 {
                let mut o = Vec3A::new(u(), u(), u()) * 4.0 - 2.0;
                let mut d = Vec3A::new(u(), u(), u()) * 2.0 - 1.0;
                if i % 2 == 1 {
                    // Towards a point of the box, so that many rays hit.
                    let inside = min + (max - min) * Vec3A::new(u(), u(), u());
                    d = to_world.transform_point3a(inside) - o;
                }
                if i % 5 == 0 {
                    // Axis-parallel in one or two components.
                    d[i % 3] = 0.0;
                    if i % 10 == 0 {
                        d[(i + 1) % 3] = -0.0;
                    }
                }
                if i % 7 == 0 && to_world == Affine3A::IDENTITY {
                    // On a face, an edge or a corner of the axis-aligned box.
                    o[i % 3] = 1.0;
                    if i % 14 == 0 {
                        o[(i + 2) % 3] = -1.0;
                    }
                }
                if d == Vec3A::ZERO {
                    d = Vec3A::X;
                }
                rays.push(Ray::new(o, d));
            }
            for chunk in rays.chunks_exact(8) {
                let t_max: [f32; 8] =
                    std::array::from_fn(|k| if k % 3 == 0 { 1.5 } else { f32::INFINITY });
                let o = [0, 1, 2].map(|c| F(std::array::from_fn(|k| chunk[k].o[c])));
                let d = [0, 1, 2].map(|c| F(std::array::from_fn(|k| chunk[k].d[c])));
                let (hit, t, face) = cuboid_lanes(min, max, &xf, &o, &d, F(t_max));
                for (k, ray) in chunk.iter().enumerate() {
                    let one = shape.intersect(ray, t_max[k]);
                    let lanes = (hit >> k & 1 == 1).then(|| (t.0[k], face[k]));
                    assert_eq!(
                        one.map(|(t, f)| (t.to_bits(), f)),
                        lanes.map(|(t, f)| (t.to_bits(), f)),
                        "{ray:?} t_max {}",
                        t_max[k]
                    );
                    assert_eq!(shape.blocks(ray, t_max[k]), lanes.is_some());
                    compared += 1;
                    hits += usize::from(one.is_some());
                }
            }
        }
        assert!(hits > compared / 3, "{hits} hits of {compared}");
    }
}
