//! Scenes: parsing a file (TOML or JSON), validating it, and converting it into the runtime
//! representation the integrator reads.
//!
//! Parsing and validation never panic. Every error names the file, the line:column and the key
//! path, whether it comes from the parser (syntax, unknown key, wrong type) or from validation
//! (a NaN radius, a missing material, a degenerate transform, a limit).

mod alpha;
mod animate;
pub mod assets;
mod build;
mod check;
mod files;
mod format;
mod frames;
mod gltf;
mod lights;
mod load;
mod locate;
mod materials;
mod merge;
mod parse;

use parse::hex;

use std::fmt;
use std::path::Path;

use glam::Vec3A;

pub use crate::util::fields::{KeyPath, Seg};
pub use alpha::AlphaTest;
pub use format::*;
pub use frames::{BadFrameRange, FrameRange};
pub use gltf::{is_gltf, scene_text as gltf_scene_text, GltfOptions};
pub use load::{scene_source, Load};
pub use locate::line_col;

/// The frame a scene is built at when none is asked for: frames are numbered from 1, as farm
/// users number them (`--frames 1-240`).
pub const FIRST_FRAME: u32 = 1;

use crate::aggregate::Accel;
use crate::camera::Camera;
use crate::light::Lights;
use crate::material::{Bsdf, Tables};
pub use crate::primitive::Primitive;
use crate::shape::Hit;
use crate::util::math::{Aabb, Ray};

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

/// What a render asks of a scene file besides its text: which frame of its `[animation]`, and
/// a film size in place of the file's own (`--resolution`), applied before the scene is built
/// so that the camera frames the new size as it frames the file's. A frame number converts
/// into a shot of the file's own size.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Shot {
    /// The frame ([`FIRST_FRAME`] for a still).
    pub frame: u32,
    /// Width and height in pixels, if not the file's.
    pub resolution: Option<(u32, u32)>,
}

impl From<u32> for Shot {
    fn from(frame: u32) -> Self {
        Self {
            frame,
            resolution: None,
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
    /// Largest mesh file in bytes.
    pub max_asset_bytes: u64,
    /// Largest number of distinct files a scene may name.
    pub max_assets: usize,
    /// Largest number of triangles over the scene's distinct meshes (instances of one mesh
    /// count once: they share it).
    pub max_triangles: usize,
    /// Largest number of placed shapes: a TOML scene's objects, and every glTF node's mesh
    /// primitives (each a shape of its own, with its transform and its BVH entry, which cost
    /// memory even when they share their triangles). A glTF file's node tree is counted
    /// before anything is built, so a small file that places a mesh of many primitives under
    /// many nodes (an instance bomb) is refused before it allocates.
    pub max_instances: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_resolution: 16_384,
            max_pixels: 64 * 1024 * 1024,
            max_objects: 1_000_000,
            max_bytes: 64 * 1024 * 1024,
            max_spp: 1 << 20,
            max_asset_bytes: 2 << 30,
            max_assets: 1024,
            max_triangles: 64 << 20,
            max_instances: 1 << 20,
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
    /// Key path, e.g. `objects[3].radius`; inside a glTF file loaded as the scene (line 0), a
    /// JSON pointer (`/meshes/0/primitives/1/indices`), or empty for the file as a whole.
    pub path: String,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 {
            // Not a problem at a line of the text: the file could not be read, or the problem
            // is at a place in a binary or generated file (a glTF file's JSON pointer).
            return match self.path.as_str() {
                "" => write!(f, "{}: {}", self.file, self.message),
                at => write!(f, "{}: {at}: {}", self.file, self.message),
            };
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
#[derive(Clone, Debug)]
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
    /// An HDR image ([`crate::envmap`]), which light sampling draws from too.
    Map {
        /// The map.
        map: std::sync::Arc<crate::envmap::EnvMap>,
        /// Its index among [`Scene::lights`], for the MIS weight of a ray that escapes.
        light: u32,
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
            Environment::Map { ref map, .. } => map.radiance(d),
        }
    }
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
    /// The denoising the scene file asks for (`[render] denoise`), if any.
    pub denoise: Option<Denoise>,
    /// The scene's content address, hex: the SHA-256 of its text, and of the files it read
    /// where it read any ([`assets::scene_hash`]).
    pub hash: String,
    /// The files the scene read (its meshes): name as the scene gives it, and SHA-256 hex.
    pub files: Vec<(String, String)>,
    /// Textures, which materials name by index.
    pub textures: Vec<std::sync::Arc<crate::texture::Texture>>,
    accel: Accel,
    shading_normals: bool,
    /// Each material's absorption per unit length inside (zero: clear), kept apart from
    /// [`Material`] so that the materials every bounce reads stay as small as they were; empty
    /// when no material absorbs.
    absorption: Vec<Vec3A>,
    /// The plastics and glTF materials that [`Bsdf::Plastic`] and [`Bsdf::Pbr`] materials
    /// index.
    tables: Tables,
    /// Each material's alpha test, by material index; empty when no material has one, which
    /// is every scene but glTF files with `MASK` or `BLEND` materials.
    alpha: Vec<Option<AlphaTest>>,
    /// What the scene's files ask for that is not rendered as they ask (a glTF file's alpha
    /// blending, say), one line each, for the user to see.
    pub warnings: Vec<String>,
}

/// What a scene is, as [`Load::check`] finds it.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneCheck {
    /// The scene's content address ([`Scene::hash`]).
    pub hash: String,
    /// Film width in pixels.
    pub width: u32,
    /// Film height in pixels.
    pub height: u32,
    /// The files the scene read ([`Scene::files`]).
    pub files: Vec<(String, String)>,
    /// The box around its bounded shapes ([`crate::guiding::guide_bounds`]).
    pub bounds: [[f32; 3]; 2],
    /// The denoising the scene file asks for ([`Scene::denoise`]).
    pub denoise: Option<Denoise>,
}

/// A scene file's `[render] denoise`, checked: what `tessera render` and the farm do when no
/// flag says otherwise.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Denoise {
    /// `fast`, `balanced` or `high`.
    pub quality: String,
    /// Filter as HDR (linear radiance); false for `ldr = true`.
    pub hdr: bool,
}

/// The box around the bounded ones of `prims` (an infinite plane is left out).
pub(crate) fn shape_bounds(prims: &[Primitive]) -> [[f32; 3]; 2] {
    let b = prims.iter().fold(Aabb::EMPTY, |b, p| {
        let o = p.shape.bounds();
        if o.min.is_finite() && o.max.is_finite() {
            Aabb {
                min: b.min.min(o.min),
                max: b.max.max(o.max),
            }
        } else {
            b
        }
    });
    [b.min.to_array(), b.max.to_array()]
}

impl Scene {
    /// Closest hit along `ray` with t in (0, t_max).
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        let hit = self.accel.intersect(&self.prims, ray, t_max);
        if self.alpha.is_empty() {
            return hit;
        }
        self.alpha_tested(ray, t_max, hit?)
    }

    /// Whether anything blocks `ray` for t in (0, t_max).
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        if self.alpha.is_empty() {
            return self.accel.occluded(&self.prims, ray, t_max);
        }
        // Any surface may be cut out where the ray meets it: the closest kept one decides.
        self.intersect(ray, t_max).is_some()
    }

    /// The radiance an emitting primitive's surface point `sp`, hit as `hit` by `ray`, sends
    /// back along the ray (its emission texture's texel included), with the index of the
    /// light it belongs to. For a primitive whose `light` is set.
    #[inline]
    pub(crate) fn emitted(
        &self,
        (ray, hit, prim, sp): (&Ray, &Hit, &Primitive, &crate::interaction::SurfacePoint),
    ) -> (usize, Vec3A) {
        let li = (prim.light + hit.part * prim.light_stride) as usize;
        let light = &self.lights.lights[li];
        let mut le = light.emitted(sp.n, -ray.d);
        if let Some(t) = &light.texture {
            le *= t.texture.lookup(prim.shape.uv(ray, hit.part));
        }
        (li, le)
    }

    /// Whether the whole scene is one BVH leaf with nothing unbounded: the scenes whose
    /// queries the packet tests answer ([`Accel::is_one_leaf`]).
    pub fn is_one_leaf(&self) -> bool {
        self.accel.is_one_leaf()
    }

    /// Whether any surface shades with a normal other than its geometric one (a smooth mesh
    /// whose file has vertex normals).
    #[inline]
    pub fn has_shading_normals(&self) -> bool {
        self.shading_normals
    }

    /// Whether any material cuts its surface out by an alpha texture: then a closest hit may
    /// be passed through, which only the scalar queries know ([`Scene::intersect`]).
    #[inline]
    pub fn has_cutouts(&self) -> bool {
        !self.alpha.is_empty()
    }

    /// Whether any material absorbs inside (coloured glass): only then do paths track the
    /// medium they travel in.
    #[inline]
    pub fn has_absorption(&self) -> bool {
        !self.absorption.is_empty()
    }

    /// Material `index`'s absorption per unit length (zero where it is clear, and in every
    /// scene without absorption).
    #[inline]
    pub fn absorption(&self, index: u32) -> Vec3A {
        self.absorption
            .get(index as usize)
            .copied()
            .unwrap_or(Vec3A::ZERO)
    }

    /// The plastics and glTF materials its materials name by index.
    #[inline(always)]
    pub fn tables(&self) -> &Tables {
        &self.tables
    }

    /// The scene's ray queries.
    pub fn accel(&self) -> &Accel {
        &self.accel
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every bounce reads a material: it stays as small as it was before the material
    /// interface (a texture index beside a diffuse albedo once made its `Bsdf` 48 bytes, and a
    /// material 80).
    #[test]
    fn a_material_stays_small() {
        assert_eq!(std::mem::size_of::<Bsdf>(), 32);
        assert_eq!(std::mem::size_of::<Material>(), 64);
    }
    use crate::util::sampling::HashRng;
    use glam::Vec3A;

    /// The BVH with its SIMD leaves finds what a brute-force scalar loop over every primitive
    /// finds, for closest hits and shadow rays, in each bundled scene.
    #[test]
    fn leaves_and_bvh_agree_with_brute_force() {
        for name in ["cornell-box", "spheres", "glass-mirror"] {
            let path = format!("{}/../../scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
            let scene = Scene::file(path.as_ref(), &Limits::default())
                .load()
                .expect("scene loads");
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
