//! glTF 2.0 files (`.gltf` with its buffers and images, or `.glb`) as scene objects: every
//! mesh its node tree places, its metallic–roughness materials, its punctual lights and its
//! cameras, in the scene's world.
//!
//! The JSON is parsed and its indices validated by the `gltf` crate; the bytes behind it are
//! read here ([`data`]), because the file is untrusted and every offset in it must be checked
//! against the bytes held. A glTF file is a scene object, so the scene's own machinery does the
//! rest: its files are read through [`Assets`] (so a farm job reads the uploaded copies and its
//! identity covers them), its textures decode once however many materials share them, and a
//! mesh that several nodes use is one BVH placed several times.

mod camera;
mod data;
mod entry;
mod lights;
mod material;
mod tangents;

use std::collections::BTreeMap;
use std::sync::Arc;

use glam::{Affine3A, Mat4, Vec2, Vec3A};
use gltf::json::validation::Validate as _;
use gltf::mesh::Mode;

use super::assets::Assets;
use super::check::{degenerate, Invalid};
use super::files::SceneFiles;
use super::{KeyPath, Limits, Material};
use crate::bsdf::pbr::Distribution;
use crate::interaction::Transformed;
use crate::material::Tables;
use crate::mesh::{MeshInstance, TriMesh};
use crate::shape::Shape;
use crate::util::fields::root as json_root;

pub(super) use camera::camera;
pub(super) use entry::describe;
pub use entry::{is_gltf, json_part, scene_text, GltfOptions};
use lights::light_at;
pub(super) use lights::{lights, GltfLight};
pub(super) use material::GltfMaterials;

/// The extensions whose data tessera reads, which a file may therefore require.
const READ: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_clearcoat",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_sheen",
    "KHR_materials_specular",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
];

/// Most nodes a file may hold: the node tree is walked once, so this bounds the walk.
const MAX_NODES: usize = 1 << 20;

/// A camera the file places, in the world.
#[derive(Clone, Debug)]
pub(crate) struct GltfCamera {
    /// Its index in the file's `cameras`.
    pub(crate) index: usize,
    /// Its name in the file, if any.
    pub(crate) name: Option<String>,
    /// Where it is.
    pub(crate) eye: Vec3A,
    /// Where it looks (its −z).
    pub(crate) forward: Vec3A,
    /// Its +y.
    pub(crate) up: Vec3A,
    /// Vertical field of view, radians; `None` for an orthographic camera.
    pub(crate) yfov: Option<f32>,
    /// An orthographic camera's half-width and half-height in world units.
    pub(crate) mag: (f32, f32),
    /// The near clipping plane's depth in world units (`znear` through the node's scale).
    pub(crate) near: f32,
    /// The far clipping plane's depth in world units (`zfar`; infinite where absent).
    pub(crate) far: f32,
}

/// What one glTF file adds to a scene.
pub(super) struct Imported {
    /// Mesh instances, each with its material's index in the scene.
    pub(super) parts: Vec<(Shape, u32)>,
    /// Punctual lights.
    pub(super) lights: Vec<GltfLight>,
    /// Cameras, in the order of the node tree.
    pub(super) cameras: Vec<GltfCamera>,
    /// Things read but not rendered as the file asks, one line each.
    pub(super) warnings: Vec<String>,
}

/// Where the imported materials go: the scene's own tables, which they join.
pub(super) struct MaterialTables<'a> {
    /// The scene's materials.
    pub(super) materials: &'a mut Vec<Material>,
    /// Their absorption.
    pub(super) absorption: &'a mut Vec<Vec3A>,
    /// The large materials (glTF's) that the small ones index.
    pub(super) kinds: &'a mut Tables,
    /// The alpha tests of `MASK` and `BLEND` materials, by material index.
    pub(super) alpha: &'a mut Vec<(u32, super::AlphaTest)>,
    /// Emission textures, as (material index, texture index).
    pub(super) emissive: &'a mut Vec<(u32, u32)>,
}

/// The directory part of a scene file name (`""` for none), which a glTF file's URIs are
/// relative to.
fn dir_of(name: &str) -> &str {
    name.rsplit_once('/').map_or("", |(d, _)| d)
}

/// A parsed file: its document, its GLB's BIN chunk, and its warnings.
pub(crate) type Parsed<'a> = (gltf::Document, Option<&'a [u8]>, Vec<String>);

/// A glTF file already read and parsed, lent to the build that imports it: a glTF file loaded
/// as a whole scene is read and parsed once, for the scene text it stands for and for its
/// contents alike.
pub(crate) struct Lent {
    /// The file's name, as the scene names it.
    name: String,
    doc: gltf::Document,
    /// A .glb's binary chunk.
    bin: Option<Vec<u8>>,
    warnings: Vec<String>,
}

impl Lent {
    /// The file `name` whose bytes are `bytes`, parsed; or why it does not parse.
    /// Errors are placed in the file, from its root.
    pub(crate) fn parse(name: &str, bytes: &[u8]) -> Result<Self, Invalid> {
        let (doc, bin, warnings) = parse(bytes)?;
        Ok(Self {
            name: name.to_string(),
            doc,
            bin: bin.map(<[u8]>::to_vec),
            warnings,
        })
    }

    /// Its document.
    pub(crate) fn doc(&self) -> &gltf::Document {
        &self.doc
    }

    /// Whether it is file `name`.
    pub(in crate::scene) fn is(&self, name: &str) -> bool {
        self.name == name
    }
}

/// A place as gltf-json's validation writes it (`meshes[0].primitives[1]["POSITION"]`), as a
/// key path.
fn validated_path(p: &str) -> KeyPath {
    let mut out = KeyPath::default();
    let mut rest = p;
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("[\"") {
            let (key, r) = r.split_once("\"]").unwrap_or((r, ""));
            out = out.key(key);
            rest = r;
        } else if let Some(r) = rest.strip_prefix('[') {
            let (n, r) = r.split_once(']').unwrap_or((r, ""));
            out = match n.parse() {
                Ok(i) => out.index(i),
                Err(_) => out.key(n),
            };
            rest = r;
        } else {
            let r = rest.strip_prefix('.').unwrap_or(rest);
            let end = r.find(['.', '[']).unwrap_or(r.len());
            out = out.key(&r[..end]);
            rest = &r[end..];
        }
    }
    out
}

/// A primitive's mesh and whether it shades smooth; `None` for one without triangles.
type Built = Option<(Arc<TriMesh>, bool)>;

/// Parses `bytes` (a `.gltf` or `.glb`) and checks it: the JSON and its indices, and the
/// extensions it requires.
pub(crate) fn parse(bytes: &[u8]) -> Result<Parsed<'_>, Invalid> {
    let whole = |m: String| (KeyPath::default(), m);
    let (json, bin) = if bytes.starts_with(b"glTF") {
        data::split_glb(bytes).map_err(whole)?
    } else {
        (bytes, None)
    };
    let root: gltf::json::Root = serde_json::from_slice(json)
        .map_err(|e| {
            // glTF 1.0 differs in shape, so its files fail to parse: say why rather than where.
            let version = serde_json::from_slice::<serde_json::Value>(json)
                .ok()
                .and_then(|v| v["asset"]["version"].as_str().map(str::to_string));
            match version {
                Some(v) if !v.starts_with("2.") => {
                    format!(
                        "glTF {v}; tessera reads glTF 2.0 (convert it, e.g. with gltf-pipeline)"
                    )
                }
                _ => format!("not valid glTF 2.0 JSON: {e}"),
            }
        })
        .map_err(whole)?;
    if !root.asset.version.starts_with("2.") {
        return Err((
            json_root("asset").key("version"),
            format!("glTF {}; tessera reads glTF 2.0", root.asset.version),
        ));
    }
    let mut warnings = Vec::new();
    for (i, ext) in root.extensions_required.iter().enumerate() {
        if READ.contains(&ext.as_str()) {
            continue;
        }
        let hint = match ext.as_str() {
            "KHR_draco_mesh_compression" | "EXT_meshopt_compression" => {
                " (its meshes are compressed: decompress it first, e.g. `gltf-transform copy in.glb out.glb`)"
            }
            _ => "",
        };
        return Err((
            json_root("extensionsRequired").index(i),
            format!("requires the extension {ext}, which tessera does not read{hint}"),
        ));
    }
    for ext in &root.extensions_used {
        if !READ.contains(&ext.as_str()) {
            warnings.push(format!("ignores the optional extension {ext}"));
        }
    }
    if root.nodes.len() > MAX_NODES {
        return Err((
            json_root("nodes"),
            format!("{} nodes, above the limit of {MAX_NODES}", root.nodes.len()),
        ));
    }
    // gltf-json's own validation indexes `accessors` by a primitive's POSITION before it
    // checks the index (found by the gltf_load fuzz target), so that one is checked first.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if index.value() >= root.accessors.len() {
                    return Err((
                        json_root("meshes")
                            .index(m)
                            .key("primitives")
                            .index(p)
                            .key("attributes")
                            .key(&semantic.to_string()),
                        format!(
                            "accessor {} does not exist ({} accessors)",
                            index.value(),
                            root.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    let mut first = None;
    root.validate(&root, gltf::json::Path::new, &mut |path, error| {
        let path = path().to_string();
        // Required extensions were judged above, against what tessera reads.
        if first.is_none() && !path.starts_with("extensionsRequired") {
            first = Some((validated_path(&path), error.to_string()));
        }
    });
    if let Some(e) = first {
        return Err(e);
    }
    Ok((
        gltf::Document::from_json_without_validation(root),
        bin,
        warnings,
    ))
}

/// Reads glTF file `name` (through `files`, so its hash joins the scene's; parsed already where
/// `lent`) and everything it names, placed by `place`. `path` is where the scene names the file, for errors.
#[allow(clippy::too_many_arguments)]
pub(super) fn import(
    name: &str,
    place: Affine3A,
    (overrides, distribution): (&BTreeMap<String, u32>, Distribution),
    tables: &mut MaterialTables,
    (files, lent): (&mut SceneFiles, Option<Lent>),
    limits: &Limits,
    assets: &dyn Assets,
    path: &KeyPath,
) -> Result<Imported, Invalid> {
    // Every error below is placed inside the file, at the JSON it concerns.
    let root = path.within(name);
    let fail = |(at, m): Invalid| (root.join(&at), m);
    // Read even when lent: the file counts among the scene's files, and its hash in the
    // scene's.
    let bytes = files.read_file(name, path, limits, assets)?;
    let Lent {
        doc,
        bin,
        mut warnings,
        ..
    } = match lent {
        Some(l) => l,
        None => Lent::parse(name, &bytes).map_err(fail)?,
    };
    drop(bytes);
    // What the node tree places, counted from the JSON before a buffer is read or a shape
    // built: a file of a few kilobytes can place millions.
    let placed = walk(&doc, place).map_err(fail)?;
    let (instances, declared) = implied(&doc, &placed);
    // The file itself was counted as one of the scene's objects.
    files
        .take_instances(instances.saturating_sub(1), instances, limits, path)
        .map_err(|(p, m)| (p.within(name), m))?;
    files
        .triangles_fit(declared, limits)
        .map_err(|m| (root.clone(), m))?;
    let dir = dir_of(name);
    let buffers = buffers(&doc, bin, dir, files, limits, assets, &root)?;
    check_overrides(&doc, overrides, name, path)?;
    let mut mats = GltfMaterials::new(
        (name, &root),
        dir,
        doc.as_json(),
        &buffers,
        (overrides, distribution),
    );
    let mut meshes: BTreeMap<(usize, usize), Built> = BTreeMap::new();
    let mut out = Imported {
        parts: Vec::new(),
        lights: Vec::new(),
        cameras: Vec::new(),
        warnings: Vec::new(),
    };
    let (mut skipped_modes, mut hidden) = (0usize, 0usize);
    for (node, world) in placed {
        if let Some(camera) = node.camera() {
            out.cameras
                .push(camera_at(&doc, &camera, &world).map_err(fail)?);
        }
        if let Some(light) = node.light() {
            out.lights.push(light_at(&light, &world));
        }
        let Some(mesh) = node.mesh() else { continue };
        if degenerate(&world).is_some() {
            hidden += 1;
            continue;
        }
        let xf = Transformed::new(world);
        for prim in mesh.primitives() {
            if !matches!(
                prim.mode(),
                Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
            ) {
                skipped_modes += 1;
                continue;
            }
            let material = mats.index(&prim.material(), tables, files, limits, assets)?;
            let uv_map = mats.uv_map(&prim.material());
            // Only a normal map reads tangents, so only its meshes carry them.
            let tangents = tables.materials[material as usize]
                .bsdf
                .needs_tangents(tables.kinds);
            let key = (mesh.index(), prim.index());
            if let std::collections::btree_map::Entry::Vacant(e) = meshes.entry(key) {
                let at = (root.key("meshes").index(mesh.index()))
                    .key("primitives")
                    .index(prim.index());
                let built = triangles(&prim, &buffers, uv_map, tangents, &at, files, limits)?;
                e.insert(built);
            }
            if let Some(Some((mesh, smooth))) = meshes.get(&key) {
                let instance = MeshInstance {
                    mesh: Arc::clone(mesh),
                    xf: xf.clone(),
                    smooth: *smooth,
                };
                out.parts.push((Shape::Mesh(instance), material));
            }
        }
    }
    if skipped_modes > 0 {
        warnings.push(format!(
            "skips {skipped_modes} primitives of points or lines (only triangles are rendered)"
        ));
    }
    if hidden > 0 {
        warnings.push(format!(
            "skips {hidden} mesh nodes whose transform flattens them (a scale of 0 hides them)"
        ));
    }
    warnings.extend(mats.warnings());
    out.warnings = warnings
        .into_iter()
        .map(|w| format!("{name}: {w}"))
        .collect();
    Ok(out)
}

/// Refuses a `materials_map` that names a material file `name` does not have, listing those
/// it has.
fn check_overrides(
    doc: &gltf::Document,
    overrides: &BTreeMap<String, u32>,
    name: &str,
    path: &KeyPath,
) -> Result<(), Invalid> {
    for o in overrides.keys() {
        if !doc.materials().any(|m| m.name() == Some(o.as_str())) {
            let known: Vec<&str> = doc.materials().filter_map(|m| m.name()).collect();
            return Err((
                path.within(name),
                format!(
                    "materials_map names `{o}`, which the file has no material of \
                     (it has: {})",
                    if known.is_empty() {
                        "none".into()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        }
    }
    Ok(())
}

/// What the `placed` nodes ([`walk`]'s) place, from the JSON alone: (shapes, triangles).
/// Shapes are the triangle primitives of every placed mesh node; triangles are counted once
/// per distinct primitive, from its accessors' declared counts (an upper bound: strips and
/// fans have fewer), as instances share them.
fn implied(doc: &gltf::Document, placed: &[(gltf::Node<'_>, Affine3A)]) -> (usize, usize) {
    let triangles_of = |prim: &gltf::Primitive| -> usize {
        let count = match prim.indices() {
            Some(a) => a.count(),
            None => prim
                .get(&gltf::Semantic::Positions)
                .map_or(0, |a| a.count()),
        };
        match prim.mode() {
            Mode::Triangles => count / 3,
            Mode::TriangleStrip | Mode::TriangleFan => count.saturating_sub(2),
            _ => 0,
        }
    };
    let is_triangles = |p: &gltf::Primitive| {
        matches!(
            p.mode(),
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        )
    };
    let mut shapes = 0usize;
    let mut used = vec![false; doc.meshes().len()];
    for (node, _) in placed {
        if let Some(mesh) = node.mesh() {
            shapes = shapes.saturating_add(mesh.primitives().filter(is_triangles).count());
            used[mesh.index()] = true;
        }
    }
    let triangles = doc
        .meshes()
        .filter(|m| used[m.index()])
        .flat_map(|m| m.primitives())
        .fold(0usize, |n, p| n.saturating_add(triangles_of(&p)));
    (shapes, triangles)
}

/// Every buffer's bytes: the GLB's BIN chunk, a data URI, or a file beside the glTF file.
fn buffers(
    doc: &gltf::Document,
    mut bin: Option<Vec<u8>>,
    dir: &str,
    files: &mut SceneFiles,
    limits: &Limits,
    assets: &dyn Assets,
    root: &KeyPath,
) -> Result<Vec<Vec<u8>>, Invalid> {
    doc.buffers()
        .map(|b| {
            let at = root.key("buffers").index(b.index());
            let uri_at = at.key("uri");
            let bytes = match b.source() {
                gltf::buffer::Source::Bin => bin
                    .take()
                    .ok_or_else(|| (at.clone(), "the file has no BIN chunk for it".into()))?,
                gltf::buffer::Source::Uri(uri) => match data::data_uri(uri) {
                    Some(r) => r.map_err(|m| (uri_at.clone(), m))?.1,
                    None => {
                        let file = data::uri_file(dir, uri).map_err(|m| (uri_at.clone(), m))?;
                        files.read_file(&file, &uri_at, limits, assets)?
                    }
                },
            };
            if bytes.len() < b.length() {
                return Err((
                    at.key("byteLength"),
                    format!("declares {} bytes, but holds {}", b.length(), bytes.len()),
                ));
            }
            Ok(bytes)
        })
        .collect()
}

/// The nodes of the scene the file shows (its `scene`, else its first, else every root node),
/// each with its world transform. A node reached twice (a cycle, or a node with two parents)
/// is an error: the graph must be a forest, and the walk then visits each node once.
fn walk(doc: &gltf::Document, place: Affine3A) -> Result<Vec<(gltf::Node<'_>, Affine3A)>, Invalid> {
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            let mut child = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    child[c.index()] = true;
                }
            }
            doc.nodes().filter(|n| !child[n.index()]).collect()
        }
    };
    let mut seen = vec![false; doc.nodes().len()];
    let mut out = Vec::new();
    let mut stack: Vec<(gltf::Node, Affine3A)> =
        roots.into_iter().rev().map(|n| (n, place)).collect();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err((
                json_root("nodes").index(node.index()),
                "is reached twice: the node graph has a cycle or a node with two parents".into(),
            ));
        }
        let m = Mat4::from_cols_array_2d(&node.transform().matrix());
        if !m.is_finite() || m.row(3) != glam::Vec4::W {
            return Err((
                json_root("nodes").index(node.index()),
                "its transform is not a finite affine map".into(),
            ));
        }
        let world = parent * Affine3A::from_mat4(m);
        let children: Vec<gltf::Node> = node.children().collect();
        for c in children.into_iter().rev() {
            stack.push((c, world));
        }
        out.push((node, world));
    }
    Ok(out)
}

/// A camera node, in the world.
fn camera_at(
    doc: &gltf::Document,
    camera: &gltf::Camera,
    world: &Affine3A,
) -> Result<GltfCamera, Invalid> {
    // The crate's `Camera::projection` unwraps the values of the camera's type, which its
    // validation does not check are there.
    let json = &doc.as_json().cameras[camera.index()];
    let perspective = matches!(
        json.type_,
        gltf::json::validation::Checked::Valid(gltf::json::camera::Type::Perspective)
    );
    if perspective && json.perspective.is_none() || !perspective && json.orthographic.is_none() {
        return Err((
            json_root("cameras").index(camera.index()),
            "its type's values (`perspective` or `orthographic`) are missing".into(),
        ));
    }
    Ok(GltfCamera {
        index: camera.index(),
        name: camera.name().map(str::to_string),
        eye: world.transform_point3a(Vec3A::ZERO),
        forward: world.transform_vector3a(Vec3A::NEG_Z),
        up: world.transform_vector3a(Vec3A::Y),
        yfov: json
            .perspective
            .as_ref()
            .filter(|_| perspective)
            .map(|p| p.yfov),
        mag: json
            .orthographic
            .as_ref()
            .map_or((0.0, 0.0), |o| (o.xmag.abs(), o.ymag.abs())),
        near: match (&json.perspective, &json.orthographic) {
            (Some(p), _) if perspective => p.znear,
            (_, Some(o)) if !perspective => o.znear,
            _ => 0.0,
        } * world.transform_vector3a(Vec3A::NEG_Z).length(),
        far: match (&json.perspective, &json.orthographic) {
            (Some(p), _) if perspective => p.zfar.unwrap_or(f32::INFINITY),
            (_, Some(o)) if !perspective => o.zfar,
            _ => f32::INFINITY,
        } * world.transform_vector3a(Vec3A::NEG_Z).length(),
    })
}

/// A primitive's per-vertex attribute `semantic` (its count in `unit`s in errors, placed at
/// the primitive `at`'s `attributes`): `None` where the primitive has none, else one value per
/// position of `n`.
fn attribute<const N: usize>(
    prim: &gltf::Primitive,
    buffers: &[Vec<u8>],
    semantic: gltf::Semantic,
    (at, unit): (&KeyPath, &str),
    n: usize,
) -> Result<Option<Vec<[f32; N]>>, Invalid> {
    let Some(a) = prim.get(&semantic) else {
        return Ok(None);
    };
    let at = at.key("attributes").key(&semantic.to_string());
    let v = data::read_floats::<N>(buffers, &a, &at)?;
    if v.len() != n {
        return Err((at, format!("{} {unit}for {n} positions", v.len())));
    }
    Ok(Some(v))
}

/// A triangle primitive's mesh, de-indexed, with whether it has vertex normals; `None` for a
/// primitive with no triangles. `tangents`: its material's normal map needs them.
#[allow(clippy::too_many_arguments)]
fn triangles(
    prim: &gltf::Primitive,
    buffers: &[Vec<u8>],
    (uv_set, uv_map): (u32, Option<material::UvMap>),
    tangents: bool,
    at: &KeyPath,
    files: &mut SceneFiles,
    limits: &Limits,
) -> Result<Built, Invalid> {
    let positions = prim
        .get(&gltf::Semantic::Positions)
        .ok_or_else(|| (at.key("attributes"), "has no POSITION".to_string()))?;
    let positions_at = at.key("attributes").key("POSITION");
    let positions = data::read_floats::<3>(buffers, &positions, &positions_at)?;
    if let Some(i) = positions
        .iter()
        .position(|p| !p.iter().all(|x| x.is_finite()))
    {
        return Err((
            positions_at,
            format!("vertex {i} is not finite: {:?}", positions[i]),
        ));
    }
    let n = positions.len();
    let indices = match prim.indices() {
        Some(a) => data::read_indices(buffers, &a, n, &at.key("indices"))?,
        None => (0..n as u32).collect(),
    };
    let corners = corners(prim.mode(), &indices);
    if corners.is_empty() {
        return Ok(None);
    }
    files.take_triangles(corners.len(), limits, at)?;
    let normals = attribute::<3>(prim, buffers, gltf::Semantic::Normals, (at, "normals "), n)?
        .unwrap_or_default();
    let uvs = attribute::<2>(
        prim,
        buffers,
        gltf::Semantic::TexCoords(uv_set),
        (at, ""),
        n,
    )?
    .unwrap_or_default();
    let p = |i: u32| Vec3A::from_array(positions[i as usize]);
    let tris: Vec<[Vec3A; 3]> = corners.iter().map(|c| c.map(p)).collect();
    let normals = if normals.is_empty() {
        Vec::new()
    } else {
        let nv = |i: u32| {
            let v = Vec3A::from_array(normals[i as usize]);
            if v.is_finite() {
                v
            } else {
                Vec3A::ZERO
            }
        };
        corners.iter().map(|c| c.map(nv)).collect()
    };
    let uvs = if uvs.is_empty() {
        Vec::new()
    } else {
        let uv = |i: u32| {
            let v = Vec2::from_array(uvs[i as usize]);
            let v = uv_map.as_ref().map_or(v, |m| material::map_uv(m, v));
            // glTF's v runs down the image from its top row; tessera's, as in OBJ, up.
            let v = Vec2::new(v.x, 1.0 - v.y);
            if v.is_finite() {
                v
            } else {
                Vec2::ZERO
            }
        };
        corners.iter().map(|c| c.map(uv)).collect()
    };
    let tangents = if !tangents || uvs.is_empty() {
        Vec::new()
    } else {
        match attribute::<4>(prim, buffers, gltf::Semantic::Tangents, (at, ""), n)? {
            Some(v) => tangents::given(&v, &corners),
            None => tangents::mikktspace(&tris, &normals, &uvs),
        }
    };
    let smooth = !normals.is_empty();
    Ok(Some((
        Arc::new(TriMesh::with_tangents(tris, normals, uvs, tangents)),
        smooth,
    )))
}

/// The triangles (their three indices) a primitive of `mode` makes of `indices`; none for
/// points and lines. Every other triangle of a strip is wound the other way, so its corners
/// swap to keep the front side consistent.
fn corners(mode: Mode, indices: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::Triangles => indices
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        Mode::TriangleStrip => indices
            .windows(3)
            .enumerate()
            .map(|(i, w)| {
                if i % 2 == 0 {
                    [w[0], w[1], w[2]]
                } else {
                    [w[1], w[0], w[2]]
                }
            })
            .collect(),
        Mode::TriangleFan => match indices.split_first() {
            Some((&hub, rest)) => rest.windows(2).map(|w| [hub, w[0], w[1]]).collect(),
            None => Vec::new(),
        },
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::validated_path;

    #[test]
    fn a_validation_path_reads_as_the_pointer_of_the_same_place() {
        let p = validated_path(r#"meshes[0].primitives[12].attributes["TEXCOORD_0"]"#);
        assert_eq!(p.pointer(), "/meshes/0/primitives/12/attributes/TEXCOORD_0");
        assert_eq!(validated_path("asset").pointer(), "/asset");
        assert_eq!(validated_path("").pointer(), "");
    }
}
