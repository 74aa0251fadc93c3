//! Triangle meshes: loading OBJ and PLY files ([`load`]), the watertight ray/triangle test
//! ([`triangle`]), and a mesh's own BVH, which every instance of it shares (the lower level of
//! the scene's two-level hierarchy: the scene's BVH holds instances, each a mesh under a
//! transform, and an instance's ray is moved into the mesh's space to traverse it).
//!
//! A scene without meshes builds none of this and its rays never look at it: the shape is one
//! more variant of [`crate::shape::Shape`], tested like the others in the scene's BVH leaves.

pub mod load;
pub mod triangle;

use std::sync::Arc;

use glam::{Vec2, Vec3A};

use crate::accel::bvh::Bvh;
use crate::math::{Aabb, Ray};
use crate::shape::{SurfacePoint, Transformed};

/// A triangle mesh in its own (object) space, with its BVH. Triangles are stored in the BVH's
/// leaf order, so that a leaf's triangles are adjacent in memory; a hit names a triangle by
/// that position.
#[derive(Debug)]
pub struct TriMesh {
    /// Vertex positions of each triangle, in leaf order.
    tris: Vec<[Vec3A; 3]>,
    /// Vertex normals of each triangle, in leaf order; empty when the file has none.
    normals: Vec<[Vec3A; 3]>,
    /// Texture coordinates of each triangle's vertices, in leaf order; empty when the file
    /// has none.
    uvs: Vec<[Vec2; 3]>,
    bvh: Bvh,
    bounds: Aabb,
}

impl TriMesh {
    /// Builds the mesh and its BVH from triangles (as vertex positions) and, optionally, their
    /// vertex normals and texture coordinates (each empty, or one entry per triangle).
    pub fn new(tris: Vec<[Vec3A; 3]>, normals: Vec<[Vec3A; 3]>, uvs: Vec<[Vec2; 3]>) -> Self {
        debug_assert!(normals.is_empty() || normals.len() == tris.len());
        debug_assert!(uvs.is_empty() || uvs.len() == tris.len());
        let bounds: Vec<Aabb> = tris
            .iter()
            .map(|t| Aabb::EMPTY.grow(t[0]).grow(t[1]).grow(t[2]))
            .collect();
        let all = bounds.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
        let bvh = Bvh::build_parallel(&bounds);
        let order = bvh.order();
        let tris_ordered = order.iter().map(|&i| tris[i as usize]).collect();
        fn in_order<T: Copy>(order: &[u32], v: Vec<T>) -> Vec<T> {
            if v.is_empty() {
                v
            } else {
                order.iter().map(|&i| v[i as usize]).collect()
            }
        }
        Self {
            tris: tris_ordered,
            normals: in_order(order, normals),
            uvs: in_order(order, uvs),
            bvh,
            bounds: all,
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// Whether the mesh has no triangles.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Whether the file gave texture coordinates.
    pub fn has_uvs(&self) -> bool {
        !self.uvs.is_empty()
    }

    /// Whether the file gave vertex normals.
    pub fn has_normals(&self) -> bool {
        !self.normals.is_empty()
    }

    /// Object-space bounds.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The triangles' vertex positions, in the order hits name them.
    pub fn triangles(&self) -> &[[Vec3A; 3]] {
        &self.tris
    }

    /// Closest hit of an object-space ray with t in (0, t_max): (t, triangle).
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<(f32, u32)> {
        let mut best = None;
        self.bvh.traverse(ray, t_max, |leaf, mut t_max| {
            for i in leaf {
                let [p0, p1, p2] = self.tris[i];
                if let Some(h) = triangle::intersect(ray.o, ray.d, p0, p1, p2, t_max) {
                    t_max = h.t;
                    best = Some((h.t, i as u32));
                }
            }
            t_max
        });
        best
    }

    /// Whether an object-space ray hits any triangle with t in (0, t_max).
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        let mut hit = false;
        self.bvh.traverse(ray, t_max, |leaf, t| {
            for i in leaf {
                let [p0, p1, p2] = self.tris[i];
                if triangle::intersect(ray.o, ray.d, p0, p1, p2, t).is_some() {
                    hit = true;
                    return -1.0;
                }
            }
            t
        });
        hit
    }

    /// The unit geometric normal of triangle `i` on its front side: the side the vertex
    /// normals point to where `smooth` uses them, else the counter-clockwise side.
    #[inline]
    pub fn front_normal(&self, i: usize, smooth: bool) -> Vec3A {
        let [p0, p1, p2] = self.tris[i];
        let n = (p1 - p0).cross(p2 - p0).normalize_or_zero();
        if smooth && self.has_normals() {
            let s = self.normals[i][0] + self.normals[i][1] + self.normals[i][2];
            if n.dot(s) < 0.0 {
                return -n;
            }
        }
        n
    }

    /// The interpolated vertex normal of triangle `i` at barycentrics `b` (unnormalised),
    /// or `None` without vertex normals.
    #[inline]
    fn shading_normal(&self, i: usize, b: [f32; 3]) -> Option<Vec3A> {
        let n = self.normals.get(i)?;
        Some(n[0] * b[0] + n[1] * b[1] + n[2] * b[2])
    }
}

/// A mesh placed in the scene: the shared mesh under this object's transform.
#[derive(Clone, Debug)]
pub struct MeshInstance {
    /// The mesh (shared by every instance of the same file and material group).
    pub mesh: Arc<TriMesh>,
    /// Object to world.
    pub xf: Transformed,
    /// Whether shading uses the interpolated vertex normals.
    pub smooth: bool,
}

impl MeshInstance {
    /// Closest hit with t in (0, t_max): (t, triangle). The ray moves into mesh space
    /// unnormalised, so t means the same in both spaces.
    ///
    /// Out of line, as are `blocks` and `surface`: inlined, a mesh's traversal would grow
    /// `Shape`'s match past what LLVM inlines into the integrator, and every scene, mesh or
    /// not, would pay a call per hit (measured: docs/renderer.md).
    #[inline(never)]
    pub fn intersect(&self, r: &Ray, t_max: f32) -> Option<(f32, u32)> {
        self.mesh.intersect(&self.xf.ray_to_object(r), t_max)
    }

    /// Whether anything of the mesh blocks `r` in (0, t_max).
    #[inline(never)]
    pub fn blocks(&self, r: &Ray, t_max: f32) -> bool {
        self.mesh.occluded(&self.xf.ray_to_object(r), t_max)
    }

    /// The surface at a hit found by [`MeshInstance::intersect`].
    #[inline(never)]
    pub fn surface(&self, r: &Ray, part: u32) -> SurfacePoint {
        let lr = self.xf.ray_to_object(r);
        let i = part as usize;
        let [p0, p1, p2] = self.mesh.tris[i];
        // The same test on the same inputs, so the same hit; its barycentrics give the point
        // from the vertices (not o + t·d, whose error grows with the distance travelled).
        let b = triangle::intersect(lr.o, lr.d, p0, p1, p2, f32::INFINITY)
            .map_or([1.0 / 3.0; 3], |h| h.b);
        let p = p0 * b[0] + p1 * b[1] + p2 * b[2];
        let n_obj = self.mesh.front_normal(i, self.smooth);
        let n = self.xf.normal_to_world(n_obj);
        let ns = if self.smooth {
            self.mesh
                .shading_normal(i, b)
                .map(|s| self.xf.normal_to_world(s))
                .filter(|s| s.is_finite() && s.length_squared() > 0.0)
                .unwrap_or(n)
        } else {
            n
        };
        SurfacePoint {
            p: self.xf.point_to_world(p),
            n,
            ns,
            err: self.xf.carry_error(p, triangle::point_error(b, p0, p1, p2)),
        }
    }

    /// The texture coordinates at a hit found by [`MeshInstance::intersect`] (zero without
    /// any in the file).
    #[inline(never)]
    pub fn uv(&self, r: &Ray, part: u32) -> Vec2 {
        let i = part as usize;
        let Some(uv) = self.mesh.uvs.get(i) else {
            return Vec2::ZERO;
        };
        let lr = self.xf.ray_to_object(r);
        let [p0, p1, p2] = self.mesh.tris[i];
        let b = triangle::intersect(lr.o, lr.d, p0, p1, p2, f32::INFINITY)
            .map_or([1.0 / 3.0; 3], |h| h.b);
        uv[0] * b[0] + uv[1] * b[1] + uv[2] * b[2]
    }

    /// World-space bounds.
    pub fn bounds(&self) -> Aabb {
        let b = self.mesh.bounds();
        crate::shape::transformed_box(&self.xf.to_world, b.min, b.max)
    }

    /// The triangles in world space with their front normals and areas, for area lights.
    pub fn world_triangles(&self) -> Vec<([Vec3A; 3], Vec3A, f32)> {
        (0..self.mesh.len())
            .map(|i| {
                let t = self.mesh.tris[i].map(|p| self.xf.point_to_world(p));
                let n = self
                    .xf
                    .normal_to_world(self.mesh.front_normal(i, self.smooth));
                let area = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length();
                (t, n, area)
            })
            .collect()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::sampling::HashRng;

    /// A closed, convex-and-concave mesh: a sphere of `rings` × `segments` quads (each split
    /// into two triangles) whose radius wobbles, so that neighbouring faces meet at folds.
    pub(crate) fn lumpy_sphere(rings: usize, segments: usize) -> Vec<[Vec3A; 3]> {
        let vertex = |r: usize, s: usize| {
            let theta = std::f32::consts::PI * r as f32 / rings as f32;
            let phi = std::f32::consts::TAU * (s % segments) as f32 / segments as f32;
            let radius = 1.0 + 0.15 * ((3 * r + 5 * (s % segments)) as f32).sin();
            let radius = if r == 0 || r == rings { 1.0 } else { radius };
            Vec3A::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            ) * radius
        };
        let mut tris = Vec::new();
        for r in 0..rings {
            for s in 0..segments {
                let (a, b, c, d) = (
                    vertex(r, s),
                    vertex(r, s + 1),
                    vertex(r + 1, s),
                    vertex(r + 1, s + 1),
                );
                // At the poles one of the two is degenerate (two corners are the pole).
                tris.push([a, b, d]);
                tris.push([a, d, c]);
            }
        }
        tris
    }

    /// Watertightness through the whole mesh path (BVH and triangle test): from points inside
    /// a closed mesh, rays aimed at its vertices and at points of its edges must all hit.
    #[test]
    fn rays_from_inside_a_closed_mesh_through_its_edges_and_vertices_all_hit() {
        let tris = lumpy_sphere(24, 48);
        let mesh = TriMesh::new(tris.clone(), Vec::new(), Vec::new());
        let mut rng = HashRng::new(17);
        let mut u = move || rng.next_f32();
        let mut rays = 0;
        for _ in 0..200 {
            let o = (Vec3A::new(u(), u(), u()) * 2.0 - 1.0) * 0.5;
            for _ in 0..200 {
                let [p0, p1, p2] = tris[(u() * tris.len() as f32) as usize % tris.len()];
                let target = match (u() * 4.0) as u32 {
                    0 => p0,
                    1 => p0 + (p1 - p0) * u(),
                    2 => p1 + (p2 - p1) * u(),
                    _ => p2 + (p0 - p2) * u(),
                };
                let ray = Ray::new(o, target - o);
                assert!(
                    mesh.intersect(&ray, f32::INFINITY).is_some(),
                    "{ray:?} escaped the closed mesh"
                );
                assert!(mesh.occluded(&ray, f32::INFINITY));
                rays += 1;
            }
        }
        assert_eq!(rays, 40_000);
    }

    /// The BVH finds what testing every triangle finds (closest t), and the parallel build
    /// gives the same tree as the sequential one.
    #[test]
    fn bvh_matches_brute_force() {
        // Above PARALLEL_ITEMS, so that the parallel build splits.
        let tris = lumpy_sphere(80, 120);
        let mesh = TriMesh::new(tris.clone(), Vec::new(), Vec::new());
        let bounds: Vec<Aabb> = tris
            .iter()
            .map(|t| Aabb::EMPTY.grow(t[0]).grow(t[1]).grow(t[2]))
            .collect();
        let idx: Vec<u32> = (0..tris.len() as u32).collect();
        assert_eq!(Bvh::build(&bounds, &idx).order(), mesh.bvh.order());
        let mut rng = HashRng::new(5);
        let mut v =
            move |s: f32| Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 * s - s;
        let mut hits = 0;
        for _ in 0..5_000 {
            let ray = Ray::new(v(2.0), v(1.0));
            let brute = tris
                .iter()
                .filter_map(|&[a, b, c]| triangle::intersect(ray.o, ray.d, a, b, c, f32::INFINITY))
                .map(|h| h.t)
                .fold(None, |m: Option<f32>, t| Some(m.map_or(t, |m| m.min(t))));
            assert_eq!(
                mesh.intersect(&ray, f32::INFINITY).map(|h| h.0),
                brute,
                "{ray:?}"
            );
            hits += usize::from(brute.is_some());
        }
        assert!(hits > 500, "{hits}");
    }
}
