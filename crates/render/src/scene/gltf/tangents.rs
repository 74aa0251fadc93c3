//! Vertex tangents for normal maps: the TANGENT attribute where the file gives one, and
//! MikkTSpace's where it does not, as the glTF specification asks (§3.7.2.1).
//!
//! A normal map is baked against a tangent frame, and only the frame the baker used reads it
//! back without seams: per-triangle ∂p/∂u turns at every edge of a curved mesh and flips across
//! a mirrored UV island. Bakers (Blender, Substance, xNormal) use MikkTSpace, whose tangents are
//! a pure function of the positions, normals and texture coordinates, so computing them here
//! gives the baker's frame, and the same bits on every machine.
//!
//! The coordinates handed to MikkTSpace are tessera's, with v up the image (the import flips
//! glTF's). With v up, MikkTSpace's bitangent sign is glTF's w: B = n × T · w points up the
//! image, where a normal map's green channel points. (Fed glTF's own v, every sign would come
//! out negated, which is why three.js negates them.)

use glam::{Vec2, Vec3A, Vec4};

/// The vertices of de-indexed triangles, and the tangents MikkTSpace writes back.
struct Corners<'a> {
    tris: &'a [[Vec3A; 3]],
    normals: &'a [[Vec3A; 3]],
    uvs: &'a [[Vec2; 3]],
    out: Vec<[Vec4; 3]>,
}

impl bevy_mikktspace::Geometry for Corners<'_> {
    fn num_faces(&self) -> usize {
        self.tris.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.tris[face][vert].to_array()
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        match self.normals.get(face) {
            Some(n) => n[vert].to_array(),
            // glTF's rule for a primitive without normals: flat ones.
            None => {
                let [a, b, c] = self.tris[face];
                (b - a).cross(c - a).normalize_or_zero().to_array()
            }
        }
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        self.uvs[face][vert].to_array()
    }

    fn set_tangent_encoded(&mut self, tangent: [f32; 4], face: usize, vert: usize) {
        self.out[face][vert] = Vec4::from_array(tangent);
    }
}

/// MikkTSpace's tangents for triangles with texture coordinates (v up) and, optionally,
/// vertex normals (empty for flat ones); empty where there are no coordinates or MikkTSpace
/// gives up (then the renderer falls back to each triangle's ∂p/∂u).
pub(super) fn mikktspace(
    tris: &[[Vec3A; 3]],
    normals: &[[Vec3A; 3]],
    uvs: &[[Vec2; 3]],
) -> Vec<[Vec4; 3]> {
    if uvs.len() != tris.len() || tris.is_empty() {
        return Vec::new();
    }
    let mut corners = Corners {
        tris,
        normals,
        uvs,
        out: vec![[Vec4::ZERO; 3]; tris.len()],
    };
    if bevy_mikktspace::generate_tangents(&mut corners) {
        corners.out
    } else {
        Vec::new()
    }
}

/// The file's TANGENT values by corner: xyz as given (zero where not finite, which the
/// renderer treats as no tangent) and w as the sign of the given w.
pub(super) fn given(values: &[[f32; 4]], corners: &[[u32; 3]]) -> Vec<[Vec4; 3]> {
    let at = |i: u32| {
        let [x, y, z, w] = values[i as usize];
        let xyz = Vec3A::new(x, y, z);
        let xyz = if xyz.is_finite() { xyz } else { Vec3A::ZERO };
        xyz.extend(if w < 0.0 { -1.0 } else { 1.0 })
    };
    corners.iter().map(|c| c.map(at)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit quad in the xy plane facing +z, as two triangles, with coordinates `uv(p)`.
    fn quad(uv: impl Fn(Vec3A) -> Vec2) -> (Vec<[Vec3A; 3]>, Vec<[Vec2; 3]>) {
        let p = [
            Vec3A::new(0.0, 0.0, 0.0),
            Vec3A::new(1.0, 0.0, 0.0),
            Vec3A::new(1.0, 1.0, 0.0),
            Vec3A::new(0.0, 1.0, 0.0),
        ];
        let tris = vec![[p[0], p[1], p[2]], [p[0], p[2], p[3]]];
        let uvs = tris.iter().map(|t| t.map(&uv)).collect();
        (tris, uvs)
    }

    #[test]
    fn a_plain_quad_gets_u_as_tangent_and_a_positive_sign() {
        let (tris, uvs) = quad(|p| Vec2::new(p.x, p.y));
        let t = mikktspace(&tris, &[], &uvs);
        for v in t.iter().flatten() {
            assert!((v.truncate() - glam::Vec3::X).length() < 1e-6, "{v}");
            assert_eq!(v.w, 1.0);
        }
    }

    #[test]
    fn a_mirrored_quad_gets_a_negative_sign_so_its_bitangent_still_points_up_the_image() {
        // u runs along −x: the tangent follows it, and n × t = −y, so w = −1 turns the
        // bitangent back to +y, along v.
        let (tris, uvs) = quad(|p| Vec2::new(1.0 - p.x, p.y));
        let t = mikktspace(&tris, &[], &uvs);
        for v in t.iter().flatten() {
            assert!((v.truncate() + glam::Vec3::X).length() < 1e-6, "{v}");
            assert_eq!(v.w, -1.0);
            let b = Vec3A::Z.cross(Vec3A::from(v.truncate())) * v.w;
            assert!((b - Vec3A::Y).length() < 1e-6);
        }
    }

    #[test]
    fn shared_vertices_get_one_tangent_where_per_triangle_frames_would_differ() {
        // A fan around a vertex whose triangles' ∂p/∂u all differ; MikkTSpace averages them
        // into one tangent for the shared corner.
        let c = Vec3A::new(0.0, 0.0, 0.5);
        let ring: Vec<Vec3A> = (0..6)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 6.0;
                Vec3A::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let tris: Vec<[Vec3A; 3]> = (0..6).map(|k| [c, ring[k], ring[(k + 1) % 6]]).collect();
        let uv = |p: Vec3A| Vec2::new(p.x * 0.5 + 0.5, p.y * 0.5 + 0.5);
        let uvs: Vec<[Vec2; 3]> = tris.iter().map(|t| t.map(uv)).collect();
        let normals: Vec<[Vec3A; 3]> = tris
            .iter()
            .map(|t| t.map(|p| (p - Vec3A::new(0.0, 0.0, -1.0)).normalize()))
            .collect();
        let t = mikktspace(&tris, &normals, &uvs);
        let first = t[0][0];
        for tri in &t {
            assert!((tri[0] - first).length() < 1e-5, "{} vs {first}", tri[0]);
        }
    }

    #[test]
    fn given_tangents_keep_their_direction_and_their_sign() {
        let t = given(
            &[
                [0.0, 1.0, 0.0, -1.0],
                [f32::NAN, 0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0, 0.3],
            ],
            &[[0, 1, 2]],
        );
        assert_eq!(t[0][0], Vec4::new(0.0, 1.0, 0.0, -1.0));
        assert_eq!(t[0][1], Vec4::new(0.0, 0.0, 0.0, 1.0));
        assert_eq!(t[0][2], Vec4::new(1.0, 0.0, 0.0, 1.0));
    }
}
