//! Rough glass: GGX microfacets over a dielectric interface, reflecting and transmitting
//! ([`RoughDielectric`] holds its arithmetic). Read as a `dielectric` with a roughness
//! (`glass::read`).

use glam::{Vec2, Vec3A};

use super::port::{leave, At, Lobe, Seen, Surface};
use super::{Bsdf, Model};
use crate::bsdf::RoughDielectric;
use crate::util::math::{Frame, Ray};

/// Rough glass as a material (the caller checked it is rough: see [`super::glass::solid`]).
pub(crate) fn new(rd: RoughDielectric) -> Bsdf {
    Bsdf::RoughDielectric(rd)
}

impl Model for RoughDielectric {
    const FAR: bool = true;
    fn draws_choice(&self) -> bool {
        true
    }
    fn has_two_sides(&self) -> bool {
        true
    }
    #[inline(always)]
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray> {
        let eta = if v.front() { self.ior } else { 1.0 / self.ior };
        let (next, through) = vertex(self, v, eta)?;
        if through {
            v.went_through();
        }
        Some(next)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, _: &S, _: f32) -> Seen {
        Seen::Albedo(Vec3A::ONE)
    }
}

/// A rough glass vertex, the path arriving on the side where the index ratio across the
/// interface is `eta`: direct light from either side by next-event estimation (when the vertex
/// samples lights) weighed against the BSDF's density under MIS, then a reflection or
/// refraction about a visible normal, weighted G/G1 and, through the interface, by 1/η² (see
/// [`crate::bsdf::dielectric`]). Returns the next ray and whether it went through; `None` ends
/// the path.
// Out of line: the loop that diffuse, mirror and glass scenes run stays as small as it was.
#[inline(never)]
fn vertex<'s, A: At<'s>>(rd: &RoughDielectric, v: &mut A, eta: f32) -> Option<(Ray, bool)> {
    let (sp, at, wo) = (*v.point(), *v.shading(), -v.ray().d);
    let u = v.numbers();
    let (bsdf_u, u_choice): (Vec2, f32) = (u.bsdf, u.choice);
    let frame = Frame::from_normal(at.ns);
    let o = frame.to_local(wo);
    if let Some(u) = u.light {
        let lobe = Lobe {
            frame: &frame,
            eval: |i| Vec3A::splat(rd.eval(o, i, eta)),
            pdf: |i| rd.pdf(o, i, eta),
        };
        v.two_sided_light(&at, u, lobe);
    }
    let s = rd.sample(o, eta, bsdf_u, u_choice)?;
    let wi = frame.to_world(s.wi);
    let path = v.path();
    path.beta *= s.weight;
    if s.refracted {
        // Radiance is compressed by 1/η² entering a denser medium.
        path.beta /= eta * eta;
        path.eta_scale *= eta * eta;
    }
    path.specular = false;
    path.prev_pdf = s.pdf;
    Some((leave(&sp, &at, wi, s.refracted)?, s.refracted))
}
