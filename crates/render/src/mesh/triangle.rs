//! The watertight ray/triangle test of Woop, Benthin and Wald (2013), as pbrt-v4 writes it,
//! for one triangle ([`intersect`]) and for four at once in SIMD lanes ([`intersect4`]), which
//! give the same bits.
//!
//! Why the edge functions are exact in sign: each is a difference of two products of f32
//! inputs, computed in f32 first. Where its magnitude exceeds the bound on that computation's
//! error (γ₃ of the products' magnitudes, plus an underflow margin), its sign is the exact
//! sign; where it does not (rays within a few ulps of an edge, rarely), it is computed again
//! in f64, where the products are exact and the difference is rounded once, so that sign is
//! exact too. The edge (a, b) seen from the triangle on its other side is (b, a), whose
//! function is then exactly the negation in either precision: two triangles that share an
//! edge can never both reject a ray that crosses it, which is what "watertight" means. pbrt
//! gets there with a fused multiply-add and an f64 fallback for zero; a fused multiply-add is
//! a library call on a CPU without FMA, and this is the same few operations on any.
//!
//! The per-ray work (the axis permutation and the shear) is done once per ray in [`WoopRay`],
//! not once per triangle.

use glam::{BVec4A, Vec3A, Vec4};

use crate::util::math::gamma;

/// A hit of one triangle: the ray parameter and the barycentric weights of the three vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Ray parameter, in (0, t_max).
    pub t: f32,
    /// Weights of p0, p1, p2 (each ≥ 0, summing to 1 up to rounding).
    pub b: [f32; 3],
}

/// A ray prepared for the test: z is the direction's largest axis (the shear divides by it),
/// and the shear takes the direction to +z.
#[derive(Clone, Copy, Debug)]
pub struct WoopRay {
    /// The axes that become x, y and z.
    k: [usize; 3],
    /// The origin, permuted.
    o: [f32; 3],
    /// Shear: x += s[0]·z, y += s[1]·z, z *= s[2].
    s: [f32; 3],
}

impl WoopRay {
    /// Prepares the ray `o + t·d`.
    #[inline]
    pub fn new(o: Vec3A, d: Vec3A) -> Self {
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
        let dz = d[kz];
        Self {
            k: [kx, ky, kz],
            o: [o[kx], o[ky], o[kz]],
            s: [-d[kx] / dz, -d[ky] / dz, 1.0 / dz],
        }
    }
}

/// Four triangles in SIMD lanes: `v[vertex][axis]` holds that coordinate of each lane's
/// vertex. A group of fewer triangles repeats its last one, which can never be the closest
/// hit in its place (the test wants t strictly below the best so far).
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Tri4 {
    v: [[Vec4; 3]; 3],
}

impl Tri4 {
    /// Packs one to four triangles (the last repeated into the empty lanes).
    pub fn new(tris: &[[Vec3A; 3]]) -> Self {
        debug_assert!((1..=4).contains(&tris.len()));
        let lane = |l: usize| tris[l.min(tris.len() - 1)];
        let v = std::array::from_fn(|vertex| {
            std::array::from_fn(|axis| {
                Vec4::from_array(std::array::from_fn(|l| lane(l)[vertex][axis]))
            })
        });
        Self { v }
    }

    /// The triangle in `lane`.
    #[inline]
    pub fn lane(&self, lane: usize) -> [Vec3A; 3] {
        self.v
            .map(|p| Vec3A::new(p[0][lane], p[1][lane], p[2][lane]))
    }
}

const G2: f32 = gamma(2);
const G3: f32 = gamma(3);
const G5: f32 = gamma(5);

/// The edge function a.x·b.y − a.y·b.x in f32, and whether its sign is certain (see the
/// module's notes): its error is below γ₃(|a.x·b.y| + |a.y·b.x|) plus what underflow can
/// add. False for NaN and infinite values too, which f64 then decides.
#[inline(always)]
fn edge32(ax: f32, ay: f32, bx: f32, by: f32) -> (f32, bool) {
    let (l, r) = (ax * by, ay * bx);
    let e = l - r;
    (e, e.abs() > G3 * (l.abs() + r.abs()) + f32::MIN_POSITIVE)
}

/// The edge function with its exact sign: the f32 value where [`edge32`] is certain of it,
/// else the f64 value (exact products, one rounding), whose sign is exact and whose f32
/// rounding is the value.
#[inline(always)]
fn edge_exact(ax: f32, ay: f32, bx: f32, by: f32) -> (f32, f64) {
    let (e, certain) = edge32(ax, ay, bx, by);
    if certain {
        (e, f64::from(e))
    } else {
        let e64 = f64::from(ax) * f64::from(by) - f64::from(ay) * f64::from(bx);
        (e64 as f32, e64)
    }
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
    intersect_prepared(&WoopRay::new(o, d), [p0, p1, p2], t_max)
}

/// [`intersect`] for a prepared ray. Every operation is the one [`intersect4`] does in each
/// lane, in the same order, so the two agree bit for bit.
#[inline]
pub fn intersect_prepared(r: &WoopRay, p: [Vec3A; 3], t_max: f32) -> Option<TriangleHit> {
    let [kx, ky, kz] = r.k;
    let (mut x, mut y, mut z) = ([0.0f32; 3], [0.0f32; 3], [0.0f32; 3]);
    for i in 0..3 {
        // Translate to the ray origin, permute, and shear so that the ray runs along +z; z is
        // scaled later, only if the edges pass.
        let az = p[i][kz] - r.o[2];
        x[i] = (p[i][kx] - r.o[0]) + r.s[0] * az;
        y[i] = (p[i][ky] - r.o[1]) + r.s[1] * az;
        z[i] = az;
    }
    let (e0, s0) = edge_exact(x[1], y[1], x[2], y[2]);
    let (e1, s1) = edge_exact(x[2], y[2], x[0], y[0]);
    let (e2, s2) = edge_exact(x[0], y[0], x[1], y[1]);
    if (s0 < 0.0 || s1 < 0.0 || s2 < 0.0) && (s0 > 0.0 || s1 > 0.0 || s2 > 0.0) {
        return None;
    }
    let det = e0 + e1 + e2;
    if det == 0.0 || !det.is_finite() {
        // Seen edge-on (or a degenerate triangle): no area to hit.
        return None;
    }
    let max3 = |a: f32, b: f32, c: f32| a.abs().max(b.abs()).max(c.abs());
    let max_z_shear = max3(z[0], z[1], z[2]);
    for zi in &mut z {
        *zi *= r.s[2];
    }
    let t_scaled = e0 * z[0] + e1 * z[1] + e2 * z[2];
    // In front of the origin. t < t_max is asked of t itself, after the division, not of the
    // scaled values before it as pbrt does: there the two roundings can refuse a t below
    // t_max, and a closest-hit search that shrinks t_max as it goes would then keep a farther
    // hit than testing every triangle finds (two triangles meeting where the ray crosses).
    if det < 0.0 && !(t_scaled < 0.0) {
        return None;
    }
    if det > 0.0 && !(t_scaled > 0.0) {
        return None;
    }
    let inv_det = 1.0 / det;
    let t = t_scaled * inv_det;
    let max_zt = max3(z[0], z[1], z[2]);
    let max_xt = max3(x[0], x[1], x[2]);
    let max_yt = max3(y[0], y[1], y[2]);
    let max_e = max3(e0, e1, e2);
    let dt = delta_t(max_xt, max_yt, max_zt, max_z_shear, max_e, inv_det);
    if !(t < t_max && t.abs() < f32::INFINITY && t > dt) {
        return None;
    }
    Some(TriangleHit {
        t,
        b: [e0 * inv_det, e1 * inv_det, e2 * inv_det],
    })
}

/// The bound below which a hit's t could be rounding alone (pbrt-v4 §6.8.7): a ray leaving
/// the surface must not hit the triangle it starts on. `max_zt` is the largest |z| scaled by
/// the shear (in units of t), `max_z_shear` the largest before that scaling (in units of
/// space), which is what the shear added to x and y: pbrt takes the scaled one there too,
/// harmless for its world-space rays of about unit length, but an instance's object-space
/// direction is as long as its transform makes it, and a mesh scaled by 1000 then got a bound
/// 1000 times too large, which refused real hits (the re-intersection sweep in
/// `tests/hard_cases.rs` found it). Generic so that one expression serves one lane and four.
#[inline(always)]
fn delta_t<T: Lanes>(max_xt: T, max_yt: T, max_zt: T, max_z_shear: T, max_e: T, inv_det: T) -> T {
    let c = |v: f32| T::splat(v);
    let delta_z = c(G3) * max_zt;
    let delta_x = c(G5) * (max_xt + max_z_shear);
    let delta_y = c(G5) * (max_yt + max_z_shear);
    let delta_e = c(2.0) * (c(G2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    c(3.0) * (c(G3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv_det.abs_()
}

/// One lane (f32) or four (Vec4), for [`delta_t`].
trait Lanes: Copy + std::ops::Mul<Output = Self> + std::ops::Add<Output = Self> {
    /// `v` in every lane.
    fn splat(v: f32) -> Self;
    /// |x| in every lane.
    fn abs_(self) -> Self;
}

impl Lanes for f32 {
    #[inline(always)]
    fn splat(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn abs_(self) -> Self {
        self.abs()
    }
}

impl Lanes for Vec4 {
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Vec4::splat(v)
    }
    #[inline(always)]
    fn abs_(self) -> Self {
        self.abs()
    }
}

/// The closest of four triangles along a prepared ray with t in (0, t_max): its hit (t and
/// barycentrics) and lane. Each lane's answer is [`intersect_prepared`]'s, bit for bit, and
/// ties go to a lane fixed by the triangles and the ray alone (the lowest of those f32
/// decided, else the lowest of the rest).
#[inline]
pub fn intersect4(r: &WoopRay, tri: &Tri4, t_max: f32) -> Option<(TriangleHit, usize)> {
    let [kx, ky, kz] = r.k;
    let (ox, oy, oz) = (
        Vec4::splat(r.o[0]),
        Vec4::splat(r.o[1]),
        Vec4::splat(r.o[2]),
    );
    let (sx, sy) = (Vec4::splat(r.s[0]), Vec4::splat(r.s[1]));
    let mut x = [Vec4::ZERO; 3];
    let mut y = [Vec4::ZERO; 3];
    let mut z = [Vec4::ZERO; 3];
    for i in 0..3 {
        let az = tri.v[i][kz] - oz;
        x[i] = (tri.v[i][kx] - ox) + sx * az;
        y[i] = (tri.v[i][ky] - oy) + sy * az;
        z[i] = az;
    }
    let edge = |ax: Vec4, ay: Vec4, bx: Vec4, by: Vec4| {
        let (l, r) = (ax * by, ay * bx);
        let e = l - r;
        let bound = Vec4::splat(G3) * (l.abs() + r.abs()) + Vec4::splat(f32::MIN_POSITIVE);
        (e, e.abs().cmpgt(bound))
    };
    let (e0, c0) = edge(x[1], y[1], x[2], y[2]);
    let (e1, c1) = edge(x[2], y[2], x[0], y[0]);
    let (e2, c2) = edge(x[0], y[0], x[1], y[1]);
    let certain = c0 & c1 & c2;
    // Certain edge functions are nonzero, so "inside" is all three of one sign.
    let zero = Vec4::ZERO;
    let neg = e0.cmplt(zero) & e1.cmplt(zero) & e2.cmplt(zero);
    let pos = e0.cmpgt(zero) & e1.cmpgt(zero) & e2.cmpgt(zero);
    let inside = certain & (neg | pos);
    let uncertain = (!certain).bitmask();
    let mut best: Option<(TriangleHit, usize)> = None;
    if inside.any() {
        let det = e0 + e1 + e2;
        let max3 = |a: Vec4, b: Vec4, c: Vec4| a.abs().max(b.abs()).max(c.abs());
        let max_z_shear = max3(z[0], z[1], z[2]);
        let sz = Vec4::splat(r.s[2]);
        let z = z.map(|zi| zi * sz);
        let t_scaled = e0 * z[0] + e1 * z[1] + e2 * z[2];
        let inf = Vec4::splat(f32::INFINITY);
        let in_front = (pos & t_scaled.cmpgt(zero)) | (neg & t_scaled.cmplt(zero));
        let inv_det = Vec4::ONE / det;
        let t = t_scaled * inv_det;
        let dt = delta_t(
            max3(x[0], x[1], x[2]),
            max3(y[0], y[1], y[2]),
            max3(z[0], z[1], z[2]),
            max_z_shear,
            max3(e0, e1, e2),
            inv_det,
        );
        let hit: BVec4A = inside
            & det.abs().cmplt(inf)
            & in_front
            & t.cmplt(Vec4::splat(t_max))
            & t.abs().cmplt(inf)
            & t.cmpgt(dt);
        let mask = hit.bitmask();
        if mask != 0 {
            let t = t.to_array();
            // The one-lane test's weights, e·(1/det), in every lane at once.
            let b = [e0 * inv_det, e1 * inv_det, e2 * inv_det].map(|v| v.to_array());
            for lane in (0..4).filter(|l| mask >> l & 1 == 1) {
                if best.is_none_or(|(bh, _)| t[lane] < bh.t) {
                    let hit = TriangleHit {
                        t: t[lane],
                        b: [b[0][lane], b[1][lane], b[2][lane]],
                    };
                    best = Some((hit, lane));
                }
            }
        }
    }
    if uncertain != 0 {
        best = uncertain_lanes(r, tri, t_max, uncertain, best);
    }
    best
}

/// The lanes whose edge functions f32 could not decide, by the one-lane test (which takes
/// f64 for them), against the best of the others.
#[cold]
#[inline(never)]
fn uncertain_lanes(
    r: &WoopRay,
    tri: &Tri4,
    t_max: f32,
    lanes: u32,
    mut best: Option<(TriangleHit, usize)>,
) -> Option<(TriangleHit, usize)> {
    for lane in (0..4).filter(|l| lanes >> l & 1 == 1) {
        let p = tri.lane(lane);
        // Strictly nearer than the best so far, so an earlier answer wins a tie.
        let limit = best.map_or(t_max, |(h, _)| h.t);
        if let Some(h) = intersect_prepared(r, p, limit) {
            best = Some((h, lane));
        }
    }
    best
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
        let mut rng = crate::util::sampling::HashRng::new(11);
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

    /// The four-lane test gives each lane's one-lane answer bit for bit, and the nearest of
    /// them, on rays at random and rays aimed at edges and vertices (where f32 cannot decide
    /// the sign of an edge function and f64 does; the test checks that such rays occur).
    #[test]
    fn four_lanes_give_the_one_lane_bits() {
        let mut rng = crate::util::sampling::HashRng::new(29);
        let mut u = move || rng.next_f32();
        let mut uncertain = 0;
        let mut hits = 0;
        for n in 0..40_000 {
            let tris: Vec<[Vec3A; 3]> = (0..1 + n % 4)
                .map(|_| std::array::from_fn(|_| Vec3A::new(u(), u(), u()) * 4.0 - 2.0))
                .collect();
            let o = Vec3A::new(u(), u(), u()) * 10.0 - 5.0;
            let [p0, p1, p2] = tris[0];
            let target = match n % 3 {
                0 => Vec3A::new(u(), u(), u()) * 4.0 - 2.0,
                1 => p0,
                _ => p1 + (p2 - p1) * u(),
            };
            let d = target - o;
            let r = WoopRay::new(o, d);
            let t_max = if n % 5 == 0 {
                u() * 10.0
            } else {
                f32::INFINITY
            };
            let lanes: Vec<Option<TriangleHit>> = (0..4)
                .map(|l| intersect_prepared(&r, tris[l.min(tris.len() - 1)], t_max))
                .collect();
            let nearest = lanes
                .iter()
                .enumerate()
                .filter_map(|(l, h)| h.map(|h| (h.t, l)))
                .fold(None, |b: Option<(f32, usize)>, (t, l)| match b {
                    Some((bt, _)) if bt <= t => b,
                    _ => Some((t, l)),
                });
            let four = intersect4(&r, &Tri4::new(&tris), t_max);
            assert_eq!(
                four.map(|h| h.0.t.to_bits()),
                nearest.map(|h| h.0.to_bits())
            );
            if let Some((hit, lane)) = four {
                // The lane's whole hit, weights included, to the bit.
                let bits = |h: TriangleHit| (h.t.to_bits(), h.b.map(f32::to_bits));
                assert_eq!(lanes[lane].map(bits), Some(bits(hit)));
                hits += 1;
            }
            // The scalar entry point is the same test.
            assert_eq!(intersect(o, d, p0, p1, p2, t_max), lanes[0]);
            let [kx, ky, kz] = r.k;
            let sheared = |p: Vec3A| {
                let az = p[kz] - r.o[2];
                (
                    (p[kx] - r.o[0]) + r.s[0] * az,
                    (p[ky] - r.o[1]) + r.s[1] * az,
                )
            };
            let ((x1, y1), (x2, y2)) = (sheared(p1), sheared(p2));
            uncertain += usize::from(!edge32(x1, y1, x2, y2).1);
        }
        assert!(hits > 10_000, "{hits}");
        assert!(uncertain > 100, "{uncertain} rays needed f64");
    }

    /// Found by fuzzing: two triangles of one group meeting on the edge the ray crosses both
    /// report hits, a few ulps apart. The four-lane test (whose second lane needs f64 there,
    /// and is tested against the first's t) must still return the nearer, as testing each
    /// triangle alone finds: t < t_max is asked of t itself.
    #[test]
    fn a_hit_below_t_max_is_never_refused_by_rounding() {
        let (a, b, c, d) = (
            Vec3A::new(-2.3, 0.0, -0.3),
            Vec3A::new(0.3, 0.0, -0.3),
            Vec3A::new(0.3, 0.0, 0.3),
            Vec3A::new(-0.3, 0.0, 0.3),
        );
        let (o, dir) = (Vec3A::new(-1.0, 1000.0, 0.0), Vec3A::new(-0.0, -1.0, -0.0));
        let t0 = intersect(o, dir, a, b, c, f32::INFINITY).expect("first").t;
        let t1 = intersect(o, dir, a, c, d, f32::INFINITY).expect("second").t;
        assert!(t1 < t0, "the case needs the second nearer: {t0} {t1}");
        assert!(intersect(o, dir, a, c, d, t0).is_some());
        let r = WoopRay::new(o, dir);
        assert_eq!(
            intersect4(&r, &Tri4::new(&[[a, b, c], [a, c, d]]), f32::INFINITY)
                .map(|(h, l)| (h.t, l)),
            Some((t1, 1))
        );
    }
}
