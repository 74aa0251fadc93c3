//! The glTF 2.0 metallic–roughness material (`pbr`): the Khronos specification's BRDF
//! (its Appendix B) with `KHR_materials_transmission` and `KHR_materials_ior`, each parameter
//! a constant or a texture, made energy-preserving where the specification's own formula is
//! not: a white material returns all the light that arrives, at every roughness, as Blender's
//! Principled BSDF does.
//!
//! The specification mixes a metal and a dielectric by `metallic` (m):
//!
//! - metal: GGX reflection with Schlick's Fresnel of F0 = the base colour c,
//!   F_s(o·h; c) ρ(o, i), ρ(o, i) = D(h) G(o, i) / (4 cos θo) ([`super::microfacet`]);
//! - dielectric: a GGX coat of index η over a base that is, by `transmission` (t), a
//!   Lambertian c/π or a thin-walled transmission (the coat's lobe mirrored through the surface
//!   and tinted by c: glTF's default when no volume is given). The specification weighs the
//!   base by 1 − F(o·h) with h the half vector of o and i, which is not energy-conserving: at a
//!   grazing view the coat reflects nearly everything while the base, whose half vectors lie far
//!   from the view, still gets nearly all of its weight (a test in `tests/bsdfs.rs` integrates
//!   it above one).
//!
//! **Multiple scattering**, as Cycles' multiscatter GGX gives it back (Turquin 2019, "Practical
//! multiple scattering compensation for microfacet models", with Kulla and Conty's Fresnel
//! term). A single-scattering GGX lobe loses the light that bounces between micro-facets: a
//! white metal at roughness 1 returns 0.31 of it head-on. With E₁(μ) the lobe's albedo for a
//! white Fresnel at cos θ = μ and Ē₁ = 2∫E₁(μ) μ dμ, the lobe is scaled by
//!
//! k(μo) = 1 + F_ms (1 − E₁(μo)) / E₁(μo),   F_ms = F̄ Ē₁ / (1 − F̄ (1 − Ē₁)),
//!
//! F̄ the Fresnel term's cosine-weighted average (the share of each further bounce that
//! survives): per channel for a metal (F̄ = c + (1 − c)/21, Schlick's), F̄ of the exact
//! dielectric Fresnel for the coat. At F = 1 the lobe then returns E₁ k = 1 exactly; its shape
//! is the single bounce's, as Cycles' is (Kulla and Conty's own lobe, tried first, is
//! diffuse-shaped, and left a rough gold 6% darker than Cycles near its highlight).
//!
//! **Albedo scaling** (the glTF specification's Appendix B recommendation, and what Cycles'
//! Principled BSDF does): the base is weighted by what the coat does not reflect at the view,
//! 1 − E_c(μo), with E_c(μ) = k(μ) E_ss(μ) the coat's albedo (E_ss = ∫ F(o·h) ρ cos θi, its
//! single bounce). So, for i above the surface,
//!
//! f cos θi = [m F_s(o·h; c) k_m(μo) + (1 − m) F(o·h) k_c(μo)] ρ cos θi
//!          + (1 − m) (1 − t) (1 − E_c(μo)) c cos θi / π
//!
//! and (1 − m) t c (1 − F(o·h′)) ρ(o, i′) w(μo) cos θi′ below it, i′ the mirror image of i
//! through the surface and w = (1 − E_c)/(E₁ − E_ss) the thin wall's scale (what the coat
//! leaves over what the mirrored single bounce passes; 1 when smooth). At c = 1 the metal
//! returns E₁ k = 1, the dielectric E_c + (1 − E_c) = 1 over its base and E_c + (1 − E_c) = 1
//! as a thin wall, at every roughness and angle (the furnace tests in `tests/bsdfs.rs`).
//! Scaling by the view alone makes the lobes non-reciprocal, as in Cycles; a path tracer only
//! ever evaluates them with o towards the camera.
//!
//! **Clear coat** (`KHR_materials_clearcoat`, Blender's Coat): a second dielectric GGX layer of
//! index 1.5, weight w_cc and its own roughness, over everything above, layered the same way:
//! its lobe w_cc F(o·h) k_cc ρ_cc cos θi on top, and all of the rest scaled by what it leaves,
//! 1 − w_cc E_cc(μo). A white material keeps all its energy under it too, w_cc E_cc +
//! (1 − w_cc E_cc)·1 = 1, and a material without one (w_cc = 0) is the one above, bit for bit.
//!
//! `distribution = "ggx"` leaves the compensation out (k = 1, w = 1): glTF's reference BRDF,
//! Mitsuba's `principled`, and Blender's "GGX".
//!
//! Roughness may come from a texture, so E_ss, E₁ and Ē₁ are tabulated over roughness as well
//! as μ ([`CoatTable`], shared by every material of one index; [`GgxAlbedo`], by all) and
//! interpolated.
//!
//! Sampling picks one of four lobes: the clear coat, the GGX reflection (visible normals), the
//! base's cosine hemisphere, or the mirrored GGX lobe for transmission, with probabilities proportional to an
//! estimate of each lobe's albedo at o; the density is the mixture's, so any lobe's direction
//! is weighed against all of them. Below the mirror threshold the reflection and transmission
//! lobes are deltas (the mirror direction, and straight through), which light sampling cannot
//! find, and the surface scatters once (E₁ = 1).

use std::sync::Arc;

use glam::{Vec2, Vec3A};

use super::albedo::multiple_colour;
pub use super::albedo::{CoatTable, GgxAlbedo};
use super::fresnel_dielectric;
use super::microfacet::{half_vector, reflect_about, TrowbridgeReitz};
use super::sheen::Sheen;
use crate::mesh::UvFrame;
use crate::texture::Texture;
use crate::util::sampling::{cosine_hemisphere_pdf, square_to_cosine_hemisphere};

/// Which microfacet model the lobes use (a scene's `distribution`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Distribution {
    /// GGX with the light it scatters more than once given back: a white material keeps all
    /// its energy. Blender's default, "Multiscatter GGX".
    #[default]
    MultiscatterGgx,
    /// GGX, single scattering: glTF's reference BRDF and Mitsuba's `principled`.
    Ggx,
}

/// The material's parameters at one point of a surface.
#[derive(Clone, Copy, Debug)]
pub struct PbrParams {
    /// Base colour, linear RGB in [0, 1].
    pub base_color: Vec3A,
    /// Metallic, in [0, 1].
    pub metallic: f32,
    /// Perceptual roughness in [0, 1]; α = roughness².
    pub roughness: f32,
    /// Transmission, in [0, 1].
    pub transmission: f32,
    /// The clear coat's weight, in [0, 1] (0: none).
    pub clearcoat: f32,
    /// The clear coat's perceptual roughness, in [0, 1].
    pub clearcoat_roughness: f32,
    /// The sheen's colour, linear RGB in [0, 1] (black: none).
    pub sheen_color: Vec3A,
    /// The sheen's perceptual roughness, in [0, 1].
    pub sheen_roughness: f32,
}

/// The BSDF at one point: [`PbrParams`] with the coat's table.
#[derive(Clone, Copy, Debug)]
pub struct PbrBsdf<'a> {
    p: PbrParams,
    distribution: TrowbridgeReitz,
    coat: &'a CoatTable,
    /// The white lobe's albedo table, where the material is compensated and not smooth.
    ms: Option<&'static GgxAlbedo>,
    /// The clear coat, where the material has one.
    clearcoat: Option<Clearcoat<'a>>,
    /// The sheen over the base, where the material has one.
    sheen: Option<Sheen>,
}

/// A clear coat: its weight, microfacets, the index-1.5 layer's table, and the white lobe's
/// albedo table where it is compensated and not smooth.
#[derive(Clone, Copy, Debug)]
struct Clearcoat<'a> {
    weight: f32,
    roughness: f32,
    distribution: TrowbridgeReitz,
    table: &'a CoatTable,
    ms: Option<&'static GgxAlbedo>,
}

impl Clearcoat<'_> {
    /// w_cc E_cc(μo) and the compensation k_cc(μo): what the coat reflects of the light from
    /// the view, and the scale of its lobe.
    fn at(&self, mu: f32) -> (f32, f32) {
        let r = self.roughness;
        let single = self.table.single(r, self.distribution.is_smooth(), mu);
        let scale = match self.ms {
            Some(g) => {
                let e1 = g.e(r, mu).max(1e-3);
                1.0 + self.table.multiple(r) * (1.0 - e1) / e1
            }
            None => 1.0,
        };
        (self.weight * single * scale, scale)
    }
}

/// A direction drawn from a [`PbrBsdf`].
#[derive(Clone, Copy, Debug)]
pub struct PbrSample {
    /// The direction, in the shading frame (below the surface: transmitted).
    pub wi: Vec3A,
    /// f |cos θi| / pdf (a delta lobe's: its reflectance or transmittance over its
    /// probability).
    pub weight: Vec3A,
    /// The mixture's density per solid angle; 0 for a delta lobe.
    pub pdf: f32,
    /// A delta lobe (smooth reflection or straight-through transmission), which light sampling
    /// cannot find.
    pub delta: bool,
}

/// Schlick's Fresnel term for reflectance `f0` at normal incidence.
#[inline]
fn schlick(f0: Vec3A, cos: f32) -> Vec3A {
    let x = (1.0 - cos).clamp(0.0, 1.0);
    let x2 = x * x;
    f0 + (Vec3A::ONE - f0) * (x2 * x2 * x)
}

/// The mirror image of `w` through the surface.
#[inline]
fn mirror(w: Vec3A) -> Vec3A {
    Vec3A::new(w.x, w.y, -w.z)
}

/// The mean of a colour's channels.
#[inline]
fn mean(c: Vec3A) -> f32 {
    (c.x + c.y + c.z) * (1.0 / 3.0)
}

/// What the lobes need of the view, looked up once per evaluation.
struct View {
    /// E_ss(μo), the coat's single bounce.
    single: f32,
    /// E₁(μo) (1 without compensation).
    e1: f32,
    /// The coat's compensation k(μo) (1 without).
    coat_scale: f32,
    /// The metal's compensation per channel (1 without).
    metal_scale: Vec3A,
    /// w_cc E_cc(μo), what the clear coat reflects (0 without one).
    clearcoat: f32,
    /// The clear coat's compensation k_cc(μo).
    clearcoat_scale: f32,
    /// max(c) E_sheen(μo), what the sheen takes from the base (0 without one).
    sheen: f32,
}

impl View {
    /// E_c(μo), the coat's albedo.
    #[inline]
    fn coat(&self) -> f32 {
        self.single * self.coat_scale
    }

    /// The scale of the thin wall's lobe, (1 − E_c)/(E₁ − E_ss): what the coat leaves, over
    /// what the mirrored single bounce passes (1 for a smooth coat, where both are 1 − F).
    #[inline]
    fn wall_scale(&self) -> f32 {
        let passed = self.e1 - self.single;
        if passed > 1e-6 {
            ((1.0 - self.coat()) / passed).max(1.0)
        } else {
            1.0
        }
    }
}

/// The lobe probabilities for one view (reflection, base, transmission); all zero where the
/// material is black from that side.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Lobes {
    clearcoat: f32,
    sheen: f32,
    reflect: f32,
    base: f32,
    through: f32,
}

impl<'a> PbrBsdf<'a> {
    /// The BSDF of parameters `p` over the coat table of the material's index, with the
    /// microfacet model `distribution`.
    pub fn new(p: PbrParams, coat: &'a CoatTable, distribution: Distribution) -> Self {
        let d = TrowbridgeReitz::from_roughness(p.roughness);
        let ms =
            (distribution == Distribution::MultiscatterGgx && !d.is_smooth()).then(GgxAlbedo::get);
        Self {
            p,
            distribution: d,
            coat,
            ms,
            clearcoat: None,
            sheen: None,
        }
    }

    /// The BSDF with its sheen (of colour `p.sheen_color` and roughness `p.sheen_roughness`)
    /// over the base; itself where the colour is black.
    pub fn with_sheen(self) -> Self {
        match Sheen::new(self.p.sheen_color, self.p.sheen_roughness) {
            Some(sheen) => Self {
                sheen: Some(sheen),
                ..self
            },
            None => self,
        }
    }

    /// The BSDF under its clear coat (of weight and roughness `p.clearcoat` and
    /// `p.clearcoat_roughness`), `table` the index-1.5 layer's; itself where the weight is 0.
    pub fn with_clearcoat(self, table: &'a CoatTable, distribution: Distribution) -> Self {
        let weight = self.p.clearcoat;
        if !(weight > 0.0) {
            return self;
        }
        let roughness = self.p.clearcoat_roughness;
        let d = TrowbridgeReitz::from_roughness(roughness);
        let ms =
            (distribution == Distribution::MultiscatterGgx && !d.is_smooth()).then(GgxAlbedo::get);
        Self {
            clearcoat: Some(Clearcoat {
                weight: weight.min(1.0),
                roughness,
                distribution: d,
                table,
                ms,
            }),
            ..self
        }
    }

    /// Its parameters.
    pub fn params(&self) -> &PbrParams {
        &self.p
    }

    /// Whether the reflection and transmission lobes are deltas.
    #[inline]
    pub fn is_smooth(&self) -> bool {
        self.distribution.is_smooth()
    }

    /// Whether any light passes through.
    #[inline]
    pub fn transmits(&self) -> bool {
        self.p.metallic < 1.0 && self.p.transmission > 0.0
    }

    #[inline]
    fn view(&self, mu: f32) -> View {
        let r = self.p.roughness;
        let single = self.coat.single(r, self.is_smooth(), mu);
        let (clearcoat, clearcoat_scale) = self.clearcoat.map_or((0.0, 1.0), |c| c.at(mu));
        let sheen = self.sheen.map_or(0.0, |s| s.albedo(mu));
        let Some(g) = self.ms else {
            return View {
                single,
                e1: 1.0,
                coat_scale: 1.0,
                metal_scale: Vec3A::ONE,
                clearcoat,
                clearcoat_scale,
                sheen,
            };
        };
        let e1 = g.e(r, mu).max(1e-3);
        let missing = (1.0 - e1) / e1;
        let average = g.average(r);
        let c = self.p.base_color;
        let f = c + (Vec3A::ONE - c) * (1.0 / 21.0);
        let fms = |f: f32| multiple_colour(f, average);
        View {
            single,
            e1,
            coat_scale: 1.0 + self.coat.multiple(r) * missing,
            metal_scale: Vec3A::ONE + Vec3A::new(fms(f.x), fms(f.y), fms(f.z)) * missing,
            clearcoat,
            clearcoat_scale,
            sheen,
        }
    }

    /// The reflection lobe's colour at o·h = `cos`, compensated: the metal's Schlick term and
    /// the coat's dielectric Fresnel, each times its scale, mixed by metallic.
    #[inline]
    fn reflectance(&self, v: &View, cos: f32) -> Vec3A {
        let m = self.p.metallic;
        let dielectric = fresnel_dielectric(cos.clamp(0.0, 1.0), self.coat.eta()).0;
        schlick(self.p.base_color, cos) * v.metal_scale * m
            + Vec3A::splat((1.0 - m) * dielectric * v.coat_scale)
    }

    /// The lobe probabilities at a view of `v`: each lobe's albedo at c's mean (the
    /// reflection kept above a floor: the coat reflects at every angle unless its index is
    /// one).
    fn lobes(&self, v: &View) -> Lobes {
        let PbrParams {
            base_color: c,
            metallic: m,
            transmission: t,
            ..
        } = self.p;
        let lum = mean(c);
        let floor = if self.coat.eta() != 1.0 { 1e-3 } else { 0.0 };
        let left = (1.0 - v.coat()).max(0.0);
        // Under a clear coat, each lobe below gets what the coat leaves; under a sheen, what
        // the sheen leaves of that.
        let sheen = v.sheen * (1.0 - v.clearcoat);
        let under = (1.0 - v.clearcoat) * (1.0 - v.sheen);
        let reflect = (m + (1.0 - m) * v.coat()).max(floor) * under;
        let base = (1.0 - m) * (1.0 - t) * left * lum * under;
        let through = (1.0 - m) * t * left * lum * under;
        let clearcoat = v.clearcoat;
        let sum = clearcoat + sheen + reflect + base + through;
        if !(sum > 0.0) {
            return Lobes {
                clearcoat: 0.0,
                sheen: 0.0,
                reflect: 0.0,
                base: 0.0,
                through: 0.0,
            };
        }
        Lobes {
            clearcoat: clearcoat / sum,
            sheen: sheen / sum,
            reflect: reflect / sum,
            base: base / sum,
            through: through / sum,
        }
    }

    /// The clear coat's lobe, f cos θi, for i above the surface (0 without a rough coat).
    #[inline]
    fn clearcoat_lobe(&self, v: &View, o: Vec3A, i: Vec3A) -> f32 {
        let Some(c) = &self.clearcoat else {
            return 0.0;
        };
        let d = &c.distribution;
        if d.is_smooth() {
            return 0.0;
        }
        let Some(h) = half_vector(o, i) else {
            return 0.0;
        };
        let f = fresnel_dielectric(o.dot(h).clamp(0.0, 1.0), c.table.eta()).0;
        c.weight * f * v.clearcoat_scale * d.d(h) * d.g(o, i) / (4.0 * o.z)
    }

    /// f(o, i) |cos θi| of the lobes light sampling can find (all but the smooth ones), in the
    /// shading frame; zero unless `o` is above the surface.
    pub fn eval(&self, o: Vec3A, i: Vec3A) -> Vec3A {
        if !(o.z > 0.0) {
            return Vec3A::ZERO;
        }
        self.eval_at(&self.view(o.z), o, i)
    }

    /// [`PbrBsdf::eval`] for `o` above the surface, its view `v` looked up already (`sample`
    /// has it, and the tables need not be read twice per drawn direction).
    fn eval_at(&self, v: &View, o: Vec3A, i: Vec3A) -> Vec3A {
        let below = self.eval_below(v, o, i);
        if self.clearcoat.is_none() {
            return below;
        }
        let coat = if i.z > 0.0 {
            self.clearcoat_lobe(v, o, i)
        } else {
            0.0
        };
        below * (1.0 - v.clearcoat) + Vec3A::splat(coat)
    }

    /// What lies under the clear coat (all of the material without one), f cos θi: the sheen
    /// over the base, where there is one.
    fn eval_below(&self, v: &View, o: Vec3A, i: Vec3A) -> Vec3A {
        let base = self.eval_base(v, o, i);
        match &self.sheen {
            None => base,
            Some(s) => base * (1.0 - v.sheen) + s.eval(o, i),
        }
    }

    /// The base's lobes (under any sheen and clear coat), f cos θi.
    fn eval_base(&self, v: &View, o: Vec3A, i: Vec3A) -> Vec3A {
        let PbrParams {
            base_color: c,
            metallic: m,
            transmission: t,
            ..
        } = self.p;
        let d = &self.distribution;
        if i.z > 0.0 {
            let base = c
                * ((1.0 - m) * (1.0 - t) * (1.0 - v.coat()).max(0.0) * i.z)
                * std::f32::consts::FRAC_1_PI;
            if self.is_smooth() {
                return base;
            }
            let Some(h) = half_vector(o, i) else {
                return base;
            };
            let rho = d.d(h) * d.g(o, i) / (4.0 * o.z);
            base + self.reflectance(v, o.dot(h).max(0.0)) * rho
        } else if i.z < 0.0 && self.transmits() && !self.is_smooth() {
            let i = mirror(i);
            let Some(h) = half_vector(o, i) else {
                return Vec3A::ZERO;
            };
            let f = fresnel_dielectric(o.dot(h).max(0.0), self.coat.eta()).0;
            let rho = d.d(h) * d.g(o, i) / (4.0 * o.z);
            c * ((1.0 - m) * t * (1.0 - f) * rho * v.wall_scale())
        } else {
            Vec3A::ZERO
        }
    }

    /// The density [`PbrBsdf::sample`] draws `i` with, but for the delta lobes.
    pub fn pdf(&self, o: Vec3A, i: Vec3A) -> f32 {
        if !(o.z > 0.0) {
            return 0.0;
        }
        self.mixture_pdf(&self.lobes(&self.view(o.z)), o, i)
    }

    fn mixture_pdf(&self, l: &Lobes, o: Vec3A, i: Vec3A) -> f32 {
        let smooth = self.is_smooth();
        if i.z > 0.0 {
            let glossy = if smooth {
                0.0
            } else {
                self.distribution.reflection_pdf(o, i)
            };
            let coat = match &self.clearcoat {
                Some(c) if l.clearcoat > 0.0 && !c.distribution.is_smooth() => {
                    l.clearcoat * c.distribution.reflection_pdf(o, i)
                }
                _ => 0.0,
            };
            let cosine = l.base + l.sheen;
            coat + l.reflect * glossy + cosine * cosine_hemisphere_pdf(i.z)
        } else if i.z < 0.0 && l.through > 0.0 && !smooth {
            l.through * self.distribution.reflection_pdf(o, mirror(i))
        } else {
            0.0
        }
    }

    /// A direction from `u` (the square) and `u_lobe` (the lobe choice), or `None` where it
    /// would leave on the wrong side, the material is black, or `o` is not above the surface.
    pub fn sample(&self, o: Vec3A, u: Vec2, u_lobe: f32) -> Option<PbrSample> {
        if !(o.z > 0.0) {
            return None;
        }
        let v = self.view(o.z);
        let l = self.lobes(&v);
        let smooth = self.is_smooth();
        let under = (1.0 - v.clearcoat) * (1.0 - v.sheen);
        let i = if u_lobe < l.clearcoat {
            let c = self.clearcoat.as_ref()?;
            if c.distribution.is_smooth() {
                let f = fresnel_dielectric(o.z, c.table.eta()).0;
                return Some(PbrSample {
                    wi: Vec3A::new(-o.x, -o.y, o.z),
                    weight: Vec3A::splat(c.weight * f / l.clearcoat),
                    pdf: 0.0,
                    delta: true,
                });
            }
            let i = reflect_about(o, c.distribution.sample_visible(o, u));
            if !(i.z > 0.0) {
                return None;
            }
            i
        } else if u_lobe < l.clearcoat + l.sheen {
            square_to_cosine_hemisphere(u)
        } else if u_lobe < l.clearcoat + l.sheen + l.reflect {
            if smooth {
                return Some(PbrSample {
                    wi: Vec3A::new(-o.x, -o.y, o.z),
                    weight: self.reflectance(&v, o.z) * under / l.reflect,
                    pdf: 0.0,
                    delta: true,
                });
            }
            let i = reflect_about(o, self.distribution.sample_visible(o, u));
            if !(i.z > 0.0) {
                return None;
            }
            i
        } else if u_lobe < l.clearcoat + l.sheen + l.reflect + l.base || l.through == 0.0 {
            if l.base == 0.0 {
                return None;
            }
            square_to_cosine_hemisphere(u)
        } else {
            let PbrParams {
                base_color: c,
                metallic: m,
                transmission: t,
                ..
            } = self.p;
            if smooth {
                let f = fresnel_dielectric(o.z, self.coat.eta()).0;
                return Some(PbrSample {
                    wi: -o,
                    weight: c * ((1.0 - m) * t * (1.0 - f) * under / l.through),
                    pdf: 0.0,
                    delta: true,
                });
            }
            let i = reflect_about(o, self.distribution.sample_visible(o, u));
            if !(i.z > 0.0) {
                return None;
            }
            mirror(i)
        };
        let pdf = self.mixture_pdf(&l, o, i);
        if !(pdf > 0.0) {
            return None;
        }
        Some(PbrSample {
            wi: i,
            weight: self.eval_at(&v, o, i) / pdf,
            pdf,
            delta: false,
        })
    }
}

/// A scalar parameter: `factor`, times a texture's channel where one is given (glTF's rule).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScalarParam {
    /// The constant, or the texture's multiplier.
    pub factor: f32,
    /// A texture (an index into the scene's textures) and its channel, 0 to 2 (R, G, B).
    pub texture: Option<(u32, u8)>,
}

impl ScalarParam {
    /// A constant.
    pub fn constant(factor: f32) -> Self {
        Self {
            factor,
            texture: None,
        }
    }

    #[inline]
    fn at(&self, textures: &[Arc<Texture>], uv: Vec2) -> f32 {
        match self.texture {
            None => self.factor,
            Some((t, c)) => {
                let texel = textures[t as usize].lookup(uv);
                (self.factor * texel[usize::from(c.min(2))]).clamp(0.0, 1.0)
            }
        }
    }
}

/// A tangent-space normal map: the texture, and the scale of its x and y (glTF's `scale`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalMap {
    /// An index into the scene's textures (decoded without the sRGB curve).
    pub texture: u32,
    /// Multiplies the map's x and y before normalising.
    pub scale: f32,
}

/// A `pbr` material as a scene builds it: each parameter a constant or a texture, the normal
/// map, and the coat's table. Kept beside the materials ([`crate::material::Bsdf::Pbr`] holds its index).
#[derive(Clone, Debug)]
pub struct PbrMaterial {
    /// Base colour (linear), or the multiplier of `base_texture`.
    pub base_color: Vec3A,
    /// A colour texture (an index into the scene's textures, sRGB-decoded).
    pub base_texture: Option<u32>,
    /// Metallic.
    pub metallic: ScalarParam,
    /// Perceptual roughness.
    pub roughness: ScalarParam,
    /// Transmission (thin-walled).
    pub transmission: ScalarParam,
    /// Normal map, for meshes with texture coordinates.
    pub normal_map: Option<NormalMap>,
    /// The coat of the material's index.
    pub coat: Arc<CoatTable>,
    /// The microfacet model.
    pub distribution: Distribution,
    /// A clear coat, where the material has one.
    pub clearcoat: Option<ClearcoatParams>,
    /// A sheen (`KHR_materials_sheen`): its colour and roughness, where the material has one.
    pub sheen: Option<(Vec3A, f32)>,
}

/// A `pbr` material's clear coat (`KHR_materials_clearcoat`).
#[derive(Clone, Debug)]
pub struct ClearcoatParams {
    /// Its weight.
    pub weight: ScalarParam,
    /// Its perceptual roughness.
    pub roughness: ScalarParam,
    /// The index-1.5 layer's table.
    pub table: Arc<CoatTable>,
}

impl ClearcoatParams {
    /// A clear coat of `weight` and `roughness`, untextured.
    pub fn new(weight: ScalarParam, roughness: ScalarParam) -> Self {
        Self {
            weight,
            roughness,
            table: CoatTable::shared(CLEARCOAT_IOR),
        }
    }
}

/// The clear coat's index, glTF's (`KHR_materials_clearcoat`) and Blender's default.
pub const CLEARCOAT_IOR: f32 = 1.5;

impl PbrMaterial {
    /// Whether any parameter or the normal map is read from a texture (which needs texture
    /// coordinates).
    pub fn is_textured(&self) -> bool {
        self.base_texture.is_some()
            || self.metallic.texture.is_some()
            || self.roughness.texture.is_some()
            || self.transmission.texture.is_some()
            || self.normal_map.is_some()
            || self
                .clearcoat
                .as_ref()
                .is_some_and(|c| c.weight.texture.is_some() || c.roughness.texture.is_some())
    }

    /// The parameters at texture coordinates `uv`.
    #[inline]
    pub fn params(&self, textures: &[Arc<Texture>], uv: Vec2) -> PbrParams {
        let base_color = match self.base_texture {
            None => self.base_color,
            Some(t) => {
                (self.base_color * textures[t as usize].lookup(uv)).clamp(Vec3A::ZERO, Vec3A::ONE)
            }
        };
        PbrParams {
            base_color,
            metallic: self.metallic.at(textures, uv),
            roughness: self.roughness.at(textures, uv),
            transmission: self.transmission.at(textures, uv),
            clearcoat: self
                .clearcoat
                .as_ref()
                .map_or(0.0, |c| c.weight.at(textures, uv)),
            clearcoat_roughness: self
                .clearcoat
                .as_ref()
                .map_or(0.0, |c| c.roughness.at(textures, uv)),
            sheen_color: self.sheen.map_or(Vec3A::ZERO, |s| s.0),
            sheen_roughness: self.sheen.map_or(0.0, |s| s.1),
        }
    }

    /// The BSDF at a point of parameters `p` (from [`PbrMaterial::params`]).
    #[inline]
    pub fn bsdf(&self, p: PbrParams) -> PbrBsdf<'_> {
        let mut b = PbrBsdf::new(p, &self.coat, self.distribution);
        if self.sheen.is_some() {
            b = b.with_sheen();
        }
        match &self.clearcoat {
            Some(c) => b.with_clearcoat(&c.table, self.distribution),
            None => b,
        }
    }

    /// The shading normal `ns` bent by the normal map at `frame`, or `ns` itself where the
    /// frame is degenerate or the map's normal is not a direction.
    ///
    /// The map's texel t gives n = (2t − 1) scaled by (s, s, 1) in the frame (T, B, ns). Where
    /// the mesh has vertex tangents (glTF's, given or MikkTSpace's), T is the interpolated
    /// tangent's part across ns and B = ns × T · w, glTF's rule, so a map baked against those
    /// tangents reads back as baked, smooth across triangles and mirrored halves alike. Without
    /// them T is the part of the triangle's ∂p/∂u across ns and B = ns × T, turned to point
    /// along ∂p/∂v (Mitsuba's `normalmap` frame). Either way the green channel points up the
    /// image, as in glTF and OpenGL.
    pub fn bend(&self, textures: &[Arc<Texture>], frame: &UvFrame, ns: Vec3A) -> Vec3A {
        let Some(map) = self.normal_map else {
            return ns;
        };
        let t = textures[map.texture as usize].lookup(frame.uv) * 2.0 - Vec3A::ONE;
        let across = |v: Vec3A| (v - ns * ns.dot(v)).try_normalize();
        let vertex = frame
            .tangent
            .and_then(|t4| Some((across(Vec3A::from(t4.truncate()))?, t4.w)));
        let (tangent, bitangent) = match vertex {
            Some((tangent, w)) => (tangent, ns.cross(tangent) * w),
            None => {
                let Some(tangent) = across(frame.dpdu) else {
                    return ns;
                };
                let bitangent = ns.cross(tangent);
                if bitangent.dot(frame.dpdv) < 0.0 {
                    (tangent, -bitangent)
                } else {
                    (tangent, bitangent)
                }
            }
        };
        (tangent * (t.x * map.scale) + bitangent * (t.y * map.scale) + ns * t.z)
            .try_normalize()
            .unwrap_or(ns)
    }
}
