//! The watertight ray/triangle test of Woop, Benthin and Wald (2013), as pbrt-v4 writes it,
//! with the edge functions in f64.
//!
//! Why f64 for the edge functions: each is a difference of two products of f32 inputs. In f64
//! those products are exact, so the difference is rounded once and its sign, which decides
//! hit or miss, is exact. The edge (a, b) seen from the triangle on its other side is
//! (b, a), whose function is then exactly the negation: two triangles that share an edge can
//! never both reject a ray that crosses it, which is what "watertight" means. pbrt gets there
//! with a fused multiply-add and an f64 fallback for zero; a fused multiply-add is a library
//! call on a CPU without FMA, and this is one expression on any.

use glam::Vec3A;

use crate::math::gamma;

/// A hit of one triangle: the ray parameter and the barycentric weights of the three vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Ray parameter, in (0, t_max).
    pub t: f32,
    /// Weights of p0, p1, p2 (each ≥ 0, summing to 1 up to rounding).
    pub b: [f32; 3],
}

/// The ray `o + t·d` against triangle (p0, p1, p2), for t in (0, t_max); both sides count.
#[inline]
pub fn intersect(
    o: Vec3A,
    d: Vec3A,
    p0: Vec3A,
    p1: Vec3A,
    p2: Vec3A,
    t_max: f32,
) -> Option<TriangleHit> {
    // Translate to the ray origin, then permute so that z is the direction's largest axis
    // (the shear divides by d.z).
    let (p0t, p1t, p2t) = (p0 - o, p1 - o, p2 - o);
    let a = d.abs();
    let kz = if a.x > a.y {
        if a.x > a.z {
            0
        } else {
            2
        }
    } else if a.y > a.z {
        1
    } else {
        2
    };
    let kx = if kz == 2 { 0 } else { kz + 1 };
    let ky = if kx == 2 { 0 } else { kx + 1 };
    let perm = |v: Vec3A| Vec3A::new(v[kx], v[ky], v[kz]);
    let d = perm(d);
    let (mut p0t, mut p1t, mut p2t) = (perm(p0t), perm(p1t), perm(p2t));
    // Shear so that the ray runs along +z; z is scaled later, only if the edges pass.
    let sx = -d.x / d.z;
    let sy = -d.y / d.z;
    let sz = 1.0 / d.z;
    p0t.x += sx * p0t.z;
    p0t.y += sy * p0t.z;
    p1t.x += sx * p1t.z;
    p1t.y += sy * p1t.z;
    p2t.x += sx * p2t.z;
    p2t.y += sy * p2t.z;
    let edge =
        |a: Vec3A, b: Vec3A| f64::from(a.x) * f64::from(b.y) - f64::from(a.y) * f64::from(b.x);
    let e0 = edge(p1t, p2t);
    let e1 = edge(p2t, p0t);
    let e2 = edge(p0t, p1t);
    if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
        return None;
    }
    let det64 = e0 + e1 + e2;
    if det64 == 0.0 || !det64.is_finite() {
        // Seen edge-on (or a degenerate triangle): no area to hit.
        return None;
    }
    let (e0, e1, e2) = (e0 as f32, e1 as f32, e2 as f32);
    let det = det64 as f32;
    if det == 0.0 {
        return None;
    }
    p0t.z *= sz;
    p1t.z *= sz;
    p2t.z *= sz;
    let t_scaled = e0 * p0t.z + e1 * p1t.z + e2 * p2t.z;
    // t in (0, t_max), compared before the division.
    if det < 0.0 && (t_scaled >= 0.0 || t_scaled <= t_max * det) {
        return None;
    }
    if det > 0.0 && (t_scaled <= 0.0 || t_scaled >= t_max * det) {
        return None;
    }
    let inv_det = 1.0 / det;
    let b = [e0 * inv_det, e1 * inv_det, e2 * inv_det];
    let t = t_scaled * inv_det;
    if !t.is_finite() {
        return None;
    }
    // Reject t that rounding alone could have made positive (pbrt-v4 §6.8.7): a ray leaving
    // the surface must not hit the triangle it starts on.
    let max_zt = Vec3A::new(p0t.z, p1t.z, p2t.z).abs().max_element();
    let delta_z = gamma(3) * max_zt;
    let max_xt = Vec3A::new(p0t.x, p1t.x, p2t.x).abs().max_element();
    let max_yt = Vec3A::new(p0t.y, p1t.y, p2t.y).abs().max_element();
    let delta_x = gamma(5) * (max_xt + max_zt);
    let delta_y = gamma(5) * (max_yt + max_zt);
    let delta_e = 2.0 * (gamma(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = Vec3A::new(e0, e1, e2).abs().max_element();
    let delta_t =
        3.0 * (gamma(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv_det.abs();
    if t <= delta_t {
        return None;
    }
    Some(TriangleHit { t, b })
}

/// Error bound of the point b0·p0 + b1·p1 + b2·p2 (pbrt-v4's γ₇ bound).
#[inline]
pub fn point_error(b: [f32; 3], p0: Vec3A, p1: Vec3A, p2: Vec3A) -> Vec3A {
    ((p0 * b[0]).abs() + (p1 * b[1]).abs() + (p2 * b[2]).abs()) * gamma(7)
        + Vec3A::splat(f32::MIN_POSITIVE)
}

/// Uniformly distributed barycentric weights from a point of the unit square (the square-root
/// warp: b0 = 1 − √u₀, b1 = u₁·√u₀), whose density on the triangle is 1/area.
#[inline]
pub fn sample_uniform(u0: f32, u1: f32) -> [f32; 3] {
    let su0 = u0.sqrt();
    let b0 = 1.0 - su0;
    let b1 = u1 * su0;
    [b0, b1, (1.0 - b0 - b1).max(0.0)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_the_inside_and_misses_the_outside() {
        let (p0, p1, p2) = (Vec3A::ZERO, Vec3A::X, Vec3A::Y);
        let o = Vec3A::new(0.25, 0.25, 1.0);
        let h = intersect(o, -Vec3A::Z, p0, p1, p2, f32::INFINITY).expect("hit");
        assert_eq!(h.t, 1.0);
        assert!(
            (h.b[1] - 0.25).abs() < 1e-6 && (h.b[2] - 0.25).abs() < 1e-6,
            "{h:?}"
        );
        // From behind too: both sides count.
        assert!(intersect(-o, Vec3A::Z, p0, p1, p2, f32::INFINITY).is_none());
        let below = Vec3A::new(0.25, 0.25, -1.0);
        assert!(intersect(below, Vec3A::Z, p0, p1, p2, f32::INFINITY).is_some());
        // Beyond t_max, behind the origin, and outside the edges.
        assert!(intersect(o, -Vec3A::Z, p0, p1, p2, 1.0).is_none());
        assert!(intersect(o, Vec3A::Z, p0, p1, p2, f32::INFINITY).is_none());
        let out = Vec3A::new(0.75, 0.75, 1.0);
        assert!(intersect(out, -Vec3A::Z, p0, p1, p2, f32::INFINITY).is_none());
        // Edge-on and degenerate.
        let side = Vec3A::new(-1.0, 0.25, 0.0);
        assert!(intersect(side, Vec3A::X, p0, p1, p2, f32::INFINITY).is_none());
        assert!(intersect(o, -Vec3A::Z, p0, p1, p1, f32::INFINITY).is_none());
    }

    /// A ray through a shared edge or vertex of a flat fan of triangles hits at least one of
    /// them, from any direction, with the edge at awkward float positions. (Closed meshes,
    /// whose folds this cannot test, are in `mesh::tests`.)
    #[test]
    fn shared_edges_and_vertices_of_a_fan_leave_no_gap() {
        let mut rng = crate::sampling::HashRng::new(11);
        let mut u = move || rng.next_f32();
        for _ in 0..20_000 {
            // A fan of 7 triangles round a centre point.
            let c = Vec3A::new(u(), u(), u()) * 3.0 - 1.5;
            let ring: Vec<Vec3A> = (0..7)
                .map(|i| {
                    let a = i as f32 / 7.0 * std::f32::consts::TAU;
                    c + Vec3A::new(a.cos(), a.sin(), 0.0) * (0.3 + u())
                })
                .collect();
            let k = (u() * 7.0) as usize % 7;
            // Aim at the centre (a shared vertex) or at a point of a shared edge.
            let target = if u() < 0.5 {
                c
            } else {
                c + (ring[k] - c) * u()
            };
            let o = Vec3A::new(u(), u(), u()) * 8.0 - 4.0;
            let o = if (o - target).length() < 1e-3 {
                o + Vec3A::X
            } else {
                o
            };
            let d = target - o;
            let hits = (0..7)
                .filter(|&i| {
                    intersect(o, d, c, ring[i], ring[(i + 1) % 7], f32::INFINITY).is_some()
                })
                .count();
            assert!(hits >= 1, "ray {o:?} → {target:?} slipped through the fan");
        }
    }
}
