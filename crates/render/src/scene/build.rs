//! Validation and conversion of a parsed scene file (the serde types of `format`) into the
//! runtime [`Scene`]: each part of the file has a builder of its own, and every error is a key
//! path with a message, which [`super::Load`] turns into file:line:column.

use std::collections::BTreeMap;
use std::sync::Arc;

use glam::{Affine3A, Vec3, Vec3A};

use super::assets::Assets;
use super::check::{
    build_transform, finite, finite3, only, positive, required, root, similarity_scale, Invalid,
};
use super::files::SceneFiles;
use super::gltf::{GltfCamera, MaterialTables};
use super::lights::{environment, punctual_lights, reach, PendingEnvironment};
use super::materials::{build_materials, BuiltMaterials};
use super::{
    CameraModel, KeyPath, Limits, Material, ObjectDesc, Primitive, Scene, SceneFile, ShapeKind,
};
use crate::aggregate::Accel;
use crate::camera::Camera;
use crate::light::{Light, LightShape, Lights, MeshLight};
use crate::material::Tables;
use crate::mesh::MeshInstance;
use crate::shape::{Shape, Transformed};

/// A scene every check has passed, its images read and their headers checked but not decoded
/// and its BVH not built: what a coordinator needs to admit a job (the pixels and the BVH are
/// the workers' cost, and an 8192² texture would cost the coordinator a gigabyte), and the
/// first half of every build ([`Assembled::finish`] is the second).
pub(super) struct Assembled {
    camera: Camera,
    width: u32,
    height: u32,
    prims: Vec<Primitive>,
    materials: Vec<Material>,
    absorption: Vec<Vec3A>,
    tables: Tables,
    lights: Vec<Light>,
    alpha_tests: Vec<(u32, super::AlphaTest)>,
    /// Mesh lights whose emission is a texture: (light, texture, the light triangles'
    /// texture coordinates), given their textures once decoded.
    textured_lights: Vec<(u32, u32, Vec<[glam::Vec2; 3]>)>,
    environment: PendingEnvironment,
    /// How far the scene reaches (where distant lights sit).
    reach: f32,
    files: SceneFiles,
    max_depth: Option<u32>,
    denoise: Option<super::Denoise>,
    warnings: Vec<String>,
}

/// Every check of a scene that needs no pixel: the film, camera, materials (textures read and
/// their headers checked), objects, lights and environment.
pub(super) fn assemble(
    desc: &SceneFile,
    limits: &Limits,
    assets: &dyn Assets,
    lent: Option<super::gltf::Lent>,
) -> Result<Assembled, Invalid> {
    if desc.version != 1 {
        return Err((
            root("version"),
            format!(
                "unsupported version {}; this tessera reads version 1",
                desc.version
            ),
        ));
    }
    let (w, h) = film_size(desc, limits)?;
    // A glTF camera is placed by its file, read with the objects.
    let camera = match desc.camera.model {
        CameraModel::Gltf => None,
        _ => Some(build_camera(desc, w, h)?),
    };
    let mut files = SceneFiles::default();
    let environment = environment(desc, &mut files, limits, assets)?;
    let mut built = build_materials(desc, &mut files, limits, assets)?;
    let mut lent = lent;
    let mut objects = build_objects(desc, &mut built, &mut files, limits, (assets, &mut lent))?;
    let reach = reach(&objects.prims);
    punctual_lights(desc, reach, &mut objects.lights)?;
    super::gltf::lights(&objects.gltf_lights, reach, &mut objects.lights)?;
    let camera = match camera {
        Some(c) => c,
        None => super::gltf::camera(desc, &objects.cameras, &objects.prims, w, h)?,
    };
    Ok(Assembled {
        camera,
        width: w,
        height: h,
        prims: objects.prims,
        materials: built.materials,
        absorption: built.absorption,
        tables: built.tables,
        lights: objects.lights,
        alpha_tests: objects.alpha_tests,
        textured_lights: objects.textured_lights,
        environment,
        reach,
        files,
        max_depth: desc.render.max_depth,
        denoise: denoise(desc.render.denoise.as_ref())?,
        warnings: objects.warnings,
    })
}

/// What the objects of a scene give: shapes with their materials, the lights their emissive
/// materials make, and what glTF files bring (lights, cameras, alpha tests, warnings).
struct Objects {
    prims: Vec<Primitive>,
    lights: Vec<Light>,
    gltf_lights: Vec<(KeyPath, String, super::gltf::GltfLight)>,
    cameras: Vec<(KeyPath, GltfCamera)>,
    warnings: Vec<String>,
    alpha_tests: Vec<(u32, super::AlphaTest)>,
    textured_lights: Vec<(u32, u32, Vec<[glam::Vec2; 3]>)>,
}

/// The scene's objects, each a shape, a mesh file or a glTF file (whose materials join
/// `built`'s).
fn build_objects(
    desc: &SceneFile,
    built: &mut BuiltMaterials,
    files: &mut SceneFiles,
    limits: &Limits,
    (assets, lent): (&dyn Assets, &mut Option<super::gltf::Lent>),
) -> Result<Objects, Invalid> {
    if desc.objects.len() > limits.max_objects {
        return Err((
            root("objects"),
            format!(
                "{} objects is above the limit of {}",
                desc.objects.len(),
                limits.max_objects
            ),
        ));
    }
    let n = desc.objects.len();
    files.take_instances(n, n, limits, &root("objects"))?;
    let mut out = Objects {
        prims: Vec::with_capacity(n),
        lights: Vec::new(),
        gltf_lights: Vec::new(),
        cameras: Vec::new(),
        warnings: Vec::new(),
        alpha_tests: Vec::new(),
        textured_lights: Vec::new(),
    };
    for (i, o) in desc.objects.iter().enumerate() {
        let op = root("objects").index(i);
        let parts = if o.shape == ShapeKind::Gltf {
            let mut tables = MaterialTables {
                materials: &mut built.materials,
                absorption: &mut built.absorption,
                kinds: &mut built.tables,
                alpha: &mut out.alpha_tests,
                emissive: &mut built.emissive,
            };
            let reads = (&mut *files, limits, assets, &mut *lent);
            let file = build_gltf(o, &op, &built.names, &mut tables, reads)?;
            let name = o.file.clone().unwrap_or_default();
            out.gltf_lights.extend(
                file.lights
                    .into_iter()
                    .map(|l| (op.key("file"), name.clone(), l)),
            );
            // Each camera placed at its own entry in the file, for errors about it.
            let cameras_at = op.key("file").within(&name).key("cameras");
            out.cameras.extend(
                file.cameras
                    .into_iter()
                    .map(|c| (cameras_at.index(c.index), c)),
            );
            out.warnings.extend(file.warnings);
            file.parts
        } else {
            let kind = if o.shape == ShapeKind::Mesh {
                "a mesh"
            } else {
                "a shape"
            };
            let name = required(o.material.as_deref(), &op, kind, "material")?;
            let material = material_index(&built.names, name, &op.key("material"))?;
            if o.shape == ShapeKind::Mesh {
                build_mesh(o, &op, material, &built.names, files, limits, assets)?
            } else {
                let emits = built.materials[material as usize].emission.max_element() > 0.0;
                vec![(build_shape(o, &op, emits)?, material)]
            }
        };
        for (shape, material) in parts {
            place(shape, material, o, &op, built, &mut out)?;
        }
    }
    Ok(out)
}

/// Adds one shape of object `o` to the scene, with the lights its material makes.
fn place(
    shape: Shape,
    material: u32,
    o: &ObjectDesc,
    op: &KeyPath,
    built: &BuiltMaterials,
    out: &mut Objects,
) -> Result<(), Invalid> {
    let emission_texture = built
        .emissive
        .iter()
        .find(|(e, _)| *e == material)
        .map(|&(_, t)| t);
    let mat = &built.materials[material as usize];
    check_texture_coordinates(
        &shape,
        mat,
        &built.tables,
        emission_texture.is_some(),
        o,
        op,
    )?;
    if o.shape != ShapeKind::Plane && !shape.bounds().is_finite() {
        return Err((
            op.clone(),
            "object is too large: its bounds overflow f32".into(),
        ));
    }
    let light = if mat.emission.max_element() > 0.0 {
        add_lights(&shape, mat, &mut out.lights)
    } else {
        u32::MAX
    };
    if let (Some(t), Shape::Mesh(m)) = (emission_texture, &shape) {
        if light != u32::MAX {
            out.textured_lights.push((light, t, m.light_uvs()));
        }
    }
    let light_stride = u32::from(matches!(shape, Shape::Cuboid { .. }));
    out.prims.push(Primitive {
        shape,
        material,
        light,
        light_stride,
    });
    Ok(())
}

impl Assembled {
    /// The scene's film size.
    pub(super) fn film(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The scene's shapes.
    pub(super) fn prims(&self) -> &[Primitive] {
        &self.prims
    }

    /// `[render] denoise`, checked.
    pub(super) fn denoise(&self) -> Option<&super::Denoise> {
        self.denoise.as_ref()
    }

    /// The files read so far (name and SHA-256).
    pub(super) fn files_read(&self) -> &[(String, String)] {
        &self.files.read
    }

    /// The runtime scene: the images decoded (each within the process's decode budget), the
    /// emission textures given to their lights, the environment map made a light, the BVH
    /// built.
    pub(super) fn finish(mut self) -> Result<(Scene, Vec<(String, String)>), Invalid> {
        let textures = self.files.decode_textures()?;
        for (light, t, uvs) in self.textured_lights {
            let texture = Arc::clone(&textures[t as usize]);
            let mean = texture.mean();
            self.lights[light as usize].texture = Some(Arc::new(crate::light::EmissionTexture {
                texture,
                uvs,
                mean,
            }));
        }
        super::merge::merge_meshes(&mut self.prims);
        let accel = Accel::build(&self.prims);
        let environment = self.environment.finish(self.reach, &mut self.lights)?;
        // A normal map bends shading normals too.
        let shading_normals = self
            .prims
            .iter()
            .any(|p| matches!(&p.shape, Shape::Mesh(m) if m.smooth && m.mesh.has_normals()))
            || self.tables.pbrs().iter().any(|p| p.normal_map.is_some());
        let absorption = if self.absorption.iter().any(|a| *a != Vec3A::ZERO) {
            self.absorption
        } else {
            Vec::new()
        };
        let mut alpha = Vec::new();
        if !self.alpha_tests.is_empty() {
            alpha = vec![None; self.materials.len()];
            for (i, a) in self.alpha_tests {
                alpha[i as usize] = Some(a);
            }
        }
        let scene = Scene {
            camera: self.camera,
            width: self.width,
            height: self.height,
            prims: self.prims,
            materials: self.materials,
            lights: Lights::new(self.lights),
            environment,
            max_depth: self.max_depth,
            denoise: self.denoise,
            hash: String::new(),
            files: Vec::new(),
            textures,
            accel,
            shading_normals,
            absorption,
            tables: self.tables,
            alpha,
            warnings: self.warnings,
        };
        Ok((scene, self.files.read))
    }
}

/// A textured material needs texture coordinates, which only meshes whose files give them
/// have.
fn check_texture_coordinates(
    shape: &Shape,
    mat: &Material,
    tables: &Tables,
    emits_texture: bool,
    o: &ObjectDesc,
    op: &KeyPath,
) -> Result<(), Invalid> {
    if !mat.bsdf.reads_uv(tables) && !emits_texture {
        return Ok(());
    }
    let why = match shape {
        Shape::Mesh(m) if m.mesh.has_uvs() => return Ok(()),
        Shape::Mesh(_) => format!(
            "its material has a texture, but `{}` gives no texture coordinates",
            o.file.as_deref().unwrap_or_default()
        ),
        _ => "its material has a texture, which needs a mesh with texture coordinates".into(),
    };
    Err((op.key("material"), why))
}

/// The index of material `name`, or an error at `path` listing the defined ones.
fn material_index(names: &BTreeMap<&str, u32>, name: &str, path: &KeyPath) -> Result<u32, Invalid> {
    names.get(name).copied().ok_or_else(|| {
        let known: Vec<&str> = names.keys().copied().collect();
        (
            path.clone(),
            format!(
                "material `{name}` is not defined (defined: {})",
                if known.is_empty() {
                    "none".to_string()
                } else {
                    known.join(", ")
                }
            ),
        )
    })
}

/// A glTF object: its file's meshes, materials, lights and cameras, placed by its transform.
fn build_gltf(
    o: &ObjectDesc,
    op: &KeyPath,
    names: &BTreeMap<&str, u32>,
    tables: &mut MaterialTables,
    (files, limits, assets, lent): (
        &mut SceneFiles,
        &Limits,
        &dyn Assets,
        &mut Option<super::gltf::Lent>,
    ),
) -> Result<super::gltf::Imported, Invalid> {
    only(
        op,
        "a gltf object",
        &shape_keys(o),
        &["file", "materials_map", "distribution"],
    )?;
    if o.material.is_some() {
        return Err((
            op.key("material"),
            "a gltf object's materials are its file's; replace them by name with \
             `materials_map = { \"file's name\" = \"scene's name\" }`"
                .into(),
        ));
    }
    let file = required(o.file.as_deref(), op, "a gltf object", "file")?;
    let ext = file.rsplit_once('.').map(|(_, e)| e.to_ascii_lowercase());
    if !matches!(ext.as_deref(), Some("gltf" | "glb")) {
        return Err((
            op.key("file"),
            format!("`{file}`: a gltf object's file must be .gltf or .glb (by its extension)"),
        ));
    }
    let xf = object_transform(o, op)?;
    let mut overrides = BTreeMap::new();
    for (from, to) in o.materials_map.iter().flatten() {
        let path = op.key("materials_map").key(from);
        overrides.insert(from.clone(), material_index(names, to, &path)?);
    }
    // A file read and parsed already (a glTF file loaded as a whole scene) is not parsed again.
    let lent = lent.take_if(|l| l.is(file));
    super::gltf::import(
        file,
        xf,
        (&overrides, o.distribution.unwrap_or_default()),
        tables,
        (files, lent),
        limits,
        assets,
        &op.key("file"),
    )
}

/// A mesh object: one shape per material group of its file, each with its material.
fn build_mesh(
    o: &ObjectDesc,
    op: &KeyPath,
    material: u32,
    names: &BTreeMap<&str, u32>,
    files: &mut SceneFiles,
    limits: &Limits,
    assets: &dyn Assets,
) -> Result<Vec<(Shape, u32)>, Invalid> {
    only(
        op,
        "a mesh",
        &shape_keys(o),
        &["file", "smooth", "materials_map"],
    )?;
    let file = required(o.file.as_deref(), op, "a mesh", "file")?;
    let xf = object_transform(o, op)?;
    let smooth = o.smooth.unwrap_or(false);
    let map = o.materials_map.clone().unwrap_or_default();
    let mut mapped = BTreeMap::new();
    for (from, to) in &map {
        let path = op.key("materials_map").key(from);
        mapped.insert(from.as_str(), material_index(names, to, &path)?);
    }
    let groups = files.get(file, &op.key("file"), limits, assets)?;
    for from in mapped.keys() {
        if !groups.iter().any(|(g, _)| g.as_deref() == Some(*from)) {
            let known: Vec<&str> = groups.iter().filter_map(|(g, _)| g.as_deref()).collect();
            return Err((
                op.key("materials_map").key(from),
                format!(
                    "`{file}` has no material group `{from}` (it has: {})",
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        }
    }
    let xf = Transformed::new(xf);
    Ok(groups
        .iter()
        .map(|(group, mesh)| {
            let m = group
                .as_deref()
                .and_then(|g| mapped.get(g).copied())
                .unwrap_or(material);
            let instance = MeshInstance {
                mesh: Arc::clone(mesh),
                xf: xf.clone(),
                smooth,
            };
            (Shape::Mesh(instance), m)
        })
        .collect())
}

/// The film's size, within the limits.
/// `[render] denoise`, checked: a known quality.
fn denoise(d: Option<&super::format::DenoiseDesc>) -> Result<Option<super::Denoise>, Invalid> {
    let Some(d) = d.filter(|d| d.on) else {
        return Ok(None);
    };
    let quality = d.quality.as_deref().unwrap_or("high");
    if !["fast", "balanced", "high"].contains(&quality) {
        return Err((
            root("render").key("denoise").key("quality"),
            format!("{quality:?} is not fast, balanced or high"),
        ));
    }
    Ok(Some(super::Denoise {
        quality: quality.to_string(),
        hdr: !d.ldr,
    }))
}

fn film_size(desc: &SceneFile, limits: &Limits) -> Result<(u32, u32), Invalid> {
    let fp = root("film");
    let (w, h) = (desc.film.width, desc.film.height);
    for (name, v) in [("width", w), ("height", h)] {
        if v == 0 {
            return Err((fp.key(name), "must be at least 1".into()));
        }
        if v > limits.max_resolution {
            return Err((
                fp.key(name),
                format!("{v} is above the limit of {}", limits.max_resolution),
            ));
        }
    }
    if w as u64 * h as u64 > limits.max_pixels {
        return Err((
            fp.clone(),
            format!("{w}×{h} is above the limit of {} pixels", limits.max_pixels),
        ));
    }
    Ok((w, h))
}

/// The camera of a `w` × `h` film.
fn build_camera(desc: &SceneFile, w: u32, h: u32) -> Result<Camera, Invalid> {
    let fp = root("film");
    let cp = root("camera");
    let c = &desc.camera;
    let model = match c.model {
        CameraModel::LookAt => "a look_at camera",
        _ => "a pitch_yaw camera",
    };
    for (key, given) in [("name", c.name.is_some()), ("index", c.index.is_some())] {
        if given {
            return Err((
                cp.key(key),
                format!("{model} does not take `{key}` (a gltf camera does)"),
            ));
        }
    }
    let eye = finite3(required(c.eye, &cp, model, "eye")?, &cp.key("eye"))?;
    let fov = finite(required(c.fov, &cp, model, "fov")?, &cp.key("fov"))?;
    if !(fov > 0.0 && fov < 180.0) {
        return Err((
            cp.key("fov"),
            format!("field of view must be in (0°, 180°), got {fov}°"),
        ));
    }
    let present = [
        ("target", c.target.is_some()),
        ("up", c.up.is_some()),
        ("pitch", c.pitch.is_some()),
        ("yaw", c.yaw.is_some()),
    ];
    let camera = match c.model {
        CameraModel::LookAt => {
            only(&cp, "a look_at camera", &present, &["target", "up"])?;
            let target = required(c.target, &cp, "a look_at camera", "target")?;
            let target = finite3(target, &cp.key("target"))?;
            let up = finite3(c.up.unwrap_or([0.0, 1.0, 0.0]), &cp.key("up"))?;
            Camera::look_at(eye, target, up, fov.to_radians(), w, h).ok_or_else(|| {
                (
                    cp.clone(),
                    "degenerate camera: target equals eye, or up is parallel to the view direction"
                        .to_string(),
                )
            })?
        }
        CameraModel::Gltf => unreachable!("a gltf camera is built by gltf::camera"),
        CameraModel::PitchYaw => {
            only(&cp, "a pitch_yaw camera", &present, &["pitch", "yaw"])?;
            if w < 2 {
                return Err((
                    fp.key("width"),
                    "the pitch_yaw camera needs a width of at least 2 (its field of view spans the outermost pixel centres)"
                        .into(),
                ));
            }
            let pitch = finite(c.pitch.unwrap_or(0.0), &cp.key("pitch"))?;
            let yaw = finite(c.yaw.unwrap_or(0.0), &cp.key("yaw"))?;
            Camera::pitch_yaw(
                eye,
                pitch.to_radians(),
                yaw.to_radians(),
                fov.to_radians(),
                w,
                h,
            )
        }
    };
    Ok(camera)
}

/// Which of the keys that belong to some shapes only an object gives, for [`only`].
fn shape_keys(o: &ObjectDesc) -> [(&'static str, bool); 11] {
    [
        ("center", o.center.is_some()),
        ("radius", o.radius.is_some()),
        ("min", o.min.is_some()),
        ("max", o.max.is_some()),
        ("size", o.size.is_some()),
        ("point", o.point.is_some()),
        ("normal", o.normal.is_some()),
        ("file", o.file.is_some()),
        ("smooth", o.smooth.is_some()),
        ("materials_map", o.materials_map.is_some()),
        ("distribution", o.distribution.is_some()),
    ]
}

/// An object's own transform (the identity without one).
fn object_transform(o: &ObjectDesc, op: &KeyPath) -> Result<Affine3A, Invalid> {
    match &o.transform {
        Some(t) => build_transform(t, &op.key("transform")),
        None => Ok(Affine3A::IDENTITY),
    }
}

/// An object's shape, in world space. `emits` rules out shapes that cannot be lights.
fn build_shape(o: &ObjectDesc, op: &KeyPath, emits: bool) -> Result<Shape, Invalid> {
    let xf = object_transform(o, op)?;
    let present = shape_keys(o);
    let shape = match o.shape {
        ShapeKind::Mesh | ShapeKind::Gltf => {
            unreachable!("files are built by build_mesh, build_gltf")
        }
        ShapeKind::Sphere => {
            only(op, "a sphere", &present, &["center", "radius"])?;
            let c = finite3(o.center.unwrap_or([0.0; 3]), &op.key("center"))?;
            let r = positive(o.radius.unwrap_or(1.0), &op.key("radius"))?;
            match similarity_scale(&xf) {
                Some(s) => Shape::Sphere {
                    center: xf.transform_point3a(c),
                    radius: r * s,
                },
                None => {
                    if emits {
                        return Err((op.key("transform"), "an emissive sphere must use a uniform scale (light sampling needs a true sphere)".into()));
                    }
                    let m = xf
                        * Affine3A::from_translation(c.into())
                        * Affine3A::from_scale(Vec3::splat(r));
                    Shape::Ellipsoid(Transformed::new(m))
                }
            }
        }
        ShapeKind::Box => {
            only(op, "a box", &present, &["min", "max"])?;
            let lo = finite3(o.min.unwrap_or([-1.0; 3]), &op.key("min"))?;
            let hi = finite3(o.max.unwrap_or([1.0; 3]), &op.key("max"))?;
            if !(hi.cmpgt(lo).all()) {
                return Err((
                    op.key("max"),
                    format!(
                        "box size must be positive on every axis: min {:?}, max {:?}",
                        lo.to_array(),
                        hi.to_array()
                    ),
                ));
            }
            Shape::Cuboid {
                min: lo,
                max: hi,
                xf: Transformed::new(xf),
            }
        }
        ShapeKind::Rect => {
            only(op, "a rect", &present, &["size"])?;
            let [sw, sh] = o.size.unwrap_or([2.0, 2.0]);
            let sw = positive(sw, &op.key("size").index(0))?;
            let sh = positive(sh, &op.key("size").index(1))?;
            let t = Transformed::new(xf);
            let p0 = xf.transform_point3a(Vec3A::new(-sw / 2.0, -sh / 2.0, 0.0));
            let e1 = xf.transform_vector3a(Vec3A::new(sw, 0.0, 0.0));
            let e2 = xf.transform_vector3a(Vec3A::new(0.0, sh, 0.0));
            let n = (t.normal_matrix * Vec3A::Z).normalize();
            Shape::Parallelogram(crate::shape::Parallelogram::new(p0, e1, e2, n))
        }
        ShapeKind::Plane => {
            only(op, "a plane", &present, &["point", "normal"])?;
            if emits {
                return Err((
                    op.key("material"),
                    "an infinite plane cannot emit (its power would be infinite); use a rect"
                        .into(),
                ));
            }
            let p = finite3(o.point.unwrap_or([0.0; 3]), &op.key("point"))?;
            let n = finite3(o.normal.unwrap_or([0.0, 1.0, 0.0]), &op.key("normal"))?;
            let n = n.try_normalize().ok_or_else(|| {
                (
                    op.key("normal"),
                    "plane normal must not be zero".to_string(),
                )
            })?;
            let t = Transformed::new(xf);
            Shape::Plane {
                point: xf.transform_point3a(p),
                normal: (t.normal_matrix * n).normalize(),
            }
        }
    };
    Ok(shape)
}

/// Adds the lights of an emissive shape (one per face of a box) and returns the first one's
/// index.
fn add_lights(shape: &Shape, mat: &Material, lights: &mut Vec<Light>) -> u32 {
    let first = lights.len() as u32;
    let mut add = |s: LightShape| {
        lights.push(Light {
            shape: s,
            radiance: mat.emission,
            two_sided: mat.two_sided,
            texture: None,
        })
    };
    match &shape {
        Shape::Sphere { center, radius } => add(LightShape::Sphere {
            center: *center,
            radius: *radius,
        }),
        Shape::Parallelogram(q) => add(LightShape::Quad(q.clone())),
        Shape::Cuboid { min, max, xf } => {
            for f in Shape::cuboid_faces(*min, *max, xf) {
                add(LightShape::Quad(f));
            }
        }
        Shape::Mesh(m) => {
            // A mesh of zero area emits nothing and has no light to sample.
            if let Some(light) = MeshLight::new(m.world_triangles()) {
                add(LightShape::Mesh(light));
            } else {
                return u32::MAX;
            }
        }
        Shape::Ellipsoid(_) | Shape::Plane { .. } => unreachable!("rejected above"),
    }
    first
}
