//! The directional-albedo tables the `pbr` material ([`super::pbr`]) is compensated by: GGX's
//! albedo for a white Fresnel, E₁(μ), and its average Ē₁ (one table for every material), and
//! each coat index's single-bounce albedo E_ss(μ) with the share F_ms of the missing energy
//! given back. Tabulated over roughness and incidence, since roughness may come from a texture,
//! and interpolated; built once per process in basic arithmetic in a fixed order, so every
//! worker builds the same ones.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, OnceLock};

use glam::{Vec2, Vec3A};

use super::fresnel_dielectric;
use super::microfacet::{reflect_about, TrowbridgeReitz, SMOOTH_ALPHA};
use crate::util::tabulate::tabulate;

/// Roughness steps of the tables ([`grid_distribution`]).
pub(super) const ROUGHNESS_STEPS: usize = 33;
/// Incidence steps of the tables, even in √μ (cos θ = (k / (MU_STEPS − 1))²): the albedos
/// change fastest towards grazing, where an even grid in μ left a white rough metal 1% short at
/// 89°.
pub(super) const MU_STEPS: usize = 32;
/// Midpoints in μ for an average over the hemisphere.
const AVERAGE_STEPS: usize = 8192;

/// (row, weight) for roughness `r` ∈ [0, 1]: rows `row` and `row + 1` blend by `weight`
/// ([`grid_distribution`]'s rows, even in √roughness).
#[inline]
fn row(r: f32) -> (usize, f32) {
    let x = r.clamp(0.0, 1.0).sqrt() * (ROUGHNESS_STEPS - 1) as f32;
    let j = (x as usize).min(ROUGHNESS_STEPS - 2);
    (j, x - j as f32)
}

/// A table over (roughness, μ), row-major in roughness, at roughness `r` and μ `mu`, by
/// bilinear interpolation.
#[inline]
pub(super) fn bilinear(table: &[f32], r: f32, mu: f32) -> f32 {
    let (j, wr) = row(r);
    let at = |j: usize| in_row(&table[j * MU_STEPS..(j + 1) * MU_STEPS], mu);
    at(j) * (1.0 - wr) + at(j + 1) * wr
}

/// One row of a table at μ `mu`, by linear interpolation in √μ.
#[inline]
fn in_row(row: &[f32], mu: f32) -> f32 {
    let x = mu.clamp(0.0, 1.0).sqrt() * (MU_STEPS - 1) as f32;
    let k = (x as usize).min(MU_STEPS - 2);
    let wm = x - k as f32;
    row[k] * (1.0 - wm) + row[k + 1] * wm
}

/// The distribution of the tables' row `j`: roughness (j / (ROUGHNESS_STEPS − 1))², even in
/// √roughness, as the albedos change fastest at low roughness (at grazing views, where the
/// lobe's width meets the view's height: an even grid in roughness left a surface of roughness
/// 0.05 reflecting 1.4% more than arrives at 89°). A smooth surface never reads the tables, so
/// no row is smooth: the first rows are the roughest a mirror is not ([`SMOOTH_ALPHA`]).
fn grid_distribution(j: usize) -> TrowbridgeReitz {
    let x = j as f32 / (ROUGHNESS_STEPS - 1) as f32;
    let r = x * x;
    TrowbridgeReitz::new((r * r).max(SMOOTH_ALPHA))
}

/// The μ of the tables' column `k`.
#[inline]
pub(super) fn grid_mu(k: usize) -> f32 {
    let x = k as f32 / (MU_STEPS - 1) as f32;
    x * x
}

/// A per-roughness value at roughness `r`, interpolated as [`bilinear`] does.
#[inline]
fn linear(values: &[f32; ROUGHNESS_STEPS], r: f32) -> f32 {
    let (j, w) = row(r);
    values[j] * (1.0 - w) + values[j + 1] * w
}

/// 2∫ g(μ) μ dμ by midpoints.
fn cosine_average(g: impl Fn(f32) -> f32) -> f32 {
    let mut sum = 0.0f64;
    for k in 0..AVERAGE_STEPS {
        let mu = (k as f32 + 0.5) / AVERAGE_STEPS as f32;
        sum += f64::from(g(mu) * mu);
    }
    (2.0 * sum / AVERAGE_STEPS as f64) as f32
}

/// ∫ F(o·m) G(o, i)/G1(o) over the normals visible at cos θo = `mu` (a reflection below the
/// surface counts nothing). The midpoint rule of the visible-normal sampler's square, its
/// radial coordinate u = 1 − (1 − s)⁴ (weight 4(1 − s)³) so that the points crowd the edge of
/// the projected disk: the steep micro-normals there are the ones that reflect below the
/// surface, and an even rule of 24 steps missed them (a white metal of roughness 0.25 at
/// 0.99992 head-on where it is 0.9962). Basic arithmetic in a fixed order, so every worker
/// builds the same tables.
fn lobe_albedo(d: &TrowbridgeReitz, mu: f32, fresnel: impl Fn(f32) -> f32) -> f32 {
    const RADIAL: usize = 48;
    const AROUND: usize = 24;
    let mu = mu.max(1e-6);
    let o = Vec3A::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let g1 = d.g1(o);
    let mut sum = 0.0f64;
    for a in 0..RADIAL {
        let s = (a as f32 + 0.5) / RADIAL as f32;
        let t = 1.0 - s;
        let (u, weight) = (1.0 - t * t * t * t, 4.0 * t * t * t);
        let mut ring = 0.0f64;
        for b in 0..AROUND {
            let m = d.sample_visible(o, Vec2::new(u, (b as f32 + 0.5) / AROUND as f32));
            let i = reflect_about(o, m);
            if i.z > 0.0 {
                ring += f64::from(fresnel(o.dot(m).max(0.0)) * d.g(o, i) / g1);
            }
        }
        sum += ring * f64::from(weight);
    }
    (sum / (RADIAL * AROUND) as f64) as f32
}

/// GGX's single-scattering albedo for a white Fresnel, E₁(μ), over roughness and incidence,
/// and its cosine-weighted average Ē₁ per roughness: what the compensation gives back. One table for every material, built once per process in basic arithmetic.
#[derive(Debug)]
pub struct GgxAlbedo {
    /// E₁ at roughness j and μ k.
    e: Vec<f32>,
    /// Ē₁ of each roughness row, as the row interpolates.
    average: [f32; ROUGHNESS_STEPS],
}

impl GgxAlbedo {
    /// The table, built at its first use.
    pub fn get() -> &'static Self {
        static TABLE: OnceLock<GgxAlbedo> = OnceLock::new();
        TABLE.get_or_init(|| {
            let e = tabulate(ROUGHNESS_STEPS * MU_STEPS, |n| {
                let (j, k) = (n / MU_STEPS, n % MU_STEPS);
                lobe_albedo(&grid_distribution(j), grid_mu(k), |_| 1.0).min(1.0)
            });
            let average = std::array::from_fn(|j| {
                cosine_average(|mu| in_row(&e[j * MU_STEPS..(j + 1) * MU_STEPS], mu))
            });
            Self { e, average }
        })
    }

    /// E₁(μ) at roughness `r`.
    #[inline]
    pub fn e(&self, r: f32, mu: f32) -> f32 {
        bilinear(&self.e, r, mu)
    }

    /// Ē₁ at roughness `r`.
    #[inline]
    pub fn average(&self, r: f32) -> f32 {
        linear(&self.average, r)
    }
}

/// A dielectric coat of one index, tabulated over roughness and incidence: its
/// single-scattering albedo E_ss(μ), and the share F_ms of its missing energy given back per
/// roughness (from its Fresnel average F̄ = 2∫F(μ) μ dμ).
#[derive(Debug, PartialEq)]
pub struct CoatTable {
    eta: f32,
    /// E_ss at roughness j and μ k, row-major in roughness.
    single: Vec<f32>,
    /// F_ms at each roughness.
    multiple: [f32; ROUGHNESS_STEPS],
}

impl CoatTable {
    /// The table for a coat of index `eta` (inside over outside), built by a fixed midpoint
    /// rule in basic arithmetic, so every worker builds the same one.
    pub fn new(eta: f32) -> Self {
        let single = tabulate(ROUGHNESS_STEPS * MU_STEPS, |n| {
            let (j, k) = (n / MU_STEPS, n % MU_STEPS);
            lobe_albedo(&grid_distribution(j), grid_mu(k), |c| {
                fresnel_dielectric(c, eta).0
            })
        });
        let fresnel_average = cosine_average(|mu| fresnel_dielectric(mu, eta).0);
        let ggx = GgxAlbedo::get();
        let multiple = std::array::from_fn(|j| multiple_colour(fresnel_average, ggx.average[j]));
        Self {
            eta,
            single,
            multiple,
        }
    }

    /// The table for `eta`, built once per process and index and shared.
    pub fn shared(eta: f32) -> Arc<Self> {
        static TABLES: OnceLock<Mutex<BTreeMap<u32, Arc<CoatTable>>>> = OnceLock::new();
        let tables = TABLES.get_or_init(Default::default);
        let mut tables = tables.lock().unwrap_or_else(|e| e.into_inner());
        tables
            .entry(eta.to_bits())
            .or_insert_with(|| Arc::new(Self::new(eta)))
            .clone()
    }

    /// E_ss(μ) at roughness `r`: for a smooth coat, F(μ) exactly.
    #[inline]
    pub fn single(&self, r: f32, smooth: bool, mu: f32) -> f32 {
        if smooth {
            return fresnel_dielectric(mu.clamp(0.0, 1.0), self.eta).0;
        }
        bilinear(&self.single, r, mu)
    }

    /// The coat's index of refraction (inside over outside).
    #[inline]
    pub fn eta(&self) -> f32 {
        self.eta
    }

    /// F_ms at roughness `r`.
    #[inline]
    pub fn multiple(&self, r: f32) -> f32 {
        linear(&self.multiple, r)
    }
}

/// The share of a lobe's missing energy given back, for a Fresnel average `f` and a white
/// lobe's average albedo `e`: F̄ Ē / (1 − F̄ (1 − Ē)) (Kulla and Conty's F̄² Ē / (1 − F̄ (1 −
/// Ē)) over the one F̄ the single bounce already holds, as Cycles has it).
#[inline]
pub(super) fn multiple_colour(f: f32, e: f32) -> f32 {
    let d = 1.0 - f * (1.0 - e);
    if d > 0.0 {
        f * e / d
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_matches_a_smooth_coat_and_a_plastics_table() {
        let table = CoatTable::new(1.5);
        for mu in [0.1f32, 0.5, 1.0] {
            let want = fresnel_dielectric(mu, 1.5).0;
            assert!((table.single(0.0, false, mu) - want).abs() < 3e-3, "{mu}");
            assert_eq!(table.single(0.3, true, mu), want);
        }
        // At a grid roughness the entry is the plastic's own integral, at a coarser rule.
        let plastic = super::super::Plastic::new(Vec3A::ONE, 0.5, 1.5);
        for mu in [0.2f32, 0.6, 1.0] {
            let (a, b) = (
                1.0 - table.single(0.5, false, mu),
                plastic.transmittance(mu),
            );
            assert!((a - b).abs() < 5e-3, "μ {mu}: {a} vs {b}");
        }
        // An index of one is no coat: nothing reflects, and nothing scatters twice.
        let none = CoatTable::new(1.0);
        assert!(none.single(0.7, false, 0.3).abs() < 1e-6);
        assert!(none.multiple(0.7).abs() < 1e-6);
    }

    /// E₁ is one for a mirror and falls with roughness: at roughness 1 (α = 1, D cos θm
    /// uniform over the projected disc) half the normals seen head-on lean past 45° and
    /// reflect below the surface, so E₁ < ½ there. Ē₁ is the table's own average.
    #[test]
    fn the_white_albedo_falls_with_roughness_and_its_average_is_the_tables() {
        let g = GgxAlbedo::get();
        assert!(g.e(0.0, 0.5) > 0.999 && g.e(0.0, 0.5) <= 1.0);
        assert!(g.e(1.0, 1.0) < g.e(0.5, 1.0) && g.e(0.5, 1.0) < 1.0);
        assert!(g.e(1.0, 1.0) < 0.5, "{}", g.e(1.0, 1.0));
        for r in [0.3f32, 0.55, 1.0] {
            let avg = cosine_average(|mu| g.e(r, mu));
            assert!(
                (avg - g.average(r)).abs() < 1e-4,
                "r {r}: {avg} vs {}",
                g.average(r)
            );
        }
    }
}
