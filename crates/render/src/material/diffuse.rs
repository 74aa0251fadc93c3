//! Lambertian reflection, f = ρ/π, with an albedo or a texture's texel at each hit. The path
//! tracer's own vertex (`At::diffuse`): it is the lobe path guiding learns and the eight-lane
//! tracer runs, so its next-event estimation and its guided sampling live with them.

use glam::Vec3A;

use super::desc::AlbedoDesc;
use super::port::{At, Reading, Seen, Surface};
use super::{Bsdf, Model};
use crate::texture::TextureUse;
use crate::util::fields::{color, required, Invalid};
use crate::util::math::Ray;

/// A diffuse material. Sixteen bytes of 4-byte fields, so that [`Bsdf`] stays the 32 bytes it
/// was before the texture joined it (every bounce reads a material: see
/// [`crate::bsdf::Metal`]).
#[derive(Clone, Copy, Debug)]
pub struct Diffuse {
    albedo: [f32; 3],
    /// A texture whose texel replaces the albedo, by index into the scene's textures;
    /// `u32::MAX` for none.
    texture: u32,
}

impl Diffuse {
    /// An untextured diffuse material of albedo `albedo`, in [0, 1].
    pub fn new(albedo: Vec3A) -> Self {
        Self {
            albedo: albedo.to_array(),
            texture: u32::MAX,
        }
    }

    /// A diffuse material whose albedo is texture `texture`'s texel.
    fn textured(texture: u32) -> Self {
        // What NEE-free code paths and tests see; the texel replaces it at each hit.
        Self {
            albedo: [0.5; 3],
            texture,
        }
    }

    /// Its albedo, or the one that stands for its texture's.
    pub fn albedo(&self) -> Vec3A {
        Vec3A::from_array(self.albedo)
    }

    /// The texture whose texel replaces its albedo.
    pub fn texture(&self) -> Option<u32> {
        (self.texture != u32::MAX).then_some(self.texture)
    }

    /// The albedo at `s`.
    #[inline(always)]
    fn albedo_at<'s, S: Surface<'s>>(&self, s: &S) -> Vec3A {
        match self.texture() {
            None => self.albedo(),
            Some(t) => s.textures()[t as usize].lookup(s.uv()),
        }
    }
}

impl Model for Diffuse {
    #[inline(always)]
    fn lanes(&self) -> Option<Vec3A> {
        match self.texture() {
            None => Some(self.albedo()),
            Some(_) => None,
        }
    }
    fn reads_uv(&self, _: &super::Tables) -> bool {
        self.texture().is_some()
    }
    #[inline(always)]
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray> {
        let albedo = self.albedo_at(v);
        v.diffuse(albedo)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, _: f32) -> Seen {
        Seen::Albedo(self.albedo_at(s))
    }
}

/// `type = "diffuse"`: an albedo, a colour or `{ texture = "file" }`.
pub(crate) fn read(r: &mut Reading<'_, '_>) -> Result<Bsdf, Invalid> {
    r.only("a diffuse material", &["albedo"])?;
    let a = required(r.desc.albedo.as_ref(), r.at, "a diffuse material", "albedo")?;
    Ok(Bsdf::Diffuse(match a {
        AlbedoDesc::Color(c) => Diffuse::new(color(*c, &r.key("albedo"), true)?),
        AlbedoDesc::Texture(file) => {
            let path = r.key("albedo").key("texture");
            Diffuse::textured((r.textures)(file, &path, TextureUse::Color)?)
        }
    }))
}
