//! Plastic: a diffuse base under a clear dielectric coat, rough or smooth — Mitsuba 3's
//! `roughplastic` and `plastic` model, so that its renders are our reference.
//!
//! In the shading frame, with o towards the viewer and i towards the light (both above):
//!
//! - the coat reflects as rough glass does, f_s cos θi = F(o·m, η) D(m) G(o, i) / (4 cos θo)
//!   (m the half vector; [`super::microfacet`]); a smooth coat is a mirror of reflectance
//!   F(cos θo, η);
//! - light that enters the coat reaches the base with the coat's transmittance
//!   t(μ) = 1 − R(μ, η), R(μ, η) = ∫ f_s cos θi dωi the coat's reflection albedo at incidence μ
//!   (1 − F(μ) for a smooth coat), is scattered by the Lambertian base ρ, bounces between base
//!   and coat, and leaves with t(cos θi) again:
//!   f_d cos θi = ρ / (1 − F̄) · t(cos θo) t(cos θi) cos θi / (π η²),
//!   F̄ = 2 ∫₀¹ R(μ, 1/η) μ dμ the coat's albedo from inside for cosine-distributed light (so the
//!   bounces sum to 1/(1 − F̄), Mitsuba's default "linear" form, exact at ρ = 1), and 1/η² the
//!   compression of radiance into the denser medium and back.
//!
//! Energy: at ρ = 1, ∫ f_d cos dωi = t(cos θo) · (1 − F̄_ext)/(η²(1 − F̄)), and for a smooth
//! coat 1 − F̄_ext = η²(1 − F̄) (reciprocity), so the albedo is t + R = 1 exactly; a rough coat
//! holds this to the accuracy of single scattering, and below ρ = 1 the albedo R + ρ·t·(…) is
//! less. The white furnace test checks it.
//!
//! Sampling picks the coat with probability p_s ∝ (1 − t(cos θo)) · w against the base's
//! t(cos θo) · (1 − w), w = 1/(1 + mean ρ) (Mitsuba's choice), then a visible normal or a
//! cosine-weighted direction; the density is the mixture's, p_s p_coat + (1 − p_s) cos θi/π,
//! so either lobe's directions are weighed against both. A smooth coat's mirror direction has
//! no density: its sample is a delta of weight F/p_s.
//!
//! R(μ, η) is tabulated at [`TABLE`] incidences and interpolated, as Mitsuba does; each entry
//! and F̄ are integrated here by a fixed midpoint rule over the visible normals (the integrand
//! F·G/G1 is smooth in the sample square), in basic arithmetic, so every worker builds the same
//! table.

use glam::{Vec2, Vec3A};

use super::fresnel_dielectric;
use super::microfacet::{half_vector, reflect_about, TrowbridgeReitz};
use crate::util::sampling::{cosine_hemisphere_pdf, square_to_cosine_hemisphere};
use crate::util::tabulate::tabulate;

/// Entries of the coat's transmittance table, over cos θ from 0 to 1 (Mitsuba's resolution).
pub const TABLE: usize = 64;

/// Midpoints per side of the sample square for each table entry.
const QUADRATURE: usize = 48;

/// A plastic as a scene builds it (kept beside the materials, like absorption, so that a
/// material stays small: [`crate::material::Bsdf::Plastic`] holds its index).
#[derive(Clone, Debug, PartialEq)]
pub struct Plastic {
    albedo: Vec3A,
    distribution: TrowbridgeReitz,
    /// Index of the coat over the outside (inside / outside).
    eta: f32,
    /// t(μ) at μ = j / (TABLE − 1).
    transmittance: [f32; TABLE],
    /// 1 / ((1 − F̄) π η²): the base's scale.
    diffuse_scale: f32,
    /// w, the coat's share of the lobe choice before t weighs it.
    coat_weight: f32,
}

/// A direction drawn from a plastic.
#[derive(Clone, Copy, Debug)]
pub struct PlasticSample {
    /// The direction, in the shading frame.
    pub wi: Vec3A,
    /// f cos θi / pdf (a smooth coat's mirror: F / p_s).
    pub weight: Vec3A,
    /// The mixture's density per solid angle; for a smooth coat's mirror, 0 with `delta` set.
    pub pdf: f32,
    /// The smooth coat's mirror direction, which light sampling cannot find.
    pub delta: bool,
}

impl Plastic {
    /// A base of albedo `albedo` under a coat of index `eta` and GGX width α from `roughness`
    /// (α = roughness²; a mirror coat below the threshold of [`TrowbridgeReitz::is_smooth`]).
    pub fn new(albedo: Vec3A, roughness: f32, eta: f32) -> Self {
        let distribution = TrowbridgeReitz::from_roughness(roughness);
        // Both tables in one run over the cores: R(μ, η) at the TABLE incidences, then
        // R(μ, 1/η)·μ at n midpoints for F̄ = 2 ∫ R(μ, 1/η) μ dμ, summed in order.
        let n = 4 * TABLE;
        let entries = tabulate(TABLE + n, |k| {
            if k < TABLE {
                let mu = k as f32 / (TABLE - 1) as f32;
                1.0 - coat_albedo(&distribution, mu, eta, QUADRATURE)
            } else {
                let mu = ((k - TABLE) as f32 + 0.5) / n as f32;
                coat_albedo(&distribution, mu, 1.0 / eta, QUADRATURE) * mu
            }
        });
        let transmittance = std::array::from_fn(|j| entries[j]);
        let inside: f64 = entries[TABLE..].iter().map(|&e| f64::from(e)).sum();
        let f_bar = (2.0 * inside / n as f64) as f32;
        let diffuse_scale = 1.0 / ((1.0 - f_bar) * std::f32::consts::PI * eta * eta);
        let mean = (albedo.x + albedo.y + albedo.z) / 3.0;
        Self {
            albedo,
            distribution,
            eta,
            transmittance,
            diffuse_scale,
            coat_weight: 1.0 / (1.0 + mean),
        }
    }

    /// The diffuse base's albedo (what a denoiser's albedo image shows of it).
    #[inline]
    pub fn albedo(&self) -> Vec3A {
        self.albedo
    }

    /// Whether the coat is a mirror.
    #[inline]
    pub fn is_smooth(&self) -> bool {
        self.distribution.is_smooth()
    }

    /// The coat's transmittance t(μ): 1 − F(μ) for a smooth coat, else by linear
    /// interpolation in the table.
    pub fn transmittance(&self, mu: f32) -> f32 {
        if self.is_smooth() {
            return 1.0 - fresnel_dielectric(mu.clamp(0.0, 1.0), self.eta).0;
        }
        let x = mu.clamp(0.0, 1.0) * (TABLE - 1) as f32;
        let j = (x as usize).min(TABLE - 2);
        let w = x - j as f32;
        self.transmittance[j] * (1.0 - w) + self.transmittance[j + 1] * w
    }

    /// p_s, the probability of sampling the coat for a viewer at cos θo = `mu`.
    fn coat_probability(&self, mu: f32) -> f32 {
        let t = self.transmittance(mu);
        let s = (1.0 - t) * self.coat_weight;
        let d = t * (1.0 - self.coat_weight);
        if s + d > 0.0 {
            s / (s + d)
        } else {
            1.0
        }
    }

    /// f(o, i) cos θi of the lobes light sampling can find (for a smooth coat, the base only);
    /// zero unless both are above the surface.
    pub fn eval(&self, o: Vec3A, i: Vec3A) -> Vec3A {
        if !(o.z > 0.0 && i.z > 0.0) {
            return Vec3A::ZERO;
        }
        let base = self.albedo
            * (self.diffuse_scale * self.transmittance(o.z) * self.transmittance(i.z) * i.z);
        if self.is_smooth() {
            return base;
        }
        let Some(m) = half_vector(o, i) else {
            return base;
        };
        let d = &self.distribution;
        let (f, _) = fresnel_dielectric(o.dot(m).max(0.0), self.eta);
        base + Vec3A::splat(f * d.d(m) * d.g(o, i) / (4.0 * o.z))
    }

    /// The density [`Plastic::sample`] draws `i` with, but for a smooth coat's mirror.
    pub fn pdf(&self, o: Vec3A, i: Vec3A) -> f32 {
        if !(o.z > 0.0 && i.z > 0.0) {
            return 0.0;
        }
        let p_s = self.coat_probability(o.z);
        let coat = if self.is_smooth() {
            0.0
        } else {
            self.distribution.reflection_pdf(o, i)
        };
        p_s * coat + (1.0 - p_s) * cosine_hemisphere_pdf(i.z)
    }

    /// A direction from `u` (the square) and `u_lobe` (the lobe choice), or `None` where it
    /// would go under the surface or `o` is not above it.
    pub fn sample(&self, o: Vec3A, u: Vec2, u_lobe: f32) -> Option<PlasticSample> {
        if !(o.z > 0.0) {
            return None;
        }
        let p_s = self.coat_probability(o.z);
        if u_lobe < p_s && self.is_smooth() {
            let (f, _) = fresnel_dielectric(o.z, self.eta);
            return Some(PlasticSample {
                wi: Vec3A::new(-o.x, -o.y, o.z),
                weight: Vec3A::splat(f / p_s),
                pdf: 0.0,
                delta: true,
            });
        }
        let i = if u_lobe < p_s {
            reflect_about(o, self.distribution.sample_visible(o, u))
        } else {
            square_to_cosine_hemisphere(u)
        };
        if !(i.z > 0.0) {
            return None;
        }
        let pdf = self.pdf(o, i);
        if !(pdf > 0.0) {
            return None;
        }
        Some(PlasticSample {
            wi: i,
            weight: self.eval(o, i) / pdf,
            pdf,
            delta: false,
        })
    }
}

/// R(μ, η): the coat's reflection albedo at incidence cos θ = μ, ∫ F(o·m) G(o, i)/G1(o) over the
/// visible normals by a midpoint rule of `n` × `n` points (a reflection below the surface
/// counts nothing); for a smooth coat, F(μ).
pub(super) fn coat_albedo(d: &TrowbridgeReitz, mu: f32, eta: f32, n: usize) -> f32 {
    // Mitsuba's table starts at 10⁻⁶ too: at μ = 0 exactly the direction is undefined.
    let mu = mu.max(1e-6);
    if d.is_smooth() {
        return fresnel_dielectric(mu, eta).0;
    }
    let o = Vec3A::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let g1 = d.g1(o);
    let mut sum = 0.0f64;
    for a in 0..n {
        for b in 0..n {
            let u = Vec2::new((a as f32 + 0.5) / n as f32, (b as f32 + 0.5) / n as f32);
            let m = d.sample_visible(o, u);
            let i = reflect_about(o, m);
            if i.z > 0.0 {
                let (f, _) = fresnel_dielectric(o.dot(m).max(0.0), eta);
                sum += f64::from(f * d.g(o, i) / g1);
            }
        }
    }
    (sum / (n * n) as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth coat's F̄ from inside equals 1 − (1 − F̄_ext)/η² (reciprocity), which is what
    /// makes the white base's albedo exactly one.
    #[test]
    fn a_smooth_coat_conserves_energy_over_a_white_base() {
        let p = Plastic::new(Vec3A::ONE, 0.0, 1.5);
        let n = 20_000;
        let mut ext = 0.0f64;
        for k in 0..n {
            let mu = (k as f64 + 0.5) / n as f64;
            ext += f64::from(fresnel_dielectric(mu as f32, 1.5).0) * mu;
        }
        let ext = 2.0 * ext / n as f64;
        // ∫ f_d cos dωi / t(cos θo) = (1 − F̄_ext) · π η² scale / π.
        let base = (1.0 - ext) * f64::from(p.diffuse_scale) * std::f64::consts::PI;
        assert!((base - 1.0).abs() < 2e-3, "{base}");
    }

    #[test]
    fn the_table_is_one_minus_fresnel_for_a_smooth_coat_and_below_it_when_rough() {
        let smooth = Plastic::new(Vec3A::ONE, 0.0, 1.5);
        for mu in [0.1f32, 0.5, 1.0] {
            let want = 1.0 - fresnel_dielectric(mu, 1.5).0;
            assert!((smooth.transmittance(mu) - want).abs() < 2e-3, "{mu}");
        }
        // Head-on, roughness hardly changes the coat's reflectance (4% at η = 1.5).
        let rough = Plastic::new(Vec3A::ONE, 0.5, 1.5);
        assert!(
            (rough.transmittance(1.0) - 0.96).abs() < 0.01,
            "{}",
            rough.transmittance(1.0)
        );
        assert!(rough.transmittance(0.05) > smooth.transmittance(0.05));
    }
}
