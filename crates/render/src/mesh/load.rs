//! Reading mesh files: OBJ with `tobj`, PLY (ASCII and binary) with `ply-rs`. Both give
//! triangles grouped by material name (an OBJ's `usemtl`; a PLY has one unnamed group), with
//! vertex normals where the file has them. Polygons are split into fans of triangles.
//!
//! Every error is one line naming the file and, where the parser knows it, the line (OBJ,
//! ASCII PLY) or the element (binary PLY). Neither crate reports positions itself, so the OBJ
//! reader counts the lines it consumes and the PLY payload is read an element at a time.

use std::io::{BufRead, Read};

use glam::{Vec2, Vec3A};

mod obj;
mod ply;

use obj::load_obj;
use ply::load_ply;

/// Triangles of one material group.
#[derive(Clone, Debug, Default)]
pub struct Group {
    /// The file's material name for the group (an OBJ's `usemtl`), if any.
    pub material: Option<String>,
    /// Vertex positions of each triangle.
    pub tris: Vec<[Vec3A; 3]>,
    /// Vertex normals of each triangle: empty, or one entry per triangle.
    pub normals: Vec<[Vec3A; 3]>,
    /// Texture coordinates of each triangle's vertices: empty, or one entry per triangle.
    pub uvs: Vec<[Vec2; 3]>,
}

/// A mesh file that could not be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{file}{at}: {message}")]
pub struct MeshError {
    /// The file, as the scene names it.
    pub file: String,
    /// Where in it: `:LINE`, ` (element face 12)`, or empty.
    pub at: String,
    /// What is wrong (one line).
    pub message: String,
}

/// Which parser a file name calls for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ.
    Obj,
    /// Stanford PLY.
    Ply,
}

impl MeshFormat {
    /// By extension (case-insensitive); `None` for anything else.
    pub fn from_name(name: &str) -> Option<Self> {
        let ext = name.rsplit_once('.')?.1;
        if ext.eq_ignore_ascii_case("obj") {
            Some(Self::Obj)
        } else if ext.eq_ignore_ascii_case("ply") {
            Some(Self::Ply)
        } else {
            None
        }
    }
}

fn error(file: &str, at: String, message: impl std::fmt::Display) -> MeshError {
    // Parser messages may span lines ("…\n\tError: …"); an error here is one line.
    let message = message.to_string();
    // ply-rs appends its grammar's internal state, which says nothing to a user.
    let message = message
        .split("Error: ParseError")
        .next()
        .unwrap_or_default();
    let message = message.split_whitespace().collect::<Vec<_>>().join(" ");
    MeshError {
        file: file.to_string(),
        at,
        message,
    }
}

/// Reads `bytes` (the file `file`) as `format`: its triangles by material group, at most
/// `max_triangles` of them. Never panics: a parser panic (there should be none) is caught and
/// reported like any other error.
pub fn load(
    file: &str,
    bytes: &[u8],
    format: MeshFormat,
    max_triangles: usize,
) -> Result<Vec<Group>, MeshError> {
    let run = || match format {
        MeshFormat::Obj => load_obj(file, bytes, max_triangles),
        MeshFormat::Ply => load_ply(file, bytes, max_triangles),
    };
    let groups = std::panic::catch_unwind(std::panic::AssertUnwindSafe(run))
        .unwrap_or_else(|_| Err(error(file, String::new(), "the parser failed on this file")))?;
    let total: usize = groups.iter().map(|g| g.tris.len()).sum();
    if total == 0 {
        return Err(error(file, String::new(), "the file holds no triangles"));
    }
    Ok(groups)
}

/// A reader that counts the lines consumed through it, so that an error from a parser that
/// reads line by line can be placed.
struct LineCounter<R> {
    inner: R,
    lines: usize,
    at_line_start: bool,
}

impl<R: BufRead> Read for LineCounter<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.count(&buf[..n]);
        Ok(n)
    }
}

impl<R: BufRead> BufRead for LineCounter<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        self.inner.fill_buf()
    }

    fn consume(&mut self, amt: usize) {
        // The bytes consumed are the front of the buffer `fill_buf` returned, which asking
        // again returns without reading.
        let seen = match self.inner.fill_buf() {
            Ok(buf) => newlines(&buf[..amt.min(buf.len())]),
            Err(_) => None,
        };
        self.note(seen);
        self.inner.consume(amt);
    }
}

impl<R> LineCounter<R> {
    fn count(&mut self, bytes: &[u8]) {
        self.note(newlines(bytes));
    }

    fn note(&mut self, seen: Option<(usize, bool)>) {
        if let Some((n, ends_line)) = seen {
            self.lines += n;
            self.at_line_start = ends_line;
        }
    }

    /// The 1-based line being read: the last one consumed.
    fn line(&self) -> usize {
        if self.at_line_start {
            self.lines
        } else {
            self.lines + 1
        }
    }
}

/// How many newlines `bytes` holds and whether it ends with one; `None` when it is empty.
fn newlines(bytes: &[u8]) -> Option<(usize, bool)> {
    let last = *bytes.last()?;
    Some((bytes.iter().filter(|&&b| b == b'\n').count(), last == b'\n'))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obj(text: &str) -> Result<Vec<Group>, MeshError> {
        load("m.obj", text.as_bytes(), MeshFormat::Obj, 1000)
    }

    #[test]
    fn obj_groups_by_usemtl_and_splits_quads() {
        let g = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl red\nf 1 2 3 4\nusemtl blue\nf 1 2 3\nusemtl red\nf 2 3 4\n")
            .expect("loads");
        let names: Vec<_> = g.iter().map(|g| g.material.as_deref()).collect();
        assert_eq!(names, [Some("red"), Some("blue")]);
        assert_eq!(g[0].tris.len(), 3);
        assert_eq!(g[1].tris.len(), 1);
        assert!(g[0].normals.is_empty());
    }

    /// ply-rs puts "Line N:" in its own message; the position is given once, not twice.
    #[test]
    fn a_ply_header_error_gives_its_line_once() {
        let bytes =
            b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nbogus line\nend_header\n";
        let e = load("h.ply", bytes, MeshFormat::Ply, 10)
            .expect_err("refused")
            .to_string();
        assert!(e.starts_with("h.ply:5: bad PLY header: "), "{e}");
        assert!(!e.contains("Line"), "{e}");
    }

    #[test]
    fn obj_errors_name_the_line() {
        let e = obj("v 0 0 0\nv 1 0 0\nv 1 1 x\nf 1 2 3\n").expect_err("refused");
        assert_eq!(
            e.to_string(),
            "m.obj:3: bad vertex position: `v` needs three numbers"
        );
        let e = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\nv 0 1 0\n# end\n").expect_err("refused");
        assert_eq!(
            e.to_string(),
            "m.obj:4: face reference 3 (`9`) names vertex 9, which does not exist (3 defined \
             before this line)"
        );
        let e =
            obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//2\n").expect_err("refused");
        assert!(
            e.to_string()
                .starts_with("m.obj:5: face reference 3 (`3//2`) names normal 2"),
            "{e}"
        );
        let e = obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nf -1 -2 -4\n").expect_err("refused");
        assert!(e.to_string().contains("names vertex -4"), "{e}");
        obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nf -1 -2 -3\n").expect("relative references load");
        let e = obj("v 0 0 0\n").expect_err("refused");
        assert_eq!(e.to_string(), "m.obj: the file holds no triangles");
        let e = obj("v 0 0 nan\nv 1 0 0\nv 1 1 0\nf 1 2 3\n").expect_err("refused");
        assert!(e.to_string().contains("not finite"), "{e}");
        // Bytes that are not UTF-8 (a Latin-1 comment) are harmless.
        obj("# caf\u{e9}\nv 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n").expect("loads");
        let latin1 = b"# caf\xe9\nv 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n";
        load("m.obj", latin1, MeshFormat::Obj, 10).expect("loads");
    }

    #[test]
    fn the_triangle_limit_is_enforced() {
        let e = load(
            "m.obj",
            b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\nf 1 2 3\n",
            MeshFormat::Obj,
            1,
        )
        .expect_err("refused");
        assert!(e.message.contains("limit"), "{e}");
    }

    #[test]
    fn ply_ascii_and_binary_give_the_same_triangles() {
        let ascii = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
        let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
        for p in [[0f32, 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]] {
            for c in p {
                bin.extend(c.to_le_bytes());
            }
        }
        bin.push(4);
        for i in [0i32, 1, 2, 3] {
            bin.extend(i.to_le_bytes());
        }
        let a = load("a.ply", ascii.as_bytes(), MeshFormat::Ply, 10).expect("ascii");
        let b = load("b.ply", &bin, MeshFormat::Ply, 10).expect("binary");
        assert_eq!(a[0].tris, b[0].tris);
        assert_eq!(a[0].tris.len(), 2);
        // Truncated: the error names the element.
        let e = load("b.ply", &bin[..bin.len() - 3], MeshFormat::Ply, 10).expect_err("refused");
        assert!(e.to_string().starts_with("b.ply (element face 0): "), "{e}");
        let e = load(
            "a.ply",
            ascii.replace("4 0 1 2 3", "3 0 1 7").as_bytes(),
            MeshFormat::Ply,
            10,
        )
        .expect_err("refused");
        assert!(
            e.to_string()
                .starts_with("a.ply (element face 0): vertex 7"),
            "{e}"
        );
        let e = load(
            "a.ply",
            ascii.replace("1 1 0", "1 x 0").as_bytes(),
            MeshFormat::Ply,
            10,
        )
        .expect_err("refused");
        assert!(
            e.to_string().starts_with("a.ply:12: bad `vertex` element"),
            "{e}"
        );
    }
}
