//! PLY, ASCII and binary, read with `ply-rs` an element at a time, so that an error names the
//! element (or, in the header, the line); polygons become fans of triangles.

use std::io::{BufRead, Cursor};

use glam::{Vec2, Vec3A};
use ply_rs::parser::Parser;
use ply_rs::ply::{ElementDef, Encoding, Property, PropertyAccess};

use super::{error, Group, LineCounter, MeshError};

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

pub(super) fn load_ply(
    file: &str,
    bytes: &[u8],
    max_triangles: usize,
) -> Result<Vec<Group>, MeshError> {
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
