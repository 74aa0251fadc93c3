//! Environment maps: light from infinitely far away read from an equirectangular (latitude–
//! longitude) HDR image, and importance sampling of it.
//!
//! **Parameterisation** (Mitsuba 3's `envmap`, so that its renders are a reference for ours):
//! in the map's own frame, +y is up and a unit direction d has u = atan2(dₓ, −d_z)/2π (wrapped
//! to [0, 1)) and v = θ/π with θ its angle from +y. Column i's texels sit at u = (i + ½)/W and
//! the last column wraps to the first; row j's texels sit at θ = πj/(H − 1), so the first row is
//! the zenith and the last the nadir. Radiance between texels is bilinear. The scene's `rotate`
//! turns the map about +y.
//!
//! **Sampling.** The texels' centres cut the sphere into W × (H − 1) cells, each a band of
//! latitude [θ_j, θ_{j+1}] by a slice of longitude 2π/W. Radiance over a cell is the bilinear
//! blend of its four corner texels. Each texel is weighted by its luminance less the map's
//! mean over the sphere, where that is positive (MIS compensation: `compensated_luminance`),
//! and a cell's weight ℓ is the mean of its corners' weights, the compensated blend's mean
//! over the cell. A cell is chosen with probability proportional to ℓ · Ω (its solid angle Ω =
//! (2π/W)(cos θ_j − cos θ_{j+1})), a row by the marginal (inverting its cdf) and then a column
//! by that row's conditional (inverting its cdf too, or, on a full-size map, from an alias
//! table in constant time: [`ALIAS_MIN_WIDTH`]), and the direction is uniform in solid angle
//! inside it (longitude uniform, cos θ uniform). The density is then constant over a cell, p =
//! P(cell)/Ω — no 1/sin θ, so no singularity at the poles — and it is positive wherever the
//! radiance stands above the map's mean. Where it is 0 (the dim, broad part of a sky), light
//! sampling cannot draw the direction and BSDF sampling covers it alone: the integrator's MIS
//! weights give it the whole there, and `--strategy nee` counts an escaping ray there in full
//! (the one place it counts one). Every number the
//! sampler and the density use comes from basic f32 arithmetic and [`crate::util::math::atan2`]
//! (no libm), so every worker gets the same bits.
//!
//! **Cost.** A path that escapes needs the radiance and, under MIS, the density along one
//! direction, and a light sample needs a direction with both: each is one lookup of the cell
//! ([`EnvMap::radiance_pdf`], [`EnvMap::sample`]), the density of every cell is a table, and a
//! sample knows its own cell, so it finds its radiance with one arctangent rather than the two
//! of mapping its direction back (docs/benchmarks/envmap-cost.md).

use std::f32::consts::PI;

use glam::{Vec2, Vec3A, Vec4};

use crate::util::distribution::{alias_bin, push_alias_entries, AliasEntry, Distribution1D};
use crate::util::math::{atan2, luminance};
use crate::util::sampling::sin_cos_turn;

mod lanes;

/// An equirectangular environment map, ready to evaluate and sample.
#[derive(Clone, Debug)]
pub struct EnvMap {
    width: usize,
    height: usize,
    /// Radiance (the image times the scene's intensity) in x, y, z, row-major, row 0 at the
    /// zenith; in w the density in solid angle of the cell whose upper-left corner the texel
    /// is, P(row)·P(column | row)/Ω (0 in the last row and in rows with nothing above the
    /// map's mean). The density shares
    /// the texel's cache line (and the lane `Vec3A` leaves unused): a large map's lookup
    /// waits on memory once for both.
    texels: Vec<Vec4>,
    /// (sin, cos) of the rotation about +y that takes the map's frame to the world's.
    rotation: (f32, f32),
    /// cos θ_j of each row of texels.
    cos_rows: Vec<f32>,
    /// Rows of cells (H − 1), by their share of ℓ·Ω: by inversion, which keeps the sampler's
    /// stratification in latitude, where a sky changes most.
    rows: Distribution1D,
    /// Each row's cells by ℓ.
    columns: Columns,
    /// ∫ (R + G + B) dω over the sphere, for choosing between the map and other lights.
    power: f32,
}

/// Why a map cannot light a scene.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvMapError {
    /// Too small to interpolate.
    #[error("{0}×{1} texels: an environment map needs at least 2×2")]
    TooSmall(usize, usize),
    /// A texel that is not a radiance.
    #[error(
        "texel ({x}, {y}) is {what}: an environment map's texels must be finite and not negative"
    )]
    BadTexel {
        /// Column.
        x: usize,
        /// Row from the top.
        y: usize,
        /// NaN, infinite or negative.
        what: &'static str,
    },
    /// So bright that its integral overflows f32.
    #[error("its radiance (after `intensity`) is too large to integrate in f32")]
    TooBright,
    /// Nothing to light with.
    #[error("every texel is black (after `intensity`): the map would light nothing")]
    Black,
}

impl EnvMap {
    /// A map of `width` × `height` linear RGB texels (row 0 at the top), scaled by
    /// `intensity`, turned `rotate_turns` of a full turn about +y.
    pub fn new(
        width: usize,
        height: usize,
        texels: &[Vec3A],
        intensity: f32,
        rotate_turns: f32,
    ) -> Result<Self, EnvMapError> {
        if width < 2 || height < 2 || texels.len() != width * height {
            return Err(EnvMapError::TooSmall(width, height));
        }
        for (k, t) in texels.iter().enumerate() {
            let what = if t.is_nan() {
                "NaN"
            } else if !t.is_finite() {
                "infinite"
            } else if t.min_element() < 0.0 {
                "negative"
            } else {
                continue;
            };
            let (x, y) = (k % width, k / width);
            return Err(EnvMapError::BadTexel { x, y, what });
        }
        // The w lanes get the cells' densities once the distributions are built.
        let mut texels: Vec<Vec4> = texels
            .iter()
            .map(|t| (*t * intensity).extend(0.0))
            .collect();
        if texels.iter().any(|t| !t.is_finite()) {
            let k = texels.iter().position(|t| !t.is_finite()).unwrap_or(0);
            let (x, y) = (k % width, k / width);
            return Err(EnvMapError::BadTexel {
                x,
                y,
                what: "infinite",
            });
        }
        // cos(πj/(H − 1)) = cos 2π·(j / 2(H − 1)), by the libm-free sine.
        let cos_rows: Vec<f32> = (0..height)
            .map(|j| sin_cos_turn(j as f32 / (2 * (height - 1)) as f32).1)
            .collect();
        let lum = compensated_luminance(&texels, width, &cos_rows);
        let mut row_weights = Vec::with_capacity(height - 1);
        let alias = width >= ALIAS_MIN_WIDTH;
        // A wide map's entries go straight into the cells (their densities once the rows'
        // distribution is known) through one row's scratch: no second table of the map's size.
        let (mut inverted, mut entries, mut row) = (Vec::new(), Vec::new(), Vec::new());
        if alias {
            entries.reserve_exact((height - 1) * width);
        }
        let mut power = 0.0f64;
        let mut cell = vec![0.0f32; width];
        for j in 0..height - 1 {
            let band = (cos_rows[j] - cos_rows[j + 1]).max(0.0);
            let (top, bottom) = (j * width, (j + 1) * width);
            let mut row_sum = 0.0f64;
            cell_weights(&lum, j, &mut cell);
            for (i, c) in cell.iter().enumerate() {
                let i1 = (i + 1) % width;
                row_sum += f64::from(*c);
                let rgb =
                    texels[top + i] + texels[top + i1] + texels[bottom + i] + texels[bottom + i1];
                power += 0.25 * f64::from(rgb.x + rgb.y + rgb.z) * f64::from(band);
            }
            row_weights.push((row_sum * f64::from(band)) as f32);
            if !alias {
                inverted.push(Distribution1D::new(&cell));
            } else {
                row.clear();
                if !push_alias_entries(&cell, &mut row) {
                    row.resize(width, AliasEntry::default());
                }
                entries.extend(row.iter().map(|&alias| CellEntry {
                    alias,
                    pdf: [0.0; 2],
                }));
            }
        }
        let power = (power * 2.0 * std::f64::consts::PI / width as f64) as f32;
        if !power.is_finite() || row_weights.iter().any(|w| !w.is_finite()) {
            return Err(EnvMapError::TooBright);
        }
        let rows = Distribution1D::new(&row_weights).ok_or(EnvMapError::Black)?;
        set_cell_densities(&mut texels, &rows, &lum, &cos_rows, width);
        drop(lum);
        let columns = if alias {
            for (k, e) in entries.iter_mut().enumerate() {
                e.pdf = [texels[k].w, texels[k - k % width + e.alias.alias()].w];
            }
            Columns::Alias(entries)
        } else {
            Columns::Inverted(inverted)
        };
        let (s, c) = sin_cos_turn(rotate_turns.rem_euclid(1.0));
        Ok(Self {
            width,
            height,
            texels,
            rotation: (s, c),
            cos_rows,
            rows,
            columns,
            power,
        })
    }

    /// Size in texels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// ∫ (R + G + B) dω over the sphere.
    pub fn power(&self) -> f32 {
        self.power
    }

    fn to_local(&self, d: Vec3A) -> Vec3A {
        let (s, c) = self.rotation;
        Vec3A::new(c * d.x - s * d.z, d.y, s * d.x + c * d.z)
    }

    fn to_world(&self, d: Vec3A) -> Vec3A {
        let (s, c) = self.rotation;
        Vec3A::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z)
    }

    /// (u, v) of a local direction: u ∈ [0, 1), v ∈ [0, 1].
    fn uv(d: Vec3A) -> Vec2 {
        let u = atan2(d.x, -d.z) * (0.5 / PI);
        let u = if u < 0.0 { u + 1.0 } else { u };
        let v = atan2((d.x * d.x + d.z * d.z).sqrt(), d.y) * (1.0 / PI);
        Vec2::new(u.min(1.0 - f32::EPSILON / 2.0), v.clamp(0.0, 1.0))
    }

    /// Column i (left texel of the cell or blend) and fraction towards i + 1 at `u`.
    fn column(&self, u: f32) -> (usize, f32) {
        let x = u * self.width as f32 - 0.5;
        let x = if x < 0.0 { x + self.width as f32 } else { x };
        let i = (x as usize).min(self.width - 1);
        (i, (x - i as f32).clamp(0.0, 1.0))
    }

    /// Row j (upper texel of the cell or blend, at most H − 2) and fraction towards j + 1.
    fn row(&self, v: f32) -> (usize, f32) {
        let y = v * (self.height - 1) as f32;
        let j = (y as usize).min(self.height - 2);
        (j, (y - j as f32).clamp(0.0, 1.0))
    }

    /// Where local direction `d` falls: its cell and the blend's fractions across it.
    #[inline]
    fn locate(&self, d: Vec3A) -> Blend {
        self.locate_uv(Self::uv(d))
    }

    /// The cell and fractions at (u, v) ([`EnvMap::uv`]).
    #[inline]
    fn locate_uv(&self, uv: Vec2) -> Blend {
        let (i, fx) = self.column(uv.x);
        let (j, fy) = self.row(uv.y);
        Blend { i, j, fx, fy }
    }

    /// The bilinear blend of cell (i, j)'s corner texels at fractions (fx, fy).
    #[inline]
    fn blend(&self, b: &Blend) -> Vec3A {
        let i1 = if b.i + 1 == self.width { 0 } else { b.i + 1 };
        let (top, bottom) = (b.j * self.width, (b.j + 1) * self.width);
        let t = |k: usize| Vec3A::from_vec4(self.texels[k]);
        let upper = t(top + b.i) * (1.0 - b.fx) + t(top + i1) * b.fx;
        let lower = t(bottom + b.i) * (1.0 - b.fx) + t(bottom + i1) * b.fx;
        upper * (1.0 - b.fy) + lower * b.fy
    }

    /// Density in solid angle of any direction in cell (i, j).
    #[inline]
    fn density(&self, b: &Blend) -> f32 {
        self.texels[b.j * self.width + b.i].w
    }

    /// Radiance arriving from direction `d` (world space, unit): along a ray with direction
    /// `d` that escapes the scene.
    pub fn radiance(&self, d: Vec3A) -> Vec3A {
        self.blend(&self.locate(self.to_local(d)))
    }

    /// [`EnvMap::radiance`] and [`EnvMap::pdf`] of `d` together, from one lookup: what a
    /// BSDF-sampled ray that escapes needs under MIS.
    pub fn radiance_pdf(&self, d: Vec3A) -> (Vec3A, f32) {
        let b = self.locate(self.to_local(d));
        (self.blend(&b), self.density(&b))
    }

    /// A direction from two uniform numbers, with its density in solid angle and the
    /// radiance arriving along it; `None` where the density is not positive and finite (a
    /// cell too thin to hold one in f32).
    pub fn sample(&self, u: Vec2) -> Option<EnvSample> {
        let d = self.sample_direction(u)?;
        Some(EnvSample {
            wi: d.wi,
            pdf: d.pdf,
            radiance: self.radiance_at(&d.point),
        })
    }

    /// [`EnvMap::sample`] without the radiance, which [`EnvMap::radiance_at`] gives for the
    /// draw's point when it is wanted: a light sample behind the surface or in shadow never
    /// reads the texels, which on a full-size map are a wait on memory each.
    #[inline]
    pub fn sample_direction(&self, u: Vec2) -> Option<EnvDraw> {
        let cell = self.draw_cell(u)?;
        let (phi, c0, c1) = self.cell_angles(&cell);
        let cos = (c0 + cell.uy * (c1 - c0)).clamp(-1.0, 1.0);
        let sin = ((1.0 - cos) * (1.0 + cos)).max(0.0).sqrt();
        let (sin_phi, cos_phi) = sin_cos_turn(phi);
        let local = Vec3A::new(sin_phi * sin, cos, -cos_phi * sin);
        Some(EnvDraw {
            wi: self.to_world(local),
            pdf: cell.pdf,
            point: MapPoint {
                i: cell.i,
                j: cell.j,
                fx: cell.ux,
                sin,
                cos,
            },
        })
    }

    /// The cell a light sample's numbers `u` draw, with the numbers' places across and down
    /// it and its density; `None` where the density is not positive and finite.
    #[inline(always)]
    fn draw_cell(&self, u: Vec2) -> Option<Cell> {
        let (j, uy) = self.rows.sample_remap(u.y);
        let (i, ux, pdf) = match &self.columns {
            Columns::Inverted(rows) => {
                let (i, ux) = rows.get(j)?.as_ref()?.sample_remap(u.x);
                (i, ux, self.texels[j * self.width + i].w)
            }
            Columns::Alias(cells) => {
                let (bin, f) = alias_bin(self.width, u.x);
                let entry = cells.get(j * self.width + bin)?;
                let (i, ux, kept) = entry.alias.pick(bin, f);
                (i, ux, if kept { entry.pdf[0] } else { entry.pdf[1] })
            }
        };
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        Some(Cell {
            i: i as u32,
            j: j as u32,
            ux,
            uy,
            pdf,
        })
    }

    /// A drawn cell's longitude (in turns, at the draw's place across it) and the cosines of
    /// its upper and lower rows' angles from the zenith.
    #[inline(always)]
    fn cell_angles(&self, cell: &Cell) -> (f32, f32, f32) {
        // Column i's cell spans texel centres i and i + 1: u = (i + ½ + ux)/W, so the blend
        // across it is ux itself.
        let mut phi = (cell.i as f32 + 0.5 + cell.ux) / self.width as f32;
        if phi >= 1.0 {
            phi -= 1.0;
        }
        let j = cell.j as usize;
        (phi, self.cos_rows[j], self.cos_rows[j + 1])
    }

    /// The radiance arriving along a draw of [`EnvMap::sample_direction`] (`point` is its own).
    /// Out of line: a light sample's radiance is read at every material's next-event site, and
    /// inlined into each it crowded the instruction cache (docs/benchmarks/envmap-alias-2026-11-30.md).
    #[inline(never)]
    pub fn radiance_at(&self, point: &MapPoint) -> Vec3A {
        // Down the cell the blend is linear in θ (rows sit at θ = πj/(H − 1)), which the
        // uniform cos θ does not give: one arctangent finds it.
        let y = atan2(point.sin, point.cos) * self.rows_per_radian();
        self.blend_down(point.i, point.j, point.fx, y)
    }

    /// (H − 1)/π: rows of texels per radian from the zenith.
    #[inline(always)]
    fn rows_per_radian(&self) -> f32 {
        (self.height - 1) as f32 / PI
    }

    /// The blend in cell (i, j) at fraction `fx` across it and `y` rows down the map.
    #[inline(always)]
    fn blend_down(&self, i: u32, j: u32, fx: f32, y: f32) -> Vec3A {
        let fy = (y - j as f32).clamp(0.0, 1.0);
        self.blend(&Blend {
            i: i as usize,
            j: j as usize,
            fx,
            fy,
        })
    }

    /// The density in solid angle with which [`EnvMap::sample`] draws direction `d`.
    pub fn pdf(&self, d: Vec3A) -> f32 {
        // The cell's corners are the texels at or before the direction in each axis.
        self.density(&self.locate(self.to_local(d)))
    }
}

/// A direction drawn from a map ([`EnvMap::sample`]).
#[derive(Clone, Copy, Debug)]
pub struct EnvSample {
    /// The direction towards the map (world space, unit).
    pub wi: Vec3A,
    /// Its density in solid angle.
    pub pdf: f32,
    /// The radiance arriving along it.
    pub radiance: Vec3A,
}

/// A direction drawn from a map without its radiance ([`EnvMap::sample_direction`]).
#[derive(Clone, Copy, Debug)]
pub struct EnvDraw {
    /// The direction towards the map (world space, unit).
    pub wi: Vec3A,
    /// Its density in solid angle.
    pub pdf: f32,
    /// Where on the map it is, for [`EnvMap::radiance_at`].
    pub point: MapPoint,
}

/// Where a draw landed on its map: its cell, the blend's fraction across it, and the sine and
/// cosine of its angle from the zenith, from which the fraction down the cell follows.
#[derive(Clone, Copy, Debug)]
pub struct MapPoint {
    i: u32,
    j: u32,
    fx: f32,
    sin: f32,
    cos: f32,
}

/// Maps at least this wide draw a row's column from an alias table; narrower ones invert the
/// row's cdf. A narrow row's search stays in cache and is cheap, and inversion keeps the
/// sampler's stratification in longitude (nearby numbers, nearby directions), which the alias
/// table gives up: on the bundled 64 × 32 sky the alias table measured a few percent more
/// error per sample and no faster. A full-size map's row (1K texels and up) is a walk through
/// memory to search, where the alias table reads one entry
/// (docs/benchmarks/envmap-alias-2026-11-30.md).
const ALIAS_MIN_WIDTH: usize = 512;

/// How a row's column is drawn ([`ALIAS_MIN_WIDTH`]).
#[derive(Clone, Debug)]
enum Columns {
    /// Each row's cdf (`None` for a row that is black throughout).
    Inverted(Vec<Option<Distribution1D>>),
    /// W alias entries a row (a black row's never read), each with the densities of the two
    /// cells it can give: a light sample reads one entry, and no texel until its radiance is
    /// wanted.
    Alias(Vec<CellEntry>),
}

/// A cell's alias entry in its row's table, with the densities of the cell itself and of its
/// alias: all a draw's density needs, in one read.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(16))]
struct CellEntry {
    alias: AliasEntry,
    pdf: [f32; 2],
}

/// A cell a light sample drew: (i, j), the sample's places across (`ux`) and down (`uy`, in
/// cos θ) it in [0, 1), and the cell's density in solid angle.
#[derive(Clone, Copy, Debug)]
struct Cell {
    i: u32,
    j: u32,
    ux: f32,
    uy: f32,
    pdf: f32,
}

/// A place on the map: cell (i, j) (its upper-left texel) and the fractions towards texels
/// i + 1 and j + 1.
#[derive(Clone, Copy)]
struct Blend {
    i: usize,
    j: usize,
    fx: f32,
    fy: f32,
}

/// The luminance a light sample draws texels by: each texel's less the map's mean over the
/// sphere, where positive, and 0 elsewhere (MIS compensation: Karlík et al. 2019, as pbrt-v4's
/// image light draws samples for the path tracer). Under MIS light samples are combined with
/// BSDF samples, which already find the broad, dim part of a sky well, so the light's samples
/// are spent on what stands out; a direction no light sample can draw (density 0) is then left
/// to BSDF sampling alone, whose MIS weight there is 1 (and which `--strategy nee` counts
/// there). A map with nothing above its mean (a uniform one) keeps plain luminance.
fn compensated_luminance(texels: &[Vec4], width: usize, cos_rows: &[f32]) -> Vec<f32> {
    let mut lum: Vec<f32> = texels
        .iter()
        .map(|t| luminance(Vec3A::from_vec4(*t)).max(0.0))
        .collect();
    // The mean of the blend over the sphere: each cell's mean luminance by its solid angle.
    let mut cell = vec![0.0f32; width];
    let mut integral = 0.0f64;
    for j in 0..cos_rows.len() - 1 {
        cell_weights(&lum, j, &mut cell);
        let band = f64::from((cos_rows[j] - cos_rows[j + 1]).max(0.0));
        integral += cell.iter().map(|&c| f64::from(c)).sum::<f64>() * band;
    }
    let mean = (integral / (2.0 * width as f64)) as f32;
    // In place: a full-size map's luminance is tens of megabytes, not worth a second copy.
    if lum.iter().any(|&l| l - mean > 0.0) {
        for l in &mut lum {
            *l = (*l - mean).max(0.0);
        }
    }
    lum
}

/// Row `j`'s cell weights ℓ (the mean weight of each cell's four corners) into `cell`, from
/// the texels' weights `lum`: computed again where needed rather than kept, a table the size
/// of the map.
fn cell_weights(lum: &[f32], j: usize, cell: &mut [f32]) {
    let width = cell.len();
    let (top, bottom) = (j * width, (j + 1) * width);
    for (i, c) in cell.iter_mut().enumerate() {
        let i1 = (i + 1) % width;
        *c = 0.25 * (lum[top + i] + lum[top + i1] + lum[bottom + i] + lum[bottom + i1]);
    }
}

/// Each cell's density in solid angle, P(row)·P(column | row)/Ω (0 in a black row), into the
/// w lane of its upper-left texel, from the texels' luminances `lum`. P(column | row) is the
/// cell's share of its row's sum in f64, rounded once.
fn set_cell_densities(
    texels: &mut [Vec4],
    rows: &Distribution1D,
    lum: &[f32],
    cos_rows: &[f32],
    width: usize,
) {
    let mut c = vec![0.0f32; width];
    for (j, row) in texels.chunks_exact_mut(width).take(rows.len()).enumerate() {
        cell_weights(lum, j, &mut c);
        let omega = (cos_rows[j] - cos_rows[j + 1]) * (2.0 * PI / width as f32);
        let total: f64 = c.iter().map(|&w| f64::from(w.max(0.0))).sum();
        for (&w, t) in c.iter().zip(row) {
            t.w = if total > 0.0 {
                let pmf = (f64::from(w.max(0.0)) / total) as f32;
                rows.pmf(j) * pmf / omega
            } else {
                0.0
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::sampling::HashRng;

    fn map(width: usize, height: usize, f: impl Fn(usize, usize) -> Vec3A) -> Vec<Vec3A> {
        (0..width * height)
            .map(|k| f(k % width, k / width))
            .collect()
    }

    #[test]
    fn texel_centres_are_where_the_parameterisation_puts_them() {
        // One bright texel at column 3, row 2 of an 8 × 5 map: its centre is u = 3.5/8,
        // θ = π·2/4 (the horizon), i.e. φ = 2π·3.5/8, direction (sin φ, 0, −cos φ).
        let t = map(8, 5, |x, y| {
            if (x, y) == (3, 2) {
                Vec3A::ONE
            } else {
                Vec3A::ZERO
            }
        });
        let m = EnvMap::new(8, 5, &t, 1.0, 0.0).expect("map");
        let phi = 2.0 * PI * 3.5 / 8.0;
        let d = Vec3A::new(phi.sin(), 0.0, -phi.cos());
        assert!((m.radiance(d) - Vec3A::ONE).abs().max_element() < 1e-5);
        // Halfway to the next column the blend is half.
        let phi = 2.0 * PI * 4.0 / 8.0;
        let d = Vec3A::new(phi.sin(), 0.0, -phi.cos());
        assert!((m.radiance(d) - Vec3A::splat(0.5)).abs().max_element() < 1e-5);
        // A quarter turn of `rotate` moves it a quarter of the way round, towards −x... from
        // the world's view: world = R·local.
        let r = EnvMap::new(8, 5, &t, 1.0, 0.25).expect("map");
        let phi = 2.0 * PI * 3.5 / 8.0;
        let local = Vec3A::new(phi.sin(), 0.0, -phi.cos());
        let world = Vec3A::new(local.z, 0.0, -local.x);
        assert!((r.radiance(world) - Vec3A::ONE).abs().max_element() < 1e-5);
        // The zenith row is the first, the nadir the last.
        let t = map(4, 3, |_, y| Vec3A::splat(y as f32 + 1.0));
        let m = EnvMap::new(4, 3, &t, 2.0, 0.0).expect("map");
        assert!(
            (m.radiance(Vec3A::Y) - Vec3A::splat(2.0))
                .abs()
                .max_element()
                < 1e-5
        );
        assert!(
            (m.radiance(-Vec3A::Y) - Vec3A::splat(6.0))
                .abs()
                .max_element()
                < 1e-5
        );
    }

    #[test]
    fn bad_maps_are_refused_by_texel() {
        let ok = map(4, 4, |_, _| Vec3A::ONE);
        let mut t = ok.clone();
        t[6] = Vec3A::new(f32::NAN, 0.0, 0.0);
        assert_eq!(
            EnvMap::new(4, 4, &t, 1.0, 0.0).expect_err("refused"),
            EnvMapError::BadTexel {
                x: 2,
                y: 1,
                what: "NaN"
            }
        );
        t[6] = Vec3A::new(0.0, -1.0, 0.0);
        assert!(EnvMap::new(4, 4, &t, 1.0, 0.0)
            .expect_err("refused")
            .to_string()
            .contains("texel (2, 1) is negative"));
        t[6] = Vec3A::splat(f32::INFINITY);
        assert!(matches!(
            EnvMap::new(4, 4, &t, 1.0, 0.0),
            Err(EnvMapError::BadTexel {
                what: "infinite",
                ..
            })
        ));
        let black = map(4, 4, |_, _| Vec3A::ZERO);
        assert_eq!(
            EnvMap::new(4, 4, &black, 1.0, 0.0).expect_err("refused"),
            EnvMapError::Black
        );
        assert_eq!(
            EnvMap::new(4, 4, &ok, 0.0, 0.0).expect_err("refused"),
            EnvMapError::Black
        );
        assert!(matches!(
            EnvMap::new(4, 4, &ok, f32::MAX, 0.0),
            Err(EnvMapError::TooBright)
        ));
        let huge = map(4, 4, |_, _| Vec3A::splat(3e38));
        assert!(matches!(
            EnvMap::new(4, 4, &huge, 2.0, 0.0),
            Err(EnvMapError::BadTexel {
                what: "infinite",
                ..
            })
        ));
        assert_eq!(
            EnvMap::new(1, 4, &ok[..4], 1.0, 0.0).expect_err("refused"),
            EnvMapError::TooSmall(1, 4)
        );
    }

    /// The sampler's own density agrees with `pdf` at the directions it draws (but for the
    /// few that land on a cell's edge, where rounding may put them in the neighbour), and the
    /// estimate mean(L/p) converges to ∫ L dω over the directions it can draw (p > 0), by
    /// quadrature: what compensation leaves to BSDF sampling is the rest of the integral.
    #[test]
    fn samples_carry_the_density_pdf_gives_and_integrate_the_radiance() {
        let t = map(16, 9, |x, y| {
            Vec3A::new(0.1 + x as f32 * 0.05, 0.2, 0.05 * y as f32)
                + if (x, y) == (5, 3) {
                    Vec3A::splat(500.0)
                } else {
                    Vec3A::ZERO
                }
        });
        let m = EnvMap::new(16, 9, &t, 1.0, 0.3).expect("map");
        let sum_rgb = |l: Vec3A| f64::from(l.x + l.y + l.z);
        // Midpoint quadrature in (φ, cos θ), which is uniform in solid angle.
        let k = 1500;
        let (mut want, mut drawable) = (0.0f64, 0.0f64);
        for a in 0..k {
            let cos = 1.0 - 2.0 * (a as f64 + 0.5) / k as f64;
            let sin = (1.0 - cos * cos).sqrt();
            for b in 0..2 * k {
                let phi = std::f64::consts::PI * (b as f64 + 0.5) / k as f64;
                let d = Vec3A::new(
                    (sin * phi.cos()) as f32,
                    cos as f32,
                    (sin * phi.sin()) as f32,
                );
                want += sum_rgb(m.radiance(d));
                if m.pdf(d) > 0.0 {
                    drawable += sum_rgb(m.radiance(d));
                }
            }
        }
        want *= 4.0 * std::f64::consts::PI / (2 * k * k) as f64;
        drawable *= 4.0 * std::f64::consts::PI / (2 * k * k) as f64;
        // The spike and its cells are drawable, the dim rest of the map mostly not.
        assert!(
            drawable > 0.5 * want && drawable < 0.98 * want,
            "{drawable} of {want}"
        );
        assert!(
            (want - f64::from(m.power())).abs() < 0.05 * want,
            "{want} vs {}",
            m.power()
        );
        let mut rng = HashRng::new(3);
        let n = 400_000;
        let (mut sum, mut off_edge) = (0.0f64, 0);
        let mut worst_radiance = 0.0f32;
        for _ in 0..n {
            let u = Vec2::new(rng.next_f32(), rng.next_f32());
            let EnvSample {
                wi: d,
                pdf,
                radiance,
            } = m.sample(u).expect("map");
            assert!((d.length() - 1.0).abs() < 1e-5);
            if (m.pdf(d) - pdf).abs() > 1e-3 * pdf {
                off_edge += 1;
            }
            // The sample's own radiance is the map's along its direction, but for rounding:
            // of the direction, which moves the blend by an ulp or so of the cell, so measured
            // against the cell's brightest corner (a wrong blend down the cell is off by a
            // share of the corners' difference).
            let by_direction = m.radiance(d);
            let b = m.locate(m.to_local(d));
            let corner = [
                (b.i, b.j),
                ((b.i + 1) % 16, b.j),
                (b.i, b.j + 1),
                ((b.i + 1) % 16, b.j + 1),
            ]
            .map(|(x, y)| Vec3A::from_vec4(m.texels[y * 16 + x]).max_element())
            .into_iter()
            .fold(0.0f32, f32::max);
            let err = (radiance - by_direction).abs().max_element() / corner;
            worst_radiance = worst_radiance.max(err);
            // One lookup gives what the two give.
            let (l, p) = m.radiance_pdf(d);
            assert_eq!((l, p.to_bits()), (by_direction, m.pdf(d).to_bits()));
            sum += sum_rgb(radiance) / f64::from(pdf);
        }
        assert!(
            worst_radiance < 1e-4,
            "sampled radiance off by {worst_radiance}"
        );
        assert!(
            off_edge < n / 10_000,
            "{off_edge} samples disagree with pdf"
        );
        let est = sum / n as f64;
        assert!(
            (est - drawable).abs() < 0.01 * drawable,
            "{est} vs {drawable}"
        );
    }

    /// Light samples go only to what stands above the map's mean: on a dim sky with one
    /// bright texel, the cells around the bright one are drawable and a dim cell is not; a
    /// uniform map (nothing above its mean) is drawn uniformly, 1/4π everywhere.
    #[test]
    fn light_samples_skip_what_lies_below_the_maps_mean() {
        let t = map(16, 9, |x, y| {
            Vec3A::splat(if (x, y) == (5, 3) { 100.0 } else { 0.5 })
        });
        let m = EnvMap::new(16, 9, &t, 1.0, 0.0).expect("map");
        let density = |i: usize, j: usize| m.texels[j * 16 + i].w;
        for (i, j) in [(4, 2), (5, 2), (4, 3), (5, 3)] {
            assert!(
                density(i, j) > 0.0,
                "cell ({i}, {j}) touches the bright texel"
            );
        }
        for (i, j) in [(0, 0), (12, 6), (7, 3), (5, 4)] {
            assert_eq!(density(i, j), 0.0, "cell ({i}, {j}) is all below the mean");
        }
        let u = EnvMap::new(16, 9, &map(16, 9, |_, _| Vec3A::ONE), 1.0, 0.0).expect("map");
        let want = 1.0 / (4.0 * PI);
        for d in [Vec3A::Y, Vec3A::X, Vec3A::new(0.0, -0.6, 0.8)] {
            assert!((u.pdf(d) - want).abs() < 1e-4 * want, "{}", u.pdf(d));
        }
    }
}
