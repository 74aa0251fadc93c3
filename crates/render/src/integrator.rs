//! The path tracer.
//!
//! Estimator (derived here, not taken from the course notes): at a diffuse vertex the BSDF is
//! f = ρ/π and the next direction is drawn with pdf cos θ/π, so the throughput update
//! f·cos θ/pdf is exactly ρ. Direct light is estimated twice — by sampling a point on a light
//! (next-event estimation) and by the BSDF-sampled ray hitting an emitter — and the two are
//! combined with the power heuristic, which keeps the sum unbiased because the two weights of
//! any light path add to one. Russian roulette after the third bounce ends paths with
//! probability 1 − q and divides survivors by q (q > 0 always), which also keeps the
//! expectation unchanged; q only trades variance against time.

use glam::{Vec2, Vec3A};

use crate::bsdf::{fresnel_dielectric, reflect, refract, sample_diffuse, Bsdf};
use crate::math::{offset_ray_origin, Ray};
use crate::sampling::{cosine_hemisphere_pdf, power_heuristic, PixelSampler};
use crate::scene::Scene;

/// How direct light is estimated. All three converge to the same image; `Mis` has the lowest
/// variance, the others exist to test that claim. Stored (in the coordinator's job records) by
/// its lower-case [`Strategy::name`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Strategy {
    /// Next-event estimation and BSDF sampling, combined by the power heuristic.
    #[default]
    Mis,
    /// BSDF sampling only: emitters count only when a path happens to hit them.
    Bsdf,
    /// Light sampling only at diffuse vertices (emitters reached by a diffuse bounce count 0).
    Nee,
}

impl Strategy {
    /// Lower-case name, as on the command line and in EXR metadata.
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Mis => "mis",
            Strategy::Bsdf => "bsdf",
            Strategy::Nee => "nee",
        }
    }

    /// Inverse of [`Strategy::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        [Strategy::Mis, Strategy::Bsdf, Strategy::Nee]
            .into_iter()
            .find(|s| s.name() == name)
    }
}

/// Samples per batch when a render or job does not choose. The batch decides the order in
/// which sums are added, so it is part of a job's identity: every entry point (`tessera
/// render`, `tessera submit`, the coordinator) must use this one value for their bits to match.
pub const DEFAULT_BATCH: u32 = 16;

/// The batch sizes accepted everywhere.
pub const BATCH_RANGE: std::ops::RangeInclusive<u32> = 1..=65536;

/// The tile edges (in pixels) the farm accepts.
pub const TILE_RANGE: std::ops::RangeInclusive<u32> = 4..=512;

/// The coordinator's tile edge for jobs that do not choose one.
pub const DEFAULT_TILE: u32 = 128;

/// Which path tracer renders. Every choice gives the same bits (`tests/wide.rs` compares the
/// many-path tracer with the scalar one sample by sample), so this is no part of a job's
/// identity and never travels to workers: it exists to time the tracers against each other.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Tracer {
    /// The many-path tracer for scenes whose bounce it models, the scalar one for the rest.
    #[default]
    Auto,
    /// One path at a time, always.
    Scalar,
    /// The many-path tracer with this many lanes (4, 8 or 16) where it applies; other counts,
    /// and other scenes, trace one path at a time.
    Lanes(usize),
}

/// Everything besides the scene that decides a render's pixels.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    /// Job seed.
    pub seed: u64,
    /// Samples per pixel.
    pub spp: u32,
    /// Samples per batch: sums are accumulated per batch and batches added in order, so this
    /// is part of a job's identity (like the seed) for bit-exact reproduction.
    pub batch: u32,
    /// Direct-lighting strategy.
    pub strategy: Strategy,
    /// Bounce at which Russian roulette starts.
    pub rr_depth: u32,
    /// Throughput below which Russian roulette starts to end paths: a path survives with
    /// probability min(0.95, max(β)/threshold). The cap keeps a path between perfect mirrors
    /// finite. pbrt's rule is threshold 1; 0.25 keeps paths through the Cornell box's bright
    /// walls alive, whose deep bounces carry much of its light, and measured less
    /// relMSE·seconds there (docs/renderer.md).
    pub rr_threshold: f32,
    /// Which tracer runs (the same bits whichever).
    pub tracer: Tracer,
    /// Noise-targeted adaptive sampling: `None` gives every pixel `spp` samples (the unbiased
    /// default); `Some` makes `spp` a cap and stops each tile once its noise meets the target
    /// ([`crate::adaptive`]). Part of a job's identity when set.
    pub adaptive: Option<crate::adaptive::Adaptive>,
    /// The frame of an animated scene this render is of (`None`: a render that names no
    /// frame, of a still scene or of an animated scene's first frame). It chooses the scene
    /// built from the file ([`crate::scene::Scene::from_str_at`]) and goes into the EXR's
    /// header, so it is part of the render's identity when set.
    pub frame: Option<u32>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            seed: 0,
            spp: 64,
            batch: DEFAULT_BATCH,
            strategy: Strategy::Mis,
            rr_depth: 3,
            rr_threshold: 0.25,
            tracer: Tracer::Auto,
            adaptive: None,
            frame: None,
        }
    }
}

/// The radiance estimate of one camera sample of pixel (`x`, `y`): the sample `sampler` (made
/// for that pixel and the job's seed) is at.
pub fn sample_pixel(
    scene: &Scene,
    settings: &RenderSettings,
    x: u32,
    y: u32,
    sampler: &PixelSampler,
) -> Vec3A {
    let [jx, jy, lx, ly] = sampler.get4(0);
    let ray = scene.camera.ray(x as f32 + jx, y as f32 + jy);
    trace(scene, settings, ray, sampler, [lx, ly])
}

/// Radiance arriving at the camera along `ray`, for a path that starts at `ray` rather than at
/// a pixel: group 0's pixel position goes unused, its light point is the first vertex's.
pub fn radiance(
    scene: &Scene,
    settings: &RenderSettings,
    ray: Ray,
    sampler: &PixelSampler,
) -> Vec3A {
    let [_, _, lx, ly] = sampler.get4(0);
    trace(scene, settings, ray, sampler, [lx, ly])
}

/// [`radiance`], given the first vertex's light-sample point `light_uv` (group 0's last two
/// numbers, which [`sample_pixel`] has already drawn with the pixel position).
///
/// Dimension layout, chosen so that each Sobol group holds the four numbers one term of the
/// image depends on jointly, and is stratified in all four together: group 0 is the pixel
/// position and the light point of the first vertex (its direct light); group 1 + 2d is
/// bounce d's direction and the light point of the vertex it reaches (one bounce of indirect
/// light); group 2 + 2d holds bounce d's scalar choices (light selection, reflect or refract,
/// Russian roulette), drawn only when one of them is needed.
fn trace(
    scene: &Scene,
    settings: &RenderSettings,
    mut ray: Ray,
    sampler: &PixelSampler,
    mut light_uv: [f32; 2],
) -> Vec3A {
    // Only smooth meshes have shading normals; other scenes skip their side tests below
    // (a branch that always goes one way) rather than pay for them at every bounce.
    let shading_normals = scene.has_shading_normals();
    let strategy = if scene.lights.is_empty() {
        Strategy::Bsdf
    } else {
        settings.strategy
    };
    let mut l = Vec3A::ZERO;
    let mut beta = Vec3A::ONE;
    let mut eta_scale = 1.0f32;
    // The camera "bounce" is specular: emitters seen directly count in full.
    let mut specular = true;
    let mut prev_pdf = 0.0f32;
    let mut prev_p = ray.o;
    let mut depth = 0u32;
    loop {
        let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
            if let Some(env) = &scene.environment {
                l += beta * env.radiance(ray.d);
            }
            break;
        };
        let prim = &scene.prims[hit.prim as usize];
        let sp = prim.shape.surface(&ray, hit.t, hit.part);
        let mat = &scene.materials[prim.material as usize];
        let wo = -ray.d;

        if prim.light != u32::MAX {
            let li = (prim.light + hit.part * prim.light_stride) as usize;
            let le = scene.lights.lights[li].emitted(sp.n, wo);
            if le != Vec3A::ZERO {
                match strategy {
                    _ if specular => l += beta * le,
                    Strategy::Bsdf => l += beta * le,
                    Strategy::Mis => {
                        let light_pdf = scene.lights.pdf(li, prev_p, sp.p, sp.n);
                        l += beta * le * power_heuristic(prev_pdf, light_pdf);
                    }
                    Strategy::Nee => {}
                }
            }
        }
        if scene.max_depth.is_some_and(|m| depth >= m) {
            break;
        }
        let front = sp.n.dot(wo) >= 0.0;
        if !front && !mat.two_sided && !matches!(mat.bsdf, Bsdf::Dielectric(_)) {
            // The back of a one-sided surface absorbs everything.
            break;
        }
        // Normals on the side the path arrived from: the geometric one for ray offsets and
        // for which side a direction leaves by, the shading one for scattering.
        let n = if front { sp.n } else { -sp.n };
        // A smooth mesh's shading normal; elsewhere ns = n and the extra side tests below,
        // which compare with the geometric normal, would repeat the shading ones.
        let shaded = shading_normals && sp.ns != sp.n;
        let ns = match (shaded, front) {
            (false, _) => n,
            (true, true) => sp.ns,
            (true, false) => -sp.ns,
        };
        let [u0, u1, next_lx, next_ly] = sampler.get4(1 + 2 * depth);
        let nee = strategy != Strategy::Bsdf && matches!(mat.bsdf, Bsdf::Diffuse(_));
        // u_rr decides Russian roulette after this bounce.
        let [u_select, u_choice, u_rr, _] = if (nee && scene.lights.lights.len() > 1)
            || matches!(mat.bsdf, Bsdf::Dielectric(_))
            || depth + 1 >= settings.rr_depth
        {
            sampler.get4(2 + 2 * depth)
        } else {
            [0.0; 4]
        };
        let [lx, ly] = std::mem::replace(&mut light_uv, [next_lx, next_ly]);
        let next = match mat.bsdf {
            Bsdf::Diffuse(albedo) => {
                let albedo = match mat.texture {
                    None => albedo,
                    Some(t) => scene.textures[t as usize].lookup(prim.shape.uv(&ray, hit.part)),
                };
                let p_out = offset_ray_origin(sp.p, sp.err, n);
                if nee {
                    if let Some(ls) = scene.lights.sample(sp.p, u_select, Vec2::new(lx, ly)) {
                        let cos = ns.dot(ls.wi);
                        // A light behind the geometric surface is unreachable, whatever the
                        // shading normal says.
                        let reachable = !shaded || n.dot(ls.wi) > 0.0;
                        if cos > 0.0 && reachable && ls.le != Vec3A::ZERO {
                            let d = ls.p - p_out;
                            if !scene.occluded(&Ray::new(p_out, d), 1.0 - 1e-4) {
                                let w = if strategy == Strategy::Mis {
                                    power_heuristic(ls.pdf, cosine_hemisphere_pdf(cos))
                                } else {
                                    1.0
                                };
                                l += beta
                                    * albedo
                                    * ls.le
                                    * (cos * std::f32::consts::FRAC_1_PI * w / ls.pdf);
                            }
                        }
                    }
                }
                let (wi, pdf) = sample_diffuse(ns, Vec2::new(u0, u1));
                // f·cos/pdf = (ρ/π)·cos / (cos/π) = ρ, with cos against the shading normal.
                beta *= albedo;
                specular = false;
                prev_pdf = pdf;
                // A direction into the geometric surface scatters nothing: f is 0 there.
                if !(prev_pdf > 0.0) || (shaded && n.dot(wi) <= 0.0) {
                    break;
                }
                Ray::new(p_out, wi)
            }
            Bsdf::Mirror(r) => {
                beta *= r;
                specular = true;
                let wi = reflect(ray.d, ns);
                if shaded && n.dot(wi) <= 0.0 {
                    break;
                }
                Ray::new(offset_ray_origin(sp.p, sp.err, n), wi)
            }
            Bsdf::Dielectric(ior) => {
                // The front side (sp.n) is outside.
                let eta = if front { ior } else { 1.0 / ior };
                let cos_i = ns.dot(wo).min(1.0);
                if shaded && !(cos_i > 0.0) {
                    // Seen from behind its shading normal: no Fresnel term is defined.
                    break;
                }
                let (f, cos_t) = fresnel_dielectric(cos_i, eta);
                specular = true;
                let (wi, through) = if u_choice < f {
                    (reflect(ray.d, ns), false)
                } else {
                    // Radiance is compressed by 1/η² entering a denser medium.
                    let wt = refract(wo, ns, eta, cos_i, cos_t);
                    beta /= eta * eta;
                    eta_scale *= eta * eta;
                    (wt, true)
                };
                // Off the side the new direction leaves by: the geometric normal decides it
                // where the shading normal could disagree.
                let side = if shaded {
                    if n.dot(wi) >= 0.0 {
                        n
                    } else {
                        -n
                    }
                } else if through {
                    -n
                } else {
                    n
                };
                Ray::new(offset_ray_origin(sp.p, sp.err, side), wi)
            }
        };
        prev_p = sp.p;
        depth += 1;
        if depth >= settings.rr_depth {
            let q = ((beta * eta_scale).max_element() / settings.rr_threshold).min(0.95);
            if !(u_rr < q) {
                break;
            }
            beta /= q;
        }
        ray = Ray::new(next.o, next.d.normalize());
    }
    l
}
