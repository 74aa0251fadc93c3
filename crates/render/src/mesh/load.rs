//! Reading mesh files: OBJ with `tobj`, PLY (ASCII and binary) with `ply-rs`. Both give
//! triangles grouped by material name (an OBJ's `usemtl`; a PLY has one unnamed group), with
//! vertex normals where the file has them. Polygons are split into fans of triangles.
//!
//! Every error is one line naming the file and, where the parser knows it, the line (OBJ,
//! ASCII PLY) or the element (binary PLY). Neither crate reports positions itself, so the OBJ
//! reader counts the lines it consumes and the PLY payload is read an element at a time.

use std::collections::BTreeSet;
use std::io::{BufRead, Cursor, Read};

use glam::{Vec2, Vec3A};
use ply_rs::parser::Parser;
use ply_rs::ply::{ElementDef, Encoding, Property, PropertyAccess};

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

/// The name `tobj` gives the synthetic material library below.
const NAMES_LIBRARY: &str = "tessera-usemtl-names";

fn load_obj(file: &str, bytes: &[u8], max_triangles: usize) -> Result<Vec<Group>, MeshError> {
    // OBJ is ASCII; other bytes turn up in comments and names (Latin-1 exports), where they
    // are harmless, so they are replaced rather than refused.
    let text = String::from_utf8_lossy(bytes);
    let (models, materials) = read_obj(file, &text)?;
    let mut groups: Vec<Group> = Vec::new();
    let mut total = 0usize;
    for model in &models {
        add_obj_model(
            file,
            model,
            &materials,
            (&mut total, max_triangles),
            &mut groups,
        )?;
    }
    // A group whose models disagree on normals or texture coordinates gets none: they are
    // all or nothing.
    for g in &mut groups {
        if g.normals.len() != g.tris.len() {
            g.normals.clear();
        }
        if g.uvs.len() != g.tris.len() {
            g.uvs.clear();
        }
    }
    Ok(groups)
}

/// An OBJ text as `tobj` reads it: its models, and the materials its `usemtl` lines name.
fn read_obj(file: &str, text: &str) -> Result<(Vec<tobj::Model>, Vec<tobj::Material>), MeshError> {
    let bytes = text.as_bytes();
    // tobj keeps a `usemtl` name only if a material library defines it, and the materials
    // come from the scene, not from .mtl files. So the reader is handed one library, first,
    // that defines every name the file uses.
    let names: BTreeSet<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| l.split_whitespace().next() == Some("usemtl"))
        .filter_map(|l| l.split_once(' ').map(|(_, n)| n.trim()))
        .filter(|n| !n.is_empty() && !n.contains(['\n', '\r']))
        .collect();
    let library: String = names.iter().map(|n| format!("newmtl {n}\n")).collect();
    let prefix = format!("mtllib {NAMES_LIBRARY}\n");
    let mut reader = LineCounter {
        inner: Cursor::new(prefix.as_bytes()).chain(Cursor::new(bytes)),
        lines: 0,
        at_line_start: true,
    };
    let options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let loaded = tobj::load_obj_buf(&mut reader, &options, |path| {
        if path == std::path::Path::new(NAMES_LIBRARY) {
            tobj::load_mtl_buf(&mut Cursor::new(library.as_bytes()))
        } else {
            // The file's own libraries: the scene maps material names, so they are not read.
            Ok((Vec::new(), Default::default()))
        }
    });
    let (models, materials) = loaded.map_err(|e| {
        // tobj notices a reference out of range only when its group ends; the face itself,
        // and the reference, are found again here (on this error path only).
        if let Some((line, message)) = bad_obj_reference(text) {
            return error(file, format!(":{line}"), message);
        }
        let line = reader.line().saturating_sub(1);
        error(file, format!(":{}", line.max(1)), obj_error_text(&e))
    })?;
    Ok((models, materials.unwrap_or_default()))
}

/// Adds `model`'s triangles (with its normals and texture coordinates, where it has all of
/// them) to the group of its material, counting them against the file's limit.
fn add_obj_model(
    file: &str,
    model: &tobj::Model,
    materials: &[tobj::Material],
    (total, max_triangles): (&mut usize, usize),
    groups: &mut Vec<Group>,
) -> Result<(), MeshError> {
    let m = &model.mesh;
    let name = m
        .material_id
        .and_then(|i| materials.get(i))
        .map(|mat| mat.name.clone());
    let vertex = |i: u32, what: &str| -> Result<Vec3A, MeshError> {
        let src = if what == "normal" {
            &m.normals
        } else {
            &m.positions
        };
        let k = i as usize * 3;
        let v = src.get(k..k + 3).ok_or_else(|| {
            error(
                file,
                String::new(),
                format!(
                    "object `{}`: a face names {what} {i}, which does not exist",
                    model.name
                ),
            )
        })?;
        let v = Vec3A::new(v[0], v[1], v[2]);
        if !v.is_finite() {
            return Err(error(
                file,
                String::new(),
                format!(
                    "object `{}`: {what} {i} is not finite: {:?}",
                    model.name,
                    v.to_array()
                ),
            ));
        }
        Ok(v)
    };
    let has_normals = m.normals.len() == m.positions.len() && !m.normals.is_empty();
    let has_uvs = m.texcoords.len() / 2 == m.positions.len() / 3 && !m.texcoords.is_empty();
    let uv = |i: u32| {
        let k = i as usize * 2;
        Vec2::new(m.texcoords[k], m.texcoords[k + 1])
    };
    let count = m.indices.len() / 3;
    *total += count;
    if *total > max_triangles {
        return Err(error(
            file,
            String::new(),
            format!("more than {max_triangles} triangles, the limit for one mesh file"),
        ));
    }
    let g = match groups.iter_mut().position(|g| g.material == name) {
        Some(i) => &mut groups[i],
        None => {
            groups.push(Group {
                material: name,
                ..Group::default()
            });
            groups.last_mut().expect("just pushed")
        }
    };
    for f in m.indices.chunks_exact(3) {
        g.tris.push([
            vertex(f[0], "vertex")?,
            vertex(f[1], "vertex")?,
            vertex(f[2], "vertex")?,
        ]);
        if has_normals {
            g.normals.push([
                vertex(f[0], "normal")?,
                vertex(f[1], "normal")?,
                vertex(f[2], "normal")?,
            ]);
        }
        if has_uvs {
            g.uvs.push([uv(f[0]), uv(f[1]), uv(f[2])]);
        }
    }
    Ok(())
}

/// The first face of an OBJ text that names a vertex, texture coordinate or normal that does
/// not exist (yet: OBJ references only what came before): its line (1-based) and what is
/// wrong, naming the reference as written and how many there were.
fn bad_obj_reference(text: &str) -> Option<(usize, String)> {
    let mut counts = [0i64; 3];
    const KINDS: [(&str, &str); 3] = [
        ("v", "vertex"),
        ("vt", "texture coordinate"),
        ("vn", "normal"),
    ];
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some(kw) if kw != "f" => {
                if let Some(k) = KINDS.iter().position(|(w, _)| *w == kw) {
                    counts[k] += 1;
                }
            }
            Some(_) => {
                for (c, word) in words.enumerate() {
                    for (k, r) in word.split('/').enumerate().take(3) {
                        if r.is_empty() {
                            continue;
                        }
                        let Ok(i) = r.parse::<i64>() else {
                            continue;
                        };
                        // Negative references count back from the last one defined.
                        let resolved = if i < 0 { counts[k] + i + 1 } else { i };
                        if resolved < 1 || resolved > counts[k] {
                            let (_, what) = KINDS[k];
                            return Some((
                                n + 1,
                                format!(
                                    "face reference {} (`{word}`) names {what} {i}, which does \
                                     not exist ({} defined before this line)",
                                    c + 1,
                                    counts[k]
                                ),
                            ));
                        }
                    }
                }
            }
            None => {}
        }
    }
    None
}

fn obj_error_text(e: &tobj::LoadError) -> String {
    use tobj::LoadError as E;
    match e {
        E::ReadError => "could not read the line (not UTF-8 text?)".into(),
        E::PositionParseError => "bad vertex position: `v` needs three numbers".into(),
        E::NormalParseError => "bad vertex normal: `vn` needs three numbers".into(),
        E::TexcoordParseError => "bad texture coordinate: `vt` needs two numbers".into(),
        E::FaceParseError => "bad face: `f` needs three or more vertex references".into(),
        E::FaceVertexOutOfBounds => {
            "a face before this line names a vertex that does not exist".into()
        }
        E::FaceNormalOutOfBounds => {
            "a face before this line names a normal that does not exist".into()
        }
        E::FaceTexCoordOutOfBounds => {
            "a face before this line names a texture coordinate that does not exist".into()
        }
        E::MaterialParseError => "bad `usemtl` or `mtllib` line".into(),
        E::InvalidObjectName => "bad object name".into(),
        other => format!("{other}"),
    }
}

/// A vertex of a PLY file: the properties a mesh uses, whatever their stored type.
#[derive(Default)]
struct PlyVertex {
    p: [f64; 3],
    n: [f64; 3],
    uv: [f64; 2],
    has: u8,
}

/// A face of a PLY file: its vertex indices (`None` where the list held a negative one).
#[derive(Default)]
struct PlyFace(Option<Vec<u32>>);

/// An element a mesh does not use (edges, materials): read past.
struct Skip;

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(x) => x.into(),
        Property::UChar(x) => x.into(),
        Property::Short(x) => x.into(),
        Property::UShort(x) => x.into(),
        Property::Int(x) => x.into(),
        Property::UInt(x) => x.into(),
        Property::Float(x) => x.into(),
        Property::Double(x) => x,
        _ => return None,
    })
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: String, property: Property) {
        let Some(x) = scalar(&property) else { return };
        let (slot, bit) = match name.as_str() {
            "x" => (&mut self.p[0], 1),
            "y" => (&mut self.p[1], 2),
            "z" => (&mut self.p[2], 4),
            "nx" => (&mut self.n[0], 8),
            "ny" => (&mut self.n[1], 16),
            "nz" => (&mut self.n[2], 32),
            "u" | "s" | "texture_u" | "texture_s" => (&mut self.uv[0], 64),
            "v" | "t" | "texture_v" | "texture_t" => (&mut self.uv[1], 128),
            _ => return,
        };
        *slot = x;
        self.has |= bit;
    }
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: String, property: Property) {
        if name != "vertex_indices" && name != "vertex_index" {
            return;
        }
        fn all<T: Copy + TryInto<u32>>(v: &[T]) -> Option<Vec<u32>> {
            v.iter().map(|&i| i.try_into().ok()).collect()
        }
        self.0 = match &property {
            Property::ListChar(v) => all(v),
            Property::ListUChar(v) => all(v),
            Property::ListShort(v) => all(v),
            Property::ListUShort(v) => all(v),
            Property::ListInt(v) => all(v),
            Property::ListUInt(v) => all(v),
            _ => None,
        };
    }
}

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

/// ply-rs's header grammar parses its integers with `unwrap`, so a count or version too long
/// for a u64 panics it (found by fuzzing). Header numbers are checked here first: 18 digits is
/// more than any real count and less than any overflow.
fn check_ply_header_numbers(file: &str, bytes: &[u8]) -> Result<(), MeshError> {
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let mut run = 0;
        for &b in line {
            run = if b.is_ascii_digit() { run + 1 } else { 0 };
            if run > 18 {
                return Err(error(
                    file,
                    format!(":{}", i + 1),
                    "bad PLY header: a number of more than 18 digits",
                ));
            }
        }
        if line.starts_with(b"end_header") {
            break;
        }
    }
    Ok(())
}

/// Reads every element of `def` as `E`, one at a time so that an error names which.
fn read_elements<E: PropertyAccess>(
    file: &str,
    reader: &mut LineCounter<Cursor<&[u8]>>,
    def: &ElementDef,
    encoding: Encoding,
    mut each: impl FnMut(usize, E) -> Result<(), MeshError>,
) -> Result<(), MeshError> {
    let parser = Parser::<E>::new();
    let mut line = String::new();
    for i in 0..def.count {
        let element = match encoding {
            Encoding::Ascii => {
                line.clear();
                let read = reader.read_line(&mut line);
                let at = format!(":{}", reader.line());
                match read {
                    Ok(0) => Err(error(
                        file,
                        at,
                        format!(
                            "the file ends after {i} of the {} `{}` elements its header declares",
                            def.count, def.name
                        ),
                    )),
                    Ok(_) => parser
                        .read_ascii_element(&line, def)
                        .map_err(|e| error(file, at, format!("bad `{}` element: {e}", def.name))),
                    Err(e) => Err(error(file, at, e)),
                }
            }
            Encoding::BinaryLittleEndian | Encoding::BinaryBigEndian => {
                let read = if encoding == Encoding::BinaryLittleEndian {
                    parser.read_little_endian_element(reader, def)
                } else {
                    parser.read_big_endian_element(reader, def)
                };
                read.map_err(|e| {
                    let why = if e.kind() == std::io::ErrorKind::UnexpectedEof {
                        "the file ends inside it".to_string()
                    } else {
                        e.to_string()
                    };
                    error(file, format!(" (element {} {i})", def.name), why)
                })
            }
        }?;
        each(i, element)?;
    }
    Ok(())
}

fn load_ply(file: &str, bytes: &[u8], max_triangles: usize) -> Result<Vec<Group>, MeshError> {
    check_ply_header_numbers(file, bytes)?;
    let mut reader = LineCounter {
        inner: Cursor::new(bytes),
        lines: 0,
        at_line_start: true,
    };
    let header = read_ply_header(file, &mut reader)?;
    let vertex_def = header.elements.get("vertex");
    let mut positions: Vec<Vec3A> = Vec::new();
    let mut normals: Vec<Vec3A> = Vec::new();
    let mut uvs: Vec<Vec2> = Vec::new();
    let mut faces: Vec<(usize, Vec<u32>)> = Vec::new();
    let mut triangles = 0usize;
    for (name, def) in &header.elements {
        match name.as_str() {
            "vertex" => {
                let has_normals = ["nx", "ny", "nz"]
                    .iter()
                    .all(|k| def.properties.contains_key(*k));
                let has_uvs = [
                    ["u", "v"],
                    ["s", "t"],
                    ["texture_u", "texture_v"],
                    ["texture_s", "texture_t"],
                ]
                .iter()
                .any(|pair| pair.iter().all(|k| def.properties.contains_key(*k)));
                if !["x", "y", "z"]
                    .iter()
                    .all(|k| def.properties.contains_key(*k))
                {
                    return Err(error(
                        file,
                        String::new(),
                        "the `vertex` element has no x, y and z properties",
                    ));
                }
                read_elements(
                    file,
                    &mut reader,
                    def,
                    header.encoding,
                    |i, v: PlyVertex| {
                        let p = Vec3A::new(v.p[0] as f32, v.p[1] as f32, v.p[2] as f32);
                        if !p.is_finite() {
                            return Err(error(
                                file,
                                format!(" (element vertex {i})"),
                                format!("position is not a finite f32: {:?}", v.p),
                            ));
                        }
                        positions.push(p);
                        if has_normals {
                            let n = Vec3A::new(v.n[0] as f32, v.n[1] as f32, v.n[2] as f32);
                            normals.push(if n.is_finite() { n } else { Vec3A::ZERO });
                        }
                        if has_uvs {
                            let uv = Vec2::new(v.uv[0] as f32, v.uv[1] as f32);
                            uvs.push(if uv.is_finite() { uv } else { Vec2::ZERO });
                        }
                        Ok(())
                    },
                )?;
            }
            "face" => {
                if vertex_def.is_none() {
                    return Err(error(file, String::new(), "faces but no `vertex` element"));
                }
                read_elements(file, &mut reader, def, header.encoding, |i, f: PlyFace| {
                    let at = || format!(" (element face {i})");
                    let Some(list) = f.0 else {
                        return Err(error(
                            file,
                            at(),
                            "no `vertex_indices` list of non-negative integers",
                        ));
                    };
                    if list.len() >= 3 {
                        triangles += list.len() - 2;
                        if triangles > max_triangles {
                            return Err(error(
                                file,
                                at(),
                                format!(
                                    "more than {max_triangles} triangles, the limit for one mesh file"
                                ),
                            ));
                        }
                        faces.push((i, list));
                    }
                    Ok(())
                })?;
            }
            _ => read_elements(file, &mut reader, def, header.encoding, |_, _: Skip| Ok(()))?,
        }
    }
    Ok(vec![fan(file, &positions, (&normals, &uvs), faces)?])
}

/// A PLY file's header, its errors positioned once (ply-rs says "Line N: …" itself).
fn read_ply_header<R: std::io::BufRead>(
    file: &str,
    reader: &mut LineCounter<R>,
) -> Result<ply_rs::ply::Header, MeshError> {
    Parser::<Skip>::new().read_header(reader).map_err(|e| {
        let at = format!(":{}", reader.line().max(1));
        // ply-rs says "Line N: …" itself; the position is given once, in `at`.
        let e = e.to_string();
        let e = e
            .strip_prefix("Line ")
            .and_then(|r| r.split_once(": "))
            .filter(|(n, _)| n.bytes().all(|b| b.is_ascii_digit()))
            .map_or(e.as_str(), |(_, rest)| rest);
        error(file, at, format!("bad PLY header: {e}"))
    })
}

/// The triangles of PLY faces (vertex lists, each with its element number), each polygon
/// as a fan, with the vertices' normals and texture coordinates where every vertex has them.
fn fan(
    file: &str,
    positions: &[Vec3A],
    (normals, uvs): (&[Vec3A], &[Vec2]),
    faces: Vec<(usize, Vec<u32>)>,
) -> Result<Group, MeshError> {
    let mut group = Group::default();
    let with_normals = normals.len() == positions.len() && !normals.is_empty();
    let with_uvs = uvs.len() == positions.len() && !uvs.is_empty();
    for (i, list) in faces {
        let get = |k: u32| {
            positions.get(k as usize).copied().ok_or_else(|| {
                error(
                    file,
                    format!(" (element face {i})"),
                    format!("vertex {k} does not exist ({} vertices)", positions.len()),
                )
            })
        };
        // A fan: a convex polygon's triangulation, and what other readers do with the rest.
        for k in 1..list.len() - 1 {
            let idx = [list[0], list[k], list[k + 1]];
            group.tris.push([get(idx[0])?, get(idx[1])?, get(idx[2])?]);
            if with_normals {
                group.normals.push(idx.map(|j| normals[j as usize]));
            }
            if with_uvs {
                group.uvs.push(idx.map(|j| uvs[j as usize]));
            }
        }
    }
    Ok(group)
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
