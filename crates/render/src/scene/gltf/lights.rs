//! A glTF file's punctual lights (`KHR_lights_punctual`): each light node placed in the world
//! ([`light_at`]), then validated as the scene's own `[[lights]]` are and added to its lights
//! ([`lights`]).

use glam::{Affine3A, Vec3A};

use super::super::check::{root, Invalid};
use super::super::lights::punctual;
use super::super::{KeyPath, LightDesc, LightKind};
use crate::light::Light;
use crate::util::fields::Seg;

/// Lumens per watt: glTF gives a punctual light's intensity in photometric units (candela for
/// point and spot lights, lux for directional ones), tessera in radiometric ones (W/sr, W/m²).
/// Blender's glTF importer and exporter convert with 683 lm/W, the luminous efficacy of light
/// at 555 nm, and so does tessera: a Blender point light of P watts is exported as P/(4π)·683
/// cd and read back as P/(4π) W/sr, the intensity of an isotropic source of P W; a sun of
/// E W/m² is exported as E·683 lux and read back as E W/m².
pub(in crate::scene) const LUMENS_PER_WATT: f32 = 683.0;

/// A punctual light from `KHR_lights_punctual`, placed in the world.
#[derive(Clone, Debug)]
pub(in crate::scene) struct GltfLight {
    /// Which light of the file, for errors.
    pub(in crate::scene) index: usize,
    /// Point, spot or directional.
    pub(in crate::scene) kind: LightKind,
    /// Colour × intensity, in W/sr (point, spot) or W/m² (directional).
    pub(in crate::scene) power: [f32; 3],
    /// Where it is.
    pub(in crate::scene) position: Vec3A,
    /// Where it shines.
    pub(in crate::scene) direction: Vec3A,
    /// Spot cone half-angles, degrees.
    pub(in crate::scene) cone: (f32, f32),
}

/// A light node, in the world.
pub(super) fn light_at(light: &gltf::khr_lights_punctual::Light, world: &Affine3A) -> GltfLight {
    use gltf::khr_lights_punctual::Kind;
    let (kind, cone) = match light.kind() {
        Kind::Point => (LightKind::Point, (0.0, 0.0)),
        Kind::Directional => (LightKind::Directional, (0.0, 0.0)),
        Kind::Spot {
            inner_cone_angle,
            outer_cone_angle,
        } => (
            LightKind::Spot,
            (inner_cone_angle.to_degrees(), outer_cone_angle.to_degrees()),
        ),
    };
    let c = light.color();
    // Candela (point, spot) or lux (directional) to W/sr or W/m², before the colour: an
    // intensity given as a whole multiple of 683 then gives the radiometric value exactly.
    let i = light.intensity() / LUMENS_PER_WATT;
    GltfLight {
        index: light.index(),
        kind,
        power: [c[0] * i, c[1] * i, c[2] * i],
        position: world.transform_point3a(Vec3A::ZERO),
        direction: world.transform_vector3a(Vec3A::NEG_Z),
        cone,
    }
}

/// The lights of glTF files (`KHR_lights_punctual`), each placed in the world, with the key
/// of the object whose file holds it: validated as `[[lights]]` are, and named in errors by
/// the file and the light's index there. A light of zero intensity is left out, as glTF
/// allows.
pub(in crate::scene) fn lights(
    placed: &[(KeyPath, String, GltfLight)],
    reach: f32,
    lights: &mut Vec<Light>,
) -> Result<(), Invalid> {
    for (path, file, g) in placed {
        if g.power.iter().all(|&p| p == 0.0) {
            continue;
        }
        let (d, p) = (Some(g.direction.to_array()), Some(g.position.to_array()));
        let mut l = LightDesc {
            kind: g.kind,
            position: None,
            direction: None,
            intensity: Some(g.power),
            irradiance: None,
            inner_angle: None,
            outer_angle: None,
            blend: None,
            angle: None,
        };
        match g.kind {
            LightKind::Point => l.position = p,
            LightKind::Spot => {
                (l.position, l.direction) = (p, d);
                let (inner, outer) = g.cone;
                l.outer_angle = Some(outer);
                if inner <= outer && outer > 0.0 {
                    // As Blender's importer reads the cones (its exporter writes inner =
                    // outer × (1 − blend), so a hard-edged spot has inner = outer).
                    l.blend = Some(1.0 - inner / outer);
                } else {
                    // Refused as the cones of a `[[lights]]` spot would be.
                    l.inner_angle = Some(inner);
                }
            }
            LightKind::Directional => {
                (l.direction, l.irradiance, l.intensity) = (d, Some(g.power), None);
            }
        }
        let light = punctual(&l, &root("lights").index(g.index), reach).map_err(|(at, m)| {
            // Checked as a `[[lights]]` entry, so the key is tessera's: said as glTF's.
            let light = (path.within(file).key("extensions"))
                .key("KHR_lights_punctual")
                .key("lights")
                .index(g.index);
            let key = match at.0.last() {
                Some(Seg::Key(k)) => match k.as_str() {
                    "outer_angle" => Some("outerConeAngle"),
                    "inner_angle" | "blend" => Some("innerConeAngle"),
                    "intensity" | "irradiance" | "color" => Some(k.as_str()),
                    _ => None,
                },
                _ => None,
            };
            match key {
                Some(k) if k.ends_with("ConeAngle") => (light.key("spot").key(k), m),
                Some("irradiance") => (light.key("intensity"), m),
                Some(k) => (light.key(k), m),
                None => (light, m),
            }
        })?;
        lights.push(light);
    }
    Ok(())
}
