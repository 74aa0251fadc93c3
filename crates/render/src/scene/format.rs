//! The scene file's serde types: what a user writes, kept apart from the runtime geometry
//! ([`crate::scene::Scene`]) they are validated and converted into. Every struct rejects
//! unknown keys. `docs/scene-format.md` documents each field.

use std::collections::BTreeMap;

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

/// A vector of exactly three numbers. serde's own `[f32; 3]` stops reading after the third
/// element, so TOML's `[0, 0, 3.9, 42, "junk"]` would load as `[0, 0, 3.9]`: a typo that
/// silently changes the scene.
fn exactly_three<'de, D: Deserializer<'de>>(d: D) -> Result<[f32; 3], D::Error> {
    let v = Vec::<f32>::deserialize(d)?;
    <[f32; 3]>::try_from(v).map_err(|v| D::Error::invalid_length(v.len(), &"a vector of 3 numbers"))
}

/// [`exactly_three`] for a key that may be left out.
fn maybe_three<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f32; 3]>, D::Error> {
    exactly_three(d).map(Some)
}

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
    /// Angular diameter, degrees (directional: a sun's disk; default 0, parallel light).
    pub angle: Option<f32>,
}

/// Material kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialKind {
    /// Lambertian reflector.
    Diffuse,
    /// Perfect mirror.
    Mirror,
    /// Smooth dielectric (glass): Fresnel reflection and refraction.
    Dielectric,
    /// A metal: GGX microfacets over a conductor's Fresnel reflectance.
    Conductor,
    /// A diffuse base under a clear dielectric coat, rough or smooth.
    Plastic,
    /// glTF 2.0's metallic–roughness material, each parameter a number or a texture.
    Pbr,
}

/// Material description.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDesc {
    /// Kind.
    #[serde(rename = "type")]
    pub kind: MaterialKind,
    /// Diffuse reflectance in [0, 1] (diffuse: a colour, or `{ texture = "file" }`; plastic:
    /// its base's colour).
    #[serde(default)]
    pub albedo: Option<AlbedoDesc>,
    /// Mirror reflectance in [0, 1] (mirror; default 1).
    #[serde(default, deserialize_with = "maybe_three")]
    pub reflectance: Option<[f32; 3]>,
    /// Index of refraction, inside over outside (dielectric; plastic's coat, default 1.5).
    pub ior: Option<f32>,
    /// Microfacet roughness in [0, 1] (conductor, dielectric, plastic; default 0, smooth; pbr:
    /// a number or a texture, default 1); α = roughness².
    pub roughness: Option<ScalarDesc>,
    /// Base colour (pbr; default white): a colour, or `{ texture = "file" }`.
    pub base_color: Option<AlbedoDesc>,
    /// Metallic in [0, 1] (pbr; default 1, glTF's): a number or a texture.
    pub metallic: Option<ScalarDesc>,
    /// Transmission in [0, 1] (pbr; default 0): a number or a texture.
    pub transmission: Option<ScalarDesc>,
    /// A tangent-space normal map (pbr), for meshes with texture coordinates.
    pub normal_map: Option<NormalMapDesc>,
    /// A thin sheet rather than a solid (dielectric, smooth only): light reflects or passes
    /// straight through.
    pub thin: Option<bool>,
    /// Absorption per unit length inside (dielectric): Beer–Lambert's σ per channel, ≥ 0.
    #[serde(default, deserialize_with = "maybe_three")]
    pub absorption: Option<[f32; 3]>,
    /// A measured metal by name (conductor): `gold`, `silver`, `copper`, `aluminium`, ….
    pub metal: Option<String>,
    /// Real part of the complex index of refraction per channel (conductor, with `k`).
    #[serde(default, deserialize_with = "maybe_three")]
    pub eta: Option<[f32; 3]>,
    /// Extinction coefficient per channel (conductor, with `eta`).
    #[serde(default, deserialize_with = "maybe_three")]
    pub k: Option<[f32; 3]>,
    /// Reflectance at normal incidence in [0, 1] (conductor; Schlick's Fresnel).
    #[serde(default, deserialize_with = "maybe_three")]
    pub f0: Option<[f32; 3]>,
    /// Emitted radiance; makes every object with this material an area light.
    #[serde(default, deserialize_with = "maybe_three")]
    pub emission: Option<[f32; 3]>,
    /// An image (sRGB-decoded) that scales `emission` point by point, on meshes with texture
    /// coordinates: glTF's `emissiveTexture`.
    pub emission_texture: Option<String>,
    /// Whether the back side reflects and emits like the front (default false: the back of a
    /// diffuse or mirror surface is black and emits nothing).
    pub two_sided: Option<bool>,
}

/// A diffuse albedo: one colour, or an image file looked up at a mesh's texture coordinates.
#[derive(Debug, Clone, PartialEq)]
pub enum AlbedoDesc {
    /// Linear RGB in [0, 1].
    Color([f32; 3]),
    /// A PNG, JPEG or EXR file, relative to the scene file.
    Texture(String),
}

impl<'de> Deserialize<'de> for AlbedoDesc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = AlbedoDesc;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a colour [r, g, b] or a table { texture = \"file.png\" }")
            }

            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<Self::Value, A::Error> {
                let mut v = Vec::new();
                while let Some(x) = seq.next_element::<f32>()? {
                    v.push(x);
                }
                <[f32; 3]>::try_from(v)
                    .map(AlbedoDesc::Color)
                    .map_err(|v| A::Error::invalid_length(v.len(), &"a vector of 3 numbers"))
            }

            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<Self::Value, A::Error> {
                let mut texture = None;
                while let Some(key) = map.next_key::<String>()? {
                    if key != "texture" {
                        return Err(A::Error::unknown_field(&key, &["texture"]));
                    }
                    texture = Some(map.next_value::<String>()?);
                }
                texture
                    .map(AlbedoDesc::Texture)
                    .ok_or_else(|| A::Error::missing_field("texture"))
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// A scalar material parameter: a number, or a texture's channel times a factor.
#[derive(Debug, Clone, PartialEq)]
pub enum ScalarDesc {
    /// The value.
    Value(f32),
    /// An image file's channel (`r`, `g` or `b`; none: the image must be grey), times
    /// `factor` (default 1).
    Texture {
        /// The file, relative to the scene file.
        file: String,
        /// 0, 1 or 2; `None` for a grey image.
        channel: Option<u8>,
        /// Multiplies the texel.
        factor: f32,
    },
}

impl<'de> Deserialize<'de> for ScalarDesc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = ScalarDesc;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(
                    "a number or a table { texture = \"file.png\", channel = \"g\", factor = 1.0 }",
                )
            }

            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Self::Value, E> {
                Ok(ScalarDesc::Value(v as f32))
            }

            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Self::Value, E> {
                Ok(ScalarDesc::Value(v as f32))
            }

            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Self::Value, E> {
                Ok(ScalarDesc::Value(v as f32))
            }

            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<Self::Value, A::Error> {
                const KEYS: &[&str] = &["texture", "channel", "factor"];
                let (mut file, mut channel, mut factor) = (None, None, 1.0f32);
                while let Some(key) = map.next_key::<String>()? {
                    match key.as_str() {
                        "texture" => file = Some(map.next_value::<String>()?),
                        "channel" => {
                            let c = map.next_value::<String>()?;
                            channel = Some(match c.as_str() {
                                "r" | "R" => 0,
                                "g" | "G" => 1,
                                "b" | "B" => 2,
                                _ => {
                                    return Err(A::Error::invalid_value(
                                        serde::de::Unexpected::Str(&c),
                                        &"\"r\", \"g\" or \"b\"",
                                    ))
                                }
                            });
                        }
                        "factor" => factor = map.next_value::<f32>()?,
                        _ => return Err(A::Error::unknown_field(&key, KEYS)),
                    }
                }
                let file = file.ok_or_else(|| A::Error::missing_field("texture"))?;
                Ok(ScalarDesc::Texture {
                    file,
                    channel,
                    factor,
                })
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// A tangent-space normal map.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NormalMapDesc {
    /// The image file (read without the sRGB curve), relative to the scene file.
    pub texture: String,
    /// Scales the map's x and y (glTF's `scale`; default 1).
    pub scale: Option<f32>,
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
