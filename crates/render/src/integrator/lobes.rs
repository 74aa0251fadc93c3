//! The glossy reflection vertices of [`super`]'s path tracer: rough or smooth metal and
//! plastic, which share next-event estimation through a lobe ([`reflected_light`]) and the
//! step to the next ray ([`follow`]).

use glam::{Vec2, Vec3A};

use super::{visible_light, Path, Shading};
use crate::bsdf::{reflect, Conductor, Plastic};
use crate::interaction::SurfacePoint;
use crate::scene::Scene;
use crate::settings::Strategy;
use crate::util::math::{offset_ray_origin, Frame, Ray};
use crate::util::sampling::power_heuristic;

/// A metal vertex. Smooth: the mirror direction, weighted by the Fresnel reflectance at this
/// angle. Rough: direct light by next-event estimation (when `light_u` is given), weighted
/// against the BSDF's own density under MIS, then a direction by visible normals with weight
/// f·cos/pdf (= F·G/G1, see [`crate::bsdf::microfacet`]). `None` ends the path.
#[allow(clippy::too_many_arguments)]
// Out of line: the loop that diffuse, mirror and glass scenes run stays as small as it was.
#[inline(never)]
pub(super) fn conductor(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    c: &Conductor,
    wo: Vec3A,
    sp: &SurfacePoint,
    at: &Shading,
    bsdf_u: Vec2,
    light_u: Option<(f32, Vec2)>,
) -> Option<Ray> {
    let p_out = offset_ray_origin(sp.p, sp.err, at.n);
    if c.distribution.is_smooth() {
        path.beta *= c.fresnel.eval(at.ns.dot(wo));
        path.specular = true;
        let wi = reflect(-wo, at.ns);
        if at.shaded && at.n.dot(wi) <= 0.0 {
            return None;
        }
        return Some(Ray::new(p_out, wi));
    }
    let frame = Frame::from_normal(at.ns);
    let o = frame.to_local(wo);
    if let Some(u) = light_u {
        let lobe = Lobe {
            frame: &frame,
            eval: |i| c.eval(o, i),
            pdf: |i| c.pdf(o, i),
        };
        reflected_light(scene, strategy, path, sp, at, p_out, u, lobe);
    }
    let s = c.sample(o, bsdf_u)?;
    follow(
        path,
        at,
        p_out,
        frame.to_world(s.wi),
        s.weight,
        s.pdf,
        false,
    )
}

/// A plastic vertex: direct light by next-event estimation (when `light_u` is given) through
/// both lobes, weighed against the mixture's density under MIS, then a direction from the
/// coat or the base chosen by `u.1` (see [`crate::bsdf::plastic`]); a smooth coat's mirror
/// direction is a specular bounce. `None` ends the path.
#[allow(clippy::too_many_arguments)]
// Out of line: the loop that diffuse, mirror and glass scenes run stays as small as it was.
#[inline(never)]
pub(super) fn plastic(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    p: &Plastic,
    wo: Vec3A,
    sp: &SurfacePoint,
    at: &Shading,
    (bsdf_u, u_lobe): (Vec2, f32),
    light_u: Option<(f32, Vec2)>,
) -> Option<Ray> {
    let p_out = offset_ray_origin(sp.p, sp.err, at.n);
    let frame = Frame::from_normal(at.ns);
    let o = frame.to_local(wo);
    if let Some(u) = light_u {
        let lobe = Lobe {
            frame: &frame,
            eval: |i| p.eval(o, i),
            pdf: |i| p.pdf(o, i),
        };
        reflected_light(scene, strategy, path, sp, at, p_out, u, lobe);
    }
    let s = p.sample(o, bsdf_u, u_lobe)?;
    follow(
        path,
        at,
        p_out,
        frame.to_world(s.wi),
        s.weight,
        s.pdf,
        s.delta,
    )
}

/// A reflection lobe at a vertex, in its shading `frame`, for the path's outgoing direction:
/// f·cos θi and the density of its sampler, both of the local direction i.
struct Lobe<'a, E, P> {
    frame: &'a Frame,
    eval: E,
    pdf: P,
}

/// Next-event estimation through a reflection lobe (rough metal, plastic): a light sample
/// from `p_out`, weighed by the power heuristic against the lobe's own density under MIS.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn reflected_light<E, P>(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    sp: &SurfacePoint,
    at: &Shading,
    p_out: Vec3A,
    u: (f32, Vec2),
    lobe: Lobe<'_, E, P>,
) where
    E: Fn(Vec3A) -> Vec3A,
    P: Fn(Vec3A) -> f32,
{
    if let Some((ls, _)) = visible_light(scene, strategy, sp, at, p_out, u) {
        let i = lobe.frame.to_local(ls.wi);
        let f = (lobe.eval)(i);
        let w = if strategy == Strategy::Mis && !ls.delta {
            power_heuristic(ls.pdf, (lobe.pdf)(i))
        } else {
            1.0
        };
        path.l += path.beta * ls.le * f * (w / ls.pdf);
    }
}

/// Continues the path from `p_out` along the reflected direction `wi` (world space) drawn
/// with weight f·cos/pdf `weight` and density `pdf` (a delta direction: `specular`); `None`
/// where it points into the geometric surface.
#[inline(always)]
fn follow(
    path: &mut Path,
    at: &Shading,
    p_out: Vec3A,
    wi: Vec3A,
    weight: Vec3A,
    pdf: f32,
    specular: bool,
) -> Option<Ray> {
    path.beta *= weight;
    path.specular = specular;
    path.prev_pdf = pdf;
    if at.shaded && at.n.dot(wi) <= 0.0 {
        return None;
    }
    Some(Ray::new(p_out, wi))
}
