//! A light sample: the point or direction drawn, its density, and its radiance, which for an
//! environment map is looked up only once the sample is known to count
//! ([`LightSample::le`]); and the samples of the lights without a surface.

use std::f32::consts::PI;

use glam::{Vec2, Vec3A};

use super::{positive_finite, Light, LightShape};
use crate::envmap::{EnvMap, MapPoint};
use crate::util::math::{Frame, Ray};
use crate::util::sampling::square_to_uniform_cone;

/// A sampled point on a light.
#[derive(Clone, Copy, Debug)]
pub struct LightSample<'a> {
    /// The point, moved off the light towards the shading point for the shadow ray.
    pub p: Vec3A,
    /// Unit direction from the shading point to the light.
    pub wi: Vec3A,
    /// Emitted radiance towards the shading point ([`LightSample::le`]).
    pub(super) le: Emitted<'a>,
    /// Density in solid angle at the shading point, light selection included; for a punctual
    /// light, its selection probability alone (the direction is a delta).
    pub pdf: f32,
    /// A punctual light: no BSDF sample can find it, so it takes no MIS weight.
    pub delta: bool,
    /// A light at infinity (directional, environment map): its shadow ray has no end.
    pub distant: bool,
}

/// A light sample's radiance: known, or an environment map's at the draw, read only once the
/// sample is known to count (in front of the surface and unoccluded): on a full-size map the
/// texels are a wait on memory.
#[derive(Clone, Copy, Debug)]
pub(super) enum Emitted<'a> {
    Known(Vec3A),
    Map(&'a EnvMap, MapPoint),
}

impl LightSample<'_> {
    /// Emitted radiance towards the shading point (0 from a one-sided light's back).
    #[inline]
    pub fn le(&self) -> Vec3A {
        match self.le {
            Emitted::Known(le) => le,
            Emitted::Map(map, point) => map.radiance_at(&point),
        }
    }

    /// Whether the sample may carry light: false where its radiance is known to be zero. A
    /// map's draw always may (its cell has a positive density, so a corner of it is lit).
    #[inline]
    pub fn may_emit(&self) -> bool {
        match self.le {
            Emitted::Known(le) => le != Vec3A::ZERO,
            Emitted::Map(..) => true,
        }
    }

    /// The shadow ray from `from` and the t it must be clear to: short of the sampled point,
    /// or, towards a light at infinity, all the way. A finite segment there would end past
    /// the scene's finite objects but let an infinite plane's far part through: from a ball
    /// above an infinite floor, the sky just under the horizon lit the ball.
    #[inline]
    pub fn shadow_ray(&self, from: Vec3A) -> (Ray, f32) {
        if self.distant {
            (Ray::new(from, self.wi), f32::INFINITY)
        } else {
            (Ray::new(from, self.p - from), 1.0 - 1e-4)
        }
    }
}

/// A sample of a light without a surface (punctual, a sun, or an environment map) from `p`, selected
/// with probability `pmf`. Out of line, so that [`Lights::sample`] stays small enough to inline
/// into the integrator.
#[inline(never)]
pub(super) fn surfaceless_sample(
    light: &Light,
    p: Vec3A,
    u: Vec2,
    pmf: f32,
) -> Option<LightSample<'_>> {
    let (wi, pdf, le, reach) = match &light.shape {
        LightShape::Environment { map, reach } => {
            let d = map.sample_direction(u)?;
            (d.wi, d.pdf, Emitted::Map(map, d.point), *reach)
        }
        LightShape::Sun {
            towards,
            one_minus_cos,
            reach,
            ..
        } => {
            let local = square_to_uniform_cone(u, *one_minus_cos);
            let wi = Frame::from_normal(*towards).to_world(local).normalize();
            let pdf = 1.0 / (2.0 * PI * one_minus_cos);
            (wi, pdf, Emitted::Known(light.radiance), *reach)
        }
        _ => return delta_sample(light, p, pmf),
    };
    let pdf = pdf * pmf;
    if !positive_finite(pdf) {
        return None;
    }
    Some(LightSample {
        // Past the sphere of the scene's finite objects, as for a directional light.
        p: p + wi * (2.0 * reach + p.length()),
        wi,
        le,
        pdf,
        delta: false,
        distant: true,
    })
}

/// A punctual light's sample from `p`, selected with probability `pmf`.
pub(super) fn delta_sample(light: &Light, p: Vec3A, pmf: f32) -> Option<LightSample<'_>> {
    let (x, wi, le) = light.sample_delta(p)?;
    Some(LightSample {
        p: x,
        wi,
        le: Emitted::Known(le),
        pdf: pmf,
        delta: true,
        distant: matches!(light.shape, LightShape::Directional { .. }),
    })
}
