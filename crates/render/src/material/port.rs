//! What a material asks of the code that uses it, as traits that code implements: a surface
//! point and what lies around it ([`Surface`]: the AOV pass and the path tracer), a path's
//! vertex ([`At`]: the path tracer's next-event estimation, its Lambertian vertex with guiding,
//! the medium a path is in), and a scene file's fields ([`Reading`]). A material reads the
//! scene through these and nothing else, so it sits below the scene and the integrators, and
//! a new one needs no code of theirs.
//!
//! The path state ([`Path`]) and a vertex's numbers ([`Numbers`]) live here too: a material
//! updates the first and draws from the second.

use std::sync::Arc;

use glam::{Vec2, Vec3A};

use super::desc::MaterialDesc;
use crate::bsdf::{PbrMaterial, Plastic};
use crate::interaction::{Shading, SurfacePoint};
use crate::mesh::UvFrame;
use crate::texture::{Texture, TextureUse};
use crate::util::fields::{only, Invalid, KeyPath};
use crate::util::math::{offset_ray_origin, Frame, Ray};

/// A path between vertices: what it has gathered, its throughput, and how it arrived at
/// its last vertex (what weighs an emitter it finds next). Copy, so that the out-of-line
/// vertices get a copy to update (the integrator's `vertex`).
#[derive(Clone, Copy)]
pub(crate) struct Path {
    pub(crate) l: Vec3A,
    pub(crate) beta: Vec3A,
    /// The product of η² over the refractions so far, which Russian roulette undoes: radiance
    /// compressed by entering glass is not a reason to end a path.
    pub(crate) eta_scale: f32,
    /// The last bounce was specular (or the camera's): light sampling could not have found
    /// the emitter, so it counts in full.
    pub(crate) specular: bool,
    pub(crate) prev_pdf: f32,
    pub(crate) prev_p: Vec3A,
    /// Absorption per unit length of the medium the path is in (zero: clear); tracked only
    /// in scenes with coloured glass. Media do not nest: leaving any glass is leaving to clear
    /// air.
    pub(crate) medium: Vec3A,
}

/// The numbers a vertex draws with (the integrator's dimension layout says from where).
#[derive(Clone, Copy)]
pub(crate) struct Numbers {
    /// The BSDF's direction.
    pub(crate) bsdf: Vec2,
    /// Light selection and the light's point, when the vertex samples a light.
    pub(crate) light: Option<(f32, Vec2)>,
    /// A glass's reflection or refraction, a layered material's lobe, a guided vertex's
    /// choice of the guide or the BSDF.
    pub(crate) choice: f32,
}

/// A reflection lobe at a vertex, in its shading `frame`, for the path's outgoing direction:
/// f·cos θi and the density of its sampler, both of the local direction i. What next-event
/// estimation weighs a light sample with.
pub(crate) struct Lobe<'a, E, P> {
    pub(crate) frame: &'a Frame,
    pub(crate) eval: E,
    pub(crate) pdf: P,
}

/// A surface point a material is asked about, and what it may read there: the scene's
/// textures and tables for as long as the scene (`'s`), the rest for the call.
pub(crate) trait Surface<'s> {
    /// The ray that arrived.
    fn ray(&self) -> &Ray;
    /// The point met.
    fn point(&self) -> &SurfacePoint;
    /// The normals on the side the ray arrived from.
    fn shading(&self) -> &Shading;
    /// Whether it arrived on the front side.
    fn front(&self) -> bool;
    /// Whether the material was declared two-sided.
    fn two_sided(&self) -> bool;
    /// The scene's textures, which materials name by index.
    fn textures(&self) -> &'s [Arc<Texture>];
    /// The large materials that the small ones index.
    fn tables(&self) -> &'s Tables;
    /// The texture coordinates there (zero off meshes).
    fn uv(&self) -> Vec2;
    /// The texture coordinates and their tangent frame there, on meshes that have them.
    fn uv_frame(&self) -> Option<UvFrame>;
}

/// A path's vertex, for a material to scatter the path at: its numbers, the path, and what
/// the integrator does for every material alike.
pub(crate) trait At<'s>: Surface<'s> {
    /// The numbers this vertex draws with.
    fn numbers(&self) -> Numbers;
    /// The path arriving here, to update.
    fn path(&mut self) -> &mut Path;
    /// A Lambertian vertex of albedo `albedo`: direct light, then a cosine-weighted
    /// direction (or the guide's, where guiding runs). `None` ends the path.
    fn diffuse(&mut self, albedo: Vec3A) -> Option<Ray>;
    /// Next-event estimation through a reflection lobe, from `p_out` above `at`.
    fn reflected_light<E, P>(
        &mut self,
        at: &Shading,
        p_out: Vec3A,
        u: (f32, Vec2),
        lobe: Lobe<'_, E, P>,
    ) where
        E: Fn(Vec3A) -> Vec3A,
        P: Fn(Vec3A) -> f32;
    /// Next-event estimation through a lobe that reflects and transmits: a light on either
    /// side of `at`.
    fn two_sided_light<E, P>(&mut self, at: &Shading, u: (f32, Vec2), lobe: Lobe<'_, E, P>)
    where
        E: Fn(Vec3A) -> Vec3A,
        P: Fn(Vec3A) -> f32;
    /// The path went through the surface: where the scene tracks media, it is now inside
    /// this material's (entering by the front) or in clear air (leaving).
    fn went_through(&mut self);
}

/// What the first non-specular surface a camera ray meets shows the AOV pass.
pub(crate) enum Seen {
    /// A surface of this albedo, clamped to [0, 1], seen along the shading normal.
    Albedo(Vec3A),
    /// A surface of this albedo, and the normal it shades with (a normal map's).
    Shaded { albedo: Vec3A, normal: Vec3A },
    /// A delta bounce: the ray goes on.
    Next(Ray),
    /// Nothing: the path ends here.
    Nothing,
}

/// The materials too large to keep in every [`crate::scene::Material`] (a plastic's tables, a glTF
/// material's textures), which the small ones name by index.
#[derive(Clone, Debug, Default)]
pub struct Tables {
    plastics: Vec<Plastic>,
    pbrs: Vec<PbrMaterial>,
}

impl Tables {
    /// The plastic at `index`.
    #[inline(always)]
    pub fn plastic(&self, index: u32) -> &Plastic {
        &self.plastics[index as usize]
    }

    /// The glTF material at `index`.
    #[inline(always)]
    pub fn pbr(&self, index: u32) -> &PbrMaterial {
        &self.pbrs[index as usize]
    }

    /// Every glTF material.
    pub fn pbrs(&self) -> &[PbrMaterial] {
        &self.pbrs
    }

    /// Keeps `p`, returning its index.
    pub(crate) fn add_plastic(&mut self, p: Plastic) -> u32 {
        self.plastics.push(p);
        self.plastics.len() as u32 - 1
    }

    /// Keeps `p`, returning its index.
    pub(crate) fn add_pbr(&mut self, p: PbrMaterial) -> u32 {
        self.pbrs.push(p);
        self.pbrs.len() as u32 - 1
    }
}

/// A texture a reader loads for a material: its file, where the scene names it, and what is
/// read from it; its index in the scene's textures.
pub(crate) type LoadTexture<'a> =
    dyn FnMut(&str, &KeyPath, TextureUse) -> Result<u32, Invalid> + 'a;

/// One `[materials.NAME]` table being read: its fields, where it is, and where what it loads
/// goes.
pub(crate) struct Reading<'a, 'b> {
    pub(crate) desc: &'a MaterialDesc,
    /// `materials.NAME`.
    pub(crate) at: &'a KeyPath,
    pub(crate) textures: &'a mut LoadTexture<'b>,
    pub(crate) tables: &'a mut Tables,
}

impl Reading<'_, '_> {
    /// Refuses every key but `allowed` (and those every material takes), naming the first
    /// other one given: `kind` is "a diffuse material" and so on.
    pub(crate) fn only(&self, kind: &str, allowed: &[&str]) -> Result<(), Invalid> {
        only(self.at, kind, &self.desc.kind_keys(), allowed)
    }

    /// The path of one of its keys.
    pub(crate) fn key(&self, k: &str) -> KeyPath {
        self.at.key(k)
    }
}

/// Continues the path from `p_out` along the reflected direction `wi` (world space) drawn
/// with weight f·cos/pdf `weight` and density `pdf` (a delta direction: `specular`); `None`
/// where it points into the geometric surface.
#[inline(always)]
pub(crate) fn follow(
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

/// The ray leaving `sp` along `wi` (world space), `through` the surface or not as the shading
/// frame says, from the geometric side it points to; `None` where the geometric normal
/// disagrees about that side.
#[inline(always)]
pub(crate) fn leave(sp: &SurfacePoint, at: &Shading, wi: Vec3A, through: bool) -> Option<Ray> {
    let above = at.n.dot(wi) >= 0.0;
    if at.shaded && above == through {
        return None;
    }
    let side = if above { at.n } else { -at.n };
    Some(Ray::new(offset_ray_origin(sp.p, sp.err, side), wi))
}
