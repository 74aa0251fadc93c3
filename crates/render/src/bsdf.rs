//! The BSDFs a material can have: Lambertian diffuse, a perfect mirror, a smooth
//! dielectric with Fresnel reflection and refraction, rough or smooth metals ([`conductor`],
//! on the GGX distribution of [`microfacet`]), rough glass ([`dielectric`]) and plastic
//! ([`plastic`]), and glTF's metallic–roughness material ([`pbr`], compensated by the tables
//! of [`albedo`]): the arithmetic of the materials in [`crate::material`], which wrap them.
//! Every function does its arithmetic in one fixed order, since the renderer's bits depend on
//! it.

pub mod albedo;
pub mod conductor;
pub mod dielectric;
pub mod microfacet;
pub mod pbr;
pub mod plastic;
pub mod sheen;

use glam::{Vec2, Vec3A};

pub use conductor::{Conductor, Fresnel, Metal, Sampled};
pub use dielectric::{DielectricSample, RoughDielectric};
pub use pbr::{PbrBsdf, PbrMaterial, PbrParams, PbrSample};
pub use plastic::{Plastic, PlasticSample};

use crate::util::math::Frame;
use crate::util::sampling::{cosine_hemisphere_pdf, square_to_cosine_hemisphere};

/// A direction from the Lambertian lobe about the unit normal `n`, drawn with pdf cos θ/π from
/// the square sample `u`, and that pdf. With f = ρ/π, the throughput update f·cos θ/pdf is
/// exactly ρ, so callers multiply by the albedo alone.
#[inline]
pub fn sample_diffuse(n: Vec3A, u: Vec2) -> (Vec3A, f32) {
    let local = square_to_cosine_hemisphere(u);
    let wi = Frame::from_normal(n).to_world(local);
    (wi, cosine_hemisphere_pdf(local.z))
}

/// Fresnel reflectance of a smooth dielectric for unpolarised light. `cos_i` ≥ 0 is on the
/// incident side; `eta` = n_transmitted / n_incident. Returns (F, cos θt), F = 1 under total
/// internal reflection.
#[inline]
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> (f32, f32) {
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return (1.0, 0.0);
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    (0.5 * (r_par * r_par + r_perp * r_perp), cos_t)
}

/// The mirror direction of `d` about the unit normal `n`.
#[inline]
pub fn reflect(d: Vec3A, n: Vec3A) -> Vec3A {
    d - n * (2.0 * d.dot(n))
}

/// The refracted direction for a path leaving along `wo` (pointing away from the surface) on
/// the side of the unit normal `n`, with relative index `eta` and the cosines
/// [`fresnel_dielectric`] returned.
#[inline]
pub fn refract(wo: Vec3A, n: Vec3A, eta: f32, cos_i: f32, cos_t: f32) -> Vec3A {
    (-wo / eta + n * (cos_i / eta - cos_t)).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_limits() {
        let (f, _) = fresnel_dielectric(1.0, 1.5);
        assert!(
            (f - 0.04).abs() < 1e-6,
            "normal incidence ((n-1)/(n+1))², got {f}"
        );
        assert_eq!(
            fresnel_dielectric(0.1, 1.0 / 1.5).0,
            1.0,
            "total internal reflection"
        );
        let (f, c) = fresnel_dielectric(0.0, 1.5);
        assert!((f - 1.0).abs() < 1e-6 && c.is_finite());
        assert_eq!(
            fresnel_dielectric(0.7, 1.0).0,
            0.0,
            "index-matched: no reflection"
        );
    }
}
