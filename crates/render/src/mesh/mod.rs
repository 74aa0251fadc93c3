//! Triangle meshes: loading OBJ and PLY files ([`load`]), the watertight ray/triangle test
//! ([`triangle`]), and a mesh's own BVH, which every instance of it shares (the lower level of
//! the scene's two-level hierarchy: the scene's BVH holds instances, each a mesh under a
//! transform, and an instance's ray is moved into the mesh's space to traverse it).
//!
//! A scene without meshes builds none of this and its rays never look at it: the shape is one
//! more variant of [`crate::shape::Shape`], tested like the others in the scene's BVH leaves.

pub mod load;
mod merge;
pub mod triangle;

use std::sync::Arc;

use glam::{Vec2, Vec3A, Vec4};

use crate::accel::bvh::Bvh;
use crate::accel::bvh8::Bvh8;
use crate::accel::pages::PagedArray;
use crate::interaction::{transformed_box, SurfacePoint, Transformed};
use crate::util::math::{Aabb, Ray};
use triangle::{Tri4, TriangleHit, WoopRay};

/// A triangle mesh in its own (object) space, with its BVH. The triangles are stored once,
/// four to a group in SIMD lanes ([`Tri4`]) in the BVH's leaf order, so that a leaf's
/// triangles are adjacent in memory and a hit's vertices are those the traversal just read.
/// A hit names a triangle by its slot: group · 4 + lane.
#[derive(Debug)]
pub struct TriMesh {
    /// The triangles, four to a group; a leaf starts a group, and a short group repeats its
    /// last triangle in the empty lanes (which can never be a closer hit than it).
    groups: PagedArray<Tri4>,
    /// How many lanes of each group are triangles of their own (1 to 4).
    group_len: Vec<u8>,
    /// Vertex normals by slot (padding lanes repeat theirs); empty when the file has none.
    normals: Vec<[Vec3A; 3]>,
    /// Texture coordinates by slot; empty when the file has none.
    uvs: Vec<[Vec2; 3]>,
    /// Vertex tangents by slot (xyz, and w = ±1 the bitangent's sign, as glTF gives them);
    /// empty unless a normal map needs them, so that other meshes carry none.
    tangents: Vec<[Vec4; 3]>,
    /// The owner each slot's hits are to name, for a mesh merged from several
    /// ([`TriMesh::merged`]); empty for a mesh of one object.
    owners: Vec<u32>,
    len: usize,
    bvh: Bvh8,
    bounds: Aabb,
}

impl TriMesh {
    /// Builds the mesh and its BVH from triangles (as vertex positions) and, optionally, their
    /// vertex normals and texture coordinates (each empty, or one entry per triangle).
    pub fn new(tris: Vec<[Vec3A; 3]>, normals: Vec<[Vec3A; 3]>, uvs: Vec<[Vec2; 3]>) -> Self {
        Self::with_tangents(tris, normals, uvs, Vec::new())
    }

    /// [`TriMesh::new`] with vertex tangents too (empty, or one entry per triangle): the frame
    /// a normal map is read in, where the file gives or implies one (glTF's TANGENT, or
    /// MikkTSpace's).
    pub fn with_tangents(
        tris: Vec<[Vec3A; 3]>,
        normals: Vec<[Vec3A; 3]>,
        uvs: Vec<[Vec2; 3]>,
        tangents: Vec<[Vec4; 3]>,
    ) -> Self {
        Self::build(tris, normals, uvs, tangents, Vec::new())
    }

    /// The mesh and its BVH from per-triangle inputs (each of the last four empty, or one
    /// entry per triangle).
    fn build(
        tris: Vec<[Vec3A; 3]>,
        normals: Vec<[Vec3A; 3]>,
        uvs: Vec<[Vec2; 3]>,
        tangents: Vec<[Vec4; 3]>,
        owners: Vec<u32>,
    ) -> Self {
        debug_assert!(normals.is_empty() || normals.len() == tris.len());
        debug_assert!(owners.is_empty() || owners.len() == tris.len());
        debug_assert!(uvs.is_empty() || uvs.len() == tris.len());
        debug_assert!(tangents.is_empty() || tangents.len() == tris.len());
        let bounds: Vec<Aabb> = tris
            .iter()
            .map(|t| Aabb::EMPTY.grow(t[0]).grow(t[1]).grow(t[2]))
            .collect();
        let all = bounds.iter().fold(Aabb::EMPTY, |a, b| a.union(*b));
        let binary = Bvh::build_parallel(&bounds);
        drop(bounds);
        let order = binary.order();
        let capacity = tris.len().div_ceil(4) + tris.len() / 8;
        let mut groups = Vec::with_capacity(capacity);
        let mut group_len = Vec::with_capacity(capacity);
        // Each slot's triangle (an index into the inputs), for the normals and coordinates.
        let mut slots: Vec<u32> = Vec::with_capacity(capacity * 4);
        // A binary subtree of up to 8 triangles becomes one leaf of two groups: fewer nodes to
        // fetch for a few more lanes tested, which measured faster than one group per leaf on
        // the million-triangle benchmark (docs/renderer.md).
        let bvh = Bvh8::collapse(&binary, 8, |leaf| {
            let start = groups.len() as u32;
            for chunk in leaf.clone().step_by(4) {
                let end = (chunk + 4).min(leaf.end);
                // Short groups repeat their last triangle, as `Tri4::new` would.
                let ids: [u32; 4] = std::array::from_fn(|l| order[(chunk + l).min(end - 1)]);
                groups.push(Tri4::new(&ids.map(|i| tris[i as usize])));
                group_len.push((end - chunk) as u8);
                slots.extend(ids);
            }
            (start, groups.len() as u32 - start)
        });
        fn by_slot<T: Copy>(slots: &[u32], v: Vec<T>) -> Vec<T> {
            if v.is_empty() {
                v
            } else {
                slots.iter().map(|&i| v[i as usize]).collect()
            }
        }
        Self {
            normals: by_slot(&slots, normals),
            uvs: by_slot(&slots, uvs),
            tangents: by_slot(&slots, tangents),
            owners: by_slot(&slots, owners),
            groups: PagedArray::new(groups),
            group_len,
            len: tris.len(),
            bvh,
            bounds: all,
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the mesh has no triangles.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether the file gave texture coordinates.
    pub fn has_uvs(&self) -> bool {
        !self.uvs.is_empty()
    }

    /// Whether the file gave vertex normals.
    pub fn has_normals(&self) -> bool {
        !self.normals.is_empty()
    }

    /// Whether a normal map's vertex tangents are kept.
    pub fn has_tangents(&self) -> bool {
        !self.tangents.is_empty()
    }

    /// The owner a hit on `slot` names, for a merged mesh ([`TriMesh::merged`]); `None` for
    /// a mesh of one object.
    #[inline]
    pub fn owner(&self, slot: u32) -> Option<u32> {
        self.owners.get(slot as usize).copied()
    }

    /// Whether the mesh was merged from several ([`TriMesh::merged`]).
    pub fn is_merged(&self) -> bool {
        !self.owners.is_empty()
    }

    /// Object-space bounds.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The slots of the triangles, each once (padding lanes left out), in leaf order.
    pub fn slots(&self) -> impl Iterator<Item = u32> + '_ {
        self.group_len
            .iter()
            .enumerate()
            .flat_map(|(g, &n)| (0..u32::from(n)).map(move |l| g as u32 * 4 + l))
    }

    /// The vertex positions of the triangle in `slot`.
    #[inline]
    pub fn triangle(&self, slot: u32) -> [Vec3A; 3] {
        self.groups.as_slice()[slot as usize / 4].lane(slot as usize % 4)
    }

    /// Every triangle's vertex positions, each once, in leaf order.
    pub fn triangles(&self) -> impl Iterator<Item = [Vec3A; 3]> + '_ {
        self.slots().map(|s| self.triangle(s))
    }

    /// Closest hit of an object-space ray with t in (0, t_max): (t, slot). Its barycentrics
    /// are kept for this thread's next [`TriMesh::barycentrics`] of the same ray and slot.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<(f32, u32)> {
        let mut best: Option<(TriangleHit, u32)> = None;
        let r = WoopRay::new(ray.o, ray.d);
        let groups = self.groups.as_slice();
        self.bvh
            .traverse(ray.o, ray.d.recip(), t_max, |start, count, mut t_max| {
                let start = start as usize;
                for (i, group) in groups[start..start + count as usize].iter().enumerate() {
                    if let Some((hit, lane)) = triangle::intersect4(&r, group, t_max) {
                        t_max = hit.t;
                        best = Some((hit, ((start + i) * 4 + lane) as u32));
                    }
                }
                t_max
            });
        let (hit, slot) = best?;
        LAST_HIT.set(Some(LastHit::new(self, ray, slot, hit.b)));
        Some((hit.t, slot))
    }

    /// The barycentrics of a hit [`TriMesh::intersect`] found along object-space `ray` at
    /// `slot`: the ones it found, kept for this thread, when they are this ray's and slot's
    /// (the hit a path shades is the last one found, almost always), else the same test
    /// again, which gives the same bits.
    #[inline]
    fn barycentrics(&self, ray: &Ray, slot: u32) -> [f32; 3] {
        let key = LastHit::new(self, ray, slot, [0.0; 3]);
        if let Some(last) = LAST_HIT.get() {
            if last.same_hit(&key) {
                return last.b;
            }
        }
        let [p0, p1, p2] = self.triangle(slot);
        triangle::intersect(ray.o, ray.d, p0, p1, p2, f32::INFINITY).map_or([1.0 / 3.0; 3], |h| h.b)
    }

    /// Whether an object-space ray hits any triangle with t in (0, t_max).
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        let mut hit = false;
        let r = WoopRay::new(ray.o, ray.d);
        let all = self.groups.as_slice();
        self.bvh
            .traverse(ray.o, ray.d.recip(), t_max, |start, count, t| {
                let groups = &all[start as usize..(start + count) as usize];
                if groups
                    .iter()
                    .any(|g| triangle::intersect4(&r, g, t).is_some())
                {
                    hit = true;
                    return -1.0;
                }
                t
            });
        hit
    }

    /// The unit geometric normal of the triangle in `slot` on its front side: the side the
    /// vertex normals point to where `smooth` uses them, else the counter-clockwise side.
    #[inline]
    pub fn front_normal(&self, slot: u32, smooth: bool) -> Vec3A {
        let [p0, p1, p2] = self.triangle(slot);
        let i = slot as usize;
        let n = (p1 - p0).cross(p2 - p0).normalize_or_zero();
        if smooth && self.has_normals() {
            let s = self.normals[i][0] + self.normals[i][1] + self.normals[i][2];
            if n.dot(s) < 0.0 {
                return -n;
            }
        }
        n
    }

    /// The interpolated vertex normal of the triangle in `slot` at barycentrics `b`
    /// (unnormalised), or `None` without vertex normals.
    #[inline]
    fn shading_normal(&self, slot: u32, b: [f32; 3]) -> Option<Vec3A> {
        let n = self.normals.get(slot as usize)?;
        Some(n[0] * b[0] + n[1] * b[1] + n[2] * b[2])
    }
}

/// The last closest hit a [`TriMesh::intersect`] on this thread found, keyed by what decides
/// its barycentrics: the mesh, the triangle's slot and the object-space ray, bit for bit.
/// Shading the hit needs them three times (the point, its texture coordinates, the normal
/// map's frame), and finding them again cost a whole triangle test each time. A key that does
/// not match (another ray's hit, another thread's) only means the test runs again, so the
/// pixels cannot depend on it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LastHit {
    mesh: usize,
    slot: u32,
    ray: [u32; 6],
    b: [f32; 3],
}

impl LastHit {
    #[inline(always)]
    fn new(mesh: &TriMesh, ray: &Ray, slot: u32, b: [f32; 3]) -> Self {
        let (o, d) = (ray.o.to_array(), ray.d.to_array());
        Self {
            mesh: std::ptr::from_ref(mesh) as usize,
            slot,
            ray: [o[0], o[1], o[2], d[0], d[1], d[2]].map(f32::to_bits),
            b,
        }
    }

    #[inline(always)]
    fn same_hit(&self, other: &Self) -> bool {
        self.mesh == other.mesh && self.slot == other.slot && self.ray == other.ray
    }
}

thread_local! {
    static LAST_HIT: std::cell::Cell<Option<LastHit>> = const { std::cell::Cell::new(None) };
}

/// This thread's last mesh hit, for [`restore_hit`]: the many-path tracer queries all its
/// lanes before it shades any, so each lane's hit would otherwise be the next lane's to lose.
#[inline(always)]
pub(crate) fn kept_hit() -> Option<LastHit> {
    LAST_HIT.get()
}

/// Makes `hit` (from [`kept_hit`]) this thread's last mesh hit again, before its point is
/// shaded. Whatever it holds, the pixels are the same: a hit that is not the one shaded only
/// means the triangle is tested again.
#[inline(always)]
pub(crate) fn restore_hit(hit: Option<LastHit>) {
    LAST_HIT.set(hit);
}

/// Texture coordinates at a hit and how the surface moves with them.
#[derive(Clone, Copy, Debug)]
pub struct UvFrame {
    /// (u, v), v up the image.
    pub uv: Vec2,
    /// ∂p/∂u, world space.
    pub dpdu: Vec3A,
    /// ∂p/∂v, world space.
    pub dpdv: Vec3A,
    /// The interpolated vertex tangent in world space (xyz) with the bitangent's sign (w), where
    /// the mesh has tangents: the bitangent is then ns × xyz · w, glTF's rule.
    pub tangent: Option<Vec4>,
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
        let [p0, p1, p2] = self.mesh.triangle(part);
        // The hit's barycentrics give the point from the vertices (not o + t·d, whose error
        // grows with the distance travelled).
        let b = self.mesh.barycentrics(&lr, part);
        let p = p0 * b[0] + p1 * b[1] + p2 * b[2];
        let n_obj = self.mesh.front_normal(part, self.smooth);
        let n = self.xf.normal_to_world(n_obj);
        let ns = if self.smooth {
            // Unit, as shading takes it: an interpolated normal is shorter than its vertices'
            // (by ~0.2% on a sphere of 2,304 triangles), which the identity transform, unlike
            // any other, leaves as it is.
            self.mesh
                .shading_normal(part, b)
                .map(|s| self.xf.normal_to_world(s).normalize())
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
        let Some(uv) = self.mesh.uvs.get(part as usize) else {
            return Vec2::ZERO;
        };
        let b = self.mesh.barycentrics(&self.xf.ray_to_object(r), part);
        uv[0] * b[0] + uv[1] * b[1] + uv[2] * b[2]
    }

    /// The texture coordinates at a hit, with the world-space derivatives ∂p/∂u and ∂p/∂v of
    /// the triangle's position: the tangent frame a normal map is given in. `None` without
    /// texture coordinates in the file, or where the triangle's coordinates are degenerate (a
    /// zero-area map, which gives no direction).
    #[inline(never)]
    pub fn uv_frame(&self, r: &Ray, part: u32) -> Option<UvFrame> {
        let uv = self.mesh.uvs.get(part as usize)?;
        let b = self.mesh.barycentrics(&self.xf.ray_to_object(r), part);
        let [p0, p1, p2] = self.mesh.triangle(part);
        let at = uv[0] * b[0] + uv[1] * b[1] + uv[2] * b[2];
        // [p1 − p0, p2 − p0] = [∂p/∂u, ∂p/∂v] · [[du1, du2], [dv1, dv2]], inverted.
        let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
        let det = d1.x * d2.y - d1.y * d2.x;
        if !(det.abs() > 1e-20) {
            return None;
        }
        let (e1, e2) = (p1 - p0, p2 - p0);
        let dpdu = (e1 * d2.y - e2 * d1.y) / det;
        let dpdv = (e2 * d1.x - e1 * d2.x) / det;
        let (dpdu, dpdv) = (
            self.xf.to_world.transform_vector3a(dpdu),
            self.xf.to_world.transform_vector3a(dpdv),
        );
        let tangent = self.mesh.tangents.get(part as usize).and_then(|t| {
            let t = t[0] * b[0] + t[1] * b[1] + t[2] * b[2];
            let xyz = self
                .xf
                .to_world
                .transform_vector3a(Vec3A::from(t.truncate()));
            // A mirroring transform turns n × t the other way from the bitangent it carries.
            let w = if (t.w < 0.0) != self.xf.mirrors {
                -1.0
            } else {
                1.0
            };
            (xyz.is_finite() && xyz.length_squared() > 0.0).then(|| xyz.extend(w))
        });
        (dpdu.is_finite() && dpdv.is_finite()).then_some(UvFrame {
            uv: at,
            dpdu,
            dpdv,
            tangent,
        })
    }

    /// World-space bounds.
    pub fn bounds(&self) -> Aabb {
        let b = self.mesh.bounds();
        transformed_box(&self.xf.to_world, b.min, b.max)
    }

    /// Each triangle's texture coordinates in the order of [`MeshInstance::world_triangles`]
    /// (a mesh light's), or zeros where the file gives none.
    pub fn light_uvs(&self) -> Vec<[Vec2; 3]> {
        self.mesh
            .slots()
            .map(|i| self.mesh.uvs.get(i as usize).copied().unwrap_or_default())
            .collect()
    }

    /// The triangles in world space with their front normals and areas, for area lights.
    pub fn world_triangles(&self) -> Vec<([Vec3A; 3], Vec3A, f32)> {
        self.mesh
            .slots()
            .map(|i| {
                let t = self.mesh.triangle(i).map(|p| self.xf.point_to_world(p));
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
    use crate::util::sampling::HashRng;

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

    /// The barycentrics a hit is shaded with are the triangle test's, bit for bit, whether
    /// they come from the hit this thread found last or from testing again (another ray's hit
    /// found since, another mesh's, another slot asked).
    #[test]
    fn kept_barycentrics_are_the_tests_own_and_a_stale_key_tests_again() {
        let tris = lumpy_sphere(12, 24);
        let (a, b) = (
            TriMesh::new(tris.clone(), Vec::new(), Vec::new()),
            TriMesh::new(tris.clone(), Vec::new(), Vec::new()),
        );
        let mut rng = HashRng::new(9);
        let mut v = move || Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
        let exact = |ray: &Ray, slot: u32| {
            let [p0, p1, p2] = a.triangle(slot);
            let h = triangle::intersect(ray.o, ray.d, p0, p1, p2, f32::INFINITY).expect("hit");
            h.b.map(f32::to_bits)
        };
        let bits = |x: [f32; 3]| x.map(f32::to_bits);
        let mut checked = 0;
        for _ in 0..2000 {
            let (r1, r2) = (Ray::new(v() * 0.5, v()), Ray::new(v() * 0.5, v()));
            let (Some((_, s1)), Some((_, s2))) = (
                a.intersect(&r1, f32::INFINITY),
                a.intersect(&r2, f32::INFINITY),
            ) else {
                continue;
            };
            // Kept: r2's hit, the last one found.
            assert_eq!(bits(a.barycentrics(&r2, s2)), exact(&r2, s2));
            // Stale for r1 (r2's is kept), for another mesh, and for another slot.
            assert_eq!(bits(a.barycentrics(&r1, s1)), exact(&r1, s1));
            assert_eq!(bits(b.barycentrics(&r2, s2)), exact(&r2, s2));
            let other = (s2 + 1) % (tris.len() as u32);
            let [p0, p1, p2] = a.triangle(other);
            let again = triangle::intersect(r2.o, r2.d, p0, p1, p2, f32::INFINITY)
                .map_or([1.0 / 3.0; 3], |h| h.b);
            assert_eq!(bits(a.barycentrics(&r2, other)), bits(again));
            checked += 1;
        }
        assert!(checked > 1000, "{checked}");
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
        assert_eq!(
            Bvh::build(&bounds, &idx).order(),
            Bvh::build_parallel(&bounds).order()
        );
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
