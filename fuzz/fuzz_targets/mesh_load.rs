//! Any bytes as an OBJ and as a PLY file: the mesh readers must return triangles or a one-line
//! error, never panic; and what loads must build a mesh whose queries agree with testing every
//! triangle one by one (the wide BVH and the four-lane test against the one-triangle test),
//! with finite answers.
#![no_main]

use glam::Vec3A;
use libfuzzer_sys::fuzz_target;
use tessera_render::math::Ray;
use tessera_render::mesh::load::{load, MeshFormat};
use tessera_render::mesh::triangle;
use tessera_render::mesh::TriMesh;

fuzz_target!(|data: &[u8]| {
    for format in [MeshFormat::Obj, MeshFormat::Ply] {
        match load("fuzz", data, format, 1 << 16) {
            Ok(groups) => {
                for g in groups {
                    assert!(g.normals.is_empty() || g.normals.len() == g.tris.len());
                    assert!(g.uvs.is_empty() || g.uvs.len() == g.tris.len());
                    let mesh = TriMesh::new(g.tris, g.normals, g.uvs);
                    check_rays(&mesh);
                }
            }
            Err(e) => {
                let line = e.to_string();
                assert!(!line.is_empty() && !line.contains('\n'), "{line:?}");
            }
        }
    }
});

/// Rays from outside along each axis and diagonally, and from the bounds' centre outwards.
fn check_rays(mesh: &TriMesh) {
    let b = mesh.bounds();
    let centre = (b.min + b.max) * 0.5;
    let mut rays = vec![Ray::new(Vec3A::new(0.1, 0.2, 10.0), -Vec3A::Z)];
    if centre.is_finite() {
        for d in [
            Vec3A::X,
            -Vec3A::Y,
            Vec3A::Z,
            Vec3A::new(1.0, -2.0, 3.0),
            Vec3A::new(-0.3, 0.5, -0.8),
        ] {
            rays.push(Ray::new(centre, d));
            rays.push(Ray::new(centre - d * 1e3, d));
        }
    }
    let tris: Vec<[Vec3A; 3]> = mesh.triangles().collect();
    assert_eq!(tris.len(), mesh.len());
    for ray in rays {
        let brute = tris
            .iter()
            .filter_map(|&[a, b, c]| triangle::intersect(ray.o, ray.d, a, b, c, f32::INFINITY))
            .map(|h| h.t)
            .fold(None, |m: Option<f32>, t| Some(m.map_or(t, |m| m.min(t))));
        let hit = mesh.intersect(&ray, f32::INFINITY);
        // Hit or miss exactly; t within rounding, since a box's entry distance and a hit's t
        // inside it round apart, so the BVH may pass a box whose triangle reports a t a few
        // ulps below the one found.
        assert_eq!(hit.is_some(), brute.is_some(), "{ray:?}");
        if let (Some((t, _)), Some(b)) = (hit, brute) {
            assert!(
                t >= b && t - b <= 1e-5 * b.max(1.0),
                "{ray:?}: {t} against {b}"
            );
        }
        if let Some((t, slot)) = hit {
            assert!(t > 0.0 && t.is_finite());
            let [a, b, c] = mesh.triangle(slot);
            assert_eq!(
                triangle::intersect(ray.o, ray.d, a, b, c, f32::INFINITY).map(|h| h.t),
                Some(t)
            );
        }
        assert_eq!(
            mesh.occluded(&ray, f32::INFINITY),
            brute.is_some(),
            "{ray:?}"
        );
    }
}
