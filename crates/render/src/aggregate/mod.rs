//! The scene's ray queries, as pbrt's aggregates: a BVH over the bounded primitives
//! ([`crate::accel::bvh`]), whose leaves hold quads four at a time in SIMD lanes ([`leaf`]),
//! plus the unbounded primitives (planes) tested one by one. Closest-hit and any-hit queries
//! for one ray, and the packet versions the many-path tracer asks for scenes of one leaf.
//!
//! Objects merged into one world-space mesh ([`crate::mesh::TriMesh::merged`]) each keep their
//! primitive, for their material and surface, but the structure holds the mesh once, under
//! the first of them, and a hit on it names the primitive its triangle came from.

pub mod leaf;

use leaf::Leaves;

use crate::accel::bvh::Bvh;
use crate::packet::{HitKeep, LaneHits, RayX4, Rays};
use crate::primitive::Primitive;
use crate::shape::{Hit, Shape};
use crate::util::math::{Aabb, Ray};

/// The acceleration structure of a scene's primitives.
#[derive(Clone, Debug)]
pub struct Accel {
    bvh: Bvh,
    leaves: Leaves,
    unbounded: Vec<u32>,
    /// Whether some primitive is part of a merged mesh, whose hits name their owners: only
    /// then does a hit look at its primitive's shape to find them.
    merged: bool,
    /// The scene's one primitive, where it is a mesh and there is nothing else (every mesh of
    /// a glTF file merged, say): the mesh's own tree is then the scene's, and the top level
    /// would only test the same box again before handing the ray to it.
    only_mesh: Option<u32>,
}

impl Accel {
    /// Builds the structure over `prims` (indices into it are what hits name).
    pub fn build(prims: &[Primitive]) -> Self {
        let bounds: Vec<Aabb> = prims.iter().map(|p| p.shape.bounds()).collect();
        // A merged mesh is tested once, under the first primitive that holds it.
        let mut merged_meshes: Vec<*const crate::mesh::TriMesh> = Vec::new();
        let mut held = |i: u32| match &prims[i as usize].shape {
            Shape::Mesh(m) if m.mesh.is_merged() => {
                let mesh = std::sync::Arc::as_ptr(&m.mesh);
                let first = !merged_meshes.contains(&mesh);
                if first {
                    merged_meshes.push(mesh);
                }
                first
            }
            _ => true,
        };
        let (bounded, unbounded): (Vec<u32>, Vec<u32>) = (0..prims.len() as u32)
            .filter(|&i| held(i))
            .partition(|&i| bounds[i as usize].is_finite());
        let only_mesh = match (bounded.as_slice(), unbounded.is_empty()) {
            (&[p], true) => matches!(prims[p as usize].shape, Shape::Mesh(_)).then_some(p),
            _ => None,
        };
        let bvh = Bvh::build(&bounds, &bounded);
        let shapes: Vec<&Shape> = prims.iter().map(|p| &p.shape).collect();
        let leaves = Leaves::build(&shapes, bvh.order(), bvh.leaves());
        Self {
            bvh,
            leaves,
            unbounded,
            merged: !merged_meshes.is_empty(),
            only_mesh,
        }
    }

    /// The primitive a hit on `prim`'s `part` names: its owner's, where `prim` holds a
    /// merged mesh.
    #[inline(always)]
    fn owner(&self, prims: &[Primitive], prim: u32, part: u32) -> u32 {
        if !self.merged {
            return prim;
        }
        match &prims[prim as usize].shape {
            Shape::Mesh(m) => m.mesh.owner(part).unwrap_or(prim),
            _ => prim,
        }
    }

    /// Closest hit along `ray` with t in (0, t_max).
    #[inline]
    pub fn intersect(&self, prims: &[Primitive], ray: &Ray, t_max: f32) -> Option<Hit> {
        let test = |p: u32, t_max: f32| prims[p as usize].shape.intersect(ray, t_max);
        if let Some(p) = self.only_mesh {
            let (t, part) = test(p, t_max)?;
            let prim = self.owner(prims, p, part);
            return Some(Hit { t, prim, part });
        }
        let mut best: Option<Hit> = None;
        let mut t = t_max;
        for &p in &self.unbounded {
            if let Some((tp, part)) = test(p, t) {
                t = tp;
                best = Some(Hit { t, prim: p, part });
            }
        }
        let r4 = RayX4::new(ray);
        self.bvh.traverse(ray, t, |leaf, t_max| {
            match self.leaves.closest(leaf, &r4, t_max, test) {
                Some((t, prim, part)) => {
                    best = Some(Hit { t, prim, part });
                    t
                }
                None => t_max,
            }
        });
        best.map(|h| Hit {
            prim: self.owner(prims, h.prim, h.part),
            ..h
        })
    }

    /// [`Accel::intersect`] with t_max = ∞ for the lanes of `r` set in `active`, for a scene
    /// of one BVH leaf and no unbounded primitives ([`Accel::is_one_leaf`], which the only
    /// caller, [`crate::wide::Wide::new`], requires); `rays` holds the same rays one by one, for
    /// the exact tests of primitives other than quads. Crate-private because on other scenes
    /// it would answer "no hit": a ray-by-ray fallback here, even out of line, cost the Cornell
    /// box measurably more instructions a sample (docs/renderer.md).
    ///
    /// Where a lane's hit is a sphere or a mesh, `keep` gets what its surface point would
    /// otherwise find again ([`HitKeep`]).
    #[inline(always)]
    pub(crate) fn intersect_lanes<const N: usize>(
        &self,
        prims: &[Primitive],
        r: &Rays<N>,
        ray: impl Fn(usize) -> Ray,
        active: u32,
        keep: &mut HitKeep<N>,
    ) -> LaneHits<N> {
        debug_assert!(self.is_one_leaf());
        self.leaves
            .closest_lanes(
                r,
                active,
                #[inline(always)]
                |p, lanes, t_max| match &prims[p as usize].shape {
                    Shape::Cuboid { min, max, xf } => {
                        let t_max = crate::util::lanes::F(*t_max);
                        let (hit, t, face) = crate::shape::cuboid_lanes(
                            *min,
                            *max,
                            xf,
                            r.origins(),
                            r.directions(),
                            t_max,
                        );
                        (hit, t.0, face)
                    }
                    Shape::Sphere { center, radius } => {
                        let (hit, t, root) = crate::shape::sphere_lanes(
                            *center,
                            *radius,
                            r.origins(),
                            r.directions(),
                            t_max,
                        );
                        let hit = hit & lanes;
                        // A lane the test reports becomes this sphere's hit, so the root written
                        // last is the hit's wherever the hit is a sphere.
                        for lane in (0..N).filter(|lane| hit >> lane & 1 == 1) {
                            keep.sphere_root[lane] = root[lane];
                        }
                        (hit, t, [0; N])
                    }
                    shape => {
                        let (mut hit, mut t, mut part) = (0, [0.0; N], [0; N]);
                        for lane in (0..N).filter(|lane| lanes >> lane & 1 == 1) {
                            if let Some((tl, pl)) = shape.intersect(&ray(lane), t_max[lane]) {
                                hit |= 1 << lane;
                                (t[lane], part[lane]) = (tl, pl);
                                if let Shape::Mesh(_) = shape {
                                    keep.mesh_hit[lane] = crate::mesh::kept_hit();
                                }
                            }
                        }
                        (hit, t, part)
                    }
                },
            )
            .map(|mut h| {
                if self.merged {
                    for lane in (0..N).filter(|lane| h.hit >> lane & 1 == 1) {
                        h.prim[lane] = self.owner(prims, h.prim[lane], h.part[lane]);
                    }
                }
                h
            })
            .unwrap_or(LaneHits {
                hit: 0,
                t: [0.0; N],
                prim: [0; N],
                part: [0; N],
            })
    }

    /// [`Accel::occluded`] for the lanes of `r` set in `active`, for a scene of one BVH leaf
    /// and no unbounded primitives (as [`Accel::intersect_lanes`]): bit i is set when
    /// something blocks lane i in (0, t_max).
    #[inline(always)]
    pub(crate) fn occluded_lanes<const N: usize>(
        &self,
        prims: &[Primitive],
        r: &Rays<N>,
        ray: impl Fn(usize) -> Ray,
        active: u32,
        t_max: f32,
    ) -> u32 {
        debug_assert!(self.is_one_leaf());
        self.leaves
            .any_lanes(
                r,
                active,
                t_max,
                #[inline(always)]
                |p, lanes| match &prims[p as usize].shape {
                    Shape::Cuboid { min, max, xf } => {
                        let t = crate::util::lanes::F::splat(t_max);
                        crate::shape::cuboid_lanes(*min, *max, xf, r.origins(), r.directions(), t).0
                    }
                    Shape::Sphere { center, radius } => {
                        let t = [t_max; N];
                        let (hit, ..) = crate::shape::sphere_lanes(
                            *center,
                            *radius,
                            r.origins(),
                            r.directions(),
                            &t,
                        );
                        hit & lanes
                    }
                    shape => (0..N)
                        .filter(|lane| lanes >> lane & 1 == 1)
                        .filter(|&lane| shape.blocks(&ray(lane), t_max))
                        .fold(0, |bits, lane| bits | 1 << lane),
                },
            )
            .unwrap_or(0)
    }

    /// Whether the whole scene is one BVH leaf with nothing unbounded: the scenes whose
    /// queries the packet tests answer.
    pub fn is_one_leaf(&self) -> bool {
        self.unbounded.is_empty() && self.leaves.is_single()
    }

    /// Whether anything blocks `ray` for t in (0, t_max).
    #[inline]
    pub fn occluded(&self, prims: &[Primitive], ray: &Ray, t_max: f32) -> bool {
        let blocks = |p: u32| prims[p as usize].shape.blocks(ray, t_max);
        if let Some(p) = self.only_mesh {
            return blocks(p);
        }
        if self.unbounded.iter().any(|&p| blocks(p)) {
            return true;
        }
        // Any hit will do: a negative t_max tells the traversal to stop at the first one.
        let r4 = RayX4::new(ray);
        let mut hit = false;
        self.bvh.traverse(ray, t_max, |leaf, t| {
            if self.leaves.any(leaf, &r4, t, blocks) {
                hit = true;
                return -1.0;
            }
            t
        });
        hit
    }
}
