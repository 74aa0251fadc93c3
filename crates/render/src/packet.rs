//! Rays in lanes, for the queries that test several at once: one ray splatted across four
//! lanes ([`RayX4`], for a leaf's quads four at a time) and a packet of `N` rays in
//! structure-of-arrays lanes ([`Rays`], for the many-path tracer), with the answers a packet
//! query gives ([`LaneHits`]).

use glam::Vec3A;

use crate::util::lanes::{splat3, v3, F, M, V3};
use crate::util::math::{Aabb, Ray};

/// How many lanes a packet query takes at most (its answers' lanes are bits of a `u32`).
pub const MAX_LANES: usize = 16;

/// A ray's components splatted across four lanes, made once per query, with what the bounding
/// box test of the other primitives needs.
#[derive(Clone, Copy, Debug)]
pub struct RayX4 {
    pub(crate) o: V3<4>,
    pub(crate) d: V3<4>,
    pub(crate) origin: Vec3A,
    pub(crate) inv_d: Vec3A,
}

impl RayX4 {
    /// Splats `ray`.
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        Self {
            o: splat3(ray.o),
            d: splat3(ray.d),
            origin: ray.o,
            inv_d: ray.d.recip(),
        }
    }
}

/// The closest hits of a packet: the lanes with one (bits), and each lane's t, primitive and
/// part (meaningful where its bit is set).
#[derive(Clone, Copy, Debug)]
pub struct LaneHits<const N: usize> {
    /// Lanes with a hit.
    pub hit: u32,
    /// Ray parameters.
    pub t: [f32; N],
    /// Primitives.
    pub prim: [u32; N],
    /// Parts of the primitives (a box's face).
    pub part: [u32; N],
}

/// What a packet query found for each lane beyond t, primitive and part, kept for the lane's
/// surface point so that it is not found again: each sphere hit's f64 root
/// ([`crate::shape::sphere_surface`]) and each mesh hit's barycentrics (`mesh::restore_hit`).
/// Written only for the lanes whose hit is a sphere or a mesh, and stale elsewhere: the
/// caller keeps one for all its queries, so that scenes without either store nothing.
#[derive(Clone, Copy, Debug)]
pub(crate) struct HitKeep<const N: usize> {
    pub(crate) sphere_root: [f64; N],
    pub(crate) mesh_hit: [Option<crate::mesh::LastHit>; N],
}

impl<const N: usize> HitKeep<N> {
    pub(crate) fn new() -> Self {
        Self {
            sphere_root: [0.0; N],
            mesh_hit: [None; N],
        }
    }
}

/// `N` rays in structure-of-arrays lanes.
#[derive(Clone, Copy, Debug)]
pub struct Rays<const N: usize> {
    pub(crate) o: V3<N>,
    pub(crate) d: V3<N>,
    inv_d: V3<N>,
}

impl<const N: usize> Rays<N> {
    /// The origins.
    #[inline(always)]
    pub fn origins(&self) -> &V3<N> {
        &self.o
    }

    /// The directions.
    #[inline(always)]
    pub fn directions(&self) -> &V3<N> {
        &self.d
    }

    /// Rays whose origins and directions are already in lanes.
    #[inline(always)]
    pub fn from_lanes(o: V3<N>, d: V3<N>) -> Self {
        Self {
            o,
            d,
            inv_d: v3(|c| d[c].recip()),
        }
    }

    /// The lanes whose rays meet `b`, with t_max per lane: [`Aabb::hit`]'s answer for each,
    /// computed the way its guarded branch does (an axis whose slab distance is NaN is
    /// unconstrained), which is the answer of its fast branch wherever there is no NaN.
    #[inline(always)]
    pub(crate) fn hit_box(&self, b: &Aabb, t_max: F<N>) -> M<N> {
        let mut near = F::NEG_INFINITY;
        let mut far = F::INFINITY;
        for axis in 0..3 {
            let t0 = (F::splat(b.min[axis]) - self.o[axis]) * self.inv_d[axis];
            let t1 = (F::splat(b.max[axis]) - self.o[axis]) * self.inv_d[axis];
            let nan = t0.is_nan_mask() | t1.is_nan_mask();
            near = near.max(F::select(nan, F::NEG_INFINITY, t0.min(t1)));
            far = far.min(F::select(
                nan,
                F::INFINITY,
                t0.max(t1) * crate::util::math::FAR_INFLATION,
            ));
        }
        near.max(F::ZERO).cmple(far.min(t_max))
    }
}
