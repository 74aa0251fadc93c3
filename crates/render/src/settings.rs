//! Everything besides the scene that decides a render's pixels: the settings a job carries
//! (and so the farm stores and sends), their ranges and defaults. Below the integrator and the
//! adaptive sampler, which both read them.

use std::ops::RangeInclusive;

/// How direct light is estimated. All three converge to the same image; `Mis` has the lowest
/// variance, the others exist to test that claim. Stored (in the coordinator's job records) by
/// its lower-case [`Strategy::name`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Strategy {
    /// Next-event estimation and BSDF sampling, combined by the power heuristic.
    #[default]
    Mis,
    /// BSDF sampling only: emitters count only when a path happens to hit them.
    Bsdf,
    /// Light sampling only at diffuse vertices (emitters reached by a diffuse bounce count 0).
    Nee,
}

impl Strategy {
    /// Lower-case name, as on the command line and in EXR metadata.
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Mis => "mis",
            Strategy::Bsdf => "bsdf",
            Strategy::Nee => "nee",
        }
    }

    /// Inverse of [`Strategy::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        [Strategy::Mis, Strategy::Bsdf, Strategy::Nee]
            .into_iter()
            .find(|s| s.name() == name)
    }
}

/// Samples per batch when a render or job does not choose. The batch decides the order in
/// which sums are added, so it is part of a job's identity: every entry point (`tessera
/// render`, `tessera submit`, the coordinator) must use this one value for their bits to match.
pub const DEFAULT_BATCH: u32 = 16;

/// The batch sizes accepted everywhere.
pub const BATCH_RANGE: std::ops::RangeInclusive<u32> = 1..=65536;

/// The tile edges (in pixels) the farm accepts.
pub const TILE_RANGE: std::ops::RangeInclusive<u32> = 4..=512;

/// The coordinator's tile edge for jobs that do not choose one.
pub const DEFAULT_TILE: u32 = 128;

/// Which path tracer renders. Every choice gives the same bits (`tests/wide.rs` compares the
/// many-path tracer with the scalar one sample by sample), so this is no part of a job's
/// identity and never travels to workers: it exists to time the tracers against each other.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Tracer {
    /// The many-path tracer for scenes whose bounce it models, the scalar one for the rest.
    #[default]
    Auto,
    /// One path at a time, always.
    Scalar,
    /// The many-path tracer with this many lanes (4, 8 or 16) where it applies; other counts,
    /// and other scenes, trace one path at a time.
    Lanes(usize),
}

/// Everything besides the scene that decides a render's pixels.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    /// Job seed.
    pub seed: u64,
    /// Samples per pixel.
    pub spp: u32,
    /// Samples per batch: sums are accumulated per batch and batches added in order, so this
    /// is part of a job's identity (like the seed) for bit-exact reproduction.
    pub batch: u32,
    /// Direct-lighting strategy.
    pub strategy: Strategy,
    /// Bounce at which Russian roulette starts.
    pub rr_depth: u32,
    /// Throughput below which Russian roulette starts to end paths: a path survives with
    /// probability min(0.95, max(β)/threshold). The cap keeps a path between perfect mirrors
    /// finite. pbrt's rule is threshold 1; 0.25 keeps paths through the Cornell box's bright
    /// walls alive, whose deep bounces carry much of its light, and measured less
    /// relMSE·seconds there (docs/renderer.md).
    pub rr_threshold: f32,
    /// Which tracer runs (the same bits whichever).
    pub tracer: Tracer,
    /// Noise-targeted adaptive sampling: `None` gives every pixel `spp` samples (the unbiased
    /// default); `Some` makes `spp` a cap and stops each tile once its noise meets the target
    /// ([`crate::adaptive`]). Part of a job's identity when set.
    pub adaptive: Option<Adaptive>,
    /// The frame of an animated scene this render is of (`None`: a render that names no
    /// frame, of a still scene or of an animated scene's first frame). It chooses the scene
    /// built from the file ([`crate::scene::Scene::from_str_at`]) and goes into the EXR's
    /// header, so it is part of the render's identity when set.
    pub frame: Option<u32>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            seed: 0,
            spp: 64,
            batch: DEFAULT_BATCH,
            strategy: Strategy::Mis,
            rr_depth: 3,
            rr_threshold: 0.25,
            tracer: Tracer::Auto,
            adaptive: None,
            frame: None,
        }
    }
}

/// The noise targets accepted: a relative error of 0.01% to 100%.
pub const NOISE_TARGET_RANGE: RangeInclusive<f64> = 1e-4..=1.0;

/// The adaptive part of a render's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adaptive {
    /// The image's relative error to stop at: the expected square root of its relMSE against
    /// the converged image, estimated from the samples (see the module's documentation).
    pub noise_target: f64,
    /// Edge of the square tiles the decision is made for, in pixels. It is part of the job's
    /// identity: other tiles stop at other batches.
    pub tile: u32,
}

/// A noise target outside [`NOISE_TARGET_RANGE`].
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "noise target {0} must be a relative error between {min} and {max}",
    min = NOISE_TARGET_RANGE.start(),
    max = NOISE_TARGET_RANGE.end()
)]
pub struct BadNoiseTarget(pub f64);

impl Adaptive {
    /// Checks the target (`tile` is the caller's to check against its own tile range).
    pub fn new(noise_target: f64, tile: u32) -> Result<Self, BadNoiseTarget> {
        if !NOISE_TARGET_RANGE.contains(&noise_target) {
            return Err(BadNoiseTarget(noise_target));
        }
        Ok(Self { noise_target, tile })
    }
}
