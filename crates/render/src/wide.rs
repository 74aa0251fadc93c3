//! Four paths at a time, the whole bounce in SIMD lanes, for the scenes whose bounce is the
//! same few operations everywhere: diffuse surfaces, one parallelogram light, one BVH leaf
//! (the Cornell box). Every lane does exactly the scalar trace's arithmetic on its own numbers
//! (no fused multiply-add, no sums across lanes), so a sample's value is
//! [`crate::integrator::sample_pixel`]'s, bit for bit, whichever lane it runs in; the pinned
//! render hashes test that. A lane whose path ends takes the pixel's next sample.

use glam::{BVec4A, Vec3A, Vec4};

use crate::integrator::{RenderSettings, Strategy};
use crate::leaf::Rays4;
use crate::light::LightShape;
use crate::math::{gamma, Ray};
use crate::sampling::{power_heuristic, sin_cos_polynomials, PixelSampler};
use crate::scene::{Bsdf, Scene};
use crate::shape::Parallelogram;

type V3 = [Vec4; 3];

/// What a light sample needs of the scene's one light, splatted across the lanes.
pub struct Wide<'a> {
    scene: &'a Scene,
    settings: &'a RenderSettings,
    p0: V3,
    e1: V3,
    e2: V3,
    normal: V3,
    area: Vec4,
    pmf: Vec4,
    radiance: V3,
    two_sided: bool,
    emits: bool,
}

fn splat3(v: Vec3A) -> V3 {
    [Vec4::splat(v.x), Vec4::splat(v.y), Vec4::splat(v.z)]
}

#[inline]
fn dot(a: &V3, b: &V3) -> Vec4 {
    (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
}

/// [`crate::math::offset_ray_origin`], lane by lane.
#[inline]
fn offset4(p: &V3, err: &V3, n: &V3) -> V3 {
    let d = (n[0].abs() * err[0] + n[1].abs() * err[1]) + n[2].abs() * err[2];
    std::array::from_fn(|c| {
        let po = p[c] + n[c] * d;
        let step = po.abs() * f32::EPSILON + Vec4::splat(f32::from_bits(1));
        let side = Vec4::select(n[c].cmpeq(Vec4::ZERO), Vec4::ZERO, Vec4::ONE.copysign(n[c]));
        po + side * step
    })
}

/// [`crate::sampling::square_to_cosine_hemisphere`], lane by lane.
#[inline]
fn cosine_hemisphere4(u0: Vec4, u1: Vec4) -> V3 {
    let ax = 2.0 * u0 - Vec4::ONE;
    let ay = 2.0 * u1 - Vec4::ONE;
    let origin = ax.cmpeq(Vec4::ZERO) & ay.cmpeq(Vec4::ZERO);
    let x_major = ax.abs().cmpgt(ay.abs());
    let num = Vec4::select(x_major, ay, ax);
    let den = Vec4::select(x_major, ax, ay);
    let (s, c) = sin_cos_polynomials(std::f32::consts::FRAC_PI_4 * (num / den));
    let dx = Vec4::select(origin, Vec4::ZERO, den * Vec4::select(x_major, c, s));
    let dy = Vec4::select(origin, Vec4::ZERO, den * Vec4::select(x_major, s, c));
    let z = sqrt4((1.0 - (dx * dx + dy * dy)).max(Vec4::ZERO));
    [dx, dy, z]
}

/// [`crate::sampling::power_heuristic`], lane by lane.
#[inline]
fn power_heuristic4(f: Vec4, g: Vec4) -> Vec4 {
    let (f2, g2) = (f * f, g * g);
    let sum = f2 + g2;
    let w = Vec4::select(sum.cmpeq(Vec4::ZERO), Vec4::ZERO, f2 / sum);
    Vec4::select(f2.abs().cmpeq(Vec4::INFINITY), Vec4::ONE, w)
}

/// Square roots, lane by lane (IEEE, correctly rounded: the scalar `sqrt`'s bits).
#[inline]
fn sqrt4(v: Vec4) -> Vec4 {
    Vec4::from_array(v.to_array().map(f32::sqrt))
}

/// Lane `lane` of three lanes as a vector.
#[inline]
fn lane3(v: &[[f32; 4]; 3], lane: usize) -> Vec3A {
    Vec3A::new(v[0][lane], v[1][lane], v[2][lane])
}

#[inline]
fn set3(v: &mut [[f32; 4]; 3], lane: usize, x: Vec3A) {
    for c in 0..3 {
        v[c][lane] = x[c];
    }
}

#[inline]
fn load3(v: &[[f32; 4]; 3]) -> V3 {
    v.map(Vec4::from_array)
}

#[inline]
fn bits(m: BVec4A) -> u32 {
    m.bitmask()
}

/// The lanes whose bits are set in `bits`, as a mask.
#[inline]
fn lanes_of(bits: u32) -> BVec4A {
    BVec4A::new(bits & 1 != 0, bits & 2 != 0, bits & 4 != 0, bits & 8 != 0)
}

/// The paths in the lanes, between bounces.
struct Lanes {
    o: [[f32; 4]; 3],
    d: [[f32; 4]; 3],
    beta: [[f32; 4]; 3],
    l: [[f32; 4]; 3],
    prev_pdf: [f32; 4],
    prev_p: [[f32; 4]; 3],
    light_uv: [[f32; 4]; 2],
    depth: [u32; 4],
    slot: [usize; 4],
    sampler: [PixelSampler; 4],
    active: u32,
}

impl<'a> Wide<'a> {
    /// The four-lane tracer for `scene`, if its bounce is one this module models.
    pub fn new(scene: &'a Scene, settings: &'a RenderSettings) -> Option<Self> {
        let diffuse = scene
            .materials
            .iter()
            .all(|m| matches!(m.bsdf, Bsdf::Diffuse(_)));
        let [light] = scene.lights.lights.as_slice() else {
            return None;
        };
        let LightShape::Quad(q) = &light.shape else {
            return None;
        };
        if !diffuse
            || settings.strategy != Strategy::Mis
            || scene.environment.is_some()
            || scene.max_depth.is_some()
            || !scene.is_one_leaf()
        {
            return None;
        }
        let Parallelogram {
            p0,
            e1,
            e2,
            normal,
            area,
            ..
        } = *q;
        // The one light's selection probability, as `Lights::sample` multiplies it in.
        let pmf = scene.lights.pdf_scale();
        Some(Self {
            scene,
            settings,
            p0: splat3(p0),
            e1: splat3(e1),
            e2: splat3(e2),
            normal: splat3(normal),
            area: Vec4::splat(area),
            pmf: Vec4::splat(pmf),
            radiance: splat3(light.radiance),
            two_sided: light.two_sided,
            emits: light.radiance != Vec3A::ZERO,
        })
    }

    /// The values of samples `samples` of pixel (`x`, `y`), into `out` in index order.
    pub fn sample_pixel(
        &self,
        x: u32,
        y: u32,
        sampler: &PixelSampler,
        samples: std::ops::Range<u32>,
        out: &mut Vec<Vec3A>,
    ) {
        let scene = self.scene;
        let settings = self.settings;
        out.clear();
        out.resize(samples.len(), Vec3A::ZERO);
        let mut s = Lanes {
            o: [[0.0; 4]; 3],
            d: [[0.0; 4]; 3],
            beta: [[0.0; 4]; 3],
            l: [[0.0; 4]; 3],
            prev_pdf: [0.0; 4],
            prev_p: [[0.0; 4]; 3],
            light_uv: [[0.0; 4]; 2],
            depth: [0; 4],
            slot: [0; 4],
            sampler: [*sampler; 4],
            active: 0,
        };
        let mut next = samples.start;
        loop {
            for lane in 0..4 {
                if s.active >> lane & 1 == 1 || next == samples.end {
                    continue;
                }
                let sm = &mut s.sampler[lane];
                sm.set_index(next);
                let [jx, jy, lx, ly] = sm.get4(0);
                let ray = scene.camera.ray(x as f32 + jx, y as f32 + jy);
                set3(&mut s.o, lane, ray.o);
                set3(&mut s.d, lane, ray.d);
                set3(&mut s.beta, lane, Vec3A::ONE);
                set3(&mut s.l, lane, Vec3A::ZERO);
                set3(&mut s.prev_p, lane, ray.o);
                s.prev_pdf[lane] = 0.0;
                s.light_uv[0][lane] = lx;
                s.light_uv[1][lane] = ly;
                s.depth[lane] = 0;
                s.slot[lane] = (next - samples.start) as usize;
                s.active |= 1 << lane;
                next += 1;
            }
            if s.active == 0 {
                return;
            }
            self.bounce(&mut s, out, settings);
        }
    }

    /// One bounce of every active lane: its closest hit, emission, light sample and next ray.
    #[inline]
    fn bounce(&self, s: &mut Lanes, out: &mut [Vec3A], settings: &RenderSettings) {
        let scene = self.scene;
        let rays: [Ray; 4] =
            std::array::from_fn(|lane| Ray::new(lane3(&s.o, lane), lane3(&s.d, lane)));
        let hits = scene.intersect4_lanes(
            &Rays4::from_lanes(load3(&s.o), load3(&s.d)),
            &rays,
            s.active,
        );
        let mut p = [[0.0f32; 4]; 3];
        let mut n = [[0.0f32; 4]; 3];
        let mut err = [[0.0f32; 4]; 3];
        let mut albedo = [[0.0f32; 4]; 3];
        let mut u = [[0.0f32; 4]; 5];
        let mut shade = 0u32;
        for lane in 0..4 {
            if s.active >> lane & 1 == 0 {
                continue;
            }
            let ray = &rays[lane];
            let Some(hit) = hits[lane] else {
                self.finish(s, out, lane);
                continue;
            };
            let prim = &scene.prims[hit.prim as usize];
            let sp = prim.shape.surface(ray, hit.t, hit.part);
            let mat = &scene.materials[prim.material as usize];
            let wo = -ray.d;
            if prim.light != u32::MAX {
                let li = (prim.light + hit.part) as usize;
                let le = scene.lights.lights[li].emitted(sp.n, wo);
                if le != Vec3A::ZERO {
                    let beta = lane3(&s.beta, lane);
                    let mut l = lane3(&s.l, lane);
                    if s.depth[lane] == 0 {
                        // The camera's "bounce" is specular: emitters seen directly count in full.
                        l += beta * le;
                    } else {
                        let prev_p = lane3(&s.prev_p, lane);
                        let light_pdf = scene.lights.pdf(li, prev_p, sp.p, sp.n);
                        l += beta * le * power_heuristic(s.prev_pdf[lane], light_pdf);
                    }
                    set3(&mut s.l, lane, l);
                }
            }
            let front = sp.n.dot(wo) >= 0.0;
            if !front && !mat.two_sided {
                self.finish(s, out, lane);
                continue;
            }
            let nn = if front { sp.n } else { -sp.n };
            let Bsdf::Diffuse(a) = mat.bsdf else {
                unreachable!("Wide::new admits diffuse scenes only")
            };
            let depth = s.depth[lane];
            let [u0, u1, nlx, nly] = s.sampler[lane].get4(1 + 2 * depth);
            let u_rr = if depth + 1 >= settings.rr_depth {
                s.sampler[lane].get4(2 + 2 * depth)[2]
            } else {
                0.0
            };
            u[0][lane] = u0;
            u[1][lane] = u1;
            u[2][lane] = s.light_uv[0][lane];
            u[3][lane] = s.light_uv[1][lane];
            u[4][lane] = u_rr;
            s.light_uv[0][lane] = nlx;
            s.light_uv[1][lane] = nly;
            set3(&mut p, lane, sp.p);
            set3(&mut n, lane, nn);
            set3(&mut err, lane, sp.err);
            set3(&mut albedo, lane, a);
            shade |= 1 << lane;
        }
        if shade == 0 {
            return;
        }
        let (p, n, err, albedo) = (load3(&p), load3(&n), load3(&err), load3(&albedo));
        let [u0, u1, lx, ly, u_rr] = u.map(Vec4::from_array);
        let p_out = offset4(&p, &err, &n);

        // Next-event estimation: `Lights::sample` for the one parallelogram light.
        let x: V3 = std::array::from_fn(|c| (self.p0[c] + self.e1[c] * lx) + self.e2[c] * ly);
        let d: V3 = std::array::from_fn(|c| x[c] - p[c]);
        let dist2 = dot(&d, &d);
        let mut valid = dist2.cmpgt(Vec4::ZERO) & dist2.cmple(Vec4::splat(f32::MAX));
        let len = sqrt4(dist2);
        let wi: V3 = d.map(|dc| dc / len);
        let cos_l = dot(&self.normal, &wi).abs();
        valid &= cos_l.cmpne(Vec4::ZERO);
        let pdf = (dist2 / (cos_l * self.area)) * self.pmf;
        valid &= pdf.cmpgt(Vec4::ZERO) & pdf.cmple(Vec4::splat(f32::MAX));
        let neg_wi: V3 = wi.map(|w| -w);
        let n_dot = dot(&self.normal, &neg_wi);
        let facing = n_dot.cmpgt(Vec4::ZERO);
        let lit = if self.two_sided {
            BVec4A::splat(self.emits)
        } else {
            facing & BVec4A::splat(self.emits)
        };
        let towards_front = n_dot.cmpge(Vec4::ZERO);
        let towards: V3 = self.normal.map(|nc| Vec4::select(towards_front, nc, -nc));
        let x_err: V3 = std::array::from_fn(|c| {
            (self.p0[c].abs() + (self.e1[c] * lx).abs() + (self.e2[c] * ly).abs()) * gamma(12)
                + Vec4::splat(f32::MIN_POSITIVE)
        });
        let lp = offset4(&x, &x_err, &towards);
        let cos = dot(&n, &wi);
        let nee = bits(valid & lit & cos.cmpgt(Vec4::ZERO)) & shade;
        if nee != 0 {
            let sd: V3 = std::array::from_fn(|c| lp[c] - p_out[c]);
            let po = p_out.map(|v| v.to_array());
            let sda = sd.map(|v| v.to_array());
            let shadow: [Ray; 4] =
                std::array::from_fn(|lane| Ray::new(lane3(&po, lane), lane3(&sda, lane)));
            let blocked =
                scene.occluded4_lanes(&Rays4::from_lanes(p_out, sd), &shadow, nee, 1.0 - 1e-4);
            let add = nee & !blocked;
            if add != 0 {
                let mask = lanes_of(add);
                let bsdf_pdf = cos * std::f32::consts::FRAC_1_PI;
                let w = power_heuristic4(pdf, bsdf_pdf);
                let factor = (cos * std::f32::consts::FRAC_1_PI * w) / pdf;
                let terms = s.beta.iter().zip(albedo.iter().zip(&self.radiance));
                for (l_c, (beta_c, (albedo_c, le_c))) in s.l.iter_mut().zip(terms) {
                    let l = Vec4::from_array(*l_c);
                    let c_add = Vec4::from_array(*beta_c) * *albedo_c * *le_c * factor;
                    *l_c = Vec4::select(mask, l + c_add, l).to_array();
                }
            }
        }

        // The next direction, cosine-weighted: f·cos/pdf = ρ.
        let local = cosine_hemisphere4(u0, u1);
        // `Frame::from_normal` and `Frame::to_world`.
        let sign = Vec4::ONE.copysign(n[2]);
        let a = -1.0 / (sign + n[2]);
        let b = n[0] * n[1] * a;
        let fs = [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]];
        let ft = [b, sign + n[1] * n[1] * a, -n[1]];
        let wi: V3 = std::array::from_fn(|c| fs[c] * local[0] + ft[c] * local[1] + n[c] * local[2]);
        let mut beta: V3 = std::array::from_fn(|c| Vec4::from_array(s.beta[c]) * albedo[c]);
        let prev_pdf = Vec4::select(
            local[2].cmpgt(Vec4::ZERO),
            local[2] * std::f32::consts::FRAC_1_PI,
            Vec4::ZERO,
        );
        let mut alive = bits(prev_pdf.cmpgt(Vec4::ZERO)) & shade;
        let mut depth = s.depth;
        let mut roulette = 0u32;
        for (lane, depth) in depth.iter_mut().enumerate() {
            if shade >> lane & 1 == 1 {
                *depth += 1;
                if *depth >= settings.rr_depth {
                    roulette |= 1 << lane;
                }
            }
        }
        if roulette != 0 {
            let m = beta[0].max(beta[1].max(beta[2]));
            let q = (m / settings.rr_threshold).min(Vec4::splat(0.95));
            let rr = lanes_of(roulette);
            alive &= !(roulette & !bits(u_rr.cmplt(q)));
            beta = beta.map(|bc| Vec4::select(rr, bc / q, bc));
        }
        let len = sqrt4(dot(&wi, &wi));
        let o = p_out.map(|v| v.to_array());
        let d = wi.map(|w| (w / len).to_array());
        let beta = beta.map(|v| v.to_array());
        let prev_pdf = prev_pdf.to_array();
        let pa = p.map(|v| v.to_array());
        for lane in 0..4 {
            if shade >> lane & 1 == 0 {
                continue;
            }
            for (dst, src) in s.beta.iter_mut().zip(&beta) {
                dst[lane] = src[lane];
            }
            if alive >> lane & 1 == 0 {
                self.finish(s, out, lane);
                continue;
            }
            for c in 0..3 {
                s.o[c][lane] = o[c][lane];
                s.d[c][lane] = d[c][lane];
                s.prev_p[c][lane] = pa[c][lane];
            }
            s.prev_pdf[lane] = prev_pdf[lane];
            s.depth[lane] = depth[lane];
        }
    }

    #[inline]
    fn finish(&self, s: &mut Lanes, out: &mut [Vec3A], lane: usize) {
        out[s.slot[lane]] = lane3(&s.l, lane);
        s.active &= !(1 << lane);
    }
}
