//! Metals: a Fresnel term for a complex index of refraction (or an artist's colour at normal
//! incidence), and the rough conductor built on it from [`super::microfacet`].
//!
//! The conductor's BRDF is single-scattering GGX: f(o, i) = D(m) G(o, i) F(o·m) / (4 cos θo
//! cos θi), m the half vector. It is sampled by visible normals, which gives the weight
//! f cos θi / pdf = F G(o, i) / G1(o) (derived in [`super::microfacet`]): never above F, so a
//! white metal (F = 1) conserves or loses energy. What it loses is the light that would scatter
//! between microfacets more than once, which this model does not follow (Kulla and Conty 2017
//! measured it: up to about 40% at α = 1 for a white metal); the tests pin the loss to the
//! integral of the model itself.

use glam::{Vec2, Vec3A};

use super::microfacet::{half_vector, reflect_about, TrowbridgeReitz};

/// How much of the light a metal reflects at each angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fresnel {
    /// The exact Fresnel reflectance of a conductor with complex index η + ik per RGB channel
    /// (relative to the outside medium, taken as vacuum).
    Complex {
        /// Real part η.
        eta: Vec3A,
        /// Extinction coefficient k.
        k: Vec3A,
    },
    /// Schlick's approximation F = F0 + (1 − F0)(1 − cos θ)⁵ from the reflectance at normal
    /// incidence, the colour an artist picks (glTF's and Unreal's metals).
    Schlick(Vec3A),
}

impl Fresnel {
    /// The reflectance for light arriving at `cos_i` (clamped to [0, 1]) from the normal.
    pub fn eval(&self, cos_i: f32) -> Vec3A {
        let c = cos_i.clamp(0.0, 1.0);
        match *self {
            Fresnel::Complex { eta, k } => Vec3A::new(
                fresnel_complex(c, eta.x, k.x),
                fresnel_complex(c, eta.y, k.y),
                fresnel_complex(c, eta.z, k.z),
            ),
            Fresnel::Schlick(f0) => {
                let m = 1.0 - c;
                let m2 = m * m;
                f0 + (Vec3A::ONE - f0) * (m2 * m2 * m)
            }
        }
    }
}

/// Fresnel reflectance of unpolarised light at the boundary with a conductor of complex index
/// η + ik, for incidence cosine `cos_i` in [0, 1]: the average of |r∥|² and |r⊥|², with the
/// transmitted cosine cos θt = √(1 − sin²θi/(η + ik)²) taken on the principal branch.
pub fn fresnel_complex(cos_i: f32, eta: f32, k: f32) -> f32 {
    let n = C::new(eta, k);
    let ci = C::new(cos_i, 0.0);
    let sin2_i = 1.0 - cos_i * cos_i;
    let sin2_t = C::new(sin2_i, 0.0).div(n.mul(n));
    let ct = C::new(1.0 - sin2_t.re, -sin2_t.im).sqrt();
    let r_par = n.mul(ci).sub(ct).div(n.mul(ci).add(ct));
    let r_perp = ci.sub(n.mul(ct)).div(ci.add(n.mul(ct)));
    0.5 * (r_par.norm2() + r_perp.norm2())
}

/// The few complex operations [`fresnel_complex`] needs, in plain f32 arithmetic.
#[derive(Clone, Copy, Debug)]
struct C {
    re: f32,
    im: f32,
}

impl C {
    fn new(re: f32, im: f32) -> Self {
        Self { re, im }
    }
    fn add(self, o: Self) -> Self {
        Self::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: Self) -> Self {
        Self::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: Self) -> Self {
        Self::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
    fn norm2(self) -> f32 {
        self.re * self.re + self.im * self.im
    }
    fn div(self, o: Self) -> Self {
        let d = o.norm2();
        Self::new(
            (self.re * o.re + self.im * o.im) / d,
            (self.im * o.re - self.re * o.im) / d,
        )
    }
    /// The principal square root (non-negative real part).
    fn sqrt(self) -> Self {
        let n = self.norm2().sqrt();
        if n == 0.0 {
            return Self::new(0.0, 0.0);
        }
        let t1 = (0.5 * (n + self.re.abs())).sqrt();
        let t2 = 0.5 * self.im / t1;
        if self.re >= 0.0 {
            Self::new(t1, t2)
        } else {
            Self::new(t2.abs(), t1.copysign(self.im))
        }
    }
}

/// A metal: GGX roughness and a Fresnel term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conductor {
    /// The microfacet distribution.
    pub distribution: TrowbridgeReitz,
    /// The reflectance of one facet.
    pub fresnel: Fresnel,
}

/// A metal as a material stores it: 28 bytes of f32s, so that [`crate::material::Bsdf`] stays the 32
/// bytes it was before metals (a larger enum made every material larger and measurably slowed
/// the scenes that have none). [`Metal::conductor`] unpacks it at the vertex.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Metal {
    alpha: f32,
    /// η, or F0 for Schlick's term.
    a: [f32; 3],
    /// k, or a negative first element (k is never negative) for Schlick's term.
    b: [f32; 3],
}

impl Metal {
    /// Packs `c`.
    pub fn new(c: &Conductor) -> Self {
        let alpha = c.distribution.alpha();
        match c.fresnel {
            Fresnel::Complex { eta, k } => Self {
                alpha,
                a: eta.into(),
                b: k.into(),
            },
            Fresnel::Schlick(f0) => Self {
                alpha,
                a: f0.into(),
                b: [-1.0; 3],
            },
        }
    }

    /// The conductor it packs.
    #[inline]
    pub fn conductor(&self) -> Conductor {
        let fresnel = if self.b[0] < 0.0 {
            Fresnel::Schlick(Vec3A::from(self.a))
        } else {
            Fresnel::Complex {
                eta: Vec3A::from(self.a),
                k: Vec3A::from(self.b),
            }
        };
        Conductor {
            distribution: TrowbridgeReitz::new(self.alpha),
            fresnel,
        }
    }

    /// Whether it is a mirror for all purposes.
    #[inline]
    pub fn is_smooth(&self) -> bool {
        TrowbridgeReitz::new(self.alpha).is_smooth()
    }
}

/// A direction drawn from a BSDF lobe.
#[derive(Clone, Copy, Debug)]
pub struct Sampled {
    /// The new direction, in the shading frame.
    pub wi: Vec3A,
    /// f cos θi / pdf.
    pub weight: Vec3A,
    /// Its density per solid angle.
    pub pdf: f32,
}

impl Conductor {
    /// f(o, i) cos θi, in the shading frame; zero unless both are above the surface.
    pub fn eval(&self, o: Vec3A, i: Vec3A) -> Vec3A {
        if !(o.z > 0.0 && i.z > 0.0) {
            return Vec3A::ZERO;
        }
        let Some(m) = half_vector(o, i) else {
            return Vec3A::ZERO;
        };
        let d = &self.distribution;
        self.fresnel.eval(o.dot(m)) * (d.d(m) * d.g(o, i) / (4.0 * o.z))
    }

    /// The density [`Conductor::sample`] draws `i` with.
    pub fn pdf(&self, o: Vec3A, i: Vec3A) -> f32 {
        if !(i.z > 0.0) {
            return 0.0;
        }
        self.distribution.reflection_pdf(o, i)
    }

    /// A reflected direction by visible normals, or `None` when it would go under the surface
    /// (the path ends: the facet reflected it into its neighbours, which this model leaves
    /// out) or `o` is not above it.
    pub fn sample(&self, o: Vec3A, u: Vec2) -> Option<Sampled> {
        if !(o.z > 0.0) {
            return None;
        }
        let d = &self.distribution;
        let m = d.sample_visible(o, u);
        let i = reflect_about(o, m);
        if !(i.z > 0.0) {
            return None;
        }
        let pdf = d.reflection_pdf(o, i);
        if !(pdf > 0.0) {
            return None;
        }
        let weight = self.fresnel.eval(o.dot(m)) * (d.g(o, i) / d.g1(o));
        Some(Sampled { wi: i, weight, pdf })
    }
}

/// Measured complex indices of refraction of common metals, at 650, 550 and 450 nm for R, G
/// and B, from refractiveindex.info's data sets (gold, silver and copper: Johnson and Christy
/// 1972; aluminium: Rakić 1995; chromium, iron and platinum: Johnson and Christy 1974) as
/// tabulated by Chaos Group ("Understanding metalness", 2018). Names are matched as written
/// here; `aluminum` is an alias.
pub const METALS: &[(&str, [f32; 3], [f32; 3])] = &[
    (
        "aluminium",
        [1.3456, 0.96521, 0.61722],
        [7.4746, 6.3995, 5.3031],
    ),
    ("chromium", [3.1071, 3.1812, 2.323], [3.3314, 3.3291, 3.135]),
    (
        "copper",
        [0.27105, 0.67693, 1.3164],
        [3.6092, 2.6248, 2.2921],
    ),
    ("gold", [0.18299, 0.42108, 1.3734], [3.4242, 2.3459, 1.7704]),
    ("iron", [2.9114, 2.9497, 2.5845], [3.0893, 2.9318, 2.767]),
    (
        "platinum",
        [2.3757, 2.0847, 1.8453],
        [4.2655, 3.7153, 3.1365],
    ),
    (
        "silver",
        [0.15943, 0.14512, 0.13547],
        [3.9291, 3.19, 2.3808],
    ),
];

/// The (η, k) of a metal in [`METALS`] by name (`aluminum` too).
pub fn metal(name: &str) -> Option<(Vec3A, Vec3A)> {
    let name = if name == "aluminum" {
        "aluminium"
    } else {
        name
    };
    METALS
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|(_, eta, k)| (Vec3A::from(*eta), Vec3A::from(*k)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn complex_fresnel_meets_its_closed_forms() {
        for (eta, k) in [(0.2f32, 3.4f32), (1.5, 0.0), (2.9, 3.0), (1.0, 0.0)] {
            // Normal incidence: ((η − 1)² + k²) / ((η + 1)² + k²).
            let want = ((eta - 1.0).powi(2) + k * k) / ((eta + 1.0).powi(2) + k * k);
            let got = fresnel_complex(1.0, eta, k);
            assert!((got - want).abs() < 1e-6, "η {eta} k {k}: {got} vs {want}");
            // Grazing: everything is reflected.
            assert!((fresnel_complex(0.0, eta, k) - 1.0).abs() < 1e-5 || eta == 1.0 && k == 0.0);
        }
        // With k = 0 it is the dielectric Fresnel term.
        for c in [0.05f32, 0.3, 0.7, 1.0] {
            let (d, _) = crate::bsdf::fresnel_dielectric(c, 1.5);
            let got = fresnel_complex(c, 1.5, 0.0);
            assert!((got - d).abs() < 1e-5, "cos {c}: {got} vs dielectric {d}");
        }
        // Index-matched: no interface.
        assert!(fresnel_complex(0.4, 1.0, 0.0).abs() < 1e-7);
    }

    #[test]
    fn named_metals_have_their_published_colours() {
        // Normal-incidence reflectance, the "F0" of real-time tables (gold about (1.0, 0.78,
        // 0.34), silver about (0.97, 0.96, 0.91) in linear sRGB, aluminium about 0.91).
        let f0 = |name: &str| {
            let (eta, k) = metal(name).expect("known");
            Fresnel::Complex { eta, k }.eval(1.0)
        };
        let gold = f0("gold");
        assert!(
            gold.x > 0.9 && (gold.y - 0.78).abs() < 0.05 && (gold.z - 0.37).abs() < 0.06,
            "{gold}"
        );
        let silver = f0("silver");
        assert!(silver.min_element() > 0.85, "{silver}");
        let al = f0("aluminum");
        assert!(al.min_element() > 0.85 && al.max_element() < 0.95, "{al}");
        assert!(metal("unobtainium").is_none());
    }

    #[test]
    fn schlick_meets_f0_and_one_at_grazing() {
        let f = Fresnel::Schlick(Vec3A::new(0.9, 0.5, 0.1));
        assert_eq!(f.eval(1.0), Vec3A::new(0.9, 0.5, 0.1));
        assert_eq!(f.eval(0.0), Vec3A::ONE);
    }
}
