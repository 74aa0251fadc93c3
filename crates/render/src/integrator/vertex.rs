//! One vertex of a path: the material the path met scatters it. Every material's vertex is
//! one arm of [`scatter`], calling that material's own code (in this folder's `lobes` and
//! `guided_vertex`, and in [`super`] for the smooth and rough glass); what the loop of
//! `trace` asks of a material before it scatters (whether to sample lights, whether
//! to draw a choice, whether its back side scatters) is [`Bsdf`]'s to answer.
//!
//! Each out-of-line vertex gets a copy of the path to update, taken back even when the path
//! ends there (its direct light counts): a `&mut` to the loop's own path would make its
//! address escape, and keep it in memory rather than in registers for every other bounce.

use glam::{Vec2, Vec3A};

use super::lobes::{self, conductor, pbr, plastic};
use super::{
    dielectric, diffuse, guided_vertex, rough_dielectric, thin_dielectric, Guiding, Path, Shading,
};
use crate::bsdf::{reflect, Bsdf, Metal, RoughDielectric};
use crate::interaction::Hit;
use crate::interaction::SurfacePoint;
use crate::primitive::Primitive;
use crate::scene::{Material, Scene};
use crate::settings::Strategy;
use crate::util::math::{offset_ray_origin, Ray};

/// Where a path meets a surface, and how it arrived.
pub(super) struct Vertex<'s> {
    pub(super) scene: &'s Scene,
    pub(super) strategy: Strategy,
    /// The ray that arrived.
    pub(super) ray: &'s Ray,
    pub(super) hit: &'s Hit,
    pub(super) prim: &'s Primitive,
    pub(super) mat: &'s Material,
    pub(super) sp: &'s SurfacePoint,
    /// The normals on the side the path arrived from.
    pub(super) at: &'s Shading,
    /// Whether it arrived on the front side.
    pub(super) front: bool,
    /// Whether the scene tracks the medium a path is in (coloured glass).
    pub(super) absorbing: bool,
}

/// The numbers a vertex draws with (`trace`'s dimension layout says from where).
#[derive(Clone, Copy)]
pub(super) struct Numbers {
    /// The BSDF's direction.
    pub(super) bsdf: Vec2,
    /// Light selection and the light's point, when the vertex samples a light.
    pub(super) light: Option<(f32, Vec2)>,
    /// A glass's reflection or refraction, a layered material's lobe, a guided vertex's
    /// choice of the guide or the BSDF.
    pub(super) choice: f32,
}

/// Scatters `path` at `v`: adds the direct light its material gathers there and returns the
/// next ray, or `None` where the path ends.
///
/// The one place a material's vertex is dispatched: an arm per material; the longer arms are
/// functions of their own, inlined (the loop's codegen is what it was).
#[inline(always)]
pub(super) fn scatter<'a, G: Guiding<'a>>(
    v: &Vertex<'_>,
    path: &mut Path,
    u: Numbers,
    guiding: &mut G,
    depth: u32,
) -> Option<Ray> {
    let (scene, strategy, sp, at) = (v.scene, v.strategy, v.sp, v.at);
    match v.mat.bsdf {
        Bsdf::Diffuse(albedo) => {
            let albedo = match v.mat.texture {
                None => albedo,
                Some(t) => scene.textures[t as usize].lookup(v.prim.shape.uv(v.ray, v.hit.part)),
            };
            match guiding.path() {
                None => diffuse(scene, strategy, path, albedo, sp, at, u.bsdf, u.light),
                Some(g) => {
                    let mut updated = *path;
                    let next = guided_vertex::diffuse(
                        scene,
                        strategy,
                        &mut updated,
                        albedo,
                        sp,
                        at,
                        (u.bsdf, u.choice),
                        u.light,
                        (g, depth),
                    );
                    *path = updated;
                    next
                }
            }
        }
        Bsdf::Mirror(r) => {
            path.beta *= r;
            path.specular = true;
            let wi = reflect(v.ray.d, at.ns);
            if at.shaded && at.n.dot(wi) <= 0.0 {
                return None;
            }
            Some(Ray::new(offset_ray_origin(sp.p, sp.err, at.n), wi))
        }
        Bsdf::Conductor(ref m) => conductor_vertex(v, m, path, u),
        Bsdf::Dielectric(ior) => {
            let next = dielectric(v.ray, sp, at, v.front, ior, u.choice)?;
            path.specular = true;
            path.beta /= next.attenuation;
            path.eta_scale *= next.attenuation;
            if v.absorbing && next.through {
                path.medium = medium_entered(v);
            }
            Some(next.ray)
        }
        Bsdf::RoughDielectric(ref rd) => rough_glass_vertex(v, rd, path, u),
        Bsdf::ThinDielectric(ior) => {
            let next = thin_dielectric(v.ray, sp, at, ior, u.choice)?;
            path.specular = true;
            Some(next)
        }
        Bsdf::Pbr(index) => pbr_vertex(v, index, path, u),
        Bsdf::Plastic(index) => plastic_vertex(v, index, path, u),
    }
}

/// A metal's vertex (rough or smooth).
#[inline(always)]
fn conductor_vertex(v: &Vertex<'_>, m: &Metal, path: &mut Path, u: Numbers) -> Option<Ray> {
    let (scene, strategy, sp, at, wo) = (v.scene, v.strategy, v.sp, v.at, -v.ray.d);
    let mut updated = *path;
    let next = conductor(
        scene,
        strategy,
        &mut updated,
        &m.conductor(),
        wo,
        sp,
        at,
        u.bsdf,
        u.light,
    );
    *path = updated;
    next
}

/// A rough glass's vertex: reflection or refraction, and the medium entered.
#[inline(always)]
fn rough_glass_vertex(
    v: &Vertex<'_>,
    rd: &RoughDielectric,
    path: &mut Path,
    u: Numbers,
) -> Option<Ray> {
    let (scene, strategy, sp, at, wo) = (v.scene, v.strategy, v.sp, v.at, -v.ray.d);
    let eta = if v.front { rd.ior } else { 1.0 / rd.ior };
    let mut updated = *path;
    let next = rough_dielectric(
        scene,
        strategy,
        &mut updated,
        rd,
        eta,
        wo,
        sp,
        at,
        (u.bsdf, u.choice),
        u.light,
    );
    *path = updated;
    let (next, through) = next?;
    if v.absorbing && through {
        path.medium = medium_entered(v);
    }
    Some(next)
}

/// A glTF metallic–roughness material's vertex.
#[inline(always)]
fn pbr_vertex(v: &Vertex<'_>, index: u32, path: &mut Path, u: Numbers) -> Option<Ray> {
    let (scene, strategy, sp, at) = (v.scene, v.strategy, v.sp, v.at);
    let mut updated = *path;
    let next = pbr(
        scene,
        strategy,
        &mut updated,
        lobes::PbrHit {
            material: scene.pbr(index),
            ray: v.ray,
            hit: v.hit,
            prim: v.prim,
            two_sided: v.mat.two_sided,
            front: v.front,
        },
        sp,
        at,
        (u.bsdf, u.choice),
        u.light,
    );
    *path = updated;
    next
}

/// A plastic's vertex: the coat or the base.
#[inline(always)]
fn plastic_vertex(v: &Vertex<'_>, index: u32, path: &mut Path, u: Numbers) -> Option<Ray> {
    let (scene, strategy, sp, at, wo) = (v.scene, v.strategy, v.sp, v.at, -v.ray.d);
    let mut updated = *path;
    let next = plastic(
        scene,
        strategy,
        &mut updated,
        scene.plastic(index),
        wo,
        sp,
        at,
        (u.bsdf, u.choice),
        u.light,
    );
    *path = updated;
    next
}

/// The medium a path is in once it has gone through `v`'s glass: the material's inside when
/// it entered by the front, clear air when it left.
#[inline]
fn medium_entered(v: &Vertex<'_>) -> Vec3A {
    if v.front {
        v.scene.absorption(v.prim.material)
    } else {
        Vec3A::ZERO
    }
}
