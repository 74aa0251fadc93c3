//! The glossy vertices of [`super`]'s path tracer: rough or smooth metal, plastic and glTF's
//! `pbr` material, which share next-event estimation through a lobe ([`reflected_light`], or
//! [`two_sided_light`] where light also passes through) and the step to the next ray
//! ([`follow`]).

use glam::{Vec2, Vec3A};

use super::{sample_light, visible_light, Path, Shading};
use crate::bsdf::{reflect, Conductor, PbrBsdf, PbrMaterial, PbrParams, Plastic};
use crate::interaction::{Hit, SurfacePoint};
use crate::primitive::Primitive;
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
pub(super) struct Lobe<'a, E, P> {
    pub(super) frame: &'a Frame,
    pub(super) eval: E,
    pub(super) pdf: P,
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

/// A `pbr` material's parameters at a hit, and the normals with its normal map applied (the
/// shading normal bent, and marked as differing from the geometric one so that every side test
/// runs). `front`: the path arrived on the front side.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn pbr_at(
    scene: &Scene,
    mat: &PbrMaterial,
    ray: &Ray,
    hit: &Hit,
    prim: &Primitive,
    sp: &SurfacePoint,
    at: &Shading,
    front: bool,
) -> (PbrParams, Shading) {
    let frame = if mat.is_textured() {
        prim.shape.uv_frame(ray, hit.part)
    } else {
        None
    };
    let uv = frame.map_or(Vec2::ZERO, |f| f.uv);
    let params = mat.params(&scene.textures, uv);
    let mut shading = *at;
    if let (Some(_), Some(frame)) = (mat.normal_map, frame) {
        let bent = mat.bend(&scene.textures, &frame, sp.ns);
        // A map that tips the normal under the geometric surface is ignored there: no
        // direction above such a normal could leave the surface consistently.
        if bent != sp.ns && bent.dot(sp.n) > 0.0 {
            shading.ns = if front { bent } else { -bent };
            shading.shaded = true;
        }
    }
    (params, shading)
}

/// What a `pbr` vertex needs to know of its hit beyond the surface point.
pub(super) struct PbrHit<'a> {
    pub(super) material: &'a PbrMaterial,
    pub(super) ray: &'a Ray,
    pub(super) hit: &'a Hit,
    pub(super) prim: &'a Primitive,
    pub(super) two_sided: bool,
    /// The path arrived on the front side.
    pub(super) front: bool,
}

/// A `pbr` vertex (see [`crate::bsdf::pbr`]): direct light by next-event estimation (when
/// `light_u` is given) through every lobe light sampling can find — from both sides where the
/// surface transmits — weighed against the mixture's density under MIS, then a direction from
/// the lobe `u.1` picks. A delta lobe's direction (smooth reflection, straight through) is a
/// specular bounce. `None` ends the path.
#[allow(clippy::too_many_arguments)]
// Out of line, with its parameters looked up here: the loop that other scenes run stays as
// small as it was.
#[inline(never)]
pub(super) fn pbr(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    h: PbrHit<'_>,
    sp: &SurfacePoint,
    at: &Shading,
    (bsdf_u, u_lobe): (Vec2, f32),
    light_u: Option<(f32, Vec2)>,
) -> Option<Ray> {
    let (params, at) = pbr_at(scene, h.material, h.ray, h.hit, h.prim, sp, at, h.front);
    let at = &at;
    let bsdf = PbrBsdf::new(params, &h.material.coat);
    if !h.front && !h.two_sided && !bsdf.transmits() {
        // The back of a one-sided surface absorbs everything.
        return None;
    }
    let bsdf = &bsdf;
    let wo = -h.ray.d;
    let frame = Frame::from_normal(at.ns);
    let o = frame.to_local(wo);
    if let Some(u) = light_u {
        let lobe = Lobe {
            frame: &frame,
            eval: |i| bsdf.eval(o, i),
            pdf: |i| bsdf.pdf(o, i),
        };
        if bsdf.transmits() && !bsdf.is_smooth() {
            two_sided_light(scene, strategy, path, sp, at, u, lobe);
        } else {
            let p_out = offset_ray_origin(sp.p, sp.err, at.n);
            reflected_light(scene, strategy, path, sp, at, p_out, u, lobe);
        }
    }
    let s = bsdf.sample(o, bsdf_u, u_lobe)?;
    let wi = frame.to_world(s.wi);
    path.beta *= s.weight;
    path.specular = s.delta;
    path.prev_pdf = s.pdf;
    leave(sp, at, wi, s.wi.z < 0.0)
}

/// The ray leaving `sp` along `wi` (world space), `through` the surface or not as the shading
/// frame says, from the geometric side it points to; `None` where the geometric normal
/// disagrees about that side.
#[inline(always)]
pub(super) fn leave(sp: &SurfacePoint, at: &Shading, wi: Vec3A, through: bool) -> Option<Ray> {
    let above = at.n.dot(wi) >= 0.0;
    if at.shaded && above == through {
        return None;
    }
    let side = if above { at.n } else { -at.n };
    Some(Ray::new(offset_ray_origin(sp.p, sp.err, side), wi))
}

/// Next-event estimation through a lobe that reflects and transmits (rough glass, a `pbr`
/// surface that lets light through): a light sample on either side, its shadow ray leaving
/// from that side, weighed by the power heuristic against the lobe's own density under MIS.
#[inline(always)]
pub(super) fn two_sided_light<E, P>(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    sp: &SurfacePoint,
    at: &Shading,
    (u_select, u_point): (f32, Vec2),
    lobe: Lobe<'_, E, P>,
) where
    E: Fn(Vec3A) -> Vec3A,
    P: Fn(Vec3A) -> f32,
{
    let Some(ls) = sample_light(scene, strategy, sp.p, u_select, u_point) else {
        return;
    };
    let cos = at.ns.dot(ls.wi);
    let side = if cos > 0.0 { at.n } else { -at.n };
    // The geometric normal must put the light on the side the shading one does.
    let reachable = !at.shaded || at.n.dot(ls.wi) * side.dot(at.n) > 0.0;
    if !(cos != 0.0 && reachable && ls.le != Vec3A::ZERO) {
        return;
    }
    let p_out = offset_ray_origin(sp.p, sp.err, side);
    let (shadow, t_max) = ls.shadow_ray(p_out);
    if scene.occluded(&shadow, t_max) {
        return;
    }
    let i = lobe.frame.to_local(ls.wi);
    let f = (lobe.eval)(i);
    let w = if strategy == Strategy::Mis && !ls.delta {
        power_heuristic(ls.pdf, (lobe.pdf)(i))
    } else {
        1.0
    };
    path.l += path.beta * ls.le * (f * w / ls.pdf);
}
