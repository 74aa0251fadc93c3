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

use crate::bsdf::sample_diffuse;
use crate::envmap::EnvMap;
use crate::interaction::{Hit, Shading, SurfacePoint};
use crate::light::LightSample;
use crate::material::port::{Numbers, Path};
use crate::primitive::Primitive;
use crate::scene::{Environment, Material, Scene};
pub use crate::settings::{
    unit_batch, RenderSettings, Strategy, Tracer, BATCH_RANGE, DEFAULT_TILE, DEFAULT_UNIT_SAMPLES,
    MIN_UNITS_PER_FRAME, TILE_RANGE, UNIT_SAMPLES_RANGE,
};
use crate::util::math::{exp_nonpositive, offset_ray_origin, Ray};
use crate::util::sampling::{cosine_hemisphere_pdf, power_heuristic, PixelSampler};

mod guided_vertex;
mod lobes;
mod vertex;
pub use guided_vertex::{GuidedPath, Guiding, NoGuide, MAX_VERTICES};
use vertex::{scatter, Vertex};

/// The radiance estimate of one camera sample of pixel (`x`, `y`): the sample `sampler` (made
/// for that pixel and the job's seed) is at.
#[inline]
pub fn sample_pixel(
    scene: &Scene,
    settings: &RenderSettings,
    x: u32,
    y: u32,
    sampler: &PixelSampler,
) -> Vec3A {
    sample_pixel_with(scene, settings, x, y, sampler, &mut NoGuide)
}

/// [`sample_pixel`] with path guiding (`guiding`: the guide it samples from and the tree it
/// trains; [`crate::guiding`]).
#[inline]
pub fn sample_pixel_with<'a, G: Guiding<'a>>(
    scene: &Scene,
    settings: &RenderSettings,
    x: u32,
    y: u32,
    sampler: &PixelSampler,
    guiding: &mut G,
) -> Vec3A {
    let [jx, jy, lx, ly] = sampler.get4(0);
    let ray = scene.camera.ray(x as f32 + jx, y as f32 + jy);
    let far = scene.camera.far_t(ray.d);
    trace(scene, settings, (ray, far), sampler, [lx, ly], guiding)
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
    trace(
        scene,
        settings,
        (ray, f32::INFINITY),
        sampler,
        [lx, ly],
        &mut NoGuide,
    )
}

/// [`radiance`], given the first vertex's light-sample point `light_uv` (group 0's last two
/// numbers, which [`sample_pixel`] has already drawn with the pixel position).
///
/// Dimension layout, chosen so that each Sobol group holds the four numbers one term of the
/// image depends on jointly, and is stratified in all four together: group 0 is the pixel
/// position and the light point of the first vertex (its direct light); group 1 + 2d is
/// bounce d's direction and the light point of the vertex it reaches (one bounce of indirect
/// light); group 2 + 2d holds bounce d's scalar choices (light selection, reflect or refract,
/// Russian roulette; with guiding, a diffuse vertex's choice of the guide or the BSDF), drawn
/// only when one of them is needed.
fn trace<'a, G: Guiding<'a>>(
    scene: &Scene,
    settings: &RenderSettings,
    (mut ray, mut t_max): (Ray, f32),
    sampler: &PixelSampler,
    mut light_uv: [f32; 2],
    guiding: &mut G,
) -> Vec3A {
    let setup = Setup::new(scene, settings);
    let mut path = Path::from_camera(ray.o);
    let mut depth = 0u32;
    loop {
        // The first segment ends at the camera's far plane, if it has one; the rest do not.
        let found = scene.intersect(&ray, t_max);
        t_max = f32::INFINITY;
        if setup.absorbing && path.medium != Vec3A::ZERO {
            path.beta *= absorbed(path.medium, found.map_or(f32::INFINITY, |h| h.t));
        }
        let Some(hit) = found else {
            escape(&mut path, scene, setup.strategy, ray.d, guiding, depth);
            break;
        };
        let prim = &scene.prims[hit.prim as usize];
        let sp = prim.shape.surface(&ray, hit.t, hit.part);
        if prim.light != u32::MAX {
            emission(
                &mut path,
                scene,
                setup.strategy,
                (&ray, &hit, prim, &sp),
                guiding,
                depth,
            );
        }
        if scene.max_depth.is_some_and(|m| depth >= m) {
            break;
        }
        let here = (&ray, &hit, prim, &sp);
        let Some(next) = setup.leave(
            scene,
            here,
            sampler,
            &mut light_uv,
            &mut path,
            guiding,
            &mut depth,
        ) else {
            break;
        };
        ray = next;
    }
    if let Some(g) = guiding.path() {
        g.finish(path.l);
    }
    path.l
}

/// What a scene and the settings decide once for every path: which side tests, media and
/// estimators its vertices need.
#[derive(Clone, Copy)]
pub(crate) struct Setup {
    /// Only smooth meshes have shading normals; other scenes skip their side tests (a branch
    /// that always goes one way) rather than pay for them at every bounce.
    shading_normals: bool,
    /// Likewise only scenes with coloured glass track the medium a path is in.
    absorbing: bool,
    strategy: Strategy,
    /// Whether vertices sample lights: punctual lights are reached by light sampling alone,
    /// whatever the strategy.
    light_sampling: bool,
    /// Lights in the scene: with one, a vertex draws no selection number.
    lights: usize,
    rr_depth: u32,
    rr_threshold: f32,
}

impl Setup {
    #[inline(always)]
    pub(crate) fn new(scene: &Scene, settings: &RenderSettings) -> Self {
        let strategy = if scene.lights.is_empty() {
            Strategy::Bsdf
        } else {
            settings.strategy
        };
        Self {
            shading_normals: scene.has_shading_normals(),
            absorbing: scene.has_absorption(),
            strategy,
            light_sampling: strategy != Strategy::Bsdf || scene.lights.has_delta(),
            lights: scene.lights.lights.len(),
            rr_depth: settings.rr_depth,
            rr_threshold: settings.rr_threshold,
        }
    }

    /// The rest of a path's visit to the surface point `here` (after what an emitter there
    /// gives it): the material scatters the path, Russian roulette follows, and the next ray
    /// is returned; `None` ends the path. `depth` counts the bounce. The scalar trace and the
    /// lanes of the many-path tracer whose material it does not model in lanes
    /// ([`crate::wide`]) both run this one function, so a sample has the same bits in either.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(crate) fn leave<'a, G: Guiding<'a>>(
        &self,
        scene: &Scene,
        (ray, hit, prim, sp): (&Ray, &Hit, &Primitive, &SurfacePoint),
        sampler: &PixelSampler,
        light_uv: &mut [f32; 2],
        path: &mut Path,
        guiding: &mut G,
        depth: &mut u32,
    ) -> Option<Ray> {
        let mat = &scene.materials[prim.material as usize];
        let (front, at) = Shading::facing(sp, -ray.d, self.shading_normals);
        if !front && !mat.two_sided && !mat.bsdf.has_two_sides() {
            // The back of a one-sided surface absorbs everything.
            return None;
        }
        let (u, u_rr) = self.numbers(mat, sampler, light_uv, guiding, *depth);
        let v = Vertex {
            scene,
            strategy: self.strategy,
            ray,
            hit,
            prim,
            mat,
            sp,
            at: &at,
            front,
            absorbing: self.absorbing,
        };
        let next = scatter(&v, path, u, guiding, *depth)?;
        path.prev_p = sp.p;
        *depth += 1;
        if *depth >= self.rr_depth && !path.survives_roulette(self.rr_threshold, u_rr) {
            return None;
        }
        Some(Ray::new(next.o, next.d.normalize()))
    }

    /// The numbers the vertex at `depth` on `mat` draws, and Russian roulette's after it;
    /// `light_uv` gives this vertex's light point and takes the next one's.
    #[inline(always)]
    fn numbers<'a, G: Guiding<'a>>(
        &self,
        mat: &Material,
        sampler: &PixelSampler,
        light_uv: &mut [f32; 2],
        guiding: &mut G,
        depth: u32,
    ) -> (Numbers, f32) {
        let [u0, u1, next_lx, next_ly] = sampler.get4(1 + 2 * depth);
        // Light sampling at every vertex whose BSDF is not a delta.
        let nee = self.light_sampling && mat.bsdf.samples_lights();
        let chooses = mat.bsdf.draws_choice() || guiding.path().is_some();
        let [u_select, u_choice, u_rr, _] =
            if (nee && self.lights > 1) || chooses || depth + 1 >= self.rr_depth {
                sampler.get4(2 + 2 * depth)
            } else {
                [0.0; 4]
            };
        let [lx, ly] = std::mem::replace(light_uv, [next_lx, next_ly]);
        let u = Numbers {
            bsdf: Vec2::new(u0, u1),
            light: nee.then_some((u_select, Vec2::new(lx, ly))),
            choice: u_choice,
        };
        (u, u_rr)
    }
}

/// What a path that escapes the scene along `d` finds: the environment and the suns.
#[inline(always)]
pub(crate) fn escape<'a, G: Guiding<'a>>(
    path: &mut Path,
    scene: &Scene,
    strategy: Strategy,
    d: Vec3A,
    guiding: &mut G,
    depth: u32,
) {
    let (before, mut sky) = (path.l, Vec3A::ZERO);
    match &scene.environment {
        None => {}
        Some(Environment::Map { map, light }) => {
            add_environment(path, scene, strategy, map, *light, d);
        }
        Some(env) => {
            sky = path.beta * env.radiance(d);
            path.l += sky;
        }
    }
    if !scene.lights.suns().is_empty() {
        add_suns(path, scene, strategy, d);
    }
    if let Some(g) = guiding.path() {
        // A constant sky is never light-sampled: it stays in the guide's training.
        g.found_direct(strategy, path.specular, path.l - before - sky, depth);
    }
}

/// What the emitter the path hit at `sp` (along `ray`) gives it.
#[inline(always)]
fn emission<'a, G: Guiding<'a>>(
    path: &mut Path,
    scene: &Scene,
    strategy: Strategy,
    (ray, hit, prim, sp): (&Ray, &Hit, &Primitive, &SurfacePoint),
    guiding: &mut G,
    depth: u32,
) {
    let (li, le) = scene.emitted((ray, hit, prim, sp));
    if le != Vec3A::ZERO {
        let before = path.l;
        add_emitted(path, scene, strategy, li, le, sp);
        if let Some(g) = guiding.path() {
            g.found_direct(strategy, path.specular, path.l - before, depth);
        }
    }
}

impl Path {
    /// A path leaving the camera from `o`. The camera "bounce" is specular: emitters seen
    /// directly count in full.
    #[inline(always)]
    fn from_camera(o: Vec3A) -> Self {
        Self {
            l: Vec3A::ZERO,
            beta: Vec3A::ONE,
            eta_scale: 1.0,
            specular: true,
            prev_pdf: 0.0,
            prev_p: o,
            medium: Vec3A::ZERO,
        }
    }

    /// Russian roulette with `u_rr`: false ends the path (probability 1 − q); a survivor's
    /// throughput is divided by q, which keeps the estimate unbiased.
    #[inline(always)]
    fn survives_roulette(&mut self, rr_threshold: f32, u_rr: f32) -> bool {
        let q = ((self.beta * self.eta_scale).max_element() / rr_threshold).min(0.95);
        if !(u_rr < q) {
            return false;
        }
        self.beta /= q;
        true
    }
}

/// Beer–Lambert's factor over a segment of length `t` in a medium absorbing `sigma` per unit;
/// one that never ends inside absorbs all of the channels that absorb at all. Out of line, as
/// only coloured glass needs it.
#[inline(never)]
fn absorbed(sigma: Vec3A, t: f32) -> Vec3A {
    Vec3A::new(
        transmittance(sigma.x, t),
        transmittance(sigma.y, t),
        transmittance(sigma.z, t),
    )
}

/// e^(−σt), with a segment that never ends (t = ∞) absorbing wholly where σ > 0 and not at
/// all where σ = 0 (where σt would be NaN).
#[inline]
fn transmittance(sigma: f32, t: f32) -> f32 {
    if sigma == 0.0 {
        1.0
    } else {
        exp_nonpositive(-sigma * t)
    }
}

/// Adds to the path what emitter `li`, hit at `sp` with radiance `le` towards it, gives it:
/// weighted by the power heuristic against light sampling under MIS, in full after a specular
/// bounce or with BSDF sampling alone, and nothing under light sampling alone (it was
/// counted when sampled).
#[inline(always)]
fn add_emitted(
    path: &mut Path,
    scene: &Scene,
    strategy: Strategy,
    li: usize,
    le: Vec3A,
    sp: &SurfacePoint,
) {
    match strategy {
        _ if path.specular => path.l += path.beta * le,
        Strategy::Bsdf => path.l += path.beta * le,
        Strategy::Mis => {
            let light_pdf = scene.lights.pdf(li, path.prev_p, sp.p, sp.n);
            path.l += path.beta * le * power_heuristic(path.prev_pdf, light_pdf);
        }
        Strategy::Nee => {}
    }
}

/// What an environment map (light `light`) gives a path that escapes along `d`: weighted
/// against light sampling as an emitter hit by a BSDF-sampled ray is ([`add_emitted`]), but in
/// full under light sampling alone where light sampling cannot draw `d`. Out of line: only
/// scenes with a map reach it.
#[inline(never)]
fn add_environment(
    path: &mut Path,
    scene: &Scene,
    strategy: Strategy,
    map: &EnvMap,
    light: u32,
    d: Vec3A,
) {
    let (le, w) = match strategy {
        _ if path.specular => (map.radiance(d), 1.0),
        Strategy::Bsdf => (map.radiance(d), 1.0),
        Strategy::Mis => {
            let (le, pdf) = map.radiance_pdf(d);
            let light_pdf = scene.lights.selection(light as usize) * pdf;
            (le, power_heuristic(path.prev_pdf, light_pdf))
        }
        // Light sampling draws the map only where it stands above its mean
        // (`EnvMap`'s MIS compensation): elsewhere this ray is the only estimate.
        Strategy::Nee => match map.radiance_pdf(d) {
            (le, 0.0) => (le, 1.0),
            _ => return,
        },
    };
    path.l += path.beta * le * w;
}

/// The suns a ray that escapes the scene along `d` looks into, weighted as
/// [`add_environment`] weights the map.
#[inline(never)]
fn add_suns(path: &mut Path, scene: &Scene, strategy: Strategy, d: Vec3A) {
    for &i in scene.lights.suns() {
        let Some((le, pdf)) = scene.lights.lights[i as usize].sun_seen(d) else {
            continue;
        };
        let w = match strategy {
            _ if path.specular => 1.0,
            Strategy::Bsdf => 1.0,
            Strategy::Mis => {
                power_heuristic(path.prev_pdf, scene.lights.selection(i as usize) * pdf)
            }
            Strategy::Nee => return,
        };
        path.l += path.beta * le * w;
    }
}

/// A diffuse vertex of albedo `albedo`: direct light by next-event estimation (when
/// `light_u`, its numbers, is given), then the next direction, cosine-weighted (f·cos/pdf =
/// (ρ/π)·cos / (cos/π) = ρ, with cos against the shading normal). `None` ends the path: no
/// direction was drawn, or it points into the geometric surface, where f is 0.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn diffuse(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    albedo: Vec3A,
    sp: &SurfacePoint,
    at: &Shading,
    bsdf_u: Vec2,
    light_u: Option<(f32, Vec2)>,
) -> Option<Ray> {
    let p_out = offset_ray_origin(sp.p, sp.err, at.n);
    if let Some(u) = light_u {
        for group in 0..light_groups(scene, strategy) {
            if let Some((le, f)) = diffuse_light(scene, strategy, sp, at, p_out, group, u) {
                path.l += path.beta * albedo * le * f;
            }
        }
    }
    let (wi, pdf) = sample_diffuse(at.ns, bsdf_u);
    path.beta *= albedo;
    path.specular = false;
    path.prev_pdf = pdf;
    if !(pdf > 0.0) || (at.shaded && at.n.dot(wi) <= 0.0) {
        return None;
    }
    Some(Ray::new(p_out, wi))
}

/// [`diffuse`]'s next-event estimation, weighed against its cosine lobe: also the many-path
/// tracer's, lane by lane, for the lights it does not sample in lanes.
#[inline(always)]
pub(crate) fn diffuse_light(
    scene: &Scene,
    strategy: Strategy,
    sp: &SurfacePoint,
    at: &Shading,
    p_out: Vec3A,
    group: usize,
    u: (f32, Vec2),
) -> Option<(Vec3A, f32)> {
    let cosine = |_: Vec3A, cos: f32| cosine_hemisphere_pdf(cos);
    direct_light(scene, strategy, sp, at, p_out, (group, u), cosine)
}

/// Next-event estimation at a diffuse vertex: a point on a light, its shadow ray from
/// `p_out`, and (under MIS) the power heuristic against BSDF sampling, whose density
/// `bsdf_pdf` gives for a direction and its cosine (the cosine lobe's, or a guided
/// mixture's). Returns the light's radiance and the factor cos·w/(π·pdf) the path's
/// throughput and albedo scale it by, or `None` when the light adds nothing.
#[inline(always)]
fn direct_light(
    scene: &Scene,
    strategy: Strategy,
    sp: &SurfacePoint,
    at: &Shading,
    p_out: Vec3A,
    (group, u): (usize, (f32, Vec2)),
    bsdf_pdf: impl Fn(Vec3A, f32) -> f32,
) -> Option<(Vec3A, f32)> {
    let (ls, cos) = visible_light(scene, strategy, sp, at, p_out, group, u)?;
    let w = if strategy == Strategy::Mis && !ls.delta {
        power_heuristic(ls.pdf, bsdf_pdf(ls.wi, cos))
    } else {
        1.0
    };
    Some((ls.le(), cos * std::f32::consts::FRAC_1_PI * w / ls.pdf))
}

/// How many light samples a vertex takes: one from each of the scene's groups of lights (the
/// distant ones and the others: [`crate::light::Lights::new`]), or under BSDF sampling alone
/// one of the punctual lights.
#[inline(always)]
pub(crate) fn light_groups(scene: &Scene, strategy: Strategy) -> usize {
    if strategy == Strategy::Bsdf {
        1
    } else {
        scene.lights.groups()
    }
}

/// A light sample for next-event estimation from `p`: a light of group `group`, or under BSDF
/// sampling alone a punctual one (the rest are found by the BSDF's rays, and counted in full
/// then).
#[inline(always)]
fn sample_light(
    scene: &Scene,
    strategy: Strategy,
    p: Vec3A,
    group: usize,
    (u_select, u_point): (f32, Vec2),
) -> Option<LightSample<'_>> {
    if strategy == Strategy::Bsdf {
        scene.lights.sample_delta(p, u_select)
    } else {
        scene.lights.sample(p, group, u_select, u_point)
    }
}

/// A point on a light that `p_out` sees, above the surface at `sp`, with the cosine of its
/// direction against the shading normal; `None` when it is behind the surface, occluded or
/// dark.
#[inline(always)]
fn visible_light<'s>(
    scene: &'s Scene,
    strategy: Strategy,
    sp: &SurfacePoint,
    at: &Shading,
    p_out: Vec3A,
    group: usize,
    u: (f32, Vec2),
) -> Option<(LightSample<'s>, f32)> {
    let ls = sample_light(scene, strategy, sp.p, group, u)?;
    let cos = at.ns.dot(ls.wi);
    // A light behind the geometric surface is unreachable, whatever the shading normal says.
    let reachable = !at.shaded || at.n.dot(ls.wi) > 0.0;
    if !(cos > 0.0 && reachable && ls.may_emit()) {
        return None;
    }
    let (shadow, t_max) = ls.shadow_ray(p_out);
    if scene.occluded(&shadow, t_max) {
        return None;
    }
    Some((ls, cos))
}
