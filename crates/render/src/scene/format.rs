//! The scene file's serde types: what a user writes, kept apart from the runtime geometry
//! ([`crate::scene::Scene`]) they are validated and converted into. Every struct rejects
//! unknown keys. `docs/scene-format.md` documents each field.

use std::collections::BTreeMap;

use serde::Deserialize;

pub use crate::material::desc::{AlbedoDesc, MaterialDesc, NormalMapDesc, ScalarDesc};
pub use crate::material::MaterialKind;
use crate::util::fields::{exactly_three, maybe_three};

/// A whole scene file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Format version; only 1 exists.
    pub version: u32,
    /// The camera.
    pub camera: CameraDesc,
    /// Image size.
    pub film: FilmDesc,
    /// Integrator settings that change the image, and so belong to the scene.
    #[serde(default)]
    pub render: RenderDesc,
    /// Light from infinitely far away; none means black.
    pub environment: Option<EnvironmentDesc>,
    /// Named materials.
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialDesc>,
    /// The objects.
    #[serde(default)]
    pub objects: Vec<ObjectDesc>,
    /// Punctual lights (point, spot, directional), besides the emitting objects.
    #[serde(default)]
    pub lights: Vec<LightDesc>,
    /// Keyframes, if the scene moves.
    pub animation: Option<AnimationDesc>,
}

/// `[animation]`: keyframes for the camera and for objects' transforms, by frame number.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnimationDesc {
    /// Camera keys, in increasing frame order.
    #[serde(default)]
    pub camera: Vec<CameraKeyDesc>,
    /// One track per animated object.
    #[serde(default)]
    pub objects: Vec<ObjectTrackDesc>,
}

/// One camera keyframe: the camera's fields that move (every key gives the same ones).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraKeyDesc {
    /// Frame number (may be fractional).
    pub frame: f64,
    /// Eye position.
    #[serde(default, deserialize_with = "maybe_three")]
    pub eye: Option<[f32; 3]>,
    /// Look-at target.
    #[serde(default, deserialize_with = "maybe_three")]
    pub target: Option<[f32; 3]>,
    /// Up vector.
    #[serde(default, deserialize_with = "maybe_three")]
    pub up: Option<[f32; 3]>,
    /// Horizontal field of view, degrees.
    pub fov: Option<f32>,
    /// Pitch, degrees (pitch_yaw cameras).
    pub pitch: Option<f32>,
    /// Yaw, degrees (pitch_yaw cameras).
    pub yaw: Option<f32>,
}

/// The keyframes of one object (by its index in `objects`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectTrackDesc {
    /// Index of the object in `objects`, from 0.
    pub object: usize,
    /// Keys, in increasing frame order.
    pub keys: Vec<ObjectKeyDesc>,
}

/// One object keyframe: a transform applied after the object's own.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectKeyDesc {
    /// Frame number (may be fractional).
    pub frame: f64,
    /// Translation (default none).
    #[serde(default, deserialize_with = "maybe_three")]
    pub translate: Option<[f32; 3]>,
    /// Rotation (default none), interpolated by slerp.
    pub rotate: Option<RotateDesc>,
    /// Scale (default 1).
    #[serde(default, deserialize_with = "maybe_three")]
    pub scale: Option<[f32; 3]>,
}

/// Which camera model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraModel {
    /// Eye, target, up vector and horizontal field of view.
    LookAt,
    /// The course notes' model: eye, pitch α, yaw β, and the horizontal field of view θ
    /// spanning the outermost pixel centres.
    PitchYaw,
    /// A camera of the scene's glTF objects (`name` or `index` picks one; the first by
    /// default), or, where they have none, one that frames the whole scene.
    Gltf,
}

/// Camera description.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    /// Camera model.
    pub model: CameraModel,
    /// Eye position (look_at, pitch_yaw).
    #[serde(default, deserialize_with = "maybe_three")]
    pub eye: Option<[f32; 3]>,
    /// Look-at target (look_at only).
    #[serde(default, deserialize_with = "maybe_three")]
    pub target: Option<[f32; 3]>,
    /// Up vector (look_at only; default +y).
    #[serde(default, deserialize_with = "maybe_three")]
    pub up: Option<[f32; 3]>,
    /// Pitch α in degrees (pitch_yaw only; default 0).
    pub pitch: Option<f32>,
    /// Yaw β in degrees (pitch_yaw only; default 0).
    pub yaw: Option<f32>,
    /// Horizontal field of view in degrees, in (0, 180) (look_at, pitch_yaw).
    pub fov: Option<f32>,
    /// The glTF camera of this name (gltf only).
    pub name: Option<String>,
    /// The glTF camera of this index in its file's `cameras` (gltf only).
    pub index: Option<usize>,
}

/// Image size in pixels.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilmDesc {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
}

/// Integrator settings stored with the scene.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderDesc {
    /// Maximum number of bounces; unlimited (Russian roulette ends paths) when absent.
    pub max_depth: Option<u32>,
    /// Add a denoised layer: `true`, or a table of the filter's options.
    pub denoise: Option<DenoiseDesc>,
}

/// `[render] denoise`: `true` (`false` is the same as leaving it out), or
/// `{ quality = "fast" | "balanced" | "high", ldr = true }`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DenoiseDesc {
    /// Asked for (`false` only from `denoise = false`).
    pub on: bool,
    /// The filter's quality, unchecked.
    pub quality: Option<String>,
    /// Filter as LDR.
    pub ldr: bool,
}

impl<'de> Deserialize<'de> for DenoiseDesc {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        /// The options' table, as written.
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Options {
            quality: Option<String>,
            #[serde(default)]
            ldr: bool,
        }
        struct Either;
        impl<'de> serde::de::Visitor<'de> for Either {
            type Value = DenoiseDesc;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("true, false, or a table of `quality` and `ldr`")
            }
            fn visit_bool<E: serde::de::Error>(self, on: bool) -> Result<DenoiseDesc, E> {
                Ok(DenoiseDesc {
                    on,
                    ..DenoiseDesc::default()
                })
            }
            fn visit_map<M: serde::de::MapAccess<'de>>(
                self,
                m: M,
            ) -> Result<DenoiseDesc, M::Error> {
                let o = Options::deserialize(serde::de::value::MapAccessDeserializer::new(m))?;
                Ok(DenoiseDesc {
                    on: true,
                    quality: o.quality,
                    ldr: o.ldr,
                })
            }
        }
        d.deserialize_any(Either)
    }
}

/// Environment kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EnvironmentKind {
    /// The same radiance in every direction.
    Constant,
    /// A blend from `bottom` (straight down) to `top` (straight up), linear in the direction's y.
    Gradient,
    /// An equirectangular HDR image (OpenEXR or Radiance .hdr), importance-sampled.
    Map,
}

/// Environment description.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentDesc {
    /// Kind.
    #[serde(rename = "type")]
    pub kind: EnvironmentKind,
    /// Radiance (constant).
    #[serde(default, deserialize_with = "maybe_three")]
    pub radiance: Option<[f32; 3]>,
    /// Radiance straight up (gradient).
    #[serde(default, deserialize_with = "maybe_three")]
    pub top: Option<[f32; 3]>,
    /// Radiance straight down (gradient).
    #[serde(default, deserialize_with = "maybe_three")]
    pub bottom: Option<[f32; 3]>,
    /// The image file, relative to the scene file (map).
    pub file: Option<String>,
    /// Scale on the image's texels (map; default 1).
    pub intensity: Option<f32>,
    /// Turn about +y, in degrees (map; default 0).
    pub rotate: Option<f32>,
}

/// Punctual light kinds (glTF's KHR_lights_punctual).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LightKind {
    /// Light from a point, the same in every direction.
    Point,
    /// A point light within a cone.
    Spot,
    /// Parallel light from infinitely far away.
    Directional,
}

/// `[[lights]]`: a punctual light.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightDesc {
    /// Kind.
    #[serde(rename = "type")]
    pub kind: LightKind,
    /// Where it is (point, spot).
    #[serde(default, deserialize_with = "maybe_three")]
    pub position: Option<[f32; 3]>,
    /// Where it shines (spot: its axis; directional: the way its light travels).
    #[serde(default, deserialize_with = "maybe_three")]
    pub direction: Option<[f32; 3]>,
    /// Intensity per steradian, per channel (point, spot).
    #[serde(default, deserialize_with = "maybe_three")]
    pub intensity: Option<[f32; 3]>,
    /// Irradiance on a surface facing it, per channel (directional).
    #[serde(default, deserialize_with = "maybe_three")]
    pub irradiance: Option<[f32; 3]>,
    /// Half-angle of the full-intensity cone, degrees (spot; default 0).
    pub inner_angle: Option<f32>,
    /// Half-angle where the intensity reaches zero, degrees (spot; default 45).
    pub outer_angle: Option<f32>,
    /// Blender's spot blend in [0, 1] (spot, in place of `inner_angle`): the intensity rises
    /// from the outer cone by a smoothstep over that fraction of 1 − cos(outer_angle), as Cycles
    /// renders it; 0 is a hard edge.
    pub blend: Option<f32>,
    /// Angular diameter, degrees (directional: a sun's disk; default 0, parallel light).
    pub angle: Option<f32>,
}

/// Shape kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    /// Sphere (`center`, `radius`).
    Sphere,
    /// Axis-aligned box in object space (`min`, `max`).
    Box,
    /// Rectangle `size` centred at the origin in the z = 0 plane, front normal +z.
    Rect,
    /// Infinite plane (`point`, `normal`).
    Plane,
    /// Triangle mesh read from an OBJ or PLY `file`.
    Mesh,
    /// Every mesh, material, light and camera of a glTF 2.0 `file` (`.gltf` or `.glb`).
    Gltf,
}

/// One object: a shape, its material and an optional transform.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDesc {
    /// Shape kind.
    pub shape: ShapeKind,
    /// Material name, a key of `[materials]` (a glTF object's materials are its file's).
    pub material: Option<String>,
    /// Sphere centre (default origin).
    #[serde(default, deserialize_with = "maybe_three")]
    pub center: Option<[f32; 3]>,
    /// Sphere radius (default 1).
    pub radius: Option<f32>,
    /// Box lower corner (default −1,−1,−1).
    #[serde(default, deserialize_with = "maybe_three")]
    pub min: Option<[f32; 3]>,
    /// Box upper corner (default 1,1,1).
    #[serde(default, deserialize_with = "maybe_three")]
    pub max: Option<[f32; 3]>,
    /// Rectangle size (default 2 × 2, the square [−1, 1]²).
    pub size: Option<[f32; 2]>,
    /// A point of the plane (default origin).
    #[serde(default, deserialize_with = "maybe_three")]
    pub point: Option<[f32; 3]>,
    /// Plane front normal (default +y).
    #[serde(default, deserialize_with = "maybe_three")]
    pub normal: Option<[f32; 3]>,
    /// Mesh file (OBJ, PLY, glTF), relative to the scene file.
    pub file: Option<String>,
    /// Whether a mesh shades with its file's vertex normals (default false: flat).
    pub smooth: Option<bool>,
    /// A mesh's material for each of its file's material names (an OBJ's `usemtl`, a glTF
    /// material's `name`), by scene material name; groups not listed use `material` (OBJ,
    /// PLY) or their own (glTF). `materials_override` is another name for it.
    #[serde(alias = "materials_override")]
    pub materials_map: Option<BTreeMap<String, String>>,
    /// The microfacet model of a glTF file's metallic–roughness materials, which glTF does not
    /// say: `multiscatter_ggx` (default, as Blender renders them) or `ggx` (glTF's reference
    /// BRDF, single scattering).
    pub distribution: Option<crate::bsdf::pbr::Distribution>,
    /// Object-to-world transform.
    pub transform: Option<TransformDesc>,
}

/// An affine transform: a full matrix, or translate · rotate · scale (scale applied first).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformDesc {
    /// Row-major 4×4 matrix whose last row is 0 0 0 1; a point p maps to M·[p, 1].
    pub matrix: Option<[[f32; 4]; 4]>,
    /// Translation.
    #[serde(default, deserialize_with = "maybe_three")]
    pub translate: Option<[f32; 3]>,
    /// Rotation about an axis.
    pub rotate: Option<RotateDesc>,
    /// Per-axis scale.
    #[serde(default, deserialize_with = "maybe_three")]
    pub scale: Option<[f32; 3]>,
}

/// A rotation by `degrees` about `axis` (right-handed).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RotateDesc {
    /// Axis (any non-zero length).
    #[serde(deserialize_with = "exactly_three")]
    pub axis: [f32; 3],
    /// Angle in degrees.
    pub degrees: f32,
}
