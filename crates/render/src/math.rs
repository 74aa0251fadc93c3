//! Small geometric helpers: rays, bounding boxes, frames and robust ray spawning.

use glam::{Vec3, Vec3A};

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
    #[inline]
    pub fn hit(&self, o: Vec3A, inv_d: Vec3A, t_max: f32) -> bool {
        let t0 = (self.min - o) * inv_d;
        let t1 = (self.max - o) * inv_d;
        let nan = t0.is_nan_mask() | t1.is_nan_mask();
        let tn = Vec3A::select(nan, Vec3A::NEG_INFINITY, t0.min(t1));
        let tf = Vec3A::select(nan, Vec3A::INFINITY, t0.max(t1) * (1.0 + 2.0 * gamma(3)));
        let t_near = tn.max_element().max(0.0);
        let t_far = tf.min_element().min(t_max);
        t_near <= t_far
    }
}

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
}

/// Moves a surface point off its surface to the side `n` points to (the side the new ray leaves
/// from), by just enough to clear the point's conservative rounding-error bound `err` (pbrt-v4's
/// `OffsetRayOrigin`): the offset along `n` is |n|·err, then each coordinate is rounded one more
/// float away from the surface, so the rounding of the addition cannot undo it. The bound
/// comes from the magnitudes of the terms the point was computed from, never from scene units,
/// so it holds at any scale and translation where a fixed epsilon fails.
#[inline]
pub fn offset_ray_origin(p: Vec3A, err: Vec3A, n: Vec3A) -> Vec3A {
    let d = n.abs().dot(err);
    let offset = n * d;
    let po = p + offset;
    let away = |v: f32, o: f32| {
        if o > 0.0 {
            v.next_up()
        } else if o < 0.0 {
            v.next_down()
        } else {
            v
        }
    };
    // By the sign of n, not of the offset: even a zero error bound moves the origin a float.
    Vec3A::new(away(po.x, n.x), away(po.y, n.y), away(po.z, n.z))
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
