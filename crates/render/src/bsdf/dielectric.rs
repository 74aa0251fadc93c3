//! Rough glass: a dielectric interface of GGX microfacets that reflect and refract (Walter et
//! al. 2007), sampled by visible normals, and the thin-walled smooth sheet.
//!
//! In the shading frame of the side the path arrives on (o·z > 0), with η = n_t/n_i the index
//! across the interface from that side, a visible normal m is drawn from D_o (see
//! [`super::microfacet`]) and the path reflects about it with the Fresnel probability F(o·m),
//! or refracts through it with 1 − F. Reflection's density is D_o(m)/(4 o·m) F and its BRDF
//! D G F/(4 cos θo cos θi), so the weight f cos θi/pdf is G(o, i)/G1(o). Refraction's half
//! vector is m ∝ −(o + η i), with dm/di = |i·m| / (i·m + o·m/η)², its density D_o(m) |i·m|
//! (1 − F)/(i·m + o·m/η)², and its BTDF (1 − F) D G |i·m| |o·m| / (cos θo |cos θi| (i·m +
//! o·m/η)²), so the weight is again G/G1; radiance is compressed by 1/η² across the interface,
//! which the integrator applies as for smooth glass. Neither weight has a cosine below it, and
//! neither exceeds one.

use glam::{Vec2, Vec3A};

use super::fresnel_dielectric;
use super::microfacet::{reflect_about, TrowbridgeReitz};

/// A rough dielectric interface: the distribution of its micro-normals, and its index of
/// refraction (inside over outside).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoughDielectric {
    /// The microfacet distribution.
    pub distribution: TrowbridgeReitz,
    /// Inside over outside.
    pub ior: f32,
}

/// A direction drawn from a rough dielectric.
#[derive(Clone, Copy, Debug)]
pub struct DielectricSample {
    /// The new direction in the shading frame: above it for a reflection, below for a
    /// refraction.
    pub wi: Vec3A,
    /// f |cos θi| / pdf, without the 1/η² of a refraction.
    pub weight: f32,
    /// Its density per solid angle.
    pub pdf: f32,
    /// Whether it went through the interface.
    pub refracted: bool,
}

impl RoughDielectric {
    /// The half vector of `o` and `i` for index `eta` (reflection or refraction, by the sides
    /// of `i`), facing up, and whether the pair is a reflection; `None` where it is not
    /// defined or either direction meets the microfacet from behind.
    fn half(o: Vec3A, i: Vec3A, eta: f32) -> Option<(Vec3A, bool)> {
        if !(o.z > 0.0) || i.z == 0.0 {
            return None;
        }
        let reflect = i.z > 0.0;
        let m = if reflect { o + i } else { o + i * eta };
        let m = m.try_normalize()?;
        let m = if m.z < 0.0 { -m } else { m };
        // A microfacet seen from behind by either direction contributes nothing.
        if m.dot(i) * i.z < 0.0 || m.dot(o) <= 0.0 {
            return None;
        }
        Some((m, reflect))
    }

    /// f(o, i) |cos θi| for a path arriving from above (`o.z` > 0) with index ratio `eta`
    /// (n_t/n_i) across the interface, refraction's 1/η² included.
    pub fn eval(&self, o: Vec3A, i: Vec3A, eta: f32) -> f32 {
        let Some((m, reflect)) = Self::half(o, i, eta) else {
            return 0.0;
        };
        let d = &self.distribution;
        let (f, _) = fresnel_dielectric(o.dot(m), eta);
        if reflect {
            return d.d(m) * d.g(o, i) * f / (4.0 * o.z);
        }
        let im = i.dot(m);
        let om = o.dot(m);
        let s = im + om / eta;
        let denom = s * s;
        (1.0 - f) * d.d(m) * d.g(o, i) * (im * om).abs() / (o.z * denom) / (eta * eta)
    }

    /// The density [`RoughDielectric::sample`] draws `i` with.
    pub fn pdf(&self, o: Vec3A, i: Vec3A, eta: f32) -> f32 {
        let Some((m, reflect)) = Self::half(o, i, eta) else {
            return 0.0;
        };
        let d = &self.distribution;
        let om = o.dot(m);
        let (f, _) = fresnel_dielectric(om, eta);
        if reflect {
            return d.d_visible(o, m) / (4.0 * om) * f;
        }
        let im = i.dot(m);
        let s = im + om / eta;
        d.d_visible(o, m) * im.abs() / (s * s) * (1.0 - f)
    }

    /// Reflects or refracts about a visible normal drawn with `u`, choosing by the Fresnel
    /// term with `u_choice`; `None` where the new direction lands on the wrong side (the light
    /// went into the multiple scattering the model leaves out).
    pub fn sample(&self, o: Vec3A, eta: f32, u: Vec2, u_choice: f32) -> Option<DielectricSample> {
        if !(o.z > 0.0) {
            return None;
        }
        let d = &self.distribution;
        let m = d.sample_visible(o, u);
        let om = o.dot(m);
        let (f, cos_t) = fresnel_dielectric(om, eta);
        let g1 = d.g1(o);
        if u_choice < f {
            let i = reflect_about(o, m);
            if !(i.z > 0.0) {
                return None;
            }
            let pdf = d.d_visible(o, m) / (4.0 * om) * f;
            return (pdf > 0.0).then(|| DielectricSample {
                wi: i,
                weight: d.g(o, i) / g1,
                pdf,
                refracted: false,
            });
        }
        // Refraction through m: −o/η + m (cos θi/η − cos θt), as for a smooth surface.
        let i = (-o / eta + m * (om / eta - cos_t)).normalize();
        if !(i.z < 0.0) {
            return None;
        }
        let im = i.dot(m);
        let s = im + om / eta;
        let pdf = d.d_visible(o, m) * im.abs() / (s * s) * (1.0 - f);
        (pdf > 0.0 && pdf.is_finite()).then(|| DielectricSample {
            wi: i,
            weight: d.g(o, i) / g1,
            pdf,
            refracted: true,
        })
    }
}

/// A thin sheet of glass (a window, a soap film), smooth: light passes straight through or
/// reflects, with the reflectance R' = R + T²R/(1 − R²) of the infinitely many internal
/// reflections between its two faces summed (T = 1 − R). Returns R'.
pub fn thin_reflectance(cos_i: f32, ior: f32) -> f32 {
    let (r, _) = fresnel_dielectric(cos_i, ior);
    if r < 1.0 {
        let t = 1.0 - r;
        r + t * t * r / (1.0 - r * r)
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thin_sheet_reflects_more_than_one_face_and_never_all() {
        for c in [1.0f32, 0.5, 0.1] {
            let (one, _) = fresnel_dielectric(c, 1.5);
            let two = thin_reflectance(c, 1.5);
            assert!(two > one && two < 1.0, "cos {c}: {one} {two}");
        }
        // Normal incidence, η = 1.5: R = 0.04, R' = 2R/(1 + R) = 0.0769….
        assert!((thin_reflectance(1.0, 1.5) - 0.08 / 1.04).abs() < 1e-6);
        assert!(thin_reflectance(0.3, 1.0) < 1e-6, "index 1: no interface");
    }
}
