//! Auxiliary images for denoising (AOVs): what a camera sample sees at its first non-specular
//! surface, as Intel Open Image Denoise and Blender's compositor take them beside a noisy
//! beauty image.
//!
//! A denoiser uses them to tell noise from detail: edges and texture in the albedo and normal
//! images are real, so it keeps them. Its documentation asks for the albedo and normal of the
//! first *diffuse* surface, seen through perfect mirrors and smooth glass (whose reflections it
//! would otherwise blur as noise), with values in [0, 1] and [−1, 1], and a zero normal where
//! the ray meets nothing. So [`first_hit`] follows the camera sample's ray through delta
//! bounces, choosing reflection or refraction at smooth glass by the Fresnel term with the
//! same number the beauty's path uses for that choice, and stops at the first surface with a
//! non-delta lobe. What it records there:
//!
//! | material | albedo |
//! |---|---|
//! | diffuse | its albedo (its texel, if textured) |
//! | plastic | its diffuse base's albedo |
//! | rough metal | its reflectance head-on, F(0°) |
//! | rough glass | 1 |
//! | pbr | its base colour (its texel, if textured); the normal is the normal map's |
//! | an emitter, seen from where it emits | its radiance's colour, largest channel 1 |
//! | nothing met (sky, or more than [`MAX_SPECULAR`] delta bounces) | 0 |
//!
//! Depth is the distance along the camera ray to the first surface it meets, mirror or not
//! (what a compositor's Z defocus and fog read), averaged over the samples that meet one.
//!
//! The pass is separate from the beauty's path (it traces the camera ray again): a render
//! without AOVs runs exactly the code it ran before, and the beauty's bits never depend on
//! whether AOVs were asked for. The same pure sample numbers make the AOVs deterministic like
//! the beauty, and [`crate::film::AovSums`] sums them per batch in index order like it.

use glam::Vec3A;

use std::sync::Arc;

use glam::Vec2;

use crate::interaction::{Hit, Shading, SurfacePoint};
use crate::material::{port, Tables};
use crate::mesh::UvFrame;
use crate::primitive::Primitive;
use crate::scene::Scene;
use crate::texture::Texture;
use crate::util::math::Ray;
use crate::util::sampling::PixelSampler;

/// Delta bounces followed before a sample is taken to have met nothing (two facing mirrors).
pub const MAX_SPECULAR: u32 = 16;

/// One camera sample's AOVs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FirstHit {
    /// Reflectance colour at the first non-specular surface, in [0, 1]; zero where none.
    pub albedo: Vec3A,
    /// Unit world-space shading normal there, facing the arriving ray; zero where none.
    pub normal: Vec3A,
    /// Distance to the first surface the camera ray meets; `None` if it meets none.
    pub depth: Option<f32>,
}

/// The AOVs of the camera sample of pixel (`x`, `y`) that `sampler` is at: its ray is the
/// beauty's ([`crate::integrator::sample_pixel`]'s), and so is each smooth-glass choice.
pub fn first_hit(scene: &Scene, x: u32, y: u32, sampler: &PixelSampler) -> FirstHit {
    let [jx, jy, _, _] = sampler.get4(0);
    let mut ray = scene.camera.ray(x as f32 + jx, y as f32 + jy);
    let shading_normals = scene.has_shading_normals();
    let mut out = FirstHit {
        albedo: Vec3A::ZERO,
        normal: Vec3A::ZERO,
        depth: None,
    };
    let mut t_max = scene.camera.far_t(ray.d);
    for bounce in 0..=MAX_SPECULAR {
        let found = scene.intersect(&ray, t_max);
        t_max = f32::INFINITY;
        let Some(hit) = found else {
            return out;
        };
        if bounce == 0 {
            out.depth = Some(hit.t);
        }
        if bounce == MAX_SPECULAR {
            return out;
        }
        let prim = &scene.prims[hit.prim as usize];
        let sp = prim.shape.surface(&ray, hit.t, hit.part);
        let mat = &scene.materials[prim.material as usize];
        let (front, at) = Shading::facing(&sp, -ray.d, shading_normals);
        if let Some(albedo) = emitter_albedo(scene, (&ray, &hit, prim, &sp)) {
            return FirstHit {
                albedo,
                normal: at.ns,
                depth: out.depth,
            };
        }
        let seen = Seen {
            scene,
            ray: &ray,
            hit: &hit,
            prim,
            sp: &sp,
            at: &at,
            front,
            two_sided: mat.two_sided,
        };
        // The beauty's u_choice for this bounce (its group 2 + 2d, second number).
        let u_choice = sampler.get4(2 + 2 * bounce)[1];
        let next = match mat.bsdf.first_hit(&seen, u_choice) {
            port::Seen::Albedo(albedo) => {
                return FirstHit {
                    albedo: albedo.clamp(Vec3A::ZERO, Vec3A::ONE),
                    normal: at.ns,
                    depth: out.depth,
                }
            }
            port::Seen::Shaded { albedo, normal } => {
                return FirstHit {
                    albedo,
                    normal,
                    depth: out.depth,
                }
            }
            port::Seen::Next(r) => r,
            port::Seen::Nothing => return out,
        };
        ray = next;
    }
    out
}

/// The albedo recorded where the camera sees an emitter: its radiance's colour, scaled so that
/// its largest channel is 1. A lamp usually reflects like what surrounds it (the Cornell box's
/// panel is the ceiling's white), and its own albedo then gave the denoiser no edge between
/// the two: the filter blurred the ceiling's dark seam around the panel into the light. The
/// emitted colour draws that edge (docs/renderer.md, "Denoising"). `None` where nothing is
/// emitted towards the ray (the back of a one-sided lamp), which records its material.
fn emitter_albedo(scene: &Scene, at: (&Ray, &Hit, &Primitive, &SurfacePoint)) -> Option<Vec3A> {
    let (_, _, prim, _) = at;
    if prim.light == u32::MAX {
        return None;
    }
    let (_, le) = scene.emitted(at);
    let peak = le.max_element();
    (peak > 0.0 && peak.is_finite()).then(|| le / peak)
}

/// A surface the AOV pass meets, as a material sees it.
struct Seen<'s> {
    scene: &'s Scene,
    ray: &'s Ray,
    hit: &'s Hit,
    prim: &'s Primitive,
    sp: &'s SurfacePoint,
    at: &'s Shading,
    front: bool,
    two_sided: bool,
}

impl<'s> port::Surface<'s> for Seen<'s> {
    fn ray(&self) -> &Ray {
        self.ray
    }
    fn point(&self) -> &SurfacePoint {
        self.sp
    }
    fn shading(&self) -> &Shading {
        self.at
    }
    fn front(&self) -> bool {
        self.front
    }
    fn two_sided(&self) -> bool {
        self.two_sided
    }
    fn textures(&self) -> &'s [Arc<Texture>] {
        &self.scene.textures
    }
    fn tables(&self) -> &'s Tables {
        self.scene.tables()
    }
    fn uv(&self) -> Vec2 {
        self.prim.shape.uv(self.ray, self.hit.part)
    }
    fn uv_frame(&self) -> Option<UvFrame> {
        self.prim.shape.uv_frame(self.ray, self.hit.part)
    }
}
