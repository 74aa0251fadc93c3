//! Light that is not an emitting object: the `[[lights]]` array (punctual lights: point, spot,
//! directional) and the `[environment]`, validated and appended to the lights of the scene's
//! emitting objects.

use std::sync::Arc;

use glam::Vec3A;

use super::assets::Assets;
use super::check::{color, finite, finite3, only, required, root, Invalid};
use super::files::{SceneFiles, MAX_TEXELS};
use super::{
    Environment, EnvironmentKind, KeyPath, LightDesc, LightKind, Limits, Primitive, SceneFile,
};
use crate::envmap::EnvMap;
use crate::light::{Falloff, Light, LightShape};
use crate::texture::{self, ImageFormat};

/// The radius of a sphere about the origin holding every finite object: what a light from
/// infinitely far away (directional, environment map) must reach past.
pub(super) fn reach(prims: &[Primitive]) -> f32 {
    prims
        .iter()
        .map(|p| p.shape.bounds())
        .filter(|b| b.min.is_finite() && b.max.is_finite())
        .map(|b| b.min.length().max(b.max.length()))
        .fold(1.0f32, f32::max)
}

/// The scene's `[[lights]]`, appended to its emitting objects' lights.
pub(super) fn punctual_lights(
    desc: &SceneFile,
    reach: f32,
    lights: &mut Vec<Light>,
) -> Result<(), Invalid> {
    for (i, l) in desc.lights.iter().enumerate() {
        lights.push(punctual(l, &root("lights").index(i), reach)?);
    }
    Ok(())
}

/// One `[[lights]]` entry at `lp`.
pub(super) fn punctual(l: &LightDesc, lp: &KeyPath, reach: f32) -> Result<Light, Invalid> {
    {
        let lp = lp.clone();
        let present = [
            ("position", l.position.is_some()),
            ("direction", l.direction.is_some()),
            ("intensity", l.intensity.is_some()),
            ("irradiance", l.irradiance.is_some()),
            ("inner_angle", l.inner_angle.is_some()),
            ("outer_angle", l.outer_angle.is_some()),
            ("angle", l.angle.is_some()),
        ];
        let power = |v: Option<[f32; 3]>, kind: &str, key: &str| -> Result<Vec3A, Invalid> {
            let c = color(required(v, &lp, kind, key)?, &lp.key(key), false)?;
            if c == Vec3A::ZERO {
                return Err((
                    lp.key(key),
                    "a light must emit something; all three are 0".into(),
                ));
            }
            Ok(c)
        };
        let direction = |kind: &str| -> Result<Vec3A, Invalid> {
            let d = finite3(
                required(l.direction, &lp, kind, "direction")?,
                &lp.key("direction"),
            )?;
            d.try_normalize()
                .ok_or_else(|| (lp.key("direction"), "must not be zero".to_string()))
        };
        let position = |kind: &str| -> Result<Vec3A, Invalid> {
            finite3(
                required(l.position, &lp, kind, "position")?,
                &lp.key("position"),
            )
        };
        let (shape, radiance) = match l.kind {
            LightKind::Point => {
                let kind = "a point light";
                only(&lp, kind, &present, &["position", "intensity"])?;
                let position = position(kind)?;
                (
                    LightShape::Point { position },
                    power(l.intensity, kind, "intensity")?,
                )
            }
            LightKind::Spot => {
                let kind = "a spot light";
                only(
                    &lp,
                    kind,
                    &present,
                    &[
                        "position",
                        "direction",
                        "intensity",
                        "inner_angle",
                        "outer_angle",
                        "blend",
                    ],
                )?;
                let (cos_outer, falloff) = spot_cones(l, &lp)?;
                let shape = LightShape::Spot {
                    position: position(kind)?,
                    axis: direction(kind)?,
                    cos_outer,
                    falloff,
                };
                (shape, power(l.intensity, kind, "intensity")?)
            }
            LightKind::Directional => {
                let kind = "a directional light";
                only(&lp, kind, &present, &["direction", "irradiance", "angle"])?;
                let towards = -direction(kind)?;
                let irradiance = power(l.irradiance, kind, "irradiance")?;
                sun_or_directional(towards, irradiance, l.angle, &lp, reach)?
            }
        };
        Ok(Light {
            shape,
            radiance,
            two_sided: false,
            texture: None,
        })
    }
}

/// A spot light's outer cone, as the cosine of its half-angle, and its falloff: `outer_angle`
/// (45 unless given) at most 90 degrees, and either `blend` in [0, 1] or `inner_angle` (0
/// unless given) from 0 to under `outer_angle`.
fn spot_cones(l: &LightDesc, lp: &KeyPath) -> Result<(f32, Falloff), Invalid> {
    // In f64, rounded once, as for rotations: every worker gets the same bits.
    let cos = |deg: f32| f64::from(deg).to_radians().cos() as f32;
    let outer = l.outer_angle.unwrap_or(45.0);
    if let Some(blend) = l.blend {
        if l.inner_angle.is_some() {
            return Err((
                lp.key("blend"),
                "give `blend` or `inner_angle`, not both".into(),
            ));
        }
        if !(0.0..=1.0).contains(&blend) {
            return Err((lp.key("blend"), format!("must be from 0 to 1, got {blend}")));
        }
        if !(outer > 0.0 && outer <= 90.0) {
            return Err((
                lp.key("outer_angle"),
                format!("must be above 0 and at most 90 degrees, got {outer}"),
            ));
        }
        let cos_outer = cos(outer);
        let width = (1.0 - cos_outer) * blend;
        return Ok((cos_outer, Falloff::Blend { width }));
    }
    let inner = l.inner_angle.unwrap_or(0.0);
    if !(0.0..90.0).contains(&inner) {
        return Err((
            lp.key("inner_angle"),
            format!("must be at least 0 and under 90 degrees, got {inner}"),
        ));
    }
    if !(outer > inner && outer <= 90.0) {
        return Err((
            lp.key("outer_angle"),
            format!(
                "must be greater than inner_angle ({inner}) and at most 90 degrees, got {outer}"
            ),
        ));
    }
    Ok((
        cos(outer),
        Falloff::Gltf {
            cos_inner: cos(inner),
        },
    ))
}

/// A directional light shining `towards`, with `irradiance`: a sun, a disk `angle` degrees
/// across, when it has one (from 0 to 90), else a delta light.
fn sun_or_directional(
    towards: Vec3A,
    irradiance: Vec3A,
    angle: Option<f32>,
    lp: &KeyPath,
    reach: f32,
) -> Result<(LightShape, Vec3A), Invalid> {
    let angle = angle.unwrap_or(0.0);
    if !(0.0..=90.0).contains(&angle) {
        return Err((
            lp.key("angle"),
            format!("must be from 0 to 90 degrees, got {angle}"),
        ));
    }
    if angle == 0.0 {
        return Ok((LightShape::Directional { towards, reach }, irradiance));
    }
    sun(towards, angle, irradiance, reach).ok_or_else(|| {
        (
            lp.key("irradiance"),
            format!(
                "spread over a disk of {angle} degrees, the radiance irradiance / (π \
                 sin²(angle / 2)) overflows a 32-bit float"
            ),
        )
    })
}

/// A sun of angular diameter `angle` degrees whose disk gives `irradiance` to a surface facing
/// it: radiance E / (π sin²θ) over the cone of half-angle θ, since ∫ L cos dω over that cone is
/// L·π·sin²θ. `None` where the radiance or the power overflows. In f64, rounded once, so that
/// every worker gets the same bits; 1 − cos θ as 2 sin²(θ/2), without cancellation.
fn sun(towards: Vec3A, angle: f32, irradiance: Vec3A, reach: f32) -> Option<(LightShape, Vec3A)> {
    let half = f64::from(angle).to_radians() / 2.0;
    let sin2 = half.sin().powi(2);
    let one_minus_cos = 2.0 * (half / 2.0).sin().powi(2);
    let scale = 1.0 / (std::f64::consts::PI * sin2);
    let radiance = (irradiance.as_dvec3() * scale).as_vec3a();
    let power = f64::from(reach).powi(2) * irradiance.as_dvec3().element_sum();
    let power_fits = ((std::f64::consts::PI * power) as f32).is_finite();
    (radiance.is_finite() && power_fits).then_some((
        LightShape::Sun {
            towards,
            sin2_max: sin2 as f32,
            one_minus_cos: one_minus_cos as f32,
            reach,
        },
        radiance,
    ))
}

/// The environment as far as it can be built before the scene's objects are: whole, or an
/// image read and its header checked, whose texels are decoded last ([`Environment::finish`]),
/// after every check that needs none, as textures are.
pub(super) enum PendingEnvironment {
    /// Built (or absent).
    Ready(Option<Environment>),
    /// An environment map to decode.
    Map {
        name: String,
        path: KeyPath,
        format: ImageFormat,
        bytes: Vec<u8>,
        intensity: f32,
        turns: f32,
    },
}

/// The `[environment]`, if the file has one; a map's file is read and its header checked.
pub(super) fn environment(
    desc: &SceneFile,
    files: &mut SceneFiles,
    limits: &Limits,
    assets: &dyn Assets,
) -> Result<PendingEnvironment, Invalid> {
    let Some(e) = &desc.environment else {
        return Ok(PendingEnvironment::Ready(None));
    };
    let ep = root("environment");
    let present = [
        ("radiance", e.radiance.is_some()),
        ("top", e.top.is_some()),
        ("bottom", e.bottom.is_some()),
        ("file", e.file.is_some()),
        ("intensity", e.intensity.is_some()),
        ("rotate", e.rotate.is_some()),
    ];
    let env = match e.kind {
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
        EnvironmentKind::Map => {
            let what = "an environment map";
            only(&ep, what, &present, &["file", "intensity", "rotate"])?;
            let name = required(e.file.as_deref(), &ep, what, "file")?;
            let intensity = finite(e.intensity.unwrap_or(1.0), &ep.key("intensity"))?;
            if !(intensity > 0.0) {
                return Err((
                    ep.key("intensity"),
                    format!("must be above 0, got {intensity}"),
                ));
            }
            let degrees = finite(e.rotate.unwrap_or(0.0), &ep.key("rotate"))?;
            let path = ep.key("file");
            let (format, bytes) = files.image_file(name, &path, limits, assets, what)?;
            return Ok(PendingEnvironment::Map {
                name: name.to_string(),
                path,
                format,
                bytes,
                intensity,
                turns: (f64::from(degrees) / 360.0).rem_euclid(1.0) as f32,
            });
        }
    };
    Ok(PendingEnvironment::Ready(Some(env)))
}

impl PendingEnvironment {
    /// The environment, a map decoded and added to `lights` (sampled like them, reaching past
    /// `reach`).
    pub(super) fn finish(
        self,
        reach: f32,
        lights: &mut Vec<Light>,
    ) -> Result<Option<Environment>, Invalid> {
        let (name, path, format, bytes, intensity, turns) = match self {
            PendingEnvironment::Ready(env) => return Ok(env),
            PendingEnvironment::Map {
                name,
                path,
                format,
                bytes,
                intensity,
                turns,
            } => (name, path, format, bytes, intensity, turns),
        };
        let fail = |m: String| (path.clone(), format!("{name}: {m}"));
        let (w, h, texels) = texture::decode_linear(&bytes, format, MAX_TEXELS).map_err(fail)?;
        let map = EnvMap::new(w, h, &texels, intensity, turns).map_err(|e| fail(e.to_string()))?;
        let map = Arc::new(map);
        let light = lights.len() as u32;
        lights.push(Light {
            shape: LightShape::Environment {
                map: map.clone(),
                reach,
            },
            radiance: Vec3A::ZERO,
            two_sided: false,
            texture: None,
        });
        Ok(Some(Environment::Map { map, light }))
    }
}
