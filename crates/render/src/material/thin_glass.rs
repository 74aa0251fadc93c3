//! A thin sheet of smooth glass (a window pane): both faces at once, so light reflects with
//! the sheet's total reflectance R' or passes straight on, unbent. Read as a `dielectric`
//! with `thin = true` (`glass::read`).

use super::port::{At, Seen, Surface};
use super::Model;
use crate::bsdf::dielectric::thin_reflectance;
use crate::bsdf::reflect;
use crate::interaction::{Shading, SurfacePoint};
use crate::util::math::{offset_ray_origin, Ray};

/// A thin sheet of glass.
#[derive(Clone, Copy, Debug)]
pub struct ThinGlass {
    /// Its index of refraction.
    pub ior: f32,
}

impl Model for ThinGlass {
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
        let next = passed(v.ray(), v.point(), v.shading(), self.ior, u)?;
        v.path().specular = true;
        Some(next)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, u_choice: f32) -> Seen {
        match passed(s.ray(), s.point(), s.shading(), self.ior, u_choice) {
            Some(r) => Seen::Next(r),
            None => Seen::Nothing,
        }
    }
}

/// A path's next ray off or through a thin sheet of glass of index `ior`: reflected with R'
/// (see [`thin_reflectance`]) or straight on, unbent. `None` where the shading normal and the
/// geometric one disagree.
#[inline(never)]
fn passed(ray: &Ray, sp: &SurfacePoint, at: &Shading, ior: f32, u_choice: f32) -> Option<Ray> {
    let (n, ns) = (at.n, at.ns);
    let cos_i = ns.dot(-ray.d).min(1.0);
    if at.shaded && !(cos_i > 0.0) {
        return None;
    }
    let (wi, side) = if u_choice < thin_reflectance(cos_i, ior) {
        (reflect(ray.d, ns), n)
    } else {
        (ray.d, -n)
    };
    if at.shaded && n.dot(wi) * side.dot(n) <= 0.0 {
        return None;
    }
    Some(Ray::new(offset_ray_origin(sp.p, sp.err, side), wi))
}
