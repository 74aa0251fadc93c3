//! Any bytes as an OBJ and as a PLY file: the mesh readers must return triangles or a one-line
//! error, never panic; and what loads must build a mesh whose rays come back finite.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_render::math::Ray;
use tessera_render::mesh::load::{load, MeshFormat};
use tessera_render::mesh::TriMesh;

fuzz_target!(|data: &[u8]| {
    for format in [MeshFormat::Obj, MeshFormat::Ply] {
        match load("fuzz", data, format, 1 << 16) {
            Ok(groups) => {
                for g in groups {
                    assert!(g.normals.is_empty() || g.normals.len() == g.tris.len());
                    assert!(g.uvs.is_empty() || g.uvs.len() == g.tris.len());
                    let mesh = TriMesh::new(g.tris, g.normals, g.uvs);
                    let ray = Ray::new(glam::Vec3A::new(0.1, 0.2, 10.0), -glam::Vec3A::Z);
                    if let Some((t, _)) = mesh.intersect(&ray, f32::INFINITY) {
                        assert!(t > 0.0 && t.is_finite());
                    }
                }
            }
            Err(e) => {
                let line = e.to_string();
                assert!(!line.is_empty() && !line.contains('\n'), "{line:?}");
            }
        }
    }
});
