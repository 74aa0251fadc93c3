//! The map for many paths at once ([`crate::wide`]): light samples drawn and rays that escape
//! looked up in SIMD lanes. The discrete steps (a light sample's row and column, a direction's
//! cell, the texels' blend) are each lane's own scalar code, reading its own cache lines; what
//! the lanes share is the trigonometry around them (a sample's sine and cosine, the two
//! arctangents of a direction's place on the map, the one of a sample's row), done by the same
//! operations as the scalar functions ([`atan2_lanes`], [`sin_cos_turn_lanes`]), so that every
//! lane gets [`EnvMap::sample_direction`]'s, [`EnvMap::radiance_at`]'s and
//! [`EnvMap::radiance_pdf`]'s bits.

use std::f32::consts::PI;

use glam::{Vec2, Vec3A};

use super::{Cell, EnvMap};
use crate::util::lanes::{v3, F, V3};
use crate::util::math::atan2_lanes;
use crate::util::sampling::sin_cos_turn_lanes;

/// Light samples of a map in lanes ([`EnvMap::sample_lanes`]).
pub(crate) struct MapDraws<const N: usize> {
    /// The directions (world space, unit).
    pub wi: V3<N>,
    /// Their densities in solid angle.
    pub pdf: F<N>,
    /// The lanes with a draw: the others' numbers are placeholders.
    pub drawn: u32,
    cell: [(u32, u32); N],
    fx: [f32; N],
    sin: F<N>,
    cos: F<N>,
}

impl EnvMap {
    /// [`EnvMap::sample_direction`] for the lanes in `lanes`, from their numbers `u`.
    #[inline(always)]
    pub(crate) fn sample_lanes<const N: usize>(&self, u: [F<N>; 2], lanes: u32) -> MapDraws<N> {
        let mut drawn = 0u32;
        let mut cell = [(0u32, 0u32); N];
        let mut fx = [0.0f32; N];
        // Placeholders for lanes without a draw: any finite numbers.
        let (mut phi, mut uy, mut pdf) = ([0.0f32; N], [0.0f32; N], [0.0f32; N]);
        let (mut c0, mut c1) = ([1.0f32; N], [1.0f32; N]);
        for lane in (0..N).filter(|lane| lanes >> lane & 1 == 1) {
            let Some(c) = self.draw_cell(Vec2::new(u[0].0[lane], u[1].0[lane])) else {
                continue;
            };
            let Cell { i, j, ux, .. } = c;
            (phi[lane], c0[lane], c1[lane]) = self.cell_angles(&c);
            (cell[lane], fx[lane], uy[lane], pdf[lane]) = ((i, j), ux, c.uy, c.pdf);
            drawn |= 1 << lane;
        }
        let (c0, c1) = (F(c0), F(c1));
        let cos = c0 + F(uy) * (c1 - c0);
        // `f32::clamp`'s two tests.
        let cos = F::select(cos.cmplt(F::splat(-1.0)), F::splat(-1.0), cos);
        let cos = F::select(cos.cmpgt(F::ONE), F::ONE, cos);
        let sin = ((1.0 - cos) * (1.0 + cos)).max(F::ZERO).sqrt();
        let (sin_phi, cos_phi) = sin_cos_turn_lanes(F(phi));
        let local = [sin_phi * sin, cos, -cos_phi * sin];
        MapDraws {
            wi: self.to_world_lanes(&local),
            pdf: F(pdf),
            drawn,
            cell,
            fx,
            sin,
            cos,
        }
    }

    /// [`EnvMap::radiance_at`] of the draws in `lanes` (a subset of `draws.drawn`); 0 in the
    /// other lanes.
    #[inline(always)]
    pub(crate) fn radiance_at_lanes<const N: usize>(
        &self,
        draws: &MapDraws<N>,
        lanes: u32,
    ) -> [[f32; N]; 3] {
        let y = atan2_lanes(draws.sin, draws.cos) * self.rows_per_radian();
        let mut le = [[0.0; N]; 3];
        for lane in (0..N).filter(|lane| lanes >> lane & 1 == 1) {
            let (i, j) = draws.cell[lane];
            let c = self.blend_down(i, j, draws.fx[lane], y.0[lane]);
            for (axis, le) in le.iter_mut().enumerate() {
                le[lane] = c[axis];
            }
        }
        le
    }

    /// [`EnvMap::radiance_pdf`] along the directions `d` of the lanes in `lanes`: the radiance
    /// and the density; 0 in the other lanes.
    #[inline(always)]
    pub(crate) fn radiance_pdf_lanes<const N: usize>(
        &self,
        d: &V3<N>,
        lanes: u32,
    ) -> ([[f32; N]; 3], [f32; N]) {
        let [x, y, z] = self.to_local_lanes(d);
        // `EnvMap::uv`, lane by lane.
        let u = atan2_lanes(x, -z) * (0.5 / PI);
        let u = F::select(u.cmplt(F::ZERO), u + 1.0, u);
        let v = atan2_lanes((x * x + z * z).sqrt(), y) * (1.0 / PI);
        let top = F::splat(1.0 - f32::EPSILON / 2.0);
        let u = F::select(u.cmplt(top), u, top);
        let v = F::select(v.cmplt(F::ZERO), F::ZERO, v);
        let v = F::select(v.cmpgt(F::ONE), F::ONE, v);
        let mut le = [[0.0; N]; 3];
        let mut pdf = [0.0; N];
        for lane in (0..N).filter(|lane| lanes >> lane & 1 == 1) {
            let b = self.locate_uv(Vec2::new(u.0[lane], v.0[lane]));
            let c: Vec3A = self.blend(&b);
            for (axis, le) in le.iter_mut().enumerate() {
                le[lane] = c[axis];
            }
            pdf[lane] = self.density(&b);
        }
        (le, pdf)
    }

    /// [`EnvMap::to_local`] in lanes.
    #[inline(always)]
    fn to_local_lanes<const N: usize>(&self, d: &V3<N>) -> V3<N> {
        let (s, c) = self.rotation;
        [c * d[0] - s * d[2], d[1], s * d[0] + c * d[2]]
    }

    /// [`EnvMap::to_world`] in lanes.
    #[inline(always)]
    fn to_world_lanes<const N: usize>(&self, d: &V3<N>) -> V3<N> {
        let (s, c) = self.rotation;
        v3(|axis| match axis {
            0 => c * d[0] + s * d[2],
            1 => d[1],
            _ => -s * d[0] + c * d[2],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A map with a bright patch, turned, so that the draws cover rows, columns and the wrap.
    fn map(width: usize, height: usize) -> EnvMap {
        let texels: Vec<Vec3A> = (0..width * height)
            .map(|k| {
                let (x, y) = (k % width, k / width);
                let patch = if (x * 7 / width, y * 5 / height) == (2, 1) {
                    40.0
                } else {
                    0.0
                };
                Vec3A::new(0.3 + patch + x as f32 * 0.01, 0.5 + y as f32 * 0.02, 0.7)
            })
            .collect();
        EnvMap::new(width, height, &texels, 1.5, 0.37).expect("a map")
    }

    /// Every lane's draw, radiance and lookup are the scalar functions' bits, on a small map
    /// (columns by inversion) and one wide enough for the alias tables, with lanes left out.
    #[test]
    fn lanes_give_the_scalar_bits() {
        for map in [map(16, 9), map(600, 7)] {
            let n = 37;
            for k in 0..n * n {
                let us: [Vec2; 8] = std::array::from_fn(|lane| {
                    let m = k * 8 + lane;
                    let a = ((m * 7919) % (n * n)) as f32 / (n * n) as f32;
                    Vec2::new((m % n) as f32 / n as f32, a.min(1.0 - f32::EPSILON / 2.0))
                });
                let u = [F(us.map(|u| u.x)), F(us.map(|u| u.y))];
                let lanes = 0xff & !(1 << (k % 8));
                let draws = map.sample_lanes::<8>(u, lanes);
                let le = map.radiance_at_lanes(&draws, draws.drawn);
                let (back, pdf) = map.radiance_pdf_lanes(&draws.wi, draws.drawn);
                for (lane, u) in us.iter().enumerate() {
                    let want = map.sample_direction(*u).filter(|_| lanes >> lane & 1 == 1);
                    assert_eq!(draws.drawn >> lane & 1 == 1, want.is_some(), "{u}");
                    let Some(want) = want else { continue };
                    let bits = |v: Vec3A| v.to_array().map(f32::to_bits);
                    let at = |c: &[[f32; 8]; 3]| Vec3A::new(c[0][lane], c[1][lane], c[2][lane]);
                    let wi = Vec3A::new(
                        draws.wi[0].0[lane],
                        draws.wi[1].0[lane],
                        draws.wi[2].0[lane],
                    );
                    assert_eq!(bits(wi), bits(want.wi), "{u}");
                    assert_eq!(draws.pdf.0[lane].to_bits(), want.pdf.to_bits());
                    assert_eq!(bits(at(&le)), bits(map.radiance_at(&want.point)), "{u}");
                    let (r, p) = map.radiance_pdf(want.wi);
                    assert_eq!(bits(at(&back)), bits(r), "{u}");
                    assert_eq!(pdf[lane].to_bits(), p.to_bits(), "{u}");
                }
            }
        }
    }
}
