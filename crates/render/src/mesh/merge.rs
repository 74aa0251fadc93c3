//! Several placed meshes as one mesh in world space, under one BVH.
//!
//! The scene's two-level hierarchy pays, for every ray, a walk of the top level and then, for
//! each instance whose box the ray enters, a move into the instance's space and a walk of its
//! own tree from the root. Objects that share no geometry gain nothing from that: a ground
//! under two props means most rays walk the ground's tree and at least one prop's, and the
//! props' boxes overlap the ground's, so neither walk can cut the other short. One tree over
//! all their triangles in world space is one walk, nearest box first across every object, as
//! Embree builds for Mitsuba and Cycles builds for its objects. Which objects to merge is the
//! scene's choice ([`crate::scene`]); this is how.
//!
//! Each triangle keeps the owner it came from, which is what a hit names, and its vertex
//! attributes in world space: positions, normals (each made unit, as an instance's were once
//! moved), tangents; texture coordinates as they were.

use glam::Vec3A;

use super::{MeshInstance, TriMesh};

impl TriMesh {
    /// One world-space mesh holding the triangles of every instance in `parts`, each with the
    /// owner its hits are to name ([`TriMesh::owner`]). The instances must agree on which
    /// vertex attributes they carry (normals, texture coordinates, tangents) and none may
    /// mirror, whose triangles would turn their front side round in world space; the caller
    /// checks both ([`TriMesh::can_merge`]).
    pub fn merged(parts: &[(&MeshInstance, u32)]) -> Self {
        debug_assert!(parts.iter().all(|(p, _)| Self::can_merge(parts[0].0, p)));
        let Some(&(first, _)) = parts.first() else {
            return Self::new(Vec::new(), Vec::new(), Vec::new());
        };
        let has = (
            first.mesh.has_normals(),
            first.mesh.has_uvs(),
            first.mesh.has_tangents(),
        );
        let n: usize = parts.iter().map(|(p, _)| p.mesh.len()).sum();
        let mut tris = Vec::with_capacity(n);
        let (mut normals, mut uvs, mut tangents) = (Vec::new(), Vec::new(), Vec::new());
        let mut owners = Vec::with_capacity(n);
        for &(instance, owner) in parts {
            let (mesh, xf) = (&instance.mesh, &instance.xf);
            for slot in mesh.slots() {
                let s = slot as usize;
                tris.push(mesh.triangle(slot).map(|p| xf.point_to_world(p)));
                if has.0 {
                    normals.push(mesh.normals[s].map(|v| xf.normal_to_world(v)));
                }
                if has.1 {
                    uvs.push(mesh.uvs[s]);
                }
                if has.2 {
                    tangents.push(mesh.tangents[s].map(|t| {
                        let xyz = xf.to_world.transform_vector3a(Vec3A::from(t.truncate()));
                        xyz.extend(t.w)
                    }));
                }
                owners.push(owner);
            }
        }
        Self::build(tris, normals, uvs, tangents, owners)
    }

    /// Whether instance `b` can share a merged mesh with instance `a`: neither mirrors, and
    /// both carry the same vertex attributes.
    pub fn can_merge(a: &MeshInstance, b: &MeshInstance) -> bool {
        let has = |m: &TriMesh| (m.has_normals(), m.has_uvs(), m.has_tangents());
        !a.xf.mirrors && !b.xf.mirrors && has(&a.mesh) == has(&b.mesh)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use glam::{Affine3A, Quat, Vec2};

    use super::*;
    use crate::interaction::Transformed;
    use crate::mesh::tests::lumpy_sphere;
    use crate::util::math::Ray;
    use crate::util::sampling::HashRng;

    fn placed(tris: Vec<[Vec3A; 3]>, xf: Affine3A, smooth: bool) -> MeshInstance {
        let normals = tris.iter().map(|t| t.map(Vec3A::normalize)).collect();
        let uvs = tris
            .iter()
            .map(|t| t.map(|p| Vec2::new(p.x, p.y)))
            .collect();
        MeshInstance {
            mesh: Arc::new(TriMesh::new(tris, normals, uvs)),
            xf: Transformed::new(xf),
            smooth,
        }
    }

    /// Rays through a scene of three placed meshes (turned, scaled, moved, overlapping) find
    /// in the merged mesh the hit the closest of the separate instances finds: the same owner,
    /// t within rounding, and a surface point, normal and texture coordinates that agree.
    #[test]
    fn a_merged_mesh_hits_what_its_instances_hit() {
        let parts = [
            placed(
                lumpy_sphere(12, 24),
                Affine3A::from_translation(Vec3A::new(0.5, 0.0, 0.0).into()),
                true,
            ),
            placed(
                lumpy_sphere(8, 16),
                Affine3A::from_scale_rotation_translation(
                    glam::Vec3::new(0.6, 1.3, 0.8),
                    Quat::from_rotation_y(0.7),
                    glam::Vec3::new(-0.6, 0.2, 0.1),
                ),
                false,
            ),
            placed(
                lumpy_sphere(6, 12),
                Affine3A::from_scale(glam::Vec3::splat(2.5)),
                true,
            ),
        ];
        let owners: Vec<(&MeshInstance, u32)> = parts.iter().zip([7, 3, 11]).collect();
        let merged = Arc::new(TriMesh::merged(&owners));
        assert!(merged.is_merged());
        assert_eq!(
            merged.len(),
            parts.iter().map(|p| p.mesh.len()).sum::<usize>()
        );
        let merged_at = |smooth: bool| MeshInstance {
            mesh: Arc::clone(&merged),
            xf: Transformed::new(Affine3A::IDENTITY),
            smooth,
        };
        let whole = [merged_at(true), merged_at(false)];
        let mut rng = HashRng::new(3);
        let mut v = move || Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
        let mut hits = 0;
        for _ in 0..4000 {
            // From outside the outer sphere, or inside it (where the inner ones are).
            let ray = Ray::new(v() * 4.0, v());
            let separate = owners
                .iter()
                .enumerate()
                .filter_map(|(k, (p, _))| p.intersect(&ray, f32::INFINITY).map(|h| (h, k)))
                .min_by(|a, b| a.0 .0.total_cmp(&b.0 .0));
            let together = merged.intersect(&ray, f32::INFINITY);
            assert_eq!(
                separate.is_some(),
                together.is_some(),
                "{ray:?}: {separate:?} against {together:?}"
            );
            let (Some(((t, part), k)), Some((tm, slot))) = (separate, together) else {
                continue;
            };
            assert!((t - tm).abs() <= 1e-4 * t.max(1.0), "{t} against {tm}");
            if (t - tm).abs() > 1e-3 * t {
                continue;
            }
            let (instance, owner) = owners[k];
            assert_eq!(merged.owner(slot), Some(owner));
            let one = &whole[usize::from(!instance.smooth)];
            let (a, b) = (instance.surface(&ray, part), one.surface(&ray, slot));
            assert!((a.p - b.p).length() < 1e-4, "{:?} against {:?}", a.p, b.p);
            assert!(a.n.dot(b.n) > 0.9999, "{:?} against {:?}", a.n, b.n);
            // Shading takes the normals as unit, the identity transform included.
            for ns in [a.ns, b.ns] {
                assert!((ns.length() - 1.0).abs() < 1e-5, "{ns:?}");
            }
            assert!(a.ns.dot(b.ns) > 0.999, "{:?} against {:?}", a.ns, b.ns);
            assert!((instance.uv(&ray, part) - one.uv(&ray, slot)).length() < 1e-4);
            hits += 1;
        }
        assert!(hits > 1500, "{hits}");
        assert!(merged.occluded(&Ray::new(Vec3A::new(0.0, 0.0, -9.0), Vec3A::Z), 20.0));
    }

    /// A mirroring instance, or one without the others' attributes, is not merged.
    #[test]
    fn mirrors_and_other_attributes_are_refused() {
        let tris = lumpy_sphere(4, 8);
        let plain = placed(tris.clone(), Affine3A::IDENTITY, true);
        let mirrored = placed(
            tris.clone(),
            Affine3A::from_scale(glam::Vec3::new(-1.0, 1.0, 1.0)),
            true,
        );
        let bare = MeshInstance {
            mesh: Arc::new(TriMesh::new(tris, Vec::new(), Vec::new())),
            xf: Transformed::new(Affine3A::IDENTITY),
            smooth: false,
        };
        assert!(TriMesh::can_merge(&plain, &plain));
        assert!(!TriMesh::can_merge(&plain, &mirrored));
        assert!(!TriMesh::can_merge(&mirrored, &plain));
        assert!(!TriMesh::can_merge(&plain, &bare));
    }
}
