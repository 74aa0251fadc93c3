//! An environment map in the lanes: the rays that leave the scene look it up together, and the
//! diffuse vertices draw their light samples of it together, where it is the only light of its
//! group (`Lights::new`'s distant lights, drawn from at every vertex). Each lane does the
//! scalar trace's arithmetic (`integrator::escape`, `integrator::diffuse_light`), the map's in
//! lanes by [`EnvMap`]'s lane twins, so a sample's bits are the same whichever tracer runs it.
//! A scene with a sun, or with the map beside other distant lights, keeps the lane-by-lane
//! steps (`by_lane.rs`).

use std::f32::consts::FRAC_1_PI;

use super::{add_where, load3, Lanes, Vertices, Wide};
use crate::envmap::EnvMap;
use crate::scene::{Environment, Scene};
use crate::util::lanes::{dot, F, M, V3};
use crate::util::sampling::power_heuristic_lanes;

/// The scene's environment map, as the lanes use it.
pub(super) struct Sky<'a> {
    map: &'a EnvMap,
    /// The map's selection probability within its group: an escaping ray's MIS weight takes
    /// it, and so does a light sample's density.
    selection: f32,
    /// Whether the map is the only light of the first group, so that the lanes draw its light
    /// samples (else every light sample is the scalar trace's, lane by lane).
    sampled: bool,
}

impl<'a> Sky<'a> {
    /// The scene's map, where it has one and no sun (a sun is seen by escaping rays too).
    pub(super) fn new(scene: &'a Scene) -> Option<Self> {
        let Some(Environment::Map { map, light }) = &scene.environment else {
            return None;
        };
        if !scene.lights.suns().is_empty() {
            return None;
        }
        Some(Self {
            map,
            selection: scene.lights.selection(*light as usize),
            sampled: scene.lights.alone_in(0, *light),
        })
    }

    /// Whether the lanes draw the map's light samples (the first group's).
    pub(super) fn sampled(&self) -> bool {
        self.sampled
    }
}

impl Wide<'_> {
    /// What the rays of the lanes in `lanes`, which left the scene, find on the map: in full
    /// after a specular bounce (the camera's too), else weighted by the power heuristic against
    /// the map's light samples, as `integrator::add_environment` under MIS.
    #[inline(always)]
    pub(super) fn escape_lanes<const N: usize>(&self, s: &mut Lanes<N>, sky: &Sky, lanes: u32) {
        let (le, pdf) = sky.map.radiance_pdf_lanes(&load3(&s.d), lanes);
        let light_pdf = sky.selection * F(pdf);
        let w = power_heuristic_lanes(F(s.prev_pdf), light_pdf);
        let w = F::select(M::from_bits(s.specular), F::ONE, w);
        let beta = &s.beta;
        add_where(&mut s.l, lanes, |c| F(beta[c]) * F(le[c]) * w);
    }

    /// Next-event estimation of the map at the diffuse vertices `v`: a direction drawn from the
    /// map, its shadow ray from `p_out` to infinity, and the power heuristic against the
    /// cosine lobe, as `integrator::diffuse_light` for the first group of lights.
    #[inline(always)]
    pub(super) fn sky_light<const N: usize, const GENERAL: bool>(
        &self,
        s: &mut Lanes<N>,
        sky: &Sky,
        v: &Vertices<N>,
        p_out: &V3<N>,
    ) {
        let draws = sky.map.sample_lanes(v.light_u, v.shade);
        // `surfaceless_sample`: the density with the selection (the group's one light) taken
        // in, positive and finite.
        let pdf = draws.pdf * sky.selection;
        let valid = pdf.cmpgt(F::ZERO) & pdf.cmple(F::splat(f32::MAX));
        let cos = dot(&v.n, &draws.wi);
        let nee = (valid & cos.cmpgt(F::ZERO)).bits() & draws.drawn;
        if nee == 0 {
            return;
        }
        let add = nee & !self.blocked::<N, GENERAL>(p_out, &draws.wi, nee, f32::INFINITY);
        if add == 0 {
            return;
        }
        let le = sky.map.radiance_at_lanes(&draws, add);
        let w = power_heuristic_lanes(pdf, cos * FRAC_1_PI);
        let factor = (cos * FRAC_1_PI * w) / pdf;
        let beta = &s.beta;
        add_where(&mut s.l, add, |c| {
            F(beta[c]) * v.albedo[c] * F(le[c]) * factor
        });
    }
}
