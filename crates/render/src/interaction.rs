//! What an intersection yields, shared by every kind of geometry: the hit itself ([`Hit`]),
//! the surface point computed for the closest one ([`SurfacePoint`], with the rounding-error
//! bound that spawned rays need), and the object-to-world map of a transformed shape or mesh
//! instance ([`Transformed`]). Below shapes and meshes, which both produce them.

use glam::{Affine3A, Mat3A, Vec3A};

use crate::util::math::{gamma, Aabb, Ray};

/// An object-to-world affine map with the inverse and normal matrix it needs at hit time.
#[derive(Clone, Debug)]
pub struct Transformed {
    /// Object to world.
    pub to_world: Affine3A,
    /// World to object.
    pub to_object: Affine3A,
    /// Inverse transpose of the linear part, which maps object normals to world normals.
    pub normal_matrix: Mat3A,
    /// Whether the map is the identity, so the ray needs no transform.
    pub identity: bool,
    /// Whether the map mirrors (a negative determinant), which turns n × t against the
    /// bitangent a tangent frame carries.
    pub mirrors: bool,
}

impl Transformed {
    /// Wraps an invertible map (the caller validated the determinant).
    pub fn new(to_world: Affine3A) -> Self {
        let to_object = to_world.inverse();
        let normal_matrix = to_object.matrix3.transpose();
        let identity = to_world == Affine3A::IDENTITY;
        let mirrors = to_world.matrix3.determinant() < 0.0;
        Self {
            to_world,
            to_object,
            normal_matrix,
            identity,
            mirrors,
        }
    }

    #[inline]
    pub(crate) fn ray_to_object(&self, r: &Ray) -> Ray {
        if self.identity {
            *r
        } else {
            Ray::new(
                self.to_object.transform_point3a(r.o),
                self.to_object.transform_vector3a(r.d),
            )
        }
    }

    #[inline]
    pub(crate) fn normal_to_world(&self, n: Vec3A) -> Vec3A {
        if self.identity {
            n
        } else {
            (self.normal_matrix * n).normalize()
        }
    }

    /// Error bound of `point_to_world(p)` for an object-space point `p` that is itself within
    /// `rel`·|p| of the exact point: the transform's own rounding (pbrt-v4's γ₃ bound) plus the
    /// object-space error carried through the linear part. Never zero, so a spawned ray always
    /// moves off a face that lies on a float grid line.
    #[inline]
    pub(crate) fn point_error(&self, p: Vec3A, rel: f32) -> Vec3A {
        let m = if self.identity {
            p.abs()
        } else {
            let l = self.to_world.matrix3;
            let a = Mat3A::from_cols(l.x_axis.abs(), l.y_axis.abs(), l.z_axis.abs());
            a * p.abs() + self.to_world.translation.abs()
        };
        m * (gamma(4) + rel) + Vec3A::splat(f32::MIN_POSITIVE)
    }

    /// Error bound of `point_to_world(p)` for an object-space point `p` whose own absolute
    /// error is at most `err` per coordinate.
    #[inline]
    pub(crate) fn carry_error(&self, p: Vec3A, err: Vec3A) -> Vec3A {
        if self.identity {
            return err;
        }
        let l = self.to_world.matrix3;
        let a = Mat3A::from_cols(l.x_axis.abs(), l.y_axis.abs(), l.z_axis.abs());
        self.point_error(p, 0.0) + a * err * (1.0 + gamma(3))
    }

    #[inline]
    pub(crate) fn point_to_world(&self, p: Vec3A) -> Vec3A {
        if self.identity {
            p
        } else {
            self.to_world.transform_point3a(p)
        }
    }
}

/// Where a ray met a primitive; the surface details are computed only for the closest hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Ray parameter.
    pub t: f32,
    /// Primitive index.
    pub prim: u32,
    /// Shape-specific part (the face of a box, 0 otherwise).
    pub part: u32,
}

/// The geometry at a hit point.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// Position, recomputed from the shape's own parameterisation (not `o + t·d`).
    pub p: Vec3A,
    /// Unit geometric normal of the shape's front side.
    pub n: Vec3A,
    /// Unit shading normal: the interpolated vertex normal of a smooth mesh, `n` elsewhere.
    /// On the same side as `n`.
    pub ns: Vec3A,
    /// Conservative bound on the absolute rounding error of each coordinate of `p`, which
    /// [`crate::util::math::offset_ray_origin`] needs to spawn rays that cannot re-hit the surface.
    pub err: Vec3A,
}

impl SurfacePoint {
    /// A point whose shading normal is its geometric normal (every shape but smooth meshes).
    #[inline(always)]
    pub fn flat(p: Vec3A, n: Vec3A, err: Vec3A) -> Self {
        Self { p, n, ns: n, err }
    }
}

/// The world bounds of the object-space box (`min`, `max`) under `m`, padded so that rounding
/// in the corner transform cannot shrink it below the shape.
pub(crate) fn transformed_box(m: &Affine3A, min: Vec3A, max: Vec3A) -> Aabb {
    let mut b = Aabb::EMPTY;
    for i in 0..8 {
        let c = Vec3A::new(
            if i & 1 == 0 { min.x } else { max.x },
            if i & 2 == 0 { min.y } else { max.y },
            if i & 4 == 0 { min.z } else { max.z },
        );
        b = b.grow(m.transform_point3a(c));
    }
    // Rounding in the corner transform must not shrink the box below the shape.
    let pad = (b.max.abs().max(b.min.abs())) * (4.0 * f32::EPSILON);
    Aabb {
        min: b.min - pad,
        max: b.max + pad,
    }
}

/// The normals at a vertex, on the side the path arrived from: the geometric one (offsets,
/// and which side a direction leaves by) and the shading one (scattering), and whether they
/// differ (a smooth mesh).
#[derive(Clone, Copy)]
pub(crate) struct Shading {
    pub(crate) n: Vec3A,
    pub(crate) ns: Vec3A,
    pub(crate) shaded: bool,
}

impl Shading {
    /// The normals at `sp` for a path leaving towards `wo`, and whether it arrived on the
    /// front side. Without `shading_normals` (every scene but smooth meshes) ns = n, and the
    /// side tests that compare the two are skipped: they would repeat the shading ones.
    #[inline(always)]
    pub(crate) fn facing(sp: &SurfacePoint, wo: Vec3A, shading_normals: bool) -> (bool, Self) {
        let front = sp.n.dot(wo) >= 0.0;
        let n = if front { sp.n } else { -sp.n };
        let shaded = shading_normals && sp.ns != sp.n;
        let ns = match (shaded, front) {
            (false, _) => n,
            (true, true) => sp.ns,
            (true, false) => -sp.ns,
        };
        (front, Self { n, ns, shaded })
    }
}
