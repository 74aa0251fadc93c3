//! OBJ, read with `tobj`: its models grouped by their `usemtl` names, each line of the file
//! counted so that an error names it.

use std::collections::BTreeSet;
use std::io::{Cursor, Read};

use glam::{Vec2, Vec3A};

use super::{error, Group, LineCounter, MeshError};

/// The name `tobj` gives the synthetic material library below.
const NAMES_LIBRARY: &str = "tessera-usemtl-names";

pub(super) fn load_obj(
    file: &str,
    bytes: &[u8],
    max_triangles: usize,
) -> Result<Vec<Group>, MeshError> {
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
