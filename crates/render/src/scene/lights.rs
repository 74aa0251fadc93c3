//! The `[[lights]]` array: punctual lights (point, spot, directional) validated and appended
//! to the lights of the scene's emitting objects.

use glam::Vec3A;

use super::check::{color, finite3, only, required, root, Invalid};
use super::{LightKind, Primitive, SceneFile};
use crate::light::{Light, LightShape};

/// The scene's `[[lights]]`, appended to its emitting objects' lights. A directional light's
/// reach is the radius of a sphere about the origin holding every finite object.
pub(super) fn punctual_lights(
    desc: &SceneFile,
    prims: &[Primitive],
    lights: &mut Vec<Light>,
) -> Result<(), Invalid> {
    let reach = prims
        .iter()
        .map(|p| p.shape.bounds())
        .filter(|b| b.min.is_finite() && b.max.is_finite())
        .map(|b| b.min.length().max(b.max.length()))
        .fold(1.0f32, f32::max);
    for (i, l) in desc.lights.iter().enumerate() {
        let lp = root("lights").index(i);
        let present = [
            ("position", l.position.is_some()),
            ("direction", l.direction.is_some()),
            ("intensity", l.intensity.is_some()),
            ("irradiance", l.irradiance.is_some()),
            ("inner_angle", l.inner_angle.is_some()),
            ("outer_angle", l.outer_angle.is_some()),
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
                    ],
                )?;
                let inner = l.inner_angle.unwrap_or(0.0);
                let outer = l.outer_angle.unwrap_or(45.0);
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
                            "must be greater than inner_angle ({inner}) and at most 90 degrees, \
                             got {outer}"
                        ),
                    ));
                }
                // In f64, rounded once, as for rotations: every worker gets the same bits.
                let cos = |deg: f32| f64::from(deg).to_radians().cos() as f32;
                let shape = LightShape::Spot {
                    position: position(kind)?,
                    axis: direction(kind)?,
                    cos_inner: cos(inner),
                    cos_outer: cos(outer),
                };
                (shape, power(l.intensity, kind, "intensity")?)
            }
            LightKind::Directional => {
                let kind = "a directional light";
                only(&lp, kind, &present, &["direction", "irradiance"])?;
                let towards = -direction(kind)?;
                (
                    LightShape::Directional { towards, reach },
                    power(l.irradiance, kind, "irradiance")?,
                )
            }
        };
        lights.push(Light {
            shape,
            radiance,
            two_sided: false,
        });
    }
    Ok(())
}
