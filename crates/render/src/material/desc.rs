//! A material as the scene file writes it (`[materials.NAME]`): one flat table whose `type`
//! picks the kind and whose other keys each kind takes or refuses (`Model`'s
//! readers say which). Kept apart from the runtime materials it is read into.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

use super::MaterialKind;
use crate::bsdf::pbr::Distribution;
use crate::util::fields::{maybe_three, unit, Invalid, KeyPath};

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
    /// A clear coat's weight in [0, 1] (pbr; default 0, none): a number or a texture.
    pub clearcoat: Option<ScalarDesc>,
    /// The clear coat's roughness in [0, 1] (pbr; default 0): a number or a texture.
    pub clearcoat_roughness: Option<ScalarDesc>,
    /// A sheen's colour, each channel in [0, 1] (pbr; default black, none).
    #[serde(default, deserialize_with = "maybe_three")]
    pub sheen_color: Option<[f32; 3]>,
    /// The sheen's roughness in [0, 1] (pbr; default 0).
    pub sheen_roughness: Option<f32>,
    /// The microfacet model (pbr): `multiscatter_ggx` (default: energy-preserving, Blender's
    /// default) or `ggx` (single scattering: glTF's reference BRDF, Mitsuba's `principled`).
    pub distribution: Option<Distribution>,
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

impl MaterialDesc {
    /// The roughness of a conductor, dielectric or plastic (`kind`), at `at`: a number in
    /// [0, 1], 0 (smooth) when not given; textures are for `pbr` materials.
    pub(crate) fn constant_roughness(&self, at: &KeyPath, kind: &str) -> Result<f32, Invalid> {
        match &self.roughness {
            None => Ok(0.0),
            Some(ScalarDesc::Value(r)) => unit(*r, &at.key("roughness")),
            Some(ScalarDesc::Texture { .. }) => Err((
                at.key("roughness"),
                format!("{kind}'s roughness is a number: textures are for pbr materials"),
            )),
        }
    }

    /// Which of the kind-specific keys it gives: each kind takes its own and refuses the rest
    /// (`emission`, `emission_texture` and `two_sided` apply to every kind).
    pub(crate) fn kind_keys(&self) -> [(&'static str, bool); 15] {
        [
            ("albedo", self.albedo.is_some()),
            ("reflectance", self.reflectance.is_some()),
            ("ior", self.ior.is_some()),
            ("roughness", self.roughness.is_some()),
            ("metal", self.metal.is_some()),
            ("eta", self.eta.is_some()),
            ("k", self.k.is_some()),
            ("f0", self.f0.is_some()),
            ("thin", self.thin.is_some()),
            ("absorption", self.absorption.is_some()),
            ("base_color", self.base_color.is_some()),
            ("metallic", self.metallic.is_some()),
            ("transmission", self.transmission.is_some()),
            ("normal_map", self.normal_map.is_some()),
            ("distribution", self.distribution.is_some()),
        ]
    }
}
