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

use crate::bsdf::{reflect, Bsdf};
use crate::integrator::{dielectric, pbr_at, thin_dielectric, Shading};
use crate::scene::Scene;
use crate::util::math::{offset_ray_origin, Ray};
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
    for bounce in 0..=MAX_SPECULAR {
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
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
        let surface = |albedo: Vec3A| FirstHit {
            albedo: albedo.clamp(Vec3A::ZERO, Vec3A::ONE),
            normal: at.ns,
            depth: out.depth,
        };
        // The beauty's u_choice for this bounce (its group 2 + 2d, second number).
        let u_choice = || sampler.get4(2 + 2 * bounce)[1];
        let next = match mat.bsdf {
            Bsdf::Diffuse(albedo) => {
                let albedo = match mat.texture {
                    None => albedo,
                    Some(t) => scene.textures[t as usize].lookup(prim.shape.uv(&ray, hit.part)),
                };
                return surface(albedo);
            }
            Bsdf::Plastic(index) => return surface(scene.plastic(index).albedo()),
            Bsdf::Pbr(index) => {
                let (params, bent) =
                    pbr_at(scene, scene.pbr(index), &ray, &hit, prim, &sp, &at, front);
                return FirstHit {
                    albedo: params.base_color,
                    normal: bent.ns,
                    depth: out.depth,
                };
            }
            Bsdf::RoughDielectric(_) => return surface(Vec3A::ONE),
            Bsdf::Conductor(ref m) if !m.is_smooth() => {
                return surface(m.conductor().fresnel.eval(1.0))
            }
            Bsdf::Conductor(_) | Bsdf::Mirror(_) => {
                let wi = reflect(ray.d, at.ns);
                if at.shaded && at.n.dot(wi) <= 0.0 {
                    return out;
                }
                Ray::new(offset_ray_origin(sp.p, sp.err, at.n), wi)
            }
            Bsdf::Dielectric(ior) => match dielectric(&ray, &sp, &at, front, ior, u_choice()) {
                Some(r) => r.ray,
                None => return out,
            },
            Bsdf::ThinDielectric(ior) => match thin_dielectric(&ray, &sp, &at, ior, u_choice()) {
                Some(r) => r,
                None => return out,
            },
        };
        ray = next;
    }
    out
}
