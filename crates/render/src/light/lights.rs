//! The scene's lights as light sampling draws them ([`Lights`]): the groups a vertex draws
//! one light from each, each light's probability within its group, the punctual lights for
//! BSDF-only rendering, and the densities MIS weighs against.

use glam::{Vec2, Vec3A};

use super::sample::{delta_sample, surfaceless_sample, Emitted};
use super::{
    positive_finite, sphere_roots, AreaSample, Light, LightSample, LightShape, LightTriangle,
};
use crate::util::distribution::Distribution1D;
use crate::util::math::{offset_ray_origin, Ray};

/// All emitters, in the groups light sampling draws one light from each ([`Lights::new`]).
#[derive(Clone, Debug, Default)]
pub struct Lights {
    /// The emitters.
    pub lights: Vec<Light>,
    /// Each group's lights by power, with their indices: the distant lights and the others
    /// where a scene has both, else all of them as one.
    groups: Vec<(Distribution1D, Vec<u32>)>,
    /// Each light's probability of being drawn within its group.
    pmf: Vec<f32>,
    /// The punctual lights alone, by power, with their indices: what BSDF-only rendering
    /// samples.
    delta: Option<(Distribution1D, Vec<u32>)>,
    /// The suns' indices: what a ray that escapes the scene must look for.
    suns: Vec<u32>,
}

impl Lights {
    /// Groups the lights: the distant ones (environment maps, suns, directional lights) and
    /// the others, where a scene has both, else all of them as one group. Light sampling
    /// draws one light of each group at every vertex, within the group by power.
    ///
    /// Why two groups, each sampled every time, rather than one choice by power among all:
    /// a distant light's power is its irradiance through the scene's cross-section, π·reach²,
    /// and the reach is the radius of the scene's bounding sphere, which a far-off ground
    /// plane sets, not the light, so power across the groups follows the scene's extent. By
    /// power a sky-lit scene gave its lamp about a tenth of the light samples, and the lamp's
    /// light reflected by a glossy surface onto a floor (a caustic, which only next-event
    /// estimation at the glossy vertex finds) came through those few samples, each weighed
    /// by the inverse of that small probability, as fireflies. A fixed even split instead
    /// cured those scenes but starved the sky of another that the lamp barely lit; drawing
    /// from both groups leaves neither to chance, for a second shadow ray where a scene has
    /// both kinds of light (docs/benchmarks/light-selection-2026-11-30.md).
    pub fn new(lights: Vec<Light>) -> Self {
        let weights: Vec<f32> = lights.iter().map(Light::power_weight).collect();
        let (far, near): (Vec<u32>, Vec<u32>) =
            (0..lights.len() as u32).partition(|&i| lights[i as usize].is_distant());
        let group = |index: Vec<u32>| {
            let w: Vec<f32> = index.iter().map(|&i| weights[i as usize]).collect();
            Distribution1D::new(&w).map(|d| (d, index))
        };
        let split = [group(far), group(near)];
        let groups: Vec<_> = if split.iter().all(Option::is_some) {
            split.into_iter().flatten().collect()
        } else {
            group((0..lights.len() as u32).collect())
                .into_iter()
                .collect()
        };
        let mut pmf = vec![0.0; lights.len()];
        for (d, index) in &groups {
            for (k, &i) in index.iter().enumerate() {
                pmf[i as usize] = d.pmf(k);
            }
        }
        let delta_index: Vec<u32> = (0..lights.len() as u32)
            .filter(|&i| lights[i as usize].is_delta())
            .collect();
        let delta = group(delta_index);
        let suns = (0..lights.len() as u32)
            .filter(|&i| matches!(lights[i as usize].shape, LightShape::Sun { .. }))
            .collect();
        Self {
            lights,
            groups,
            pmf,
            delta,
            suns,
        }
    }

    /// Whether any light is punctual.
    #[inline]
    pub fn has_delta(&self) -> bool {
        self.delta.is_some()
    }

    /// Picks a punctual light by power among the punctual ones: what rendering with BSDF
    /// sampling alone still needs, since no ray finds them.
    pub fn sample_delta(&self, p: Vec3A, u_select: f32) -> Option<LightSample<'_>> {
        let (dist, index) = self.delta.as_ref()?;
        let k = dist.sample(u_select);
        delta_sample(&self.lights[index[k] as usize], p, dist.pmf(k))
    }

    /// The indices of the suns, which a ray that escapes the scene may see.
    #[inline]
    pub fn suns(&self) -> &[u32] {
        &self.suns
    }

    /// Whether there is anything to sample.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }

    /// How many groups light sampling draws a light from at each vertex ([`Lights::new`]): 2
    /// where a scene has distant lights and others, else 1, or 0 without lights.
    #[inline]
    pub fn groups(&self) -> usize {
        self.groups.len()
    }

    /// Whether light `index` is the only light of group `group` (its selection is then 1).
    pub fn alone_in(&self, group: usize, index: u32) -> bool {
        self.groups
            .get(group)
            .is_some_and(|(_, i)| i[..] == [index])
    }

    /// The selection probability of a scene's first light (what [`Lights::sample`] multiplies
    /// its density by), or 0 where there is no light.
    pub fn pdf_scale(&self) -> f32 {
        self.selection(0)
    }

    /// Picks a light of group `group` and a point on it as seen from `p`. Always inlined, as
    /// it was before punctual lights, whose case is a call: inlined, it costs the area lights
    /// nothing.
    #[inline(always)]
    pub fn sample(
        &self,
        p: Vec3A,
        group: usize,
        u_select: f32,
        u: Vec2,
    ) -> Option<LightSample<'_>> {
        let (dist, index) = self.groups.get(group)?;
        let k = dist.sample(u_select);
        let light = &self.lights[index[k] as usize];
        let pmf = dist.pmf(k);
        if !light.is_area() {
            return surfaceless_sample(light, p, u, pmf);
        }
        let AreaSample { x, n, err, wi, pdf } = light.sample(p, u)?;
        let pdf = pdf * pmf;
        if !positive_finite(pdf) {
            return None;
        }
        let mut le = light.emitted(n, -wi);
        if let Some(t) = &light.texture {
            if let LightShape::Mesh(m) = &light.shape {
                le *= t.at_sample(m, u);
            }
        }
        let towards = if n.dot(-wi) >= 0.0 { n } else { -n };
        Some(LightSample {
            p: offset_ray_origin(x, err, towards),
            wi,
            le: Emitted::Known(le),
            pdf,
            delta: false,
            distant: false,
        })
    }

    /// Total density (solid angle) with which [`Lights::sample`] from `p` produces direction
    /// `w`, summed over every light the line through `w` crosses, occluded or not. This is the
    /// sampler's exact direction density, for tests; the integrator needs only [`Lights::pdf`],
    /// because a sample behind another surface is blocked by its shadow ray.
    pub fn pdf_direction(&self, p: Vec3A, w: Vec3A) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        let pmf = |i: usize| self.pmf[i];
        let ray = Ray::new(p, w);
        let mut total = 0.0;
        for (i, light) in self.lights.iter().enumerate() {
            let hit = match &light.shape {
                LightShape::Quad(q) => q
                    .intersect(&ray, f32::INFINITY)
                    .map(|t| (ray.at(t), q.normal)),
                LightShape::Sphere { center, radius } => sphere_roots(p, w, *center, *radius)
                    .and_then(|(t0, t1)| {
                        let t = if t0 > 0.0 { t0 } else { t1 };
                        (t > 0.0).then(|| (ray.at(t), (ray.at(t) - *center).normalize()))
                    }),
                LightShape::Mesh(m) => {
                    // Every triangle the line crosses: each is a separate way to draw `w`.
                    for &LightTriangle { p: [p0, p1, p2], n } in &m.tris {
                        let hit = crate::mesh::triangle::intersect(p, w, p0, p1, p2, f32::INFINITY);
                        if let Some(h) = hit {
                            total += pmf(i) * light.pdf(p, ray.at(h.t), n);
                        }
                    }
                    None
                }
                LightShape::Environment { map, .. } => {
                    total += pmf(i) * map.pdf(w);
                    None
                }
                LightShape::Sun { .. } => {
                    total += light.sun_seen(w).map_or(0.0, |(_, pdf)| pmf(i) * pdf);
                    None
                }
                _ => None,
            };
            if let Some((x, n)) = hit {
                total += pmf(i) * light.pdf(p, x, n);
            }
        }
        total
    }

    /// The probability with which [`Lights::sample`] selects light `index` within its group
    /// (0 where there is no light): the group is drawn from at every vertex, so this is the
    /// light's whole selection probability.
    #[inline]
    pub fn selection(&self, index: usize) -> f32 {
        self.pmf.get(index).copied().unwrap_or(0.0)
    }

    /// Density (solid angle, selection included) with which [`Lights::sample`] from `p` would
    /// have chosen point `x` (normal `n`) of light `index`.
    #[inline]
    pub fn pdf(&self, index: usize, p: Vec3A, x: Vec3A, n: Vec3A) -> f32 {
        if self.is_empty() {
            return 0.0;
        }
        self.selection(index) * self.lights[index].pdf(p, x, n)
    }
}

#[cfg(test)]
mod tests {
    use std::f32::consts::PI;
    use std::sync::Arc;

    use super::*;
    use crate::envmap::EnvMap;

    fn light(shape: LightShape, radiance: f32) -> Light {
        Light {
            shape,
            radiance: Vec3A::splat(radiance),
            two_sided: false,
            texture: None,
        }
    }

    /// A scene with distant lights and others draws from each group at every vertex, within
    /// it by power, whatever the scene's reach (which power across the groups followed: a
    /// lamp's share fell a hundredfold when the reach grew tenfold); a scene of one kind of
    /// light is one group, by power.
    #[test]
    fn distant_and_local_lights_are_drawn_from_apart_whatever_the_reach() {
        let map = Arc::new(EnvMap::new(2, 2, &[Vec3A::ONE; 4], 1.0, 0.0).expect("a map"));
        let point = |x: f32, radiance: f32| {
            light(
                LightShape::Point {
                    position: Vec3A::new(x, 0.0, 0.0),
                },
                radiance,
            )
        };
        let scene = |reach: f32| {
            Lights::new(vec![
                light(
                    LightShape::Environment {
                        map: map.clone(),
                        reach,
                    },
                    0.0,
                ),
                point(0.0, 1.0),
                point(1.0, 3.0),
                light(
                    LightShape::Directional {
                        towards: Vec3A::Y,
                        reach,
                    },
                    2.0,
                ),
            ])
        };
        // The map's power over the directional light's: ∫(R + G + B) dω = 3·4π against 3·2.
        let env = (2.0 * PI) / (2.0 * PI + 1.0);
        for reach in [1.0f32, 10.0, 1000.0] {
            let l = scene(reach);
            assert_eq!(l.groups(), 2);
            let want = [env, 0.25, 0.75, 1.0 - env];
            for (i, w) in want.into_iter().enumerate() {
                let got = l.selection(i);
                assert!(
                    (got - w).abs() < 1e-6,
                    "reach {reach}, light {i}: {got} vs {w}"
                );
            }
            // Group 0 draws only distant lights, group 1 only the points.
            for k in 0..64 {
                let u = (k as f32 + 0.5) / 64.0;
                let far = l
                    .sample(Vec3A::Y, 0, u, Vec2::splat(0.3))
                    .expect("a sample");
                assert!(far.distant, "u {u}");
                let near = l
                    .sample(Vec3A::Y, 1, u, Vec2::splat(0.3))
                    .expect("a sample");
                assert!(!near.distant && near.delta, "u {u}");
            }
            assert!(l.sample(Vec3A::Y, 2, 0.5, Vec2::splat(0.3)).is_none());
        }
        let local = Lights::new(vec![point(0.0, 1.0), point(1.0, 3.0)]);
        assert_eq!(local.groups(), 1);
        assert!((local.selection(0) - 0.25).abs() < 1e-6);
        let far = Lights::new(vec![light(
            LightShape::Environment { map, reach: 5.0 },
            0.0,
        )]);
        assert_eq!((far.groups(), far.selection(0)), (1, 1.0));
        assert_eq!(Lights::new(Vec::new()).groups(), 0);
    }

    /// The two-compare form means exactly "positive and finite", subnormals and the largest
    /// float included.
    #[test]
    fn positive_finite_is_the_open_positive_range() {
        let cases = [
            0.0,
            -0.0,
            f32::from_bits(1),
            f32::MIN_POSITIVE,
            1.0,
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
            -1.0,
            -f32::from_bits(1),
        ];
        for x in cases {
            assert_eq!(
                positive_finite(x),
                x > 0.0 && x.is_finite(),
                "{x:e} ({:#x})",
                x.to_bits()
            );
        }
    }
}
