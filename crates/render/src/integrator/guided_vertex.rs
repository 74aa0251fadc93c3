//! Path guiding's vertex (issue #60): at a diffuse vertex, one-sample MIS between the BSDF and
//! the guide learned at the vertex's place ([`crate::guide`]), and the training record each
//! vertex leaves.
//!
//! Estimator. With probability α the next direction comes from the guide's density p_g,
//! otherwise from the cosine lobe p_b = cos/π. Either way the direction's density is the
//! mixture's, p = α·p_g + (1 − α)·p_b, and the throughput takes f·cos/p = (ρ/π)·cos/p. That is
//! the one-sample MIS estimator with the balance heuristic, unbiased for any p_g that is a
//! density and is positive wherever f·cos·L is (p_b already is, for α < 1): so a guide learned
//! from garbage costs variance, never bias. The same p is the BSDF side's density against
//! light sampling, in both places the power heuristic reads it (an emitter the path hits next,
//! and next-event estimation here), so the two weights of any light path still add to one.
//! A guide sample below the surface has f = 0: the path ends, contributing 0, as it should.
//!
//! α is the vertex's leaf's own ([`SdTree::alpha_at`]), 0 where it learned nothing, so an
//! untrained region (or the first epoch) costs no variance. Each leaf chooses it from
//! [`crate::guide::ALPHAS`] by the second moment its vertices measured for each candidate
//! (below): where the cosine lobe does better, as on most of a Cornell box, the leaf turns
//! guiding off. Any α below 1 keeps the estimator unbiased, so the choice, noisy or not,
//! costs variance only.
//!
//! Choosing α. A direction ω drawn from the mixture q that the vertex used, with integrand
//! F(ω) = L_i·cos, estimates the second moment of the estimator of any other mixture q_c by
//! F²/(q·q_c): its expectation under q is ∫F²/q_c, which is that estimator's second moment.
//! Each guided vertex adds that, per candidate, to its leaf of the tree it trains, and the
//! next guide's leaf takes the candidate of least sum. The candidates' densities use the guide
//! the vertex sampled, not the one the choice is for: the next guide is that one refined, so
//! the choice lags one epoch, as Müller et al.'s (2019) online one does.
//!
//! Training. Each vertex keeps the throughput after it and what the path had gathered before
//! its continuation; at the path's end the radiance that arrived along its direction is what
//! was gathered since, divided by that throughput, channel by channel. The record is that
//! radiance times the cosine at the vertex over the direction's density, L_i·cos/p: its
//! expectation over the sampled directions in a region of the sphere is the integral of
//! L_i·cos there, so the guide learns the product a diffuse vertex would ideally sample
//! (Müller's L_i/p learns L_i alone; L_i·cos measured less error, docs/renderer.md). Direct
//! light found by next-event estimation is not recorded: light sampling already finds it, and
//! guiding is for the light it cannot find.

use glam::{Vec2, Vec3A};

use super::{direct_light, light_groups, Path, Shading};
use crate::bsdf::sample_diffuse;
use crate::guide::{DirTree, SdTree, ALPHAS};
use crate::interaction::SurfacePoint;
use crate::scene::Scene;
use crate::settings::Strategy;
use crate::util::math::{offset_ray_origin, Ray};
use crate::util::sampling::cosine_hemisphere_pdf;

/// The most vertices of one path that are recorded: deeper ones carry little, and the bound
/// keeps a path's record on the stack.
pub const MAX_VERTICES: usize = 16;

/// The guide a path tracer samples from and the tree it trains: the integrator's only
/// contact with guiding. The tracer is generic over it, so that a render without guiding
/// ([`NoGuide`]) compiles every guided step away and pays nothing for it.
pub trait Guiding<'a> {
    /// The path being guided, if any.
    fn path(&mut self) -> Option<&mut GuidedPath<'a>>;
}

/// No guiding: the tracer as it is without it.
pub struct NoGuide;

impl<'a> Guiding<'a> for NoGuide {
    #[inline(always)]
    fn path(&mut self) -> Option<&mut GuidedPath<'a>> {
        None
    }
}

impl<'a> Guiding<'a> for GuidedPath<'a> {
    #[inline(always)]
    fn path(&mut self) -> Option<&mut GuidedPath<'a>> {
        Some(self)
    }
}

/// One recorded vertex.
#[derive(Clone, Copy, Default)]
struct Vertex {
    p: Vec3A,
    wi: Vec3A,
    /// The direction's density over its cosine.
    pdf: f32,
    /// The path's throughput after the vertex.
    beta: Vec3A,
    /// The guide's density at `wi` and the cosine lobe's (none: no guide was trained here,
    /// and the vertex measures no α).
    densities: Option<(f32, f32)>,
    /// What the path had gathered before its continuation.
    l: Vec3A,
    /// The bounce it was at.
    depth: u32,
}

/// A guided path in progress: the guide it samples from (none in the first epoch), the tree
/// its vertices train (none in the last epoch), and its vertices so far.
pub struct GuidedPath<'a> {
    guide: Option<&'a SdTree>,
    train: Option<&'a mut SdTree>,
    vertices: [Vertex; MAX_VERTICES],
    len: usize,
}

impl<'a> GuidedPath<'a> {
    /// Paths sampling from `guide` and recording into `train`.
    pub fn new(guide: Option<&'a SdTree>, train: Option<&'a mut SdTree>) -> Self {
        Self {
            guide,
            train,
            vertices: [Vertex::default(); MAX_VERTICES],
            len: 0,
        }
    }

    /// The distribution to mix with the BSDF at `p` and its selection probability (which
    /// may be 0): none where nothing was learned.
    #[inline]
    fn at(&self, p: Vec3A) -> Option<(&'a DirTree, f32)> {
        self.guide
            .map(|g| g.alpha_at(p))
            .filter(|(d, _)| d.is_trained())
    }

    /// Records the path that ended having gathered `l`, and starts the next.
    pub(super) fn finish(&mut self, l: Vec3A) {
        let n = std::mem::take(&mut self.len);
        let Some(train) = self.train.as_deref_mut() else {
            return;
        };
        for v in &self.vertices[..n] {
            let gathered = l - v.l;
            let mut li = 0.0f64;
            for c in 0..3 {
                if v.beta[c] > 0.0 {
                    li += (gathered[c] / v.beta[c]) as f64;
                }
            }
            let li = li / 3.0;
            let record = li / v.pdf as f64;
            // F²/(q·q_c) for each candidate mixture q_c, with F = L_i·cos: the record is F/q.
            let moments = v.densities.map(|(pg, pb)| {
                let f = li * (pb * std::f32::consts::PI) as f64;
                ALPHAS.map(|a| record * f / (a * pg + (1.0 - a) * pb) as f64)
            });
            train.record_with(v.p, v.wi, record, moments.as_ref());
        }
    }

    /// Takes `light`, found at bounce `depth` by the last recorded vertex's continuation
    /// (the vertex one bounce before) and weighed against light sampling, out of that
    /// vertex's record (but not out of the vertices' before it, for which it is indirect
    /// light; nor when an unrecorded glossy vertex lies between, whose direct light it is):
    /// next-event estimation finds it, and a guide that learned it would take directions from
    /// the light sampler and not give them to the light that needs them. Light found after a
    /// specular bounce (a caustic), which light sampling cannot find, stays in.
    pub(super) fn found_direct(
        &mut self,
        strategy: Strategy,
        specular: bool,
        light: Vec3A,
        depth: u32,
    ) {
        if strategy == Strategy::Mis && !specular && self.len > 0 {
            let last = &mut self.vertices[self.len - 1];
            if last.depth + 1 == depth {
                last.l += light;
            }
        }
    }

    #[inline]
    fn push(&mut self, v: Vertex) {
        if self.train.is_some() && self.len < MAX_VERTICES {
            self.vertices[self.len] = v;
            self.len += 1;
        }
    }
}

/// [`super::diffuse`] with the guide in the mix: direct light by next-event estimation
/// weighed against the mixture's density, then a direction from the guide (when `u_pick` < α)
/// or the cosine lobe, weighted by f·cos over the mixture's density. `None` ends the path.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
pub(super) fn diffuse(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    albedo: Vec3A,
    sp: &SurfacePoint,
    at: &Shading,
    (bsdf_u, u_pick): (Vec2, f32),
    light_u: Option<(f32, Vec2)>,
    (g, depth): (&mut GuidedPath<'_>, u32),
) -> Option<Ray> {
    let p_out = offset_ray_origin(sp.p, sp.err, at.n);
    let guide = g.at(sp.p);
    // The guide's density enters the mixture only where it is sampled (α > 0); elsewhere the
    // mixture is the cosine lobe, and a trained leaf still evaluates the guide at the sampled
    // direction, to measure α for the next guide.
    let mixture = |wi: Vec3A, cos: f32| match guide {
        Some((d, a)) if a > 0.0 => a * d.pdf(wi) + (1.0 - a) * cosine_hemisphere_pdf(cos),
        _ => cosine_hemisphere_pdf(cos),
    };
    if let Some(u) = light_u {
        for group in 0..light_groups(scene, strategy) {
            if let Some((le, f)) = direct_light(scene, strategy, sp, at, p_out, (group, u), mixture)
            {
                path.l += path.beta * albedo * le * f;
            }
        }
    }
    // Each technique's density at its own sample is the one it drew by; the other's is
    // evaluated.
    let (wi, cos, pdf, densities) = match guide {
        Some((d, a)) if u_pick < a => {
            let (wi, pg) = d.sample(bsdf_u);
            let cos = at.ns.dot(wi);
            let pb = cosine_hemisphere_pdf(cos);
            (wi, cos, a * pg + (1.0 - a) * pb, Some((pg, pb)))
        }
        Some((d, a)) => {
            let (wi, pb) = sample_diffuse(at.ns, bsdf_u);
            let pg = d.pdf(wi);
            (wi, at.ns.dot(wi), a * pg + (1.0 - a) * pb, Some((pg, pb)))
        }
        None => {
            let (wi, p) = sample_diffuse(at.ns, bsdf_u);
            (wi, at.ns.dot(wi), p, None)
        }
    };
    path.specular = false;
    if !(cos > 0.0) || (at.shaded && at.n.dot(wi) <= 0.0) {
        return None;
    }
    if !(pdf > 0.0) {
        return None;
    }
    path.beta *= albedo * (cos * std::f32::consts::FRAC_1_PI / pdf);
    path.prev_pdf = pdf;
    g.push(Vertex {
        p: sp.p,
        wi,
        pdf: pdf / cos,
        beta: path.beta,
        densities,
        l: path.l,
        depth,
    });
    Some(Ray::new(p_out, wi))
}
