//! Scenes: parsing a file (TOML or JSON), validating it, and converting it into the runtime
//! representation the integrator reads.
//!
//! Parsing and validation never panic. Every error names the file, the line:column and the key
//! path, whether it comes from the parser (syntax, unknown key, wrong type) or from validation
//! (a NaN radius, a missing material, a degenerate transform, a limit).

mod format;
mod locate;

use std::fmt;
use std::path::Path;

use glam::{Affine3A, Mat3, Vec3, Vec3A};
use sha2::{Digest, Sha256};

pub use format::*;
pub use locate::{line_col, KeyPath, Seg};

use crate::accel::Accel;
use crate::bsdf::Bsdf;
use crate::camera::Camera;
use crate::light::{Light, LightShape, Lights};
use crate::math::{v3, Ray};
use crate::shape::{Hit, Shape, Transformed};

/// Which syntax a scene is written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// TOML (the default).
    Toml,
    /// JSON.
    Json,
}

impl Format {
    /// Guesses from a file name: `.json` is JSON, anything else TOML.
    pub fn from_path(path: &Path) -> Self {
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("json") => Format::Json,
            _ => Format::Toml,
        }
    }
}

/// Configurable bounds on what a scene may ask for, so that a hostile or mistaken file cannot
/// exhaust memory or time.
#[derive(Clone, Debug)]
pub struct Limits {
    /// Largest width or height in pixels.
    pub max_resolution: u32,
    /// Largest width × height.
    pub max_pixels: u64,
    /// Largest number of objects.
    pub max_objects: usize,
    /// Largest scene text in bytes.
    pub max_bytes: usize,
    /// Largest samples per pixel a render may ask for.
    pub max_spp: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_resolution: 16_384,
            max_pixels: 64 * 1024 * 1024,
            max_objects: 1_000_000,
            max_bytes: 64 * 1024 * 1024,
            max_spp: 1 << 20,
        }
    }
}

/// A scene that failed to load.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct SceneError {
    /// The file (or a name given by the caller).
    pub file: String,
    /// 1-based line; 0 when the problem is not inside the text (an unreadable file).
    pub line: usize,
    /// 1-based column; 0 with line 0.
    pub column: usize,
    /// Key path, e.g. `objects[3].radius`.
    pub path: String,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 {
            // Not a problem inside the text (the file could not be read).
            return write!(f, "{}: {}", self.file, self.message);
        }
        write!(
            f,
            "{}:{}:{}: {}: {}",
            self.file, self.line, self.column, self.path, self.message
        )
    }
}

/// A runtime material.
#[derive(Clone, Copy, Debug)]
pub struct Material {
    /// Scattering.
    pub bsdf: Bsdf,
    /// Emitted radiance (zero for non-emitters).
    pub emission: Vec3A,
    /// Whether the back side reflects and emits like the front. One-sided surfaces (the
    /// default, as in Mitsuba) are black from behind.
    pub two_sided: bool,
}

/// Light from infinitely far away.
#[derive(Clone, Copy, Debug)]
pub enum Environment {
    /// Uniform radiance.
    Constant(Vec3A),
    /// Blend from `bottom` (direction y = −1) to `top` (y = +1).
    Gradient {
        /// Radiance straight up.
        top: Vec3A,
        /// Radiance straight down.
        bottom: Vec3A,
    },
}

impl Environment {
    /// Radiance arriving from direction `-d` along a ray with unit direction `d`.
    #[inline]
    pub fn radiance(&self, d: Vec3A) -> Vec3A {
        match *self {
            Environment::Constant(l) => l,
            Environment::Gradient { top, bottom } => {
                let t = (0.5 * (d.y + 1.0)).clamp(0.0, 1.0);
                bottom * (1.0 - t) + top * t
            }
        }
    }
}

/// One object of the runtime scene.
#[derive(Clone, Debug)]
pub struct Primitive {
    /// Geometry.
    pub shape: Shape,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// Index of this primitive's first light in [`Scene::lights`] (a box has one per face),
    /// or `u32::MAX` if it does not emit.
    pub light: u32,
}

/// The runtime scene: everything needed to render, in the form the integrator reads.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Camera.
    pub camera: Camera,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Primitives.
    pub prims: Vec<Primitive>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Emitters.
    pub lights: Lights,
    /// Environment, if any.
    pub environment: Option<Environment>,
    /// Bounce limit, if any.
    pub max_depth: Option<u32>,
    /// SHA-256 of the scene text, hex: the scene's content address.
    pub hash: String,
    accel: Accel,
}

impl Scene {
    /// Reads, parses, validates and builds a scene file.
    pub fn load(path: &Path, limits: &Limits) -> Result<Self, SceneError> {
        let file = path.display().to_string();
        let meta = std::fs::metadata(path).map_err(|e| io_error(&file, e))?;
        if meta.len() > limits.max_bytes as u64 {
            return Err(at_start(
                &file,
                format!(
                    "scene is {} bytes, above the limit of {}",
                    meta.len(),
                    limits.max_bytes
                ),
            ));
        }
        let text = std::fs::read_to_string(path).map_err(|e| io_error(&file, e))?;
        Self::from_str(&text, Format::from_path(path), &file, limits)
    }

    /// Parses, validates and builds a scene from text; `file` names it in errors.
    pub fn from_str(
        text: &str,
        format: Format,
        file: &str,
        limits: &Limits,
    ) -> Result<Self, SceneError> {
        if text.len() > limits.max_bytes {
            return Err(at_start(
                file,
                format!(
                    "scene is {} bytes, above the limit of {}",
                    text.len(),
                    limits.max_bytes
                ),
            ));
        }
        let desc = parse(text, format, file)?;
        let mut scene = build(&desc, limits)
            .map_err(|(path, message)| locate(text, format, file, &path, message))?;
        scene.hash = hex(&Sha256::digest(text.as_bytes()));
        Ok(scene)
    }

    /// Closest hit along `ray` with t in (0, t_max).
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        self.accel.intersect(&self.prims, ray, t_max)
    }

    /// Whether anything blocks `ray` for t in (0, t_max).
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        self.accel.occluded(&self.prims, ray, t_max)
    }

    /// Whether the whole scene is one BVH leaf with nothing unbounded: the scenes whose
    /// queries the packet tests answer ([`Accel::is_one_leaf`]).
    pub fn is_one_leaf(&self) -> bool {
        self.accel.is_one_leaf()
    }

    /// The scene's ray queries.
    pub fn accel(&self) -> &Accel {
        &self.accel
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn io_error(file: &str, e: std::io::Error) -> SceneError {
    SceneError {
        file: file.into(),
        line: 0,
        column: 0,
        path: String::new(),
        message: format!("cannot read the scene: {e}"),
    }
}

fn at_start(file: &str, message: String) -> SceneError {
    SceneError {
        file: file.into(),
        line: 1,
        column: 1,
        path: "(document)".into(),
        message,
    }
}

fn locate(text: &str, format: Format, file: &str, path: &KeyPath, message: String) -> SceneError {
    let span = match format {
        Format::Toml => locate::toml_span(text, path),
        Format::Json => locate::json_span(text, path),
    };
    let (line, column) = span.map_or((1, 1), |s| line_col(text, s.start));
    SceneError {
        file: file.into(),
        line,
        column,
        path: path.to_string(),
        message,
    }
}

fn convert_path(p: &serde_path_to_error::Path) -> KeyPath {
    use serde_path_to_error::Segment;
    KeyPath(
        p.iter()
            .filter_map(|s| match s {
                Segment::Seq { index } => Some(Seg::Index(*index)),
                Segment::Map { key } => Some(Seg::Key(key.clone())),
                Segment::Enum { .. } | Segment::Unknown => None,
            })
            .collect(),
    )
}

/// serde reports an unknown key against its parent table; name the key itself.
fn unknown_key_path(mut path: KeyPath, message: &str) -> KeyPath {
    if let Some(rest) = message.strip_prefix("unknown field `") {
        if let Some(name) = rest.split('`').next() {
            if path.0.last() != Some(&Seg::Key(name.to_string())) {
                path.0.push(Seg::Key(name.to_string()));
            }
        }
    }
    path
}

fn parse(text: &str, format: Format, file: &str) -> Result<SceneFile, SceneError> {
    match format {
        Format::Toml => {
            let de = toml::Deserializer::new(text);
            serde_path_to_error::deserialize::<_, SceneFile>(de).map_err(|e| {
                let path = convert_path(e.path());
                let inner = e.into_inner();
                let mut message = inner.message().trim().to_string();
                if path.0.is_empty() && inner.span().is_some() {
                    message = format!("syntax error: {message}");
                }
                let path = unknown_key_path(path, &message);
                let (line, column) = match inner.span() {
                    Some(s) => line_col(text, s.start),
                    None => {
                        locate::toml_span(text, &path).map_or((1, 1), |s| line_col(text, s.start))
                    }
                };
                SceneError {
                    file: file.into(),
                    line,
                    column,
                    path: path.to_string(),
                    message,
                }
            })
        }
        Format::Json => {
            let mut de = serde_json::Deserializer::from_str(text);
            let r = serde_path_to_error::deserialize::<_, SceneFile>(&mut de)
                .map_err(|e| (convert_path(e.path()), e.into_inner()))
                .and_then(|v| de.end().map(|()| v).map_err(|e| (KeyPath::default(), e)));
            r.map_err(|(path, inner)| {
                let full = inner.to_string();
                // serde_json appends " at line L column C"; keep the message without it.
                let message = full.split(" at line ").next().unwrap_or(&full).to_string();
                let path = unknown_key_path(path, &message);
                SceneError {
                    file: file.into(),
                    line: inner.line(),
                    column: inner.column(),
                    path: path.to_string(),
                    message,
                }
            })
        }
    }
}

type Invalid = (KeyPath, String);

fn root(k: &str) -> KeyPath {
    KeyPath(vec![Seg::Key(k.to_string())])
}

fn finite3(v: [f32; 3], path: &KeyPath) -> Result<Vec3A, Invalid> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v3(v))
    } else {
        Err((path.clone(), format!("must be finite numbers, got {v:?}")))
    }
}

fn color(v: [f32; 3], path: &KeyPath, max_one: bool) -> Result<Vec3A, Invalid> {
    let c = finite3(v, path)?;
    if c.min_element() < 0.0 {
        return Err((path.clone(), format!("must not be negative, got {v:?}")));
    }
    if max_one && c.max_element() > 1.0 {
        return Err((
            path.clone(),
            format!(
                "must be at most 1 (a surface cannot reflect more than it receives), got {v:?}"
            ),
        ));
    }
    Ok(c)
}

fn positive(x: f32, path: &KeyPath) -> Result<f32, Invalid> {
    if x.is_finite() && x > 0.0 {
        Ok(x)
    } else {
        Err((
            path.clone(),
            format!("must be a finite number greater than 0, got {x}"),
        ))
    }
}

fn finite(x: f32, path: &KeyPath) -> Result<f32, Invalid> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err((path.clone(), format!("must be a finite number, got {x}")))
    }
}

/// Rejects fields that do not belong to the chosen kind, so a typo'd or misplaced key is an
/// error rather than silently ignored.
fn only(
    path: &KeyPath,
    kind: &str,
    present: &[(&str, bool)],
    allowed: &[&str],
) -> Result<(), Invalid> {
    for (name, is) in present {
        if *is && !allowed.contains(name) {
            return Err((path.key(name), format!("`{name}` does not apply to {kind}")));
        }
    }
    Ok(())
}

/// The value of a key that `kind` cannot do without, or an error at that key saying so.
fn required<T>(value: Option<T>, path: &KeyPath, kind: &str, name: &str) -> Result<T, Invalid> {
    value.ok_or_else(|| (path.key(name), format!("{kind} needs `{name}`")))
}

fn build_transform(t: &TransformDesc, path: &KeyPath) -> Result<Affine3A, Invalid> {
    let m = if let Some(rows) = t.matrix {
        if t.translate.is_some() || t.rotate.is_some() || t.scale.is_some() {
            return Err((
                path.key("matrix"),
                "give either `matrix` or translate/rotate/scale, not both".into(),
            ));
        }
        for (r, row) in rows.iter().enumerate() {
            for (c, x) in row.iter().enumerate() {
                if !x.is_finite() {
                    return Err((
                        path.key("matrix").index(r),
                        format!("element {c} must be finite, got {x}"),
                    ));
                }
            }
        }
        if rows[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err((
                path.key("matrix").index(3),
                format!(
                    "the last row of an affine matrix must be [0, 0, 0, 1], got {:?}",
                    rows[3]
                ),
            ));
        }
        let col = |c: usize| Vec3::new(rows[0][c], rows[1][c], rows[2][c]);
        Affine3A::from_mat3_translation(Mat3::from_cols(col(0), col(1), col(2)), col(3))
    } else {
        let mut m = Affine3A::IDENTITY;
        if let Some(s) = t.scale {
            let s = finite3(s, &path.key("scale"))?;
            m = Affine3A::from_scale(s.into()) * m;
        }
        if let Some(r) = &t.rotate {
            let rp = path.key("rotate");
            let axis = finite3(r.axis, &rp.key("axis"))?;
            let axis = axis
                .try_normalize()
                .ok_or_else(|| (rp.key("axis"), "rotation axis must not be zero".to_string()))?;
            let deg = finite(r.degrees, &rp.key("degrees"))?;
            // In f64, rounded once: f32 `sin_cos` is picked per CPU at load time and may round
            // differently, and every worker must build the same geometry bits.
            let r = glam::DMat3::from_axis_angle(axis.as_dvec3(), f64::from(deg).to_radians());
            let r = Mat3::from_cols(r.x_axis.as_vec3(), r.y_axis.as_vec3(), r.z_axis.as_vec3());
            m = Affine3A::from_mat3(r) * m;
        }
        if let Some(tr) = t.translate {
            let tr = finite3(tr, &path.key("translate"))?;
            m = Affine3A::from_translation(tr.into()) * m;
        }
        m
    };
    let lin = m.matrix3;
    let det = lin.determinant();
    let scale = lin.x_axis.length() * lin.y_axis.length() * lin.z_axis.length();
    if !(det.abs() > 1e-6 * scale) || !det.is_finite() || scale == 0.0 {
        return Err((
            path.clone(),
            format!("transform is degenerate (determinant {det:e}): it flattens the shape"),
        ));
    }
    Ok(m)
}

/// Whether the linear part is a rotation times a uniform scale; returns the scale.
fn similarity_scale(m: &Affine3A) -> Option<f32> {
    let (x, y, z) = (m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis);
    let (lx, ly, lz) = (x.length(), y.length(), z.length());
    let tol = 1e-5 * lx;
    let ortho =
        x.dot(y).abs() <= tol * ly && y.dot(z).abs() <= tol * lz && x.dot(z).abs() <= tol * lz;
    ((lx - ly).abs() <= tol && (lx - lz).abs() <= tol && ortho).then_some(lx)
}

fn build(desc: &SceneFile, limits: &Limits) -> Result<Scene, Invalid> {
    if desc.version != 1 {
        return Err((
            root("version"),
            format!(
                "unsupported version {}; this tessera reads version 1",
                desc.version
            ),
        ));
    }
    // Film.
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
    // Camera.
    let cp = root("camera");
    let c = &desc.camera;
    let eye = finite3(c.eye, &cp.key("eye"))?;
    let fov = finite(c.fov, &cp.key("fov"))?;
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
    // Environment.
    let environment = match &desc.environment {
        None => None,
        Some(e) => {
            let ep = root("environment");
            let present = [
                ("radiance", e.radiance.is_some()),
                ("top", e.top.is_some()),
                ("bottom", e.bottom.is_some()),
            ];
            Some(match e.kind {
                EnvironmentKind::Constant => {
                    only(&ep, "a constant environment", &present, &["radiance"])?;
                    let r = required(e.radiance, &ep, "a constant environment", "radiance")?;
                    Environment::Constant(color(r, &ep.key("radiance"), false)?)
                }
                EnvironmentKind::Gradient => {
                    only(&ep, "a gradient environment", &present, &["top", "bottom"])?;
                    let top = required(e.top, &ep, "a gradient environment", "top")?;
                    let bottom = required(e.bottom, &ep, "a gradient environment", "bottom")?;
                    Environment::Gradient {
                        top: color(top, &ep.key("top"), false)?,
                        bottom: color(bottom, &ep.key("bottom"), false)?,
                    }
                }
            })
        }
    };
    // Materials.
    let mut materials = Vec::with_capacity(desc.materials.len());
    let mut names = std::collections::BTreeMap::new();
    for (name, m) in &desc.materials {
        let mp = root("materials").key(name);
        let present = [
            ("albedo", m.albedo.is_some()),
            ("reflectance", m.reflectance.is_some()),
            ("ior", m.ior.is_some()),
        ];
        let bsdf = match m.kind {
            MaterialKind::Diffuse => {
                only(&mp, "a diffuse material", &present, &["albedo"])?;
                let a = required(m.albedo, &mp, "a diffuse material", "albedo")?;
                Bsdf::Diffuse(color(a, &mp.key("albedo"), true)?)
            }
            MaterialKind::Mirror => {
                only(&mp, "a mirror material", &present, &["reflectance"])?;
                Bsdf::Mirror(color(
                    m.reflectance.unwrap_or([1.0; 3]),
                    &mp.key("reflectance"),
                    true,
                )?)
            }
            MaterialKind::Dielectric => {
                only(&mp, "a dielectric material", &present, &["ior"])?;
                let ior = required(m.ior, &mp, "a dielectric material", "ior")?;
                Bsdf::Dielectric(positive(ior, &mp.key("ior"))?)
            }
        };
        let emission = match m.emission {
            Some(e) => color(e, &mp.key("emission"), false)?,
            None => Vec3A::ZERO,
        };
        if m.two_sided.is_some() && m.kind == MaterialKind::Dielectric && m.emission.is_none() {
            return Err((
                mp.key("two_sided"),
                "a dielectric has two sides by nature; `two_sided` does not apply".into(),
            ));
        }
        names.insert(name.as_str(), materials.len() as u32);
        materials.push(Material {
            bsdf,
            emission,
            two_sided: m.two_sided.unwrap_or(false),
        });
    }
    // Objects.
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
    let mut prims = Vec::with_capacity(desc.objects.len());
    let mut lights = Vec::new();
    for (i, o) in desc.objects.iter().enumerate() {
        let op = root("objects").index(i);
        let material = *names.get(o.material.as_str()).ok_or_else(|| {
            let known: Vec<&str> = names.keys().copied().collect();
            (
                op.key("material"),
                format!(
                    "material `{}` is not defined (defined: {})",
                    o.material,
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            )
        })?;
        let emits = materials[material as usize].emission.max_element() > 0.0;
        let xf = match &o.transform {
            Some(t) => build_transform(t, &op.key("transform"))?,
            None => Affine3A::IDENTITY,
        };
        let present = [
            ("center", o.center.is_some()),
            ("radius", o.radius.is_some()),
            ("min", o.min.is_some()),
            ("max", o.max.is_some()),
            ("size", o.size.is_some()),
            ("point", o.point.is_some()),
            ("normal", o.normal.is_some()),
        ];
        let shape = match o.shape {
            ShapeKind::Sphere => {
                only(&op, "a sphere", &present, &["center", "radius"])?;
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
                only(&op, "a box", &present, &["min", "max"])?;
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
                only(&op, "a rect", &present, &["size"])?;
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
                only(&op, "a plane", &present, &["point", "normal"])?;
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
        let bounds = shape.bounds();
        if o.shape != ShapeKind::Plane && !bounds.is_finite() {
            return Err((
                op.clone(),
                "object is too large: its bounds overflow f32".into(),
            ));
        }
        let mat = &materials[material as usize];
        let light = if emits {
            let first = lights.len() as u32;
            let mut add = |s: LightShape| {
                lights.push(Light {
                    shape: s,
                    radiance: mat.emission,
                    two_sided: mat.two_sided,
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
                Shape::Ellipsoid(_) | Shape::Plane { .. } => unreachable!("rejected above"),
            }
            first
        } else {
            u32::MAX
        };
        prims.push(Primitive {
            shape,
            material,
            light,
        });
    }
    let accel = Accel::build(&prims);
    Ok(Scene {
        camera,
        width: w,
        height: h,
        prims,
        materials,
        lights: Lights::new(lights),
        environment,
        max_depth: desc.render.max_depth,
        hash: String::new(),
        accel,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::HashRng;
    use glam::Vec3A;

    /// The BVH with its SIMD leaves finds what a brute-force scalar loop over every primitive
    /// finds, for closest hits and shadow rays, in each bundled scene.
    #[test]
    fn leaves_and_bvh_agree_with_brute_force() {
        for name in ["cornell-box", "spheres", "glass-mirror"] {
            let path = format!("{}/../../scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
            let scene = Scene::load(path.as_ref(), &Limits::default()).expect("scene loads");
            let mut rng = HashRng::new(5);
            let mut v =
                |s: f32| Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 2.0 * s - s;
            let mut hits = 0;
            for i in 0..20_000 {
                let ray = Ray::new(v(1.5), v(1.0));
                let t_max = if i % 2 == 0 { f32::INFINITY } else { 1.0 };
                let mut brute: Option<(f32, u32)> = None;
                for (p, prim) in scene.prims.iter().enumerate() {
                    let limit = brute.map_or(t_max, |b| b.0);
                    if let Some((t, _)) = prim.shape.intersect(&ray, limit) {
                        brute = Some((t, p as u32));
                    }
                }
                let got = scene.intersect(&ray, t_max);
                assert_eq!(got.map(|h| h.t), brute.map(|b| b.0), "{name}: {ray:?}");
                if let (Some(h), Some((_, p))) = (got, brute) {
                    // Equal t from two primitives (an edge shared by two walls) may pick
                    // either; otherwise the primitive must match.
                    let same_t_other = scene.prims[h.prim as usize]
                        .shape
                        .intersect(&ray, t_max)
                        .is_some_and(|(t, _)| t == h.t);
                    assert!(h.prim == p || same_t_other, "{name}: {ray:?}");
                    hits += 1;
                }
                assert_eq!(
                    scene.occluded(&ray, t_max),
                    brute.is_some(),
                    "{name}: {ray:?}"
                );
            }
            assert!(hits > 5_000, "{name}: the rays must hit often ({hits})");
        }
    }
}
