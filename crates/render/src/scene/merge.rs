//! Which placed meshes share one world-space mesh and BVH ([`crate::mesh::TriMesh::merged`]
//! says why that is faster): every mesh the scene places once, that does not emit, does not
//! mirror and is small enough that a second BVH build is cheap, grouped by the vertex
//! attributes it carries. A group of one stays as it is, as does a mesh placed more than once
//! (instancing is what keeps its triangles stored once) and an emitter (its light samples its
//! own triangles, named by its own slots).
//!
//! The choice is a function of the scene alone, and the merged mesh is built in the scene's
//! order of primitives, so every worker merges the same way and renders the same bits.

use std::collections::BTreeMap;
use std::sync::Arc;

use glam::Affine3A;

use crate::interaction::Transformed;
use crate::mesh::{MeshInstance, TriMesh};
use crate::primitive::Primitive;
use crate::shape::Shape;

/// Meshes of more triangles than this keep their own BVH: their walk is long enough that the
/// top level's share of a ray is small, and merging would build their tree a second time.
pub const MERGE_MAX_TRIANGLES: usize = 1 << 16;

/// Merges the meshes of `prims` that qualify (the module's rules) in place: each keeps its
/// primitive (material, smoothing), now an identity instance of the merged mesh.
pub(super) fn merge_meshes(prims: &mut [Primitive]) {
    let mut uses: BTreeMap<*const TriMesh, usize> = BTreeMap::new();
    for p in prims.iter() {
        if let Shape::Mesh(m) = &p.shape {
            *uses.entry(Arc::as_ptr(&m.mesh)).or_default() += 1;
        }
    }
    // Groups of candidates, each led by its first member, in the order of primitives.
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (i, p) in prims.iter().enumerate() {
        let Shape::Mesh(m) = &p.shape else { continue };
        if p.light != u32::MAX
            || uses[&Arc::as_ptr(&m.mesh)] > 1
            || m.mesh.len() > MERGE_MAX_TRIANGLES
            || m.xf.mirrors
        {
            continue;
        }
        match groups
            .iter_mut()
            .find(|g| TriMesh::can_merge(instance(&prims[g[0]]), m))
        {
            Some(g) => g.push(i),
            None => groups.push(vec![i]),
        }
    }
    for group in groups.into_iter().filter(|g| g.len() > 1) {
        let parts: Vec<(&MeshInstance, u32)> = group
            .iter()
            .map(|&i| (instance(&prims[i]), i as u32))
            .collect();
        let mesh = Arc::new(TriMesh::merged(&parts));
        for i in group {
            let smooth = instance(&prims[i]).smooth;
            prims[i].shape = Shape::Mesh(MeshInstance {
                mesh: Arc::clone(&mesh),
                xf: Transformed::new(Affine3A::IDENTITY),
                smooth,
            });
        }
    }
}

fn instance(p: &Primitive) -> &MeshInstance {
    match &p.shape {
        Shape::Mesh(m) => m,
        _ => unreachable!("only meshes are grouped"),
    }
}
