//! The Trowbridge–Reitz (GGX) microfacet distribution, isotropic, with the height-correlated
//! Smith masking–shadowing term and sampling of the normals visible from a direction (Heitz
//! 2018, "Sampling the GGX Distribution of Visible Normals").
//!
//! Everything is in the shading frame, z the macro normal. With α the width:
//!
//! - D(m) = 1 / (π α² cos⁴θm (1 + tan²θm/α²)²) = α² / (π (α² cos²θm + sin²θm)²), normalised
//!   so that ∫ D(m) cos θm dm = 1;
//! - Λ(w) = (√(1 + α² tan²θ) − 1) / 2, G1(w) = 1 / (1 + Λ(w)), G(o, i) = 1 / (1 + Λ(o) + Λ(i));
//! - the visible normals from o have density D_o(m) = G1(o) max(0, o·m) D(m) / cos θo, which
//!   integrates to one over m; [`TrowbridgeReitz::sample_visible`] draws from it exactly.
//!
//! A reflection i = 2(o·m)m − o has the Jacobian dm/di = 1/(4 |o·m|), so the density of i is
//! D_o(m)/(4 |o·m|) = G1(o) D(m) / (4 cos θo). Dividing the single-scattering BRDF
//! D G F / (4 cos θo cos θi), times cos θi, by that density leaves F·G(o, i)/G1(o): at most F,
//! since G ≤ G1. A sampled reflection can lose energy (the multiple scattering this model
//! leaves out) but never gain it, and no division by a small cosine is left in the weight.
//!
//! Only basic f32 operations and `sqrt` are used (correctly rounded everywhere), and angles go
//! through [`sin_cos_turn`], so every machine computes the same bits.

use glam::{Vec2, Vec3A};

use crate::util::sampling::sin_cos_turn;

/// Widths below this are treated as a perfect mirror: D is then too narrow for f32 (pbrt-v4
/// uses the same threshold).
pub const SMOOTH_ALPHA: f32 = 1e-3;

/// The isotropic Trowbridge–Reitz distribution of width α.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrowbridgeReitz {
    alpha: f32,
}

impl TrowbridgeReitz {
    /// The distribution for a scene's `roughness` r ∈ [0, 1]: α = r², the perceptual mapping
    /// glTF, Disney and Blender use (Mitsuba's `alpha` is this α).
    pub fn from_roughness(roughness: f32) -> Self {
        Self {
            alpha: roughness * roughness,
        }
    }

    /// The distribution of width `alpha` itself.
    pub fn new(alpha: f32) -> Self {
        Self { alpha }
    }

    /// α.
    pub fn alpha(&self) -> f32 {
        self.alpha
    }

    /// Whether the surface is a mirror for all purposes (α below [`SMOOTH_ALPHA`]).
    pub fn is_smooth(&self) -> bool {
        self.alpha < SMOOTH_ALPHA
    }

    /// D(m), the density of micro-normals per unit projected area; zero for normals facing
    /// into the surface.
    pub fn d(&self, m: Vec3A) -> f32 {
        if !(m.z > 0.0) {
            return 0.0;
        }
        // With sin²θ from x and y rather than 1 − cos²θ, which cancels near the pole, where a
        // narrow lobe is: D = α² / (π (α² cos²θ + sin²θ)²), the formula above multiplied out.
        let a2 = self.alpha * self.alpha;
        let t = a2 * (m.z * m.z) + (m.x * m.x + m.y * m.y);
        a2 / (std::f32::consts::PI * t * t)
    }

    /// Smith's Λ(w).
    pub fn lambda(&self, w: Vec3A) -> f32 {
        let cos2 = w.z * w.z;
        if !(cos2 > 0.0) {
            return f32::INFINITY;
        }
        let tan2 = (w.x * w.x + w.y * w.y) / cos2;
        ((1.0 + self.alpha * self.alpha * tan2).sqrt() - 1.0) * 0.5
    }

    /// G1(w): the fraction of the micro-surface seen from w that is not masked.
    pub fn g1(&self, w: Vec3A) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// G(o, i), height-correlated masking and shadowing.
    pub fn g(&self, o: Vec3A, i: Vec3A) -> f32 {
        1.0 / (1.0 + self.lambda(o) + self.lambda(i))
    }

    /// D_o(m): the density of the normals visible from `o` (cos θo > 0).
    pub fn d_visible(&self, o: Vec3A, m: Vec3A) -> f32 {
        let om = o.dot(m);
        if !(o.z > 0.0 && om > 0.0) {
            return 0.0;
        }
        self.g1(o) * om * self.d(m) / o.z
    }

    /// A micro-normal drawn from D_o for a direction `o` above the surface (Heitz 2018: the
    /// hemisphere configuration stretched by α, a point on the projected disk, unstretched).
    pub fn sample_visible(&self, o: Vec3A, u: Vec2) -> Vec3A {
        let a = self.alpha;
        let mut h = Vec3A::new(a * o.x, a * o.y, o.z).normalize();
        if h.z < 0.0 {
            h = -h;
        }
        // An orthonormal basis around h, with t1 horizontal (any, at normal incidence).
        let len2 = h.x * h.x + h.y * h.y;
        let t1 = if len2 > 1e-14 {
            let inv = 1.0 / len2.sqrt();
            Vec3A::new(-h.y * inv, h.x * inv, 0.0)
        } else {
            Vec3A::X
        };
        let t2 = h.cross(t1);
        // A uniform point on the disk, its second coordinate squeezed onto the part of the
        // disk the visible hemisphere projects to.
        let r = u.x.sqrt();
        let (s, c) = sin_cos_turn(u.y);
        let (p1, mut p2) = (r * c, r * s);
        let half = 0.5 * (1.0 + h.z);
        let below = (1.0 - p1 * p1).max(0.0).sqrt();
        p2 = (1.0 - half) * below + half * p2;
        let p3 = (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
        let n = t1 * p1 + t2 * p2 + h * p3;
        Vec3A::new(a * n.x, a * n.y, n.z.max(1e-6)).normalize()
    }

    /// The density, per solid angle of `i`, of a reflection about a visible normal drawn for
    /// `o`: G1(o) D(m) / (4 cos θo), with m the half vector. Zero where `o` is below the
    /// surface or the half vector faces away from `o`.
    pub fn reflection_pdf(&self, o: Vec3A, i: Vec3A) -> f32 {
        let Some(m) = half_vector(o, i) else {
            return 0.0;
        };
        if !(o.z > 0.0 && o.dot(m) > 0.0) {
            return 0.0;
        }
        self.g1(o) * self.d(m) / (4.0 * o.z)
    }
}

/// The unit half vector of a reflection from `o` into `i`, on the side of the macro normal;
/// `None` where the two are opposite.
#[inline]
pub fn half_vector(o: Vec3A, i: Vec3A) -> Option<Vec3A> {
    let m = (o + i).try_normalize()?;
    Some(if m.z < 0.0 { -m } else { m })
}

/// `o` mirrored about the unit normal `m`: 2(o·m)m − o.
#[inline]
pub fn reflect_about(o: Vec3A, m: Vec3A) -> Vec3A {
    m * (2.0 * o.dot(m)) - o
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ∫ f(w) dw over the sphere by a midpoint rule in (θ, φ), dw = sin θ dθ dφ: fine steps
    /// near the pole, where the narrow lobes are.
    fn integrate(f: impl Fn(Vec3A) -> f64, n: usize) -> f64 {
        let mut s = 0.0;
        let dt = std::f64::consts::PI / n as f64;
        let dp = 2.0 * std::f64::consts::PI / (2 * n) as f64;
        for i in 0..n {
            let t = (i as f64 + 0.5) * dt;
            let (st, ct) = t.sin_cos();
            for j in 0..2 * n {
                let p = (j as f64 + 0.5) * dp;
                let w = Vec3A::new((st * p.cos()) as f32, (st * p.sin()) as f32, ct as f32);
                s += f(w) * st * dt * dp;
            }
        }
        s
    }

    #[test]
    fn projected_normals_and_visible_normals_integrate_to_one() {
        for alpha in [0.05f32, 0.2, 0.5, 1.0] {
            let d = TrowbridgeReitz::new(alpha);
            let n = 600;
            let proj = integrate(|m| (d.d(m) * m.z.max(0.0)) as f64, n);
            assert!((proj - 1.0).abs() < 2e-3, "α {alpha}: ∫D cos = {proj}");
            for theta in [0.0f32, 0.7, 1.4] {
                let o = Vec3A::new(theta.sin(), 0.0, theta.cos());
                let vis = integrate(|m| d.d_visible(o, m) as f64, n);
                assert!(
                    (vis - 1.0).abs() < 3e-3,
                    "α {alpha}, θo {theta}: ∫D_o = {vis}"
                );
            }
        }
    }

    #[test]
    fn masking_is_one_at_normal_incidence_and_bounded_everywhere() {
        let d = TrowbridgeReitz::new(0.7);
        assert_eq!(d.g1(Vec3A::Z), 1.0);
        for z in [1e-7f32, 1e-3, 0.3, 0.99] {
            let w = Vec3A::new((1.0 - z * z).sqrt(), 0.0, z);
            let (g1, g) = (d.g1(w), d.g(w, Vec3A::Z));
            assert!(g1.is_finite() && (0.0..=1.0).contains(&g1), "{z}: G1 {g1}");
            assert!(g <= g1, "{z}: G {g} above G1 {g1}");
        }
        assert_eq!(d.g1(Vec3A::X), 0.0, "grazing: fully masked");
    }
}
