//! Small geometric helpers: rays, bounding boxes, frames and robust ray spawning.

use glam::{Vec3, Vec3A};

use crate::util::lanes::{v3 as lanes3, F, M, V3};

/// A ray `o + t·d`. `d` need not be unit length: transformed shapes rely on `t`
/// being preserved by affine maps, which only holds when `d` is mapped unnormalised.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Origin.
    pub o: Vec3A,
    /// Direction.
    pub d: Vec3A,
}

impl Ray {
    /// Creates a ray.
    #[inline]
    pub fn new(o: Vec3A, d: Vec3A) -> Self {
        Self { o, d }
    }

    /// The point at parameter `t`.
    #[inline]
    pub fn at(&self, t: f32) -> Vec3A {
        self.o + self.d * t
    }
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: Vec3A,
    /// Upper corner.
    pub max: Vec3A,
}

impl Aabb {
    /// The empty box (union identity).
    pub const EMPTY: Self = Self {
        min: Vec3A::splat(f32::INFINITY),
        max: Vec3A::splat(f32::NEG_INFINITY),
    };

    /// Smallest box holding both.
    #[inline]
    pub fn union(self, o: Self) -> Self {
        Self {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// Smallest box holding `self` and `p`.
    #[inline]
    pub fn grow(self, p: Vec3A) -> Self {
        Self {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    /// Box centre.
    #[inline]
    pub fn centroid(&self) -> Vec3A {
        (self.min + self.max) * 0.5
    }

    /// Surface area (0 for empty boxes), used by the SAH.
    #[inline]
    pub fn area(&self) -> f32 {
        let e = (self.max - self.min).max(Vec3A::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    /// Whether the box is finite (not empty, not infinite).
    pub fn is_finite(&self) -> bool {
        self.min.is_finite() && self.max.is_finite()
    }

    /// Slab test against a ray with precomputed reciprocal direction. Returns whether the
    /// ray overlaps `[0, t_max]`. The far distance is inflated by 1 + 2γ₃ (pbrt-v4) so that
    /// rounding never makes a ray miss a box that its primitive is inside.
    ///
    /// A zero direction component with the origin exactly on that slab's plane gives 0·∞ = NaN;
    /// the ray lies in the face plane, so that axis is treated as unconstrained (a conservative
    /// hit). This is explicit because SIMD `min`/`max` do not ignore NaN the way `f32::min` does.
    /// Such rays are rare, so they take a branch of their own: the common case skips the six
    /// selects that the guards cost, with the same answer (a unit test compares the two).
    #[inline]
    pub fn hit(&self, o: Vec3A, inv_d: Vec3A, t_max: f32) -> bool {
        let t0 = (self.min - o) * inv_d;
        let t1 = (self.max - o) * inv_d;
        let nan = t0.is_nan_mask() | t1.is_nan_mask();
        if nan.any() {
            return Self::overlap_guarded(t0, t1, nan, t_max);
        }
        let t_near = t0.min(t1).max_element().max(0.0);
        let far = (t0.max(t1) * FAR_INFLATION).min_element();
        // Neither is NaN here, so a plain compare does what `f32::min` does without the
        // compare and blend its NaN rule costs.
        let t_far = if far < t_max { far } else { t_max };
        t_near <= t_far
    }

    /// [`Aabb::hit`]'s answer from slab distances `t0`, `t1` of which the lanes in `nan` are
    /// NaN: those axes are unconstrained.
    #[cold]
    fn overlap_guarded(t0: Vec3A, t1: Vec3A, nan: glam::BVec3A, t_max: f32) -> bool {
        let tn = Vec3A::select(nan, Vec3A::NEG_INFINITY, t0.min(t1));
        let tf = Vec3A::select(nan, Vec3A::INFINITY, t0.max(t1) * FAR_INFLATION);
        let t_near = tn.max_element().max(0.0);
        let t_far = tf.min_element().min(t_max);
        t_near <= t_far
    }
}

/// What a slab test's far distance is multiplied by: 1 + 2γ₃ (pbrt-v4) covers the rounding of
/// the three operations behind each distance, so that a box is never missed by rounding alone.
pub(crate) const FAR_INFLATION: f32 = 1.0 + 2.0 * gamma(3);

/// pbrt's γₙ = nε/(1−nε), the relative error bound of n floating-point operations.
#[inline]
pub const fn gamma(n: i32) -> f32 {
    let e = f32::EPSILON * 0.5;
    (n as f32 * e) / (1.0 - n as f32 * e)
}

/// An orthonormal frame around a unit normal (Duff et al. 2017, branchless and free of the
/// singularity the naive cross-product construction has near the poles).
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// First tangent.
    pub s: Vec3A,
    /// Second tangent.
    pub t: Vec3A,
    /// Normal.
    pub n: Vec3A,
}

impl Frame {
    /// Builds a frame whose third axis is `n` (unit length).
    #[inline]
    pub fn from_normal(n: Vec3A) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3A::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3A::new(b, sign + n.y * n.y * a, -n.y);
        Self { s, t, n }
    }

    /// Local coordinates to world.
    #[inline]
    pub fn to_world(&self, v: Vec3A) -> Vec3A {
        self.s * v.x + self.t * v.y + self.n * v.z
    }

    /// World coordinates to local (the frame is orthonormal, so its transpose inverts it).
    #[inline]
    pub fn to_local(&self, v: Vec3A) -> Vec3A {
        Vec3A::new(self.s.dot(v), self.t.dot(v), self.n.dot(v))
    }
}

/// Moves a surface point off its surface to the side `n` points to (the side the new ray leaves
/// from), by just enough to clear the point's conservative rounding-error bound `err` (pbrt-v4's
/// `OffsetRayOrigin`): the offset along `n` is |n|·err, then each coordinate is pushed at least
/// one more float away from the surface, so the rounding of the addition cannot undo it. The
/// bound comes from the magnitudes of the terms the point was computed from, never from scene
/// units, so it holds at any scale and translation where a fixed epsilon fails.
///
/// The extra float is a step of |x|·2⁻²³ plus the smallest subnormal, added along the sign of
/// `n`: at least one ulp of x at every magnitude (two at most), so the rounded sum lands at or
/// beyond x's neighbour on that side. pbrt steps with `next_up`/`next_down`, exactly one ulp;
/// per axis that is a branch on the sign of n and another on x's class, which LLVM keeps even
/// when written without `if`s. This is a handful of vector operations instead
/// (docs/renderer.md).
#[inline]
pub fn offset_ray_origin(p: Vec3A, err: Vec3A, n: Vec3A) -> Vec3A {
    /// 2⁻²³: |x|·2⁻²³ is at least x's ulp (the spacing above |x|), and exact, being a power of 2.
    const ULP_SCALE: f32 = f32::EPSILON;
    let d = n.abs().dot(err);
    let po = p + n * d;
    // Adding the smallest subnormal keeps the step positive where |x|·2⁻²³ underflows to 0
    // (x = 0 and subnormal x), and is rounded away wherever it does not.
    let step = po.abs() * ULP_SCALE + Vec3A::splat(f32::from_bits(1));
    // By the sign of n, not of the offset: even a zero error bound moves the origin. An axis
    // n does not lean along (n = ±0) stays put, as with pbrt.
    let side = Vec3A::select(n.cmpeq(Vec3A::ZERO), Vec3A::ZERO, Vec3A::ONE.copysign(n));
    po + side * step
}

/// [`offset_ray_origin`], lane by lane, for the many-path tracer (`wide.rs`): the same bits
/// in every lane (`tests::the_lanes_twins_give_the_scalar_bits`).
#[inline(always)]
pub fn offset_ray_origin_lanes<const N: usize>(p: &V3<N>, err: &V3<N>, n: &V3<N>) -> V3<N> {
    let d = (n[0].abs() * err[0] + n[1].abs() * err[1]) + n[2].abs() * err[2];
    lanes3(|c| {
        let po = p[c] + n[c] * d;
        let step = po.abs() * f32::EPSILON + F::splat(f32::from_bits(1));
        let side = F::select(n[c].cmpeq(F::ZERO), F::ZERO, F::ONE.copysign(n[c]));
        po + side * step
    })
}

/// [`Frame::from_normal`]'s first two axes, lane by lane, for the many-path tracer: the same
/// bits in every lane.
#[inline(always)]
pub fn frame_from_normal_lanes<const N: usize>(n: &V3<N>) -> [V3<N>; 2] {
    let sign = F::ONE.copysign(n[2]);
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    [
        [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]],
        [b, sign + n[1] * n[1] * a, -n[1]],
    ]
}

/// Converts an RGB (or XYZ) array to `Vec3A`.
#[inline]
pub fn v3(a: [f32; 3]) -> Vec3A {
    Vec3A::from(Vec3::from(a))
}

/// Rec. 709 luminance of linear RGB.
#[inline]
pub fn luminance(c: Vec3A) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// Helpers shared by the crate's unit tests.
/// e^x for x ≤ 0 (Beer–Lambert's transmittance), in basic f32 arithmetic: 2^(x·log₂e) as a
/// power of two times a degree-8 Taylor polynomial of 2^f on [0, 1), within 2·10⁻⁷ + |x|·10⁻⁷
/// relative (the second term is the rounding of x·log₂e).
/// Not `f32::exp`, whose implementation glibc picks per CPU at load time (see
/// [`crate::util::sampling::sin_cos_octant`]): every worker must compute the same bits.
#[inline]
pub fn exp_nonpositive(x: f32) -> f32 {
    let y = x * std::f32::consts::LOG2_E;
    if !(y > -126.0) {
        // Below the smallest normal, or NaN: the path carries nothing.
        return 0.0;
    }
    let y = y.min(0.0);
    let k = y.floor();
    let t = (y - k) * std::f32::consts::LN_2;
    let p = 1.0
        + t * (1.0
            + t * (1.0 / 2.0
                + t * (1.0 / 6.0
                    + t * (1.0 / 24.0
                        + t * (1.0 / 120.0
                            + t * (1.0 / 720.0 + t * (1.0 / 5040.0 + t * (1.0 / 40320.0))))))));
    p * f32::from_bits(((k as i32 + 127) as u32) << 23)
}

/// atan2(y, x) in (−π, π], in basic f32 arithmetic: reduced to atan of a ratio in [0, 1], then
/// about tan(π/8) to [−0.42, 0.42], where Cephes' degree-9 odd polynomial is within 2 ulp.
/// Not `f32::atan2`, whose implementation glibc picks per CPU at load time (see
/// [`crate::util::sampling::sin_cos_octant`]): an environment map's texel for a direction must
/// be the same on every worker. atan2(0, 0) is 0; NaN gives NaN.
#[inline]
pub fn atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ay > ax { (ax, ay) } else { (ay, ax) };
    let t = if hi > 0.0 { lo / hi } else { lo };
    // tan(π/8): above it, atan t = π/4 + atan((t − 1)/(t + 1)).
    let (base, t) = if t > 0.414_213_57 {
        (FRAC_PI_4, (t - 1.0) / (t + 1.0))
    } else {
        (0.0, t)
    };
    let z = t * t;
    let p =
        (((8.053_744_5e-2 * z - 1.387_768_6e-1) * z + 1.997_771_1e-1) * z - 3.333_295e-1) * z * t
            + t;
    let mut r = base + p;
    if ay > ax {
        r = FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 || (y == 0.0 && y.is_sign_negative() && x < 0.0) {
        r = -r;
    }
    r
}

/// [`atan2`], lane by lane, for the many-path tracer: each branch of the scalar function a
/// select over the same operations, so every lane gets the scalar bits
/// (`tests::atan2_lanes_gives_the_scalar_bits`).
#[inline(always)]
pub fn atan2_lanes<const N: usize>(y: F<N>, x: F<N>) -> F<N> {
    use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let steep = ay.cmpgt(ax);
    let (lo, hi) = (F::select(steep, ax, ay), F::select(steep, ay, ax));
    let t = F::select(hi.cmpgt(F::ZERO), lo / hi, lo);
    let reduce = t.cmpgt(F::splat(0.414_213_57));
    let base = F::select(reduce, F::splat(FRAC_PI_4), F::ZERO);
    let t = F::select(reduce, (t - 1.0) / (t + 1.0), t);
    let z = t * t;
    let p =
        (((8.053_744_5e-2 * z - 1.387_768_6e-1) * z + 1.997_771_1e-1) * z - 3.333_295e-1) * z * t
            + t;
    let r = base + p;
    let r = F::select(steep, FRAC_PI_2 - r, r);
    let r = F::select(x.cmplt(F::ZERO), PI - r, r);
    // y = −0 with x < 0 is the lower side of the cut: −π, as the scalar function gives.
    let lower = (0..N).fold(0u32, |bits, lane| {
        let (y, x) = (y.0[lane], x.0[lane]);
        bits | u32::from(y < 0.0 || (y == 0.0 && y.is_sign_negative() && x < 0.0)) << lane
    });
    F::select(M::from_bits(lower), -r, r)
}

/// The polar angle θ ∈ [0, π] of a unit vector whose cosine (its component along the pole) is
/// `cos`: acos, by [`atan2`] (same reason).
#[inline]
pub fn acos(cos: f32) -> f32 {
    let c = cos.clamp(-1.0, 1.0);
    // (1 − c)(1 + c) rather than 1 − c²: no cancellation near the poles.
    atan2(((1.0 - c) * (1.0 + c)).sqrt(), c)
}

#[cfg(test)]
pub(crate) mod testing {
    /// Counts a randomised test's hits and misses, so that it can check that both answers were
    /// exercised: a sweep that only ever misses would pass whatever the code under test did.
    #[derive(Default)]
    pub(crate) struct Tally {
        hits: u32,
        misses: u32,
    }

    impl Tally {
        /// Counts one answer.
        pub(crate) fn record(&mut self, hit: bool) {
            if hit {
                self.hits += 1;
            } else {
                self.misses += 1;
            }
        }

        /// Panics unless there were more than `min` of each.
        pub(crate) fn assert_both_above(&self, min: u32) {
            let (hits, misses) = (self.hits, self.misses);
            assert!(hits > min && misses > min, "{hits} hits, {misses} misses");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lanes' twins give the scalar functions' bits in every lane, at random points and
    /// at the edges (zero and signed-zero normals, zero errors, huge and subnormal points).
    #[test]
    fn the_lanes_twins_give_the_scalar_bits() {
        let mut rng = crate::util::sampling::HashRng::new(11);
        let mut u = move || 2.0 * rng.next_f32() - 1.0;
        let edges = [0.0, -0.0, 1.0, -1.0, 1e30, f32::from_bits(1), 1e-30];
        for round in 0..2000 {
            let mut v = |i: usize| {
                if round % 4 == 0 {
                    edges[(round / 4 + i) % edges.len()]
                } else {
                    u() * 10f32.powi((i % 5) as i32 - 2)
                }
            };
            let p = Vec3A::new(v(0), v(1), v(2));
            let err = Vec3A::new(v(3), v(4), v(5)).abs();
            let n = Vec3A::new(u(), u(), u()).normalize_or(Vec3A::Z);
            let n = if round % 7 == 0 {
                Vec3A::new(n.x, 0.0, -0.0)
            } else {
                n
            };
            let lanes = |x: Vec3A| -> V3<4> { lanes3(|c| F::splat(x[c])) };
            let got = offset_ray_origin_lanes(&lanes(p), &lanes(err), &lanes(n));
            let want = offset_ray_origin(p, err, n);
            for c in 0..3 {
                assert_eq!(got[c].0[2].to_bits(), want[c].to_bits(), "{p} {err} {n}");
            }
            let nn = n.normalize_or(Vec3A::Z);
            let [s, t] = frame_from_normal_lanes(&lanes(nn));
            let f = Frame::from_normal(nn);
            for c in 0..3 {
                assert_eq!(s[c].0[1].to_bits(), f.s[c].to_bits(), "{nn}");
                assert_eq!(t[c].0[3].to_bits(), f.t[c].to_bits(), "{nn}");
            }
        }
    }

    #[test]
    fn frame_is_orthonormal_everywhere() {
        for n in [
            Vec3A::Z,
            -Vec3A::Z,
            Vec3A::X,
            Vec3A::new(0.0, 0.0, -0.0),
            Vec3A::new(1e-20, 0.0, -1.0).normalize(),
            Vec3A::new(0.3, -0.4, 0.5).normalize(),
        ] {
            let n = if n.length() == 0.0 { Vec3A::Z } else { n };
            let f = Frame::from_normal(n);
            for (a, b) in [(f.s, f.t), (f.t, f.n), (f.s, f.n)] {
                assert!(a.dot(b).abs() < 1e-5, "{n:?}");
            }
            for a in [f.s, f.t, f.n] {
                assert!((a.length() - 1.0).abs() < 1e-5, "{n:?}");
            }
        }
    }

    #[test]
    fn offset_moves_to_the_normal_side_at_every_magnitude() {
        for p in [
            Vec3A::ZERO,
            Vec3A::splat(1e8),
            Vec3A::splat(-3.5),
            Vec3A::splat(1e-3),
            Vec3A::splat(-1e-30),
        ] {
            let n = Vec3A::new(0.0, 1.0, 0.0);
            let err = p.abs() * gamma(4);
            let q = offset_ray_origin(p, err, n);
            assert!(q.y > p.y, "{p:?} -> {q:?}");
            assert!(q.y - p.y >= err.y, "clears the error bound: {p:?} -> {q:?}");
            assert_eq!(q.x, p.x);
            let q = offset_ray_origin(p, err, -n);
            assert!(q.y < p.y);
        }
    }

    /// On every axis and every float class, the origin moves past the exact offset point by at
    /// least the neighbouring float on n's side (pbrt's one-ulp step), and by at most three
    /// floats; an axis with n = ±0 keeps the offset point's coordinate.
    #[test]
    fn offset_steps_at_least_one_float_at_every_class() {
        let xs = [
            0.0f32,
            -0.0,
            f32::from_bits(1),
            -f32::from_bits(1),
            f32::from_bits(0x007f_ffff),
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            1.0,
            -1.0,
            1.0 - f32::EPSILON / 2.0,
            2.0,
            -2.0,
            3.7e-12,
            -6.1e7,
            1e8,
            f32::MAX / 4.0,
        ];
        let floats_between = |a: f32, b: f32| -> i64 {
            // Position on the number line counted in floats (ordered bits).
            let key = |x: f32| {
                let b = x.to_bits() as i32;
                i64::from(if b < 0 { i32::MIN - b } else { b })
            };
            key(b) - key(a)
        };
        for &x in &xs {
            for (sign, toward) in [
                (1.0f32, f32::next_up as fn(f32) -> f32),
                (-1.0, f32::next_down),
            ] {
                for axis in 0..3 {
                    let mut n = Vec3A::ZERO;
                    n[axis] = sign;
                    let p = Vec3A::splat(x);
                    let q = offset_ray_origin(p, Vec3A::ZERO, n);
                    let moved = floats_between(x, q[axis]) * sign as i64;
                    assert!(
                        if sign > 0.0 {
                            q[axis] >= toward(x)
                        } else {
                            q[axis] <= toward(x)
                        },
                        "x = {x:e}, n = {n:?}: {} is not past {}",
                        q[axis],
                        toward(x)
                    );
                    assert!(
                        (1..=3).contains(&moved),
                        "x = {x:e}, n = {n:?}: moved {moved}"
                    );
                    for other in (0..3).filter(|&a| a != axis) {
                        // x + n·0: the offset's addition turns −0 into +0.
                        assert_eq!(
                            q[other].to_bits(),
                            (x + 0.0).to_bits(),
                            "x = {x:e}, n = {n:?}"
                        );
                    }
                }
            }
        }
        // A tilted normal: each axis steps on its own sign; a NaN point stays NaN.
        let n = Vec3A::new(0.6, -0.8, 0.0);
        let q = offset_ray_origin(Vec3A::ONE, Vec3A::ZERO, n);
        assert!(q.x > 1.0 && q.y < 1.0 && q.z == 1.0, "{q:?}");
        assert!(offset_ray_origin(Vec3A::splat(f32::NAN), Vec3A::ZERO, n)
            .x
            .is_nan());
    }

    #[test]
    fn aabb_slab_without_guards_agrees_with_the_guarded_test() {
        // Origins on the boxes' faces, edges and corners and on their planes' extensions, with
        // random directions and directions aimed at edges, so that many answers sit on the
        // t_near = t_far boundary. `overlap_guarded` is the test as it was before the branch,
        // with every lane guarded.
        let boxes = [
            Aabb {
                min: Vec3A::new(-1.0, 0.0, 0.5),
                max: Vec3A::new(1.0, 0.5, 2.0),
            },
            // Zero thickness in z.
            Aabb {
                min: Vec3A::new(-1.0, 0.0, 2.0),
                max: Vec3A::new(1.0, 0.5, 2.0),
            },
        ];
        let mut rng = crate::util::sampling::HashRng::new(11);
        let coords = [-3.0, -1.0, -0.25, 0.0, 0.5, 1.0, 2.0, 3.0];
        let pick = |rng: &mut crate::util::sampling::HashRng, n: usize| {
            (rng.next_f32() * n as f32) as usize % n
        };
        let mut tally = testing::Tally::default();
        for _ in 0..200_000 {
            let b = boxes[pick(&mut rng, 2)];
            // Grid origins lie on the boxes' planes; random ones make x·(1/x) round away from 1.
            let o = Vec3A::from_array([(); 3].map(|_| match pick(&mut rng, 2) {
                0 => coords[pick(&mut rng, coords.len())],
                _ => rng.next_f32() * 6.0 - 3.0,
            }));
            let d = if rng.next_f32() < 0.5 {
                Vec3A::from_array([(); 3].map(|_| rng.next_f32() - 0.5))
                    * [1.0, 1e-3, 1e3][pick(&mut rng, 3)]
            } else {
                // Aimed at a point of one of the box's edges, where rounding alone decides
                // whether t_near ≤ t_far.
                let mut corner = || {
                    let m = [(); 3].map(|_| rng.next_f32() < 0.5);
                    Vec3A::select(glam::BVec3A::new(m[0], m[1], m[2]), b.min, b.max)
                };
                let (c0, c1) = (corner(), corner());
                c0.lerp(c1, rng.next_f32()) - o
            };
            let t_max = [f32::INFINITY, 1.0, 0.0, 1e-30][pick(&mut rng, 4)];
            let inv_d = d.recip();
            let (t0, t1) = ((b.min - o) * inv_d, (b.max - o) * inv_d);
            let nan = t0.is_nan_mask() | t1.is_nan_mask();
            let fast = b.hit(o, inv_d, t_max);
            assert_eq!(
                fast,
                Aabb::overlap_guarded(t0, t1, nan, t_max),
                "box {b:?} o {o:?} d {d:?} t_max {t_max}"
            );
            tally.record(fast);
        }
        tally.assert_both_above(10_000);
    }

    #[test]
    fn aabb_slab_handles_zero_direction_components() {
        let b = Aabb {
            min: Vec3A::ZERO,
            max: Vec3A::ONE,
        };
        let d = Vec3A::new(1.0, 0.0, 0.0);
        let inv = d.recip();
        assert!(b.hit(Vec3A::new(-1.0, 0.5, 0.5), inv, f32::INFINITY));
        assert!(!b.hit(Vec3A::new(-1.0, 1.5, 0.5), inv, f32::INFINITY));
        // Origin exactly on the y = 0 face plane, moving parallel to it: conservative hit.
        assert!(b.hit(Vec3A::new(-1.0, 0.0, 0.5), inv, f32::INFINITY));
        assert!(b.hit(Vec3A::new(-1.0, 1.0, 0.5), inv, f32::INFINITY));
        // Negative zero behaves like positive zero.
        let dn = Vec3A::new(1.0, -0.0, 0.0);
        assert!(b.hit(Vec3A::new(-1.0, 0.0, 0.5), dn.recip(), f32::INFINITY));
        assert!(b.hit(Vec3A::new(-1.0, 0.5, 0.5), dn.recip(), f32::INFINITY));
        assert!(!b.hit(Vec3A::new(-1.0, 1.5, 0.5), dn.recip(), f32::INFINITY));
        assert!(!b.hit(Vec3A::new(-1.0, 0.5, 0.5), inv, 0.5));
    }

    #[test]
    fn exp_nonpositive_is_accurate_and_ends_at_zero() {
        let mut x = 0.0f32;
        while x > -87.0 {
            let got = super::exp_nonpositive(x) as f64;
            let want = (x as f64).exp();
            assert!(
                (got - want).abs() <= (2e-7 + 1e-7 * x.abs() as f64) * want,
                "e^{x}: {got} vs {want}"
            );
            x -= 0.0137;
        }
        assert_eq!(super::exp_nonpositive(0.0), 1.0);
        assert_eq!(super::exp_nonpositive(-1000.0), 0.0);
        assert_eq!(super::exp_nonpositive(f32::NEG_INFINITY), 0.0);
        assert_eq!(super::exp_nonpositive(f32::NAN), 0.0);
    }

    /// Every lane of [`atan2_lanes`] is [`atan2`]'s, bit for bit: on a grid through every
    /// octant and both sides of the reduction at tan π/8, on the axes and the cut with both
    /// zeros, and for NaN and infinite inputs, each in a different lane of its eight.
    #[test]
    fn atan2_lanes_gives_the_scalar_bits() {
        let mut values = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.414_213_57,
            0.414_213_6,
            f32::MIN_POSITIVE,
        ];
        values.extend([
            1e-30,
            -1e-30,
            1e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ]);
        values.extend((0..200).map(|i| -3.0 + 6.0 * (i as f32 + 0.3) / 200.0));
        let pairs: Vec<(f32, f32)> = values
            .iter()
            .flat_map(|&y| values.iter().map(move |&x| (y, x)))
            .collect();
        for (k, chunk) in pairs.chunks(8).enumerate() {
            let mut y = [0.5f32; 8];
            let mut x = [0.5f32; 8];
            for (lane, &(yl, xl)) in chunk.iter().enumerate() {
                // Rotate the lanes, so that a value meets every lane.
                let lane = (lane + k) % 8;
                y[lane] = yl;
                x[lane] = xl;
            }
            let got = atan2_lanes(F(y), F(x));
            for lane in 0..8 {
                assert_eq!(
                    got.0[lane].to_bits(),
                    atan2(y[lane], x[lane]).to_bits(),
                    "atan2({}, {})",
                    y[lane],
                    x[lane]
                );
            }
        }
    }

    #[test]
    fn atan2_and_acos_are_within_a_few_ulp_of_f64() {
        let mut worst = 0.0f64;
        let n = 2000;
        for i in 0..n {
            for j in 0..n {
                let y = -2.0 + 4.0 * (i as f32 + 0.37) / n as f32;
                let x = -2.0 + 4.0 * (j as f32 + 0.61) / n as f32;
                let want = (y as f64).atan2(x as f64);
                worst = worst.max((super::atan2(y, x) as f64 - want).abs());
            }
        }
        assert!(worst < 5e-7, "atan2 off by {worst}");
        for (y, x, want) in [
            (0.0f32, 1.0f32, 0.0f64),
            (1.0, 0.0, std::f64::consts::FRAC_PI_2),
            (0.0, -1.0, std::f64::consts::PI),
            (-1.0, 0.0, -std::f64::consts::FRAC_PI_2),
            (1.0, 1.0, std::f64::consts::FRAC_PI_4),
            (0.0, 0.0, 0.0),
        ] {
            assert!(
                (super::atan2(y, x) as f64 - want).abs() < 3e-7,
                "atan2({y}, {x})"
            );
        }
        assert!(super::atan2(f32::NAN, 1.0).is_nan());
        let mut worst = 0.0f64;
        for i in 0..=20000 {
            let c = -1.0 + 2.0 * i as f32 / 20000.0;
            worst = worst.max((super::acos(c) as f64 - (c as f64).acos()).abs());
        }
        assert!(worst < 5e-7, "acos off by {worst}");
        assert_eq!(super::acos(1.5), 0.0);
    }
}
