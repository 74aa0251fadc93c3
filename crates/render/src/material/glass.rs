//! Smooth glass: Fresnel reflection and refraction at an interface of some index (inside over
//! outside), one direction or the other chosen by the Fresnel reflectance; a delta BSDF. This
//! module also reads `type = "dielectric"` for every glass: smooth, rough
//! ([`super::rough_glass`]) or a thin sheet ([`super::thin_glass`]).

use super::port::{At, Reading, Seen, Surface};
use super::rough_glass;
use super::thin_glass::ThinGlass;
use super::{Bsdf, Model};
use crate::bsdf::microfacet::TrowbridgeReitz;
use crate::bsdf::{fresnel_dielectric, reflect, refract, RoughDielectric};
use crate::interaction::{Shading, SurfacePoint};
use crate::util::fields::{positive, required, Invalid};
use crate::util::math::{offset_ray_origin, Ray};

/// Smooth glass.
#[derive(Clone, Copy, Debug)]
pub struct Glass {
    /// Its relative index of refraction, inside over outside.
    pub ior: f32,
}

impl Model for Glass {
    fn samples_lights(&self) -> bool {
        false
    }
    fn draws_choice(&self) -> bool {
        true
    }
    fn has_two_sides(&self) -> bool {
        true
    }
    #[inline(always)]
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray> {
        let u = v.numbers().choice;
        let next = refracted(v.ray(), v.point(), v.shading(), v.front(), self.ior, u)?;
        let path = v.path();
        path.specular = true;
        path.beta /= next.attenuation;
        path.eta_scale *= next.attenuation;
        if next.through {
            v.went_through();
        }
        Some(next.ray)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, u_choice: f32) -> Seen {
        match refracted(
            s.ray(),
            s.point(),
            s.shading(),
            s.front(),
            self.ior,
            u_choice,
        ) {
            Some(r) => Seen::Next(r.ray),
            None => Seen::Nothing,
        }
    }
}

/// A path's next ray through (or off) a smooth dielectric, and what its throughput is divided
/// by.
struct Refracted {
    ray: Ray,
    /// η² through the surface (radiance is compressed by 1/η² entering a denser medium), 1
    /// on reflection.
    attenuation: f32,
    /// Whether the path went through.
    through: bool,
}

/// Reflects or refracts the path at a smooth dielectric of index `ior` (outside on the front
/// side), choosing by the Fresnel reflectance with `u_choice`; `None` when no Fresnel term is
/// defined (seen from behind the shading normal).
#[inline(always)]
fn refracted(
    ray: &Ray,
    sp: &SurfacePoint,
    at: &Shading,
    front: bool,
    ior: f32,
    u_choice: f32,
) -> Option<Refracted> {
    let (n, ns, shaded) = (at.n, at.ns, at.shaded);
    let wo = -ray.d;
    // The front side (sp.n) is outside.
    let eta = if front { ior } else { 1.0 / ior };
    let cos_i = ns.dot(wo).min(1.0);
    if shaded && !(cos_i > 0.0) {
        // Seen from behind its shading normal: no Fresnel term is defined.
        return None;
    }
    let (f, cos_t) = fresnel_dielectric(cos_i, eta);
    let (wi, through) = if u_choice < f {
        (reflect(ray.d, ns), false)
    } else {
        (refract(wo, ns, eta, cos_i, cos_t), true)
    };
    // Off the side the new direction leaves by: the geometric normal decides it
    // where the shading normal could disagree.
    let side = if shaded {
        if n.dot(wi) >= 0.0 {
            n
        } else {
            -n
        }
    } else if through {
        -n
    } else {
        n
    };
    // Radiance is compressed by 1/η² entering a denser medium.
    Some(Refracted {
        ray: Ray::new(offset_ray_origin(sp.p, sp.err, side), wi),
        attenuation: if through { eta * eta } else { 1.0 },
        through,
    })
}

/// Solid glass of index `ior` and `roughness`: smooth under the mirror threshold, or at an
/// index of 1 (no interface to scatter at), bit for bit; rough otherwise. What both scene
/// readers make of a glass.
pub(crate) fn solid(ior: f32, roughness: f32) -> Bsdf {
    let distribution = TrowbridgeReitz::from_roughness(roughness);
    if distribution.is_smooth() || ior == 1.0 {
        return Bsdf::Dielectric(Glass { ior });
    }
    rough_glass::new(RoughDielectric { distribution, ior })
}

/// `type = "dielectric"`: an index, a roughness, thin or solid, and for a solid an absorption
/// inside (which the scene keeps beside the material).
pub(crate) fn read(r: &mut Reading<'_, '_>) -> Result<Bsdf, Invalid> {
    let kind = "a dielectric material";
    r.only(kind, &["ior", "roughness", "thin", "absorption"])?;
    let m = r.desc;
    let ior = required(m.ior, r.at, kind, "ior")?;
    let ior = positive(ior, &r.key("ior"))?;
    let roughness = m.constant_roughness(r.at, "a dielectric")?;
    if m.thin == Some(true) {
        if roughness > 0.0 {
            return Err((
                r.key("roughness"),
                "a thin dielectric is smooth: rough thin sheets are not modelled".into(),
            ));
        }
        if m.absorption.is_some() {
            return Err((
                r.key("absorption"),
                "a thin dielectric has no inside to absorb in".into(),
            ));
        }
        return Ok(Bsdf::ThinDielectric(ThinGlass { ior }));
    }
    Ok(solid(ior, roughness))
}
