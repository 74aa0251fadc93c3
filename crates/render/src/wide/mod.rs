//! Many paths at a time, the whole bounce in SIMD lanes, for the scenes whose bounce is mostly
//! the same few operations: diffuse surfaces and one parallelogram light (the Cornell box).
//! Every lane does exactly the scalar trace's arithmetic on its own numbers
//! (no fused multiply-add, no sums across lanes; see [`crate::util::lanes`]), so a sample's value is
//! [`crate::integrator::sample_pixel`]'s, bit for bit, whichever lane it runs in and however
//! many lanes there are; the pinned render hashes test that. A lane whose path ends takes the
//! next sample of the run, which goes on from one pixel to the next, so the lanes stay busy.
//!
//! A vertex on a material the lanes do not model (a mirror, glass, a metal) is the scalar
//! trace's own step, run on that lane's path alone and put back into the lanes
//! (`Wide::leave_in_lane`): the diffuse walls around a glass ball still shade together, and
//! the ball costs what it costs the scalar trace. Likewise a smooth mesh's point whose shading
//! normal is not its geometric one. A scene that is one BVH leaf (the Cornell box) answers the
//! lanes' ray queries in lanes; any other asks the scene lane by lane. Under any lights but
//! one parallelogram the diffuse lanes sample them lane by lane too (`Wide::light_in_lane`),
//! and a path that leaves the scene finds its sky lane by lane (`Wide::escape_in_lane`), but
//! for an environment map without a sun, which the lanes look up together, and sample
//! together where it is the only distant light (`sky.rs`). Under a sky the tracer then runs
//! ([`Wide::anywhere`], `--tracer lanes8`) but does not pay on every scene, so the default
//! ([`Wide::new`]) leaves those scenes to the scalar trace.
//!
//! Eight lanes by default: two 128-bit registers per number, whose independent work keeps more
//! of the core busy than one does, compiled also for AVX2 and AVX-512 encodings chosen at run
//! time (see `trace8`); sixteen lanes measured slower than eight (docs/renderer.md).

mod by_lane;
mod sky;

use std::ops::Range;

use glam::{Vec2, Vec3A};

use crate::integrator::{RenderSettings, Setup, Strategy};
use crate::interaction::{Hit, SurfacePoint};
use crate::light::LightShape;
use crate::packet::{HitKeep, LaneHits, Rays};
use crate::primitive::Primitive;
use crate::scene::Scene;
use crate::shape::{Parallelogram, Shape};
use crate::util::lanes::{dot, splat3, transpose3, v3, F, M, V3};
use crate::util::math::{frame_from_normal_lanes, gamma, offset_ray_origin_lanes, Ray};
use crate::util::sampling::{
    power_heuristic, power_heuristic_lanes, square_to_cosine_hemisphere_lanes, PixelSampler,
};
use by_lane::{blocked_by_lane, closest_by_lane};
use sky::Sky;

/// The many-path tracer for one scene and its settings.
pub struct Wide<'a> {
    scene: &'a Scene,
    settings: &'a RenderSettings,
    /// The scalar trace's decisions, for the lanes whose material it steps.
    setup: Setup,
    /// The scene's light, where it is one parallelogram: the lanes sample it in lanes. Any
    /// other set of lights is sampled lane by lane, by the scalar trace's code.
    quad: Option<QuadLight>,
    /// Whether a vertex draws a number to pick one of several lights.
    picks_light: bool,
    /// Whether a path that leaves the scene finds an environment or a sun.
    escapes: bool,
    /// The environment map, where the lanes look it up themselves (`sky.rs`).
    sky: Option<Sky<'a>>,
    /// Whether the lanes' queries go to the one leaf's packet tests.
    one_leaf: bool,
    /// Whether the scene needs more than the Cornell box's bounce: a vertex that may be the
    /// scalar step's (a material the lanes do not shade, a bent shading normal), after which
    /// a path may have refracted or a lane be kept out of the shaded lanes' update, or queries
    /// asked lane by lane. The tracer is compiled for both answers (`GENERAL`), so that the
    /// Cornell box's bounce pays for none of it.
    general: bool,
    lanes: usize,
}

/// The one parallelogram light the lanes sample.
struct QuadLight {
    shape: Parallelogram,
    /// Its selection probability, as `Lights::sample` multiplies it in.
    pmf: f32,
    radiance: Vec3A,
    two_sided: bool,
    emits: bool,
}

/// Samples `samples` of pixel (`x`, `y`), for [`Wide::trace`]; `sampler` is the pixel's
/// sampler at any sample index.
#[derive(Clone, Debug)]
pub struct PixelRun {
    /// Column.
    pub x: u32,
    /// Row.
    pub y: u32,
    /// The pixel's sampler.
    pub sampler: PixelSampler,
    /// The sample indices.
    pub samples: Range<u32>,
}

/// What a light sample needs of the scene's one light, splatted across the lanes.
struct LightLanes<const N: usize> {
    p0: V3<N>,
    e1: V3<N>,
    e2: V3<N>,
    normal: V3<N>,
    area: F<N>,
    pmf: F<N>,
    radiance: V3<N>,
    two_sided: bool,
    emits: bool,
}

/// Lane `lane` of three lanes as a vector.
#[inline(always)]
fn lane3<const N: usize>(v: &[[f32; N]; 3], lane: usize) -> Vec3A {
    Vec3A::new(v[0][lane], v[1][lane], v[2][lane])
}

#[inline(always)]
fn set3<const N: usize>(v: &mut [[f32; N]; 3], lane: usize, x: Vec3A) {
    for c in 0..3 {
        v[c][lane] = x[c];
    }
}

#[inline(always)]
fn load3<const N: usize>(v: &[[f32; N]; 3]) -> V3<N> {
    v3(|c| F(v[c]))
}

/// The vertices a bounce shades, in lanes: where the paths hit, and the numbers that decide
/// what happens there.
struct Vertices<const N: usize> {
    /// The hit points.
    p: V3<N>,
    /// Their normals, on the side the ray came from.
    n: V3<N>,
    /// The points' rounding-error bounds.
    err: V3<N>,
    /// The diffuse albedo there.
    albedo: V3<N>,
    /// The BSDF sample's two numbers.
    u: [F<N>; 2],
    /// The light sample's two numbers.
    light_u: [F<N>; 2],
    /// Russian roulette's number.
    u_rr: F<N>,
    /// The lanes shaded.
    shade: u32,
    /// The lanes the scalar step moved on this bounce, whose state the shaded lanes' update
    /// leaves as it is.
    stepped: u32,
    /// The lanes whose light sample of the second group of lights adds
    /// `Lanes::later_light`.
    later: u32,
}

/// A mesh hit's surface point with the barycentrics its query kept made this thread's last
/// hit again. Out of line: inlined, the arm cost the Cornell box, which has no mesh, 0.9% more
/// instructions (its bounce compiled differently).
#[inline(never)]
fn kept_mesh_surface(
    shape: &Shape,
    ray: &Ray,
    hit: Hit,
    kept: Option<crate::mesh::LastHit>,
) -> SurfacePoint {
    crate::mesh::restore_hit(kept);
    shape.surface(ray, hit.t, hit.part)
}

/// The paths in the lanes, between bounces.
struct Lanes<const N: usize> {
    o: [[f32; N]; 3],
    d: [[f32; N]; 3],
    beta: [[f32; N]; 3],
    l: [[f32; N]; 3],
    prev_pdf: [f32; N],
    prev_p: [[f32; N]; 3],
    light_uv: [[f32; N]; 2],
    /// The product of η² over the refractions so far (`Path::eta_scale`).
    eta: [f32; N],
    /// The lanes whose last bounce was specular, or the camera's.
    specular: u32,
    /// What the lanes' last queries found for their sphere and mesh hits' points.
    keep: HitKeep<N>,
    /// What a vertex's light sample of the second group of lights adds, drawn lane by lane
    /// but added after the first group's, which the lanes draw (`sky.rs`): the scalar trace's
    /// order. Read only in the lanes of `Vertices::later`.
    later_light: [[f32; N]; 3],
    depth: [u32; N],
    /// Where the lane's value goes in the output.
    slot: [usize; N],
    /// Which run the lane's sampler belongs to.
    run: [usize; N],
    sampler: [PixelSampler; N],
    active: u32,
}

impl<'a> Wide<'a> {
    /// The many-path tracer for `scene` where it pays, eight paths at a time: where its one
    /// light is a parallelogram, which the lanes sample together; and in a closed world (no
    /// sky, no sun) of one BVH leaf whatever its lights (several rectangles, spheres, emissive
    /// meshes, points, spots), which the lanes sample one by one. Under a sky or a sun most
    /// paths leave a scene's few diffuse surfaces for the sky, and the lanes measured slower
    /// than the scalar trace where the materials were mostly metals and pbr, also with the map
    /// looked up and sampled in lanes (`sky.rs`); on a world that is not one leaf (an infinite
    /// plane) the lanes query one ray at a time, which measured slower with a sphere light
    /// (docs/renderer.md, "The lanes under other lights", "The map in lanes").
    pub fn new(scene: &'a Scene, settings: &'a RenderSettings) -> Option<Self> {
        Self::anywhere(scene, settings).filter(|w| w.quad.is_some() || (!w.escapes && w.one_leaf))
    }

    /// The many-path tracer for `scene` wherever it can run, whatever the lights: what
    /// `--tracer lanes4|lanes8|lanes16` asks for, and the same bits as the scalar trace
    /// everywhere. It needs a diffuse material (what it shades in lanes), MIS, and none of
    /// cut-outs, coloured glass, a depth limit or a camera's far plane.
    pub fn anywhere(scene: &'a Scene, settings: &'a RenderSettings) -> Option<Self> {
        let diffuse = scene.materials.iter().any(|m| m.bsdf.lanes().is_some());
        let quad = match scene.lights.lights.as_slice() {
            [light] => match &light.shape {
                LightShape::Quad(q) => Some(QuadLight {
                    shape: q.clone(),
                    pmf: scene.lights.pdf_scale(),
                    radiance: light.radiance,
                    two_sided: light.two_sided,
                    emits: light.radiance != Vec3A::ZERO,
                }),
                _ => None,
            },
            _ => None,
        };
        if !diffuse
            || settings.strategy != Strategy::Mis
            // Without lights the scalar trace counts every emitter in full (BSDF sampling).
            || scene.lights.is_empty()
            || scene.max_depth.is_some()
            || scene.camera.clips_far()
            // Its queries know neither cut-outs nor media.
            || scene.has_cutouts()
            || scene.has_absorption()
        {
            return None;
        }
        Some(Self {
            scene,
            settings,
            setup: Setup::new(scene, settings),
            picks_light: scene.lights.lights.len() > 1,
            escapes: scene.environment.is_some() || !scene.lights.suns().is_empty(),
            sky: Sky::new(scene),
            one_leaf: scene.is_one_leaf(),
            general: quad.is_none()
                || scene.environment.is_some()
                || !scene.is_one_leaf()
                || scene.has_shading_normals()
                || scene.materials.iter().any(|m| m.bsdf.lanes().is_none()),
            quad,
            lanes: 8,
        })
    }

    /// The same tracer with `lanes` lanes (4, 8 or 16; `None` for any other count). The values
    /// are the same bits whatever the count.
    pub fn with_lanes(mut self, lanes: usize) -> Option<Self> {
        matches!(lanes, 4 | 8 | 16).then(|| {
            self.lanes = lanes;
            self
        })
    }

    /// How many paths run at once.
    pub fn lanes(&self) -> usize {
        self.lanes
    }

    /// The values of samples `samples` of pixel (`x`, `y`), into `out` in index order.
    pub fn sample_pixel(
        &self,
        x: u32,
        y: u32,
        sampler: &PixelSampler,
        samples: Range<u32>,
        out: &mut Vec<Vec3A>,
    ) {
        let run = PixelRun {
            x,
            y,
            sampler: *sampler,
            samples,
        };
        self.trace(std::slice::from_ref(&run), out);
    }

    /// The values of every run's samples, into `out`: run by run, each in index order.
    pub fn trace(&self, runs: &[PixelRun], out: &mut Vec<Vec3A>) {
        match self.lanes {
            4 if self.general => self.trace_lanes::<4, true>(runs, out),
            4 => self.trace_lanes::<4, false>(runs, out),
            16 if self.general => self.trace_lanes::<16, true>(runs, out),
            16 => self.trace_lanes::<16, false>(runs, out),
            _ => trace8(self, runs, out),
        }
    }

    #[inline(always)]
    fn trace_lanes<const N: usize, const GENERAL: bool>(
        &self,
        runs: &[PixelRun],
        out: &mut Vec<Vec3A>,
    ) {
        out.clear();
        out.resize(runs.iter().map(|r| r.samples.len()).sum(), Vec3A::ZERO);
        let Some(first) = runs.first() else {
            return;
        };
        let scene = self.scene;
        let light = self.quad.as_ref().map(|q| LightLanes::<N> {
            p0: splat3(q.shape.p0),
            e1: splat3(q.shape.e1),
            e2: splat3(q.shape.e2),
            normal: splat3(q.shape.normal),
            area: F::splat(q.shape.area),
            pmf: F::splat(q.pmf),
            radiance: splat3(q.radiance),
            two_sided: q.two_sided,
            emits: q.emits,
        });
        let mut s = Lanes::<N> {
            o: [[0.0; N]; 3],
            d: [[0.0; N]; 3],
            beta: [[0.0; N]; 3],
            l: [[0.0; N]; 3],
            prev_pdf: [0.0; N],
            prev_p: [[0.0; N]; 3],
            light_uv: [[0.0; N]; 2],
            eta: [1.0; N],
            specular: 0,
            keep: HitKeep::new(),
            later_light: [[0.0; N]; 3],
            depth: [0; N],
            slot: [0; N],
            run: [0; N],
            sampler: [first.sampler; N],
            active: 0,
        };
        let (mut run, mut next, mut slot) = (0, first.samples.start, 0);
        loop {
            for lane in 0..N {
                if s.active >> lane & 1 == 1 {
                    continue;
                }
                while run < runs.len() && next >= runs[run].samples.end {
                    run += 1;
                    next = runs.get(run).map_or(0, |r| r.samples.start);
                }
                let Some(r) = runs.get(run) else {
                    break;
                };
                let sm = &mut s.sampler[lane];
                if s.run[lane] != run {
                    *sm = r.sampler;
                    s.run[lane] = run;
                }
                sm.set_index(next);
                let [jx, jy, lx, ly] = sm.get4(0);
                let ray = scene.camera.ray(r.x as f32 + jx, r.y as f32 + jy);
                set3(&mut s.o, lane, ray.o);
                set3(&mut s.d, lane, ray.d);
                set3(&mut s.beta, lane, Vec3A::ONE);
                set3(&mut s.l, lane, Vec3A::ZERO);
                set3(&mut s.prev_p, lane, ray.o);
                s.prev_pdf[lane] = 0.0;
                s.light_uv[0][lane] = lx;
                s.light_uv[1][lane] = ly;
                if GENERAL {
                    s.eta[lane] = 1.0;
                }
                s.specular |= 1 << lane;
                s.depth[lane] = 0;
                s.slot[lane] = slot;
                s.active |= 1 << lane;
                slot += 1;
                next += 1;
            }
            if s.active == 0 {
                return;
            }
            self.bounce::<N, GENERAL>(&mut s, light.as_ref(), out);
        }
    }

    /// One bounce of every active lane: its closest hit, emission, light sample and next ray.
    #[inline(always)]
    fn bounce<const N: usize, const GENERAL: bool>(
        &self,
        s: &mut Lanes<N>,
        light: Option<&LightLanes<N>>,
        out: &mut [Vec3A],
    ) {
        let Some(v) = self.shade_hits::<N, GENERAL>(s, out) else {
            return;
        };
        let p_out = offset_ray_origin_lanes(&v.p, &v.err, &v.n);
        // Without it the lanes sampled their lights one by one as they shaded the hits.
        if let Some(light) = light {
            self.direct_light::<N, GENERAL>(s, light, &v, &p_out);
        } else if let Some(sky) = self.sky.as_ref().filter(|sky| GENERAL && sky.sampled()) {
            self.sky_light::<N, GENERAL>(s, sky, &v, &p_out);
            if v.later != 0 {
                let later = &s.later_light;
                add_where(&mut s.l, v.later, |c| F(later[c]));
            }
        }
        self.continue_paths::<N, GENERAL>(s, &v, p_out, out);
    }

    /// The closest hits of the active lanes' rays: the one leaf's packet tests, else one ray at
    /// a time.
    #[inline(always)]
    fn closest<const N: usize, const GENERAL: bool>(&self, s: &mut Lanes<N>) -> LaneHits<N> {
        let scene = self.scene;
        let ray_of = |lane| Ray::new(lane3(&s.o, lane), lane3(&s.d, lane));
        if !GENERAL || self.one_leaf {
            scene.accel().intersect_lanes(
                &scene.prims,
                &Rays::from_lanes(load3(&s.o), load3(&s.d)),
                ray_of,
                s.active,
                &mut s.keep,
            )
        } else {
            closest_by_lane(scene, s.active, ray_of, &mut s.keep)
        }
    }

    /// Intersects the active lanes' rays, adds what emitters they hit give (weighted against
    /// light sampling), ends the paths that leave the scene or hit a back face, and returns the
    /// vertices of the others, in lanes; `None` if no lane has one.
    #[inline(always)]
    fn shade_hits<const N: usize, const GENERAL: bool>(
        &self,
        s: &mut Lanes<N>,
        out: &mut [Vec3A],
    ) -> Option<Vertices<N>> {
        let scene = self.scene;
        let settings = self.settings;
        let hits = self.closest::<N, GENERAL>(s);
        // Per lane as whole vectors, turned into lanes afterwards (`lanes::transpose3`).
        let mut p = [Vec3A::ZERO; N];
        let mut n = [Vec3A::ZERO; N];
        let mut err = [Vec3A::ZERO; N];
        let mut albedo = [Vec3A::ZERO; N];
        let mut u = [[0.0f32; N]; 5];
        let (mut shade, mut stepped, mut escaped) = (0u32, 0u32, 0u32);
        let mut later = 0u32;
        let sky = self.sky.as_ref().filter(|_| GENERAL);
        for lane in 0..N {
            if s.active >> lane & 1 == 0 {
                continue;
            }
            if hits.hit >> lane & 1 == 0 {
                if sky.is_some() {
                    escaped |= 1 << lane;
                    continue;
                }
                if GENERAL && self.escapes {
                    self.escape_in_lane(s, lane);
                }
                finish(s, out, lane);
                continue;
            }
            let (ray, hit, prim, sp) = self.hit_point::<N, GENERAL>(s, &hits, lane);
            let ray = &ray;
            let mat = &scene.materials[prim.material as usize];
            let wo = -ray.d;
            if prim.light != u32::MAX {
                self.add_emitted::<N, GENERAL>(s, lane, (ray, &hit, prim, &sp));
            }
            // A point whose shading normal bends away from the geometric one (`Shading::facing`).
            let shaded = GENERAL && scene.has_shading_normals() && sp.ns != sp.n;
            let Some(a) = mat.bsdf.lanes().filter(|_| !shaded) else {
                if !GENERAL {
                    unreachable!("a scene with a vertex the lanes do not shade is general");
                }
                if self.leave_in_lane(s, out, lane, (ray, &hit, prim, &sp)) {
                    stepped |= 1 << lane;
                }
                continue;
            };
            let front = sp.n.dot(wo) >= 0.0;
            if !front && !mat.two_sided {
                finish(s, out, lane);
                continue;
            }
            let nn = if front { sp.n } else { -sp.n };
            let depth = s.depth[lane];
            let [u0, u1, nlx, nly] = s.sampler[lane].get4(1 + 2 * depth);
            // `Setup::numbers` for a diffuse vertex that samples a light.
            let [u_select, _, u_rr, _] =
                if depth + 1 >= settings.rr_depth || (GENERAL && self.picks_light) {
                    s.sampler[lane].get4(2 + 2 * depth)
                } else {
                    [0.0; 4]
                };
            if GENERAL && self.quad.is_none() && self.light_by_lane(s, lane, (&sp, wo, a), u_select)
            {
                later |= 1 << lane;
            }
            u[0][lane] = u0;
            u[1][lane] = u1;
            u[2][lane] = s.light_uv[0][lane];
            u[3][lane] = s.light_uv[1][lane];
            u[4][lane] = u_rr;
            s.light_uv[0][lane] = nlx;
            s.light_uv[1][lane] = nly;
            p[lane] = sp.p;
            n[lane] = nn;
            err[lane] = sp.err;
            albedo[lane] = a;
            shade |= 1 << lane;
        }
        if let Some(sky) = sky.filter(|_| escaped != 0) {
            self.escape_lanes(s, sky, escaped);
            for lane in (0..N).filter(|lane| escaped >> lane & 1 == 1) {
                finish(s, out, lane);
            }
        }
        if shade == 0 {
            return None;
        }
        let [u0, u1, lx, ly, u_rr] = [F(u[0]), F(u[1]), F(u[2]), F(u[3]), F(u[4])];
        Some(Vertices {
            p: transpose3(&p),
            n: transpose3(&n),
            err: transpose3(&err),
            albedo: transpose3(&albedo),
            u: [u0, u1],
            light_u: [lx, ly],
            u_rr,
            shade,
            stepped,
            later,
        })
    }

    /// Lane `lane`'s ray, what it hit and the point there, from the lanes' closest hits `hits`.
    #[inline(always)]
    fn hit_point<const N: usize, const GENERAL: bool>(
        &self,
        s: &Lanes<N>,
        hits: &LaneHits<N>,
        lane: usize,
    ) -> (Ray, Hit, &'a Primitive, SurfacePoint) {
        let ray = Ray::new(lane3(&s.o, lane), lane3(&s.d, lane));
        let hit = Hit {
            t: hits.t[lane],
            prim: hits.prim[lane],
            part: hits.part[lane],
        };
        let prim = &self.scene.prims[hit.prim as usize];
        // Quads, most of a room's hits, without the call and the match on the shape; a
        // sphere from the root its packet test found, a mesh from its kept barycentrics.
        let sp = match &prim.shape {
            Shape::Parallelogram(q) => q.surface(&ray, hit.t),
            Shape::Sphere { center, radius } if GENERAL && self.one_leaf => {
                crate::shape::sphere_surface(&ray, *center, *radius, s.keep.sphere_root[lane])
            }
            shape @ Shape::Mesh(_) if GENERAL => {
                kept_mesh_surface(shape, &ray, hit, s.keep.mesh_hit[lane])
            }
            shape => shape.surface(&ray, hit.t, hit.part),
        };
        (ray, hit, prim, sp)
    }

    /// Next-event estimation at lane `lane`'s diffuse vertex (its point, the direction the
    /// path leaves towards and its albedo) for lights the lanes do not sample in lanes, by the
    /// scalar trace's code. Where the lanes draw the map's samples (`sky.rs`) this is the
    /// second group's alone, kept in `Lanes::later_light` to be added after the map's; returns
    /// whether it was.
    #[inline(always)]
    fn light_by_lane<const N: usize>(
        &self,
        s: &mut Lanes<N>,
        lane: usize,
        (sp, wo, albedo): (&SurfacePoint, Vec3A, Vec3A),
        u_select: f32,
    ) -> bool {
        let u = (
            u_select,
            Vec2::new(s.light_uv[0][lane], s.light_uv[1][lane]),
        );
        if !self.sky.as_ref().is_some_and(Sky::sampled) {
            self.light_in_lane(s, lane, sp, wo, albedo, u);
            return false;
        }
        let Some(c) = self.later_light_in_lane(s, lane, sp, wo, albedo, u) else {
            return false;
        };
        set3(&mut s.later_light, lane, c);
        true
    }

    /// What the emitter lane `lane`'s ray hit at `here` gives its path: in full after a
    /// specular bounce (the camera's too), else weighted by the power heuristic against light
    /// sampling, as the scalar trace's `add_emitted` under MIS.
    #[inline(always)]
    fn add_emitted<const N: usize, const GENERAL: bool>(
        &self,
        s: &mut Lanes<N>,
        lane: usize,
        (ray, hit, prim, sp): (&Ray, &Hit, &Primitive, &SurfacePoint),
    ) {
        let scene = self.scene;
        let (li, le) = if GENERAL {
            // Mesh lights' triangles, emission textures.
            scene.emitted((ray, hit, prim, sp))
        } else {
            let li = (prim.light + hit.part) as usize;
            (li, scene.lights.lights[li].emitted(sp.n, -ray.d))
        };
        if le == Vec3A::ZERO {
            return;
        }
        let beta = lane3(&s.beta, lane);
        let mut l = lane3(&s.l, lane);
        if s.specular >> lane & 1 == 1 {
            l += beta * le;
        } else {
            let prev_p = lane3(&s.prev_p, lane);
            let light_pdf = scene.lights.pdf(li, prev_p, sp.p, sp.n);
            l += beta * le * power_heuristic(s.prev_pdf[lane], light_pdf);
        }
        set3(&mut s.l, lane, l);
    }

    /// Next-event estimation at the vertices: `Lights::sample` for the one parallelogram
    /// light, a shadow ray, and the power heuristic against BSDF sampling.
    #[inline(always)]
    fn direct_light<const N: usize, const GENERAL: bool>(
        &self,
        s: &mut Lanes<N>,
        light: &LightLanes<N>,
        v: &Vertices<N>,
        p_out: &V3<N>,
    ) {
        let (p, n, albedo, shade) = (&v.p, &v.n, &v.albedo, v.shade);
        let [lx, ly] = v.light_u;
        let p_out = *p_out;
        let x: V3<N> = v3(|c| (light.p0[c] + light.e1[c] * lx) + light.e2[c] * ly);
        let d: V3<N> = v3(|c| x[c] - p[c]);
        let dist2 = dot(&d, &d);
        let mut valid = dist2.cmpgt(F::ZERO) & dist2.cmple(F::splat(f32::MAX));
        let len = dist2.sqrt();
        let wi: V3<N> = v3(|c| d[c] / len);
        let cos_l = dot(&light.normal, &wi).abs();
        valid &= cos_l.cmpne(F::ZERO);
        let pdf = (dist2 / (cos_l * light.area)) * light.pmf;
        valid &= pdf.cmpgt(F::ZERO) & pdf.cmple(F::splat(f32::MAX));
        let neg_wi: V3<N> = v3(|c| -wi[c]);
        let n_dot = dot(&light.normal, &neg_wi);
        let facing = n_dot.cmpgt(F::ZERO);
        let lit = if light.two_sided {
            M::splat(light.emits)
        } else {
            facing & M::splat(light.emits)
        };
        let towards_front = n_dot.cmpge(F::ZERO);
        let towards: V3<N> = v3(|c| F::select(towards_front, light.normal[c], -light.normal[c]));
        let x_err: V3<N> = v3(|c| {
            (light.p0[c].abs() + (light.e1[c] * lx).abs() + (light.e2[c] * ly).abs()) * gamma(12)
                + F::splat(f32::MIN_POSITIVE)
        });
        let lp = offset_ray_origin_lanes(&x, &x_err, &towards);
        let cos = dot(n, &wi);
        let nee = (valid & lit & cos.cmpgt(F::ZERO)).bits() & shade;
        if nee != 0 {
            let sd: V3<N> = v3(|c| lp[c] - p_out[c]);
            let add = nee & !self.blocked::<N, GENERAL>(&p_out, &sd, nee, 1.0 - 1e-4);
            if add != 0 {
                let bsdf_pdf = cos * std::f32::consts::FRAC_1_PI;
                let w = power_heuristic_lanes(pdf, bsdf_pdf);
                let factor = (cos * std::f32::consts::FRAC_1_PI * w) / pdf;
                let beta = &s.beta;
                add_where(&mut s.l, add, |c| {
                    F(beta[c]) * albedo[c] * light.radiance[c] * factor
                });
            }
        }
    }

    /// Which of the shadow rays `o + t·d`, t in (0, `t_max`), of the lanes in `lanes`
    /// something blocks: the one leaf's packet test, else one ray at a time.
    #[inline(always)]
    fn blocked<const N: usize, const GENERAL: bool>(
        &self,
        o: &V3<N>,
        d: &V3<N>,
        lanes: u32,
        t_max: f32,
    ) -> u32 {
        let scene = self.scene;
        let (oa, da) = (v3(|c| o[c].0), v3(|c| d[c].0));
        let shadow = |lane| Ray::new(lane3(&oa, lane), lane3(&da, lane));
        if !GENERAL || self.one_leaf {
            scene.accel().occluded_lanes(
                &scene.prims,
                &Rays::from_lanes(*o, *d),
                shadow,
                lanes,
                t_max,
            )
        } else {
            blocked_by_lane(scene, lanes, shadow, t_max)
        }
    }

    /// The next direction at each vertex, cosine-weighted (f·cos/pdf = ρ), then Russian
    /// roulette; the lanes' paths move on, and those that end are written to `out`.
    #[inline(always)]
    fn continue_paths<const N: usize, const GENERAL: bool>(
        &self,
        s: &mut Lanes<N>,
        v: &Vertices<N>,
        p_out: V3<N>,
        out: &mut [Vec3A],
    ) {
        let settings = self.settings;
        let (p, n, albedo, shade, u_rr) = (&v.p, &v.n, &v.albedo, v.shade, v.u_rr);
        let [u0, u1] = v.u;
        let local = square_to_cosine_hemisphere_lanes(u0, u1);
        // `Frame::from_normal` and `Frame::to_world`.
        let [fs, ft] = frame_from_normal_lanes(n);
        let wi: V3<N> = v3(|c| fs[c] * local[0] + ft[c] * local[1] + n[c] * local[2]);
        let mut beta: V3<N> = v3(|c| F(s.beta[c]) * albedo[c]);
        let prev_pdf = F::select(
            local[2].cmpgt(F::ZERO),
            local[2] * std::f32::consts::FRAC_1_PI,
            F::ZERO,
        );
        let mut alive = prev_pdf.cmpgt(F::ZERO).bits() & shade;
        let mut depth = s.depth;
        let mut roulette = 0u32;
        // Without branches: which lanes were shaded, and which of them are past the roulette's
        // depth, are each a coin toss for the branch predictor.
        for (lane, depth) in depth.iter_mut().enumerate() {
            let shaded = shade >> lane & 1;
            *depth += shaded;
            roulette |= (shaded & u32::from(*depth >= settings.rr_depth)) << lane;
        }
        if roulette != 0 {
            let m = if GENERAL {
                // `Path::survives_roulette`: η² undone (1 until a path has refracted).
                let eta = F(s.eta);
                (beta[0] * eta).max((beta[1] * eta).max(beta[2] * eta))
            } else {
                beta[0].max(beta[1].max(beta[2]))
            };
            let q = (m / settings.rr_threshold).min(F::splat(0.95));
            let rr = M::from_bits(roulette);
            alive &= !(roulette & !u_rr.cmplt(q).bits());
            beta = v3(|c| F::select(rr, beta[c] / q, beta[c]));
        }
        let len = dot(&wi, &wi).sqrt();
        // Whole vectors, not lane by lane: every lane still active after this bounce was
        // shaded in it or stepped by the scalar trace (whose lanes are kept), and the others
        // are refilled before they are read again. (A vector load of numbers stored one float
        // at a time waits for the stores to retire.)
        let kept = if GENERAL { v.stepped } else { 0 };
        for c in 0..3 {
            store(&mut s.o[c], p_out[c], kept);
            store(&mut s.d[c], wi[c] / len, kept);
            store(&mut s.beta[c], beta[c], kept);
            store(&mut s.prev_p[c], p[c], kept);
        }
        store(&mut s.prev_pdf, prev_pdf, kept);
        s.specular &= !shade;
        s.depth = depth;
        let ended = shade & !alive;
        for lane in (0..N).filter(|lane| ended >> lane & 1 == 1) {
            finish(s, out, lane);
        }
    }
}

/// `v` into `dst`, but for the lanes in `kept`.
#[inline(always)]
fn store<const N: usize>(dst: &mut [f32; N], v: F<N>, kept: u32) {
    *dst = if kept == 0 {
        v.0
    } else {
        F::select(M::from_bits(kept), F(*dst), v).0
    };
}

/// `add(c)` added to component `c` of `l` in the lanes of `lanes`. Each component computed as
/// it is added: a vector of the three first measured 1% more instructions in the Cornell box.
#[inline(always)]
fn add_where<const N: usize>(l: &mut [[f32; N]; 3], lanes: u32, add: impl Fn(usize) -> F<N>) {
    let mask = M::from_bits(lanes);
    for (c, l_c) in l.iter_mut().enumerate() {
        let old = F(*l_c);
        *l_c = F::select(mask, old + add(c), old).0;
    }
}

/// A lane's path has ended: its value goes to its slot, and the lane is free.
#[inline(always)]
fn finish<const N: usize>(s: &mut Lanes<N>, out: &mut [Vec3A], lane: usize) {
    out[s.slot[lane]] = lane3(&s.l, lane);
    s.active &= !(1 << lane);
}

/// Eight lanes, compiled for the build's baseline (x86-64-v2), for AVX2 and for AVX-512 (with
/// VL), the widest the CPU has chosen at run time. The lanes stay 128-bit operations in every
/// version, each IEEE-rounded as in the others, so the bits are the same: what the newer
/// encodings give is three operands instead of two (fewer register copies) and, with AVX-512,
/// 32 registers instead of 16 (fewer spills of the eight lanes' numbers). Nothing fuses a
/// multiply and an add: Rust never contracts them, and the lanes never call `mul_add`.
#[multiversion::multiversion(targets("x86_64+avx512f+avx512vl+avx2", "x86_64+avx2"))]
fn trace8<'a>(wide: &Wide<'a>, runs: &[PixelRun], out: &mut Vec<Vec3A>) {
    if wide.general {
        wide.trace_lanes::<8, true>(runs, out);
    } else {
        wide.trace_lanes::<8, false>(runs, out);
    }
}
