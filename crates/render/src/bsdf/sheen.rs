//! glTF's sheen (`KHR_materials_sheen`, Blender's Sheen as its exporter writes it): the
//! back-scattering of fine fibres over a base, as the extension defines it. With c the sheen
//! colour and α = r² (r its roughness),
//!
//! f_sheen(o, i) = c D(h) V(o, i),  D(h) = (2 + 1/α) sin(θh)^(1/α) / (2π)  (Estevez and Kulla
//! 2017, "Charlie"),  V = 1 / (4 (cos θi + cos θo − cos θi cos θo))  (Neubelt and Pettineo's
//! visibility, the extension's simpler one),
//!
//! over the base scaled by what the sheen takes, 1 − max(c) E(μo), with E(μ) the white lobe's
//! albedo (tabulated over r and μ, [`SheenAlbedo`]): a white material under a white sheen
//! keeps all its energy, E + (1 − E). The lobe is drawn from the cosine hemisphere.
//!
//! Cycles' Sheen is another model (Zeltner et al. 2022, "microfibre"): docs/blender.md says
//! how the two differ.

use std::sync::OnceLock;

use glam::{Vec2, Vec3A};

use super::albedo::{bilinear, grid_mu, MU_STEPS, ROUGHNESS_STEPS};
use crate::util::sampling::square_to_cosine_hemisphere;
use crate::util::tabulate::tabulate;

/// The smallest α: below it the lobe is a sliver at grazing half vectors that neither the
/// table nor a cosine draw resolves (glTF's sample viewer clamps the same way).
const MIN_ALPHA: f32 = 0.0049;

/// A sheen layer at one point.
#[derive(Clone, Copy, Debug)]
pub struct Sheen {
    color: Vec3A,
    roughness: f32,
    inv_alpha: f32,
    /// Looked up once here rather than at every evaluation.
    table: &'static SheenAlbedo,
}

impl Sheen {
    /// The sheen of `color` and perceptual `roughness`; `None` where the colour is black.
    pub fn new(color: Vec3A, roughness: f32) -> Option<Self> {
        if !(color.max_element() > 0.0) {
            return None;
        }
        let roughness = roughness.clamp(0.0, 1.0);
        Some(Self {
            color,
            roughness,
            inv_alpha: 1.0 / (roughness * roughness).max(MIN_ALPHA),
            table: SheenAlbedo::get(),
        })
    }

    /// f cos θi for `o` and `i` above the surface, in the shading frame.
    #[inline]
    pub fn eval(&self, o: Vec3A, i: Vec3A) -> Vec3A {
        self.color * white(self.inv_alpha, o, i)
    }

    /// max(c) E(μo): the share of the light from the view the sheen takes from the base.
    #[inline]
    pub fn albedo(&self, mu: f32) -> f32 {
        self.color.max_element().min(1.0) * self.table.e(self.roughness, mu)
    }
}

/// The white lobe's D V cos θi.
#[inline]
fn white(inv_alpha: f32, o: Vec3A, i: Vec3A) -> f32 {
    if !(o.z > 0.0 && i.z > 0.0) {
        return 0.0;
    }
    let Some(h) = (o + i).try_normalize() else {
        return 0.0;
    };
    let sin2 = (1.0 - h.z * h.z).max(0.0);
    let d = (2.0 + inv_alpha) * sin2.powf(0.5 * inv_alpha) * (0.5 * std::f32::consts::FRAC_1_PI);
    let v = 1.0 / (4.0 * (i.z + o.z - i.z * o.z));
    d * v * i.z
}

/// The white sheen lobe's albedo E(μ) over roughness and μ, built once per process.
#[derive(Debug)]
pub struct SheenAlbedo {
    e: Vec<f32>,
}

impl SheenAlbedo {
    /// The table, built at its first use.
    pub fn get() -> &'static Self {
        static TABLE: OnceLock<SheenAlbedo> = OnceLock::new();
        TABLE.get_or_init(|| Self {
            e: tabulate(ROUGHNESS_STEPS * MU_STEPS, |n| {
                let (j, k) = (n / MU_STEPS, n % MU_STEPS);
                let x = j as f32 / (ROUGHNESS_STEPS - 1) as f32;
                let r = x * x;
                let inv_alpha = 1.0 / (r * r).max(MIN_ALPHA);
                lobe_albedo(inv_alpha, grid_mu(k)).min(1.0)
            }),
        })
    }

    /// E(μ) at roughness `r`.
    #[inline]
    pub fn e(&self, r: f32, mu: f32) -> f32 {
        bilinear(&self.e, r, mu)
    }
}

/// ∫ D V cos θi dωi by a midpoint rule over the cosine hemisphere (π times the mean of
/// D V over cosine-distributed directions).
fn lobe_albedo(inv_alpha: f32, mu: f32) -> f32 {
    const N: usize = 160;
    let mu = mu.max(1e-4);
    let o = Vec3A::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let mut sum = 0.0f64;
    for a in 0..N {
        for b in 0..N {
            let u = Vec2::new((a as f32 + 0.5) / N as f32, (b as f32 + 0.5) / N as f32);
            let i = square_to_cosine_hemisphere(u);
            if i.z > 0.0 {
                sum += f64::from(white(inv_alpha, o, i) / i.z);
            }
        }
    }
    (std::f64::consts::PI * sum / (N * N) as f64) as f32
}
