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
    /// BSDF sampling only: emitters count only when a path happens to hit them. Punctual
    /// lights, which no path can hit, are still light-sampled.
    Bsdf,
    /// Light sampling only at diffuse vertices (emitters reached by a diffuse bounce count 0,
    /// but for an environment map's directions that its light samples never draw, which count
    /// in full: [`crate::envmap::EnvMap`]).
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

/// The samples a unit (one tile × one batch) aims at when a render or job does not choose its
/// batch ([`unit_batch`]): enough that a unit is seconds of a many-core worker's time on a
/// production scene (and a fifth of a second on the Cornell box), and its partial sums (52
/// bytes a pixel) a small fraction of the samples' worth of work the coordinator merges.
pub const DEFAULT_UNIT_SAMPLES: u64 = 1 << 24;

/// The unit sizes `--unit-samples` accepts.
pub const UNIT_SAMPLES_RANGE: RangeInclusive<u64> = (1 << 12)..=(1 << 34);

/// The units [`unit_batch`] cuts a frame into at least, where its lower bound on a unit's
/// size allows: enough to spread one frame over tens of workers.
pub const MIN_UNITS_PER_FRAME: u64 = 64;

/// The batch a render or job takes when it does not choose one: the rule every entry point
/// (`tessera render`, `tessera submit`, the coordinator's admission of a request with batch 0)
/// applies, so that their bits match without flags. The batch decides the order in which sums
/// are added, so it is part of a job's identity; the rule reads only the image's size, the
/// samples per pixel, whether sampling is adaptive and the unit target, never the tile size a
/// coordinator is configured with, which cannot change a bit.
///
/// With a nominal tile of [`DEFAULT_TILE`]² pixels (or the whole image, if smaller), the batch
/// is the one that cuts the frame into [`MIN_UNITS_PER_FRAME`] units, held between a quarter
/// of `unit_samples` and `unit_samples` per unit: small frames get a few units of useful size
/// rather than many tiny ones, large frames units of at most `unit_samples`. It is rounded
/// down to a power of two, and is never more than `spp`. Adaptive sampling decides after every
/// batch past its pilot, so there the batch is also at most [`MIN_SAMPLES`]
/// and an eighth of `spp`, which keeps its decision points.
pub fn unit_batch(width: u32, height: u32, spp: u32, adaptive: bool, unit_samples: u64) -> u32 {
    let pixels = (width as u64 * height as u64).max(1);
    let tile = (DEFAULT_TILE as u64 * DEFAULT_TILE as u64).min(pixels);
    let tiles = (width.div_ceil(DEFAULT_TILE) as u64 * height.div_ceil(DEFAULT_TILE) as u64).max(1);
    let most = (unit_samples / tile).max(1);
    let least = (unit_samples / 4 / tile).clamp(1, most);
    let spread = (spp as u64 * tiles / MIN_UNITS_PER_FRAME).clamp(least, most);
    let mut batch = 1u64 << spread.ilog2();
    if adaptive {
        batch = batch.min(MIN_SAMPLES as u64).min((spp as u64 / 8).max(1));
        batch = 1 << batch.ilog2();
    }
    batch.min(spp.max(1) as u64).min(*BATCH_RANGE.end() as u64) as u32
}

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
    /// The many-path tracer where it pays (`Wide::new`), the scalar one for the rest.
    #[default]
    Auto,
    /// One path at a time, always.
    Scalar,
    /// The many-path tracer with this many lanes (4, 8 or 16) wherever it can run
    /// (`Wide::anywhere`); other counts, and other scenes, trace one path at a time.
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
    /// built from the file ([`crate::scene::Load::at`]) and goes into the EXR's
    /// header, so it is part of the render's identity when set.
    pub frame: Option<u32>,
    /// Extra images for denoising to render beside the beauty ([`Aovs`]); none by default. They
    /// come from a pass of their own, so the beauty has the same bits and speed without them.
    pub aovs: Aovs,
    /// The film's size in pixels in place of the scene file's own (`--resolution`), applied
    /// when the scene is built ([`crate::scene::Shot`]); part of the render's identity when
    /// set, like `spp`.
    pub resolution: Option<(u32, u32)>,
    /// Path guiding ([`crate::guiding`]): a render of these settings is
    /// [`crate::guiding::render_frame_guided`]'s, in epochs, and a farm's units are
    /// [`crate::guiding::units`]. Part of a job's identity when set. [`crate::render_frame`]
    /// does not read it: callers choose the guided renderer by it.
    pub guiding: bool,
}

/// Which auxiliary images (AOVs) a render writes beside the beauty, for a denoiser (Intel Open
/// Image Denoise, Blender's compositor): each pixel's mean over its samples of what the
/// camera ray sees at its first non-specular surface ([`crate::aov`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize)]
pub struct Aovs {
    /// `albedo.R`, `albedo.G`, `albedo.B`: the surface's reflectance colour, in [0, 1].
    pub albedo: bool,
    /// `normal.X`, `normal.Y`, `normal.Z`: its world-space shading normal, facing the camera
    /// ray; zero where the ray escapes.
    pub normal: bool,
    /// `Z`: the distance along the camera ray to the first surface it meets, over the samples
    /// that meet one; +∞ where none does.
    pub depth: bool,
}

impl Aovs {
    /// All three.
    pub const ALL: Aovs = Aovs {
        albedo: true,
        normal: true,
        depth: true,
    };

    /// The names `--aov` takes, in the order the header lists them.
    pub const NAMES: [&'static str; 3] = ["albedo", "normal", "depth"];

    /// From a comma-separated list of [`Aovs::NAMES`] (empty: none). The error names the
    /// entry that is not one.
    pub fn parse(list: &str) -> Result<Self, String> {
        let mut out = Self::default();
        for name in list.split(',').map(str::trim).filter(|n| !n.is_empty()) {
            match name {
                "albedo" => out.albedo = true,
                "normal" => out.normal = true,
                "depth" => out.depth = true,
                other => {
                    return Err(format!(
                        "unknown AOV {other:?}: expected a comma-separated list of {}",
                        Self::NAMES.join(", ")
                    ))
                }
            }
        }
        Ok(out)
    }

    /// Whether any is asked for.
    pub fn any(self) -> bool {
        self.albedo || self.normal || self.depth
    }

    /// The list [`Aovs::parse`] reads back (empty for none).
    pub fn list(self) -> String {
        let on = [self.albedo, self.normal, self.depth];
        Self::NAMES
            .iter()
            .zip(on)
            .filter(|(_, on)| *on)
            .map(|(n, _)| *n)
            .collect::<Vec<_>>()
            .join(",")
    }
}

impl RenderSettings {
    /// What these settings ask of the scene file: their frame (the first where none is named)
    /// and film size.
    pub fn shot(&self) -> crate::scene::Shot {
        crate::scene::Shot {
            frame: self.frame.unwrap_or(crate::scene::FIRST_FRAME),
            resolution: self.resolution,
        }
    }
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            seed: 0,
            spp: 64,
            batch: 16,
            strategy: Strategy::Mis,
            rr_depth: 3,
            rr_threshold: 0.25,
            tracer: Tracer::Auto,
            adaptive: None,
            frame: None,
            aovs: Aovs::default(),
            resolution: None,
            guiding: false,
        }
    }
}

/// Samples every pixel takes before its tile's noise may stop it (the pilot): a variance
/// estimated from a handful of samples is often far too low (a dark tile whose rare bright
/// paths have not been found yet looks noiseless). Here, below [`crate::adaptive`], because
/// the batch rule ([`unit_batch`]) keeps adaptive batches within it.
pub const MIN_SAMPLES: u32 = 64;

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

#[cfg(test)]
mod tests {
    use super::*;

    fn units(w: u32, h: u32, spp: u32, batch: u32) -> u64 {
        (w.div_ceil(DEFAULT_TILE) as u64 * h.div_ceil(DEFAULT_TILE) as u64)
            * spp.div_ceil(batch) as u64
    }

    #[test]
    fn the_unit_rule_gives_these_batches() {
        let u = DEFAULT_UNIT_SAMPLES;
        // (width, height, spp, adaptive) → batch, as docs/farm.md tabulates them.
        let cases = [
            ((256, 256, 1024, false), 256),
            ((1024, 1024, 1024, false), 1024),
            ((1024, 1024, 256, false), 256),
            ((1920, 1080, 64, false), 64),
            ((4096, 4096, 8, false), 8),
            ((256, 256, 64, false), 64),
            ((16, 16, 65536, false), 16384),
            ((1, 1, 1, false), 1),
            ((256, 256, 1024, true), 64),
            ((256, 256, 100, true), 8),
            ((256, 256, 3, true), 1),
        ];
        for ((w, h, spp, adaptive), want) in cases {
            assert_eq!(
                unit_batch(w, h, spp, adaptive, u),
                want,
                "{w}×{h} at {spp} spp"
            );
        }
    }

    #[test]
    fn the_unit_rule_keeps_its_bounds() {
        for (w, h) in [(1, 1), (7, 300), (256, 256), (1920, 1080), (8192, 8192)] {
            for spp in [1, 2, 3, 17, 64, 100, 1024, 4096, 65536, 1 << 20] {
                for u in [1 << 12, 1 << 20, DEFAULT_UNIT_SAMPLES, 1 << 34] {
                    for adaptive in [false, true] {
                        let b = unit_batch(w, h, spp, adaptive, u);
                        assert!(b.is_power_of_two() || b == spp, "{w}×{h} {spp} {u}: {b}");
                        assert!(BATCH_RANGE.contains(&b) && b <= spp, "{b} for {spp} spp");
                        let tile = (DEFAULT_TILE as u64).pow(2).min(w as u64 * h as u64);
                        // A unit never exceeds the target (one sample a pixel aside).
                        assert!(b == 1 || tile * b as u64 <= u, "{w}×{h} {spp} {u}: {b}");
                        // Below a quarter of the target (an eighth, after rounding to a power
                        // of two) only to give the frame its units, or because the samples
                        // run out.
                        if !adaptive && b < spp && b < *BATCH_RANGE.end() && tile * b as u64 * 8 < u
                        {
                            assert!(
                                units(w, h, spp, b) >= MIN_UNITS_PER_FRAME / 2,
                                "{w}×{h} {spp} {u}: {b}"
                            );
                        }
                    }
                }
            }
        }
    }
}
