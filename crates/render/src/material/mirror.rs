//! A perfect mirror of some reflectance: one direction, a delta BSDF that light sampling
//! cannot reach.

use glam::Vec3A;

use super::port::{At, Reading, Seen, Surface};
use super::{Bsdf, Model};
use crate::bsdf::reflect;
use crate::util::fields::{color, Invalid};
use crate::util::math::{offset_ray_origin, Ray};

/// A mirror.
#[derive(Clone, Copy, Debug)]
pub struct Mirror {
    /// Its reflectance, in [0, 1].
    pub reflectance: Vec3A,
}

impl Model for Mirror {
    fn samples_lights(&self) -> bool {
        false
    }
    #[inline(always)]
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray> {
        let path = v.path();
        path.beta *= self.reflectance;
        path.specular = true;
        mirrored(v)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, _: f32) -> Seen {
        mirrored(s).map_or(Seen::Nothing, Seen::Next)
    }
}

/// The ray reflected about the shading normal at `s` (a mirror's, a smooth metal's); `None`
/// where it points into the geometric surface.
#[inline(always)]
pub(super) fn mirrored<'s, S: Surface<'s>>(s: &S) -> Option<Ray> {
    let (at, sp) = (s.shading(), s.point());
    let wi = reflect(s.ray().d, at.ns);
    if at.shaded && at.n.dot(wi) <= 0.0 {
        return None;
    }
    Some(Ray::new(offset_ray_origin(sp.p, sp.err, at.n), wi))
}

/// `type = "mirror"`: a reflectance, 1 when not given.
pub(crate) fn read(r: &mut Reading<'_, '_>) -> Result<Bsdf, Invalid> {
    r.only("a mirror material", &["reflectance"])?;
    let reflectance = color(
        r.desc.reflectance.unwrap_or([1.0; 3]),
        &r.key("reflectance"),
        true,
    )?;
    Ok(Bsdf::Mirror(Mirror { reflectance }))
}
