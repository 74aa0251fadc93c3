//! Runtime geometry and its ray intersection routines.
//!
//! Shapes are stored in the cheapest form their transform allows: a sphere under a similarity
//! stays a world-space sphere, a rectangle under any affine map is a world-space parallelogram,
//! and only boxes under rotation/shear and spheres under non-uniform scale pay for a transform
//! of the ray into object space.

mod lanes;

use glam::{BVec3A, Vec3A};

pub(crate) use lanes::{cuboid_lanes, sphere_lanes};

use crate::interaction::transformed_box;
pub use crate::interaction::{Hit, SurfacePoint, Transformed};
use crate::util::math::{gamma, Aabb, Ray};

/// Geometry of one primitive, in world space unless it carries a transform.
#[derive(Clone, Debug)]
pub enum Shape {
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vec3A,
        /// Radius (> 0).
        radius: f32,
    },
    /// The unit sphere under an affine map that is not a similarity (an ellipsoid).
    Ellipsoid(Transformed),
    /// A parallelogram `p0 + u·e1 + v·e2`, u, v ∈ [0, 1].
    Parallelogram(Parallelogram),
    /// An infinite plane.
    Plane {
        /// A point of the plane.
        point: Vec3A,
        /// Unit normal (the front side).
        normal: Vec3A,
    },
    /// A triangle mesh under a transform (the part of a hit is the triangle).
    Mesh(crate::mesh::MeshInstance),
    /// A box `[min, max]` in object space, under a transform (which may be the identity).
    Cuboid {
        /// Object-space lower corner.
        min: Vec3A,
        /// Object-space upper corner.
        max: Vec3A,
        /// Object-to-world map.
        xf: Transformed,
    },
}

/// A parallelogram with the dual basis that turns a plane point into (u, v).
#[derive(Clone, Debug)]
pub struct Parallelogram {
    /// Corner.
    pub p0: Vec3A,
    /// First edge.
    pub e1: Vec3A,
    /// Second edge.
    pub e2: Vec3A,
    /// Unit normal of the front side.
    pub normal: Vec3A,
    /// Area.
    pub area: f32,
    /// Dual basis: u = (p − p0)·a1, v = (p − p0)·a2 for a point p of the plane.
    pub(crate) a1: Vec3A,
    pub(crate) a2: Vec3A,
}

impl Parallelogram {
    /// Builds one from a corner, two edges and the front normal (which must be ±(e1×e2)).
    pub fn new(p0: Vec3A, e1: Vec3A, e2: Vec3A, normal: Vec3A) -> Self {
        let c = e1.cross(e2);
        let c2 = c.length_squared();
        Self {
            p0,
            e1,
            e2,
            normal: normal.normalize(),
            area: c2.sqrt(),
            a1: e2.cross(c) / c2,
            a2: c.cross(e1) / c2,
        }
    }

    /// The point at (u, v).
    #[inline]
    pub fn point(&self, u: f32, v: f32) -> Vec3A {
        self.p0 + self.e1 * u + self.e2 * v
    }

    /// The surface point at `t` along `r` (a hit of this parallelogram).
    #[inline(always)]
    pub fn surface(&self, r: &Ray, t: f32) -> SurfacePoint {
        let d = r.at(t) - self.p0;
        let (u, v) = (d.dot(self.a1), d.dot(self.a2));
        SurfacePoint::flat(self.point(u, v), self.normal, self.point_error(u, v))
    }

    /// Ray parameter of the hit in (0, t_max), if any; closed on all four edges.
    #[inline]
    #[allow(clippy::manual_range_contains)] // `contains` short-circuits: a branch per bound
    pub fn intersect(&self, r: &Ray, t_max: f32) -> Option<f32> {
        // One branch for the whole test: which walls of a room a ray meets is a coin toss, so
        // early exits mispredict. A zero denominator gives t = ±∞ or NaN, which fails the range
        // test, as do NaN u and v.
        let t = self.normal.dot(self.p0 - r.o) / self.normal.dot(r.d);
        let q = r.at(t) - self.p0;
        let u = q.dot(self.a1);
        let v = q.dot(self.a2);
        // Closed on all four edges: flush neighbours (a box built from quads) leave no cracks.
        let inside = (t > 0.0) & (t < t_max) & (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (v <= 1.0);
        inside.then_some(t)
    }

    /// Error bound of [`Parallelogram::point`]`(u, v)`: the rounding of p0 + u·e1 + v·e2 (and of
    /// u, v themselves, which moves the point within the plane but not off it) scaled by the
    /// magnitudes of its terms.
    #[inline]
    pub fn point_error(&self, u: f32, v: f32) -> Vec3A {
        (self.p0.abs() + (self.e1 * u).abs() + (self.e2 * v).abs()) * gamma(12)
            + Vec3A::splat(f32::MIN_POSITIVE)
    }

    fn bounds(&self) -> Aabb {
        Aabb::EMPTY
            .grow(self.p0)
            .grow(self.p0 + self.e1)
            .grow(self.p0 + self.e2)
            .grow(self.p0 + self.e1 + self.e2)
    }
}

/// Error bound of a sphere point computed as `c + v` (v = n·r, the re-projection every sphere
/// point goes through: hits and light samples alike).
#[inline]
pub fn sphere_point_error(c: Vec3A, v: Vec3A) -> Vec3A {
    (c.abs() + v.abs()) * gamma(8) + Vec3A::splat(f32::MIN_POSITIVE)
}

/// The surface point of a sphere's hit along `r` whose root in f64 (from
/// [`sphere_roots_f64`], chosen by [`hit_root`]) is `t64`: the direction from the centre in f64,
/// as o + t·d in f32 can be off by more than the whole sphere when the ray starts far away.
/// The many-path tracer's packet test hands over the root it found, so the point costs no
/// second root (`packet::HitKeep`).
#[inline]
pub(crate) fn sphere_surface(r: &Ray, center: Vec3A, radius: f32, t64: f64) -> SurfacePoint {
    let rel = (r.o.as_dvec3() - center.as_dvec3()) + r.d.as_dvec3() * t64;
    sphere_point(center, radius, rel.normalize().as_vec3a())
}

/// The point of a sphere in unit direction `n` from its centre: re-projected onto the surface,
/// which removes the error of o + t·d (pbrt-v4).
#[inline]
fn sphere_point(center: Vec3A, radius: f32, n: Vec3A) -> SurfacePoint {
    let p = center + n * radius;
    SurfacePoint::flat(p, n, sphere_point_error(center, n * radius))
}

/// Which of a sphere's f64 roots (t0 ≤ t1) a hit at f32 `t` (one of them, rounded) was.
#[inline(always)]
pub(crate) fn hit_root(t0: f64, t1: f64, t: f32) -> f64 {
    if (t1 as f32) == t {
        t1
    } else {
        t0
    }
}

/// Roots of `|o + t·d − c|² = r²` in increasing order, as f32 (see [`sphere_roots_f64`]).
#[inline]
pub fn sphere_roots(o: Vec3A, d: Vec3A, c: Vec3A, r: f32) -> Option<(f32, f32)> {
    sphere_roots_f64(o, d, c, r).map(|(t0, t1)| (t0 as f32, t1 as f32))
}

/// Roots of `|o + t·d − c|² = r²` in increasing order, in f64 from the f32 inputs.
///
/// The discriminant comes from the squared perpendicular distance |f × d|²/|d|² (Ray Tracing
/// Gems ch. 7), not b² − 4ac, whose cancellation loses a small or distant sphere entirely; and
/// the second root comes from Vieta's formula. Even so, in f32 the cross product of a ray 10⁴
/// away cancels to an error larger than a 10⁻⁴ sphere; in f64 the products of f32 inputs are
/// exact and the result is correct to well under an f32 ULP, for about the same cost as f32 on
/// scalar SSE2. The test suite checks hit/miss and t against an independent f64 reference.
#[inline]
pub fn sphere_roots_f64(o: Vec3A, d: Vec3A, c: Vec3A, r: f32) -> Option<(f64, f64)> {
    let f = o.as_dvec3() - c.as_dvec3();
    let d = d.as_dvec3();
    let r = r as f64;
    let a = d.length_squared();
    let b = -f.dot(d); // half of −b in at² + bt + c
    let perp2 = f.cross(d).length_squared() / a;
    let disc = (r - perp2.sqrt()) * (r + perp2.sqrt());
    if !(disc >= 0.0) {
        return None;
    }
    let fl = f.length();
    let cc = (fl - r) * (fl + r);
    let q = b + b.signum() * (a * disc).sqrt();
    if q == 0.0 {
        // Tangent ray through the centre's perpendicular foot: a double root at t = b/a.
        let t = b / a;
        return Some((t, t));
    }
    let (t0, t1) = (cc / q, q / a);
    Some(if t0 <= t1 { (t0, t1) } else { (t1, t0) })
}

/// Slab test against `[min, max]`. Returns (t_near, face_near, t_far, face_far) where faces are
/// numbered axis·2 + (1 if the max side). Ties between axes go to the lowest axis; a zero
/// direction component whose origin lies outside its slab misses; one inside is unconstrained.
///
/// Vectorised: a zero component gives ±∞ slab distances, which order correctly, except for an
/// origin exactly on that slab's plane, where 0·∞ is NaN; that origin is inside the closed slab,
/// so the axis is made unconstrained explicitly (SIMD `min`/`max` would propagate the NaN).
#[inline]
pub fn slab(o: Vec3A, d: Vec3A, min: Vec3A, max: Vec3A) -> Option<(f32, u32, f32, u32)> {
    let hit = slab_unchecked(o, d, min, max);
    (hit.0 <= hit.2).then_some(hit)
}

/// [`slab`] without the final test: the ray misses unless t_near ≤ t_far. For callers that
/// fold that test into their own, so that a miss costs no mispredicted branch.
#[inline]
fn slab_unchecked(o: Vec3A, d: Vec3A, min: Vec3A, max: Vec3A) -> (f32, u32, f32, u32) {
    let (inv, near, far) = slab_distances(o, d, min, max);
    let t_near = near.max_element();
    let t_far = far.min_element();
    // The face index without data-dependent branches (they mispredict in a render): the lowest
    // axis whose slab distance is the extreme one, and that axis's direction sign. `near` and
    // `far` hold no NaN, so each mask has a bit set.
    let an = near.cmpeq(Vec3A::splat(t_near)).bitmask().trailing_zeros();
    let af = far.cmpeq(Vec3A::splat(t_far)).bitmask().trailing_zeros();
    // Entering through the min face when moving towards +axis (including +0), else the max face.
    let pos = inv.cmpgt(Vec3A::ZERO).bitmask();
    let f_near = an * 2 + (!(pos >> an) & 1);
    let f_far = af * 2 + ((pos >> af) & 1);
    (t_near, f_near, t_far, f_far)
}

/// Per-axis slab entry and exit distances, NaN-free, with the reciprocal direction.
#[inline]
fn slab_distances(o: Vec3A, d: Vec3A, min: Vec3A, max: Vec3A) -> (Vec3A, Vec3A, Vec3A) {
    let inv = d.recip();
    let t_lo = (min - o) * inv;
    let t_hi = (max - o) * inv;
    let nan = t_lo.is_nan_mask() | t_hi.is_nan_mask();
    let near = Vec3A::select(nan, Vec3A::NEG_INFINITY, t_lo.min(t_hi));
    let far = Vec3A::select(nan, Vec3A::INFINITY, t_lo.max(t_hi));
    (inv, near, far)
}

/// For slab distances (`tn`, `tf`): whether `tn` lies in (0, t_max), and whether the slab is
/// hit in that range at all. Selects rather than branches, as in the slab test.
#[inline]
fn slab_in_range(tn: f32, tf: f32, t_max: f32) -> (bool, bool) {
    let near_ok = (tn > 0.0) & (tn < t_max);
    let far_ok = (tf > 0.0) & (tf < t_max);
    (near_ok, (tn <= tf) & (near_ok | far_ok))
}

/// Unit object-space normal of box face `face`.
#[inline]
fn face_normal(face: u32) -> Vec3A {
    // A table rather than a store into one component (see `Shape::surface`'s snap).
    const NORMALS: [Vec3A; 6] = [
        Vec3A::NEG_X,
        Vec3A::X,
        Vec3A::NEG_Y,
        Vec3A::Y,
        Vec3A::NEG_Z,
        Vec3A::Z,
    ];
    NORMALS[face as usize % 6]
}

impl Shape {
    /// The closest hit with t in (0, t_max), if any.
    #[inline]
    pub fn intersect(&self, r: &Ray, t_max: f32) -> Option<(f32, u32)> {
        let pick = |t0: f32, t1: f32| {
            if t0 > 0.0 && t0 < t_max {
                Some((t0, 0))
            } else if t1 > 0.0 && t1 < t_max {
                Some((t1, 0))
            } else {
                None
            }
        };
        match self {
            Shape::Sphere { center, radius } => {
                let (t0, t1) = sphere_roots(r.o, r.d, *center, *radius)?;
                pick(t0, t1)
            }
            Shape::Ellipsoid(xf) => {
                let lr = xf.ray_to_object(r);
                let (t0, t1) = sphere_roots(lr.o, lr.d, Vec3A::ZERO, 1.0)?;
                pick(t0, t1)
            }
            Shape::Parallelogram(q) => q.intersect(r, t_max).map(|t| (t, 0)),
            Shape::Mesh(m) => m.intersect(r, t_max),
            Shape::Plane { point, normal } => {
                let denom = normal.dot(r.d);
                if denom == 0.0 {
                    return None;
                }
                let t = normal.dot(*point - r.o) / denom;
                (t > 0.0 && t < t_max).then_some((t, 0))
            }
            Shape::Cuboid { min, max, xf } => {
                let lr = xf.ray_to_object(r);
                let (tn, fnear, tf, ffar) = slab_unchecked(lr.o, lr.d, *min, *max);
                let (near_ok, hit) = slab_in_range(tn, tf, t_max);
                let (t, face) = if near_ok { (tn, fnear) } else { (tf, ffar) };
                hit.then_some((t, face))
            }
        }
    }

    /// Whether the shape has a hit with t in (0, t_max): exactly `intersect(..).is_some()`, for
    /// shadow rays, without the work of choosing which hit and which face.
    #[inline]
    pub fn blocks(&self, r: &Ray, t_max: f32) -> bool {
        match self {
            Shape::Cuboid { min, max, xf } => {
                let lr = xf.ray_to_object(r);
                let (_, near, far) = slab_distances(lr.o, lr.d, *min, *max);
                slab_in_range(near.max_element(), far.min_element(), t_max).1
            }
            Shape::Mesh(m) => m.blocks(r, t_max),
            _ => self.intersect(r, t_max).is_some(),
        }
    }

    /// Surface position and normal at a hit found by [`Shape::intersect`].
    #[inline]
    pub fn surface(&self, r: &Ray, t: f32, part: u32) -> SurfacePoint {
        match self {
            Shape::Sphere { center, radius } => {
                match sphere_roots_f64(r.o, r.d, *center, *radius) {
                    Some((t0, t1)) => sphere_surface(r, *center, *radius, hit_root(t0, t1, t)),
                    None => sphere_point(*center, *radius, (r.at(t) - *center).normalize()),
                }
            }
            Shape::Ellipsoid(xf) => {
                let lr = xf.ray_to_object(r);
                let pl = lr.at(t).normalize();
                SurfacePoint::flat(
                    xf.point_to_world(pl),
                    xf.normal_to_world(pl),
                    xf.point_error(pl, gamma(8)),
                )
            }
            Shape::Parallelogram(q) => q.surface(r, t),
            Shape::Mesh(m) => m.surface(r, part),
            Shape::Plane { point, normal } => {
                let p = r.at(t);
                SurfacePoint::flat(
                    p - *normal * normal.dot(p - *point),
                    *normal,
                    (p.abs() + point.abs()) * gamma(12),
                )
            }
            Shape::Cuboid { min, max, xf } => {
                let lr = xf.ray_to_object(r);
                // Snap to the face plane: the hit is on it by construction. A select, not a
                // store into one component: a one-float store read back as a vector misses the
                // store-to-load forwarding, which cost a tenth of this function's time.
                let axis = part / 2;
                let on_axis = BVec3A::new(axis == 0, axis == 1, axis == 2);
                let bound = if part % 2 == 1 { *max } else { *min };
                let pl = Vec3A::select(on_axis, bound, lr.at(t)).clamp(*min, *max);
                SurfacePoint::flat(
                    xf.point_to_world(pl),
                    xf.normal_to_world(face_normal(part)),
                    xf.point_error(pl, gamma(4)),
                )
            }
        }
    }

    /// Texture coordinates at a hit found by [`Shape::intersect`]: a mesh's, where its file
    /// gives them; zero elsewhere (scenes give textures to such meshes only).
    #[inline]
    pub fn uv(&self, r: &Ray, part: u32) -> glam::Vec2 {
        match self {
            Shape::Mesh(m) => m.uv(r, part),
            _ => glam::Vec2::ZERO,
        }
    }

    /// A mesh's texture coordinates and tangent frame at a hit ([`crate::mesh::MeshInstance::uv_frame`]);
    /// `None` for every other shape.
    #[inline]
    pub fn uv_frame(&self, r: &Ray, part: u32) -> Option<crate::mesh::UvFrame> {
        match self {
            Shape::Mesh(m) => m.uv_frame(r, part),
            _ => None,
        }
    }

    /// World-space bounds; infinite for planes (which the BVH keeps aside).
    pub fn bounds(&self) -> Aabb {
        match self {
            Shape::Sphere { center, radius } => Aabb {
                min: *center - Vec3A::splat(*radius),
                max: *center + Vec3A::splat(*radius),
            },
            Shape::Ellipsoid(xf) => transformed_box(&xf.to_world, Vec3A::splat(-1.0), Vec3A::ONE),
            Shape::Parallelogram(q) => q.bounds(),
            Shape::Mesh(m) => m.bounds(),
            Shape::Plane { .. } => Aabb {
                min: Vec3A::splat(f32::NEG_INFINITY),
                max: Vec3A::splat(f32::INFINITY),
            },
            Shape::Cuboid { min, max, xf } => transformed_box(&xf.to_world, *min, *max),
        }
    }

    /// The faces of a box as world-space parallelograms with outward normals, in face order.
    pub fn cuboid_faces(min: Vec3A, max: Vec3A, xf: &Transformed) -> [Parallelogram; 6] {
        std::array::from_fn(|face| {
            let axis = face / 2;
            let (u_axis, v_axis) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut p0 = min;
            if face % 2 == 1 {
                p0[axis] = max[axis];
            }
            let mut e1 = Vec3A::ZERO;
            e1[u_axis] = max[u_axis] - min[u_axis];
            let mut e2 = Vec3A::ZERO;
            e2[v_axis] = max[v_axis] - min[v_axis];
            let w = |p: Vec3A| xf.to_world.transform_point3a(p);
            let wp0 = w(p0);
            let n = xf.normal_to_world(face_normal(face as u32));
            Parallelogram::new(wp0, w(p0 + e1) - wp0, w(p0 + e2) - wp0, n)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Affine3A;

    #[test]
    fn sphere_roots_match_f64_for_tiny_distant_sphere() {
        let (c, r) = (Vec3A::ZERO, 1e-4f32);
        let o = Vec3A::new(0.0, 0.0, 1e4);
        let d = Vec3A::new(0.0, 0.0, -1.0);
        let (t0, t1) = sphere_roots(o, d, c, r).expect("hit");
        assert!(((t0 as f64) - (1e4 - 1e-4)).abs() < 1e-3, "{t0}");
        assert!(((t1 as f64) - (1e4 + 1e-4)).abs() < 1e-3, "{t1}");
    }

    #[test]
    fn slab_tie_rule_and_zero_components() {
        // Through an edge: x and y planes tie; the lowest axis wins.
        let (tn, f, _, _) = slab(
            Vec3A::new(-2.0, -2.0, 0.5),
            Vec3A::new(1.0, 1.0, 0.0),
            Vec3A::ZERO,
            Vec3A::ONE,
        )
        .expect("hit");
        assert_eq!((tn, f), (2.0, 0));
        // Parallel to a face with the origin outside the slab: miss. Negative zero too.
        assert!(slab(
            Vec3A::new(-1.0, 2.0, 0.5),
            Vec3A::new(1.0, -0.0, 0.0),
            Vec3A::ZERO,
            Vec3A::ONE
        )
        .is_none());
        // Zero-thickness box.
        let r = slab(
            Vec3A::new(0.5, 0.5, -1.0),
            Vec3A::Z,
            Vec3A::ZERO,
            Vec3A::new(1.0, 1.0, 0.0),
        );
        let (tn, f, tf, _) = r.expect("hits the flat box");
        assert_eq!((tn, tf, f), (1.0, 1.0, 4));
    }

    #[test]
    fn parallelogram_uv_and_normal() {
        let q = Parallelogram::new(Vec3A::ZERO, Vec3A::X * 2.0, Vec3A::Y, Vec3A::Z);
        assert_eq!(q.area, 2.0);
        let r = Ray::new(Vec3A::new(1.0, 0.5, 1.0), -Vec3A::Z);
        assert_eq!(q.intersect(&r, f32::INFINITY), Some(1.0));
        let r = Ray::new(Vec3A::new(2.5, 0.5, 1.0), -Vec3A::Z);
        assert_eq!(q.intersect(&r, f32::INFINITY), None);
    }

    /// The shadow-ray test answers exactly what the closest-hit test does, for rotated and flat
    /// boxes, rays from inside, from faces and edges, with zero direction components, and at
    /// every t_max.
    #[test]
    fn blocks_is_intersect_is_some() {
        let m =
            Affine3A::from_rotation_y(0.5) * Affine3A::from_scale(glam::Vec3::new(1.0, 2.0, 3.0));
        let shapes = [
            Shape::Cuboid {
                min: Vec3A::splat(-1.0),
                max: Vec3A::ONE,
                xf: Transformed::new(m),
            },
            Shape::Cuboid {
                min: Vec3A::ZERO,
                max: Vec3A::new(1.0, 1.0, 0.0),
                xf: Transformed::new(Affine3A::IDENTITY),
            },
            Shape::Sphere {
                center: Vec3A::ZERO,
                radius: 1.0,
            },
        ];
        let mut rng = crate::util::sampling::HashRng::new(3);
        let mut coord = || [-2.0, -1.0, -0.0, 0.0, 0.5, 1.0, 2.0][(rng.next_f32() * 7.0) as usize];
        let mut tally = crate::util::math::testing::Tally::default();
        for _ in 0..20_000 {
            let o = Vec3A::new(coord(), coord(), coord());
            let d = Vec3A::new(coord(), coord(), coord());
            let ray = Ray::new(o, d);
            for shape in &shapes {
                for t_max in [f32::INFINITY, 1.0, 0.5, 0.0] {
                    let want = shape.intersect(&ray, t_max).is_some();
                    assert_eq!(shape.blocks(&ray, t_max), want, "{shape:?} {ray:?} {t_max}");
                    tally.record(want);
                }
            }
        }
        tally.assert_both_above(10_000);
    }

    #[test]
    fn rotated_cuboid_hits_and_normals_are_unit() {
        let m =
            Affine3A::from_rotation_y(0.5) * Affine3A::from_scale(glam::Vec3::new(1.0, 2.0, 3.0));
        let s = Shape::Cuboid {
            min: Vec3A::splat(-1.0),
            max: Vec3A::ONE,
            xf: Transformed::new(m),
        };
        let r = Ray::new(Vec3A::new(0.0, 0.0, 10.0), -Vec3A::Z);
        let (t, part) = s.intersect(&r, f32::INFINITY).expect("hit");
        let sp = s.surface(&r, t, part);
        assert!((sp.n.length() - 1.0).abs() < 1e-6);
        assert!(sp.n.z > 0.0, "{:?}", sp.n);
        assert!((sp.p - r.at(t)).length() < 1e-5);
    }
}
