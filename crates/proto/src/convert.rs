//! Conversions between the wire types and the renderer's, written once: every crate that
//! speaks the protocol uses these, so a value cannot mean one thing to the coordinator and
//! another to a worker.

use tessera_render::adaptive::BadNoiseTarget;
use tessera_render::film::AovSums;
use tessera_render::{
    Adaptive, Aovs, PixelRect, RenderSettings, Strategy, TileSums, BATCH_RANGE, DEFAULT_TILE,
};

use crate::v1 as pb;

impl From<PixelRect> for pb::Rect {
    fn from(r: PixelRect) -> Self {
        Self {
            x0: r.x0,
            y0: r.y0,
            width: r.width,
            height: r.height,
        }
    }
}

impl From<pb::Rect> for PixelRect {
    fn from(r: pb::Rect) -> Self {
        Self {
            x0: r.x0,
            y0: r.y0,
            width: r.width,
            height: r.height,
        }
    }
}

impl From<Strategy> for pb::Strategy {
    fn from(s: Strategy) -> Self {
        match s {
            Strategy::Mis => Self::Mis,
            Strategy::Bsdf => Self::Bsdf,
            Strategy::Nee => Self::Nee,
        }
    }
}

/// A strategy number this build does not know (from a newer peer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("unknown strategy {0}")]
pub struct UnknownStrategy(pub i32);

/// The strategy a message's `strategy` field names; unset means MIS, as the protocol says. An
/// unknown number is an error, never some other strategy: that would render other bits as if
/// they were the job's.
pub fn strategy_from_wire(v: i32) -> Result<Strategy, UnknownStrategy> {
    match pb::Strategy::try_from(v) {
        Ok(pb::Strategy::Unspecified | pb::Strategy::Mis) => Ok(Strategy::Mis),
        Ok(pb::Strategy::Bsdf) => Ok(Strategy::Bsdf),
        Ok(pb::Strategy::Nee) => Ok(Strategy::Nee),
        Err(_) => Err(UnknownStrategy(v)),
    }
}

impl From<&RenderSettings> for pb::RenderSettings {
    fn from(s: &RenderSettings) -> Self {
        Self {
            spp: s.spp,
            seed: s.seed,
            batch: s.batch,
            strategy: pb::Strategy::from(s.strategy) as i32,
            noise_target: s.adaptive.map_or(0.0, |a| a.noise_target),
            frame: s.frame,
            aovs: s.aovs.list(),
            guiding: s.guiding,
            resolution: s
                .resolution
                .map(|(width, height)| pb::Resolution { width, height }),
        }
    }
}

/// Why a message's render settings cannot be a render's.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BadSettings {
    /// The message has no settings.
    #[error("no render settings")]
    Missing,
    /// No samples.
    #[error("spp 0 must be at least 1")]
    NoSamples,
    /// A batch outside [`BATCH_RANGE`].
    #[error("batch {0} must be between {min} and {max}", min = BATCH_RANGE.start(), max = BATCH_RANGE.end())]
    Batch(u32),
    /// A strategy this build does not know.
    #[error(transparent)]
    Strategy(#[from] UnknownStrategy),
    /// A noise target outside the accepted range.
    #[error(transparent)]
    NoiseTarget(#[from] BadNoiseTarget),
    /// An AOV list naming something that is not one.
    #[error("aovs: {0}")]
    Aovs(String),
    /// Path guiding with a noise target: adaptive sampling stops tiles at different batches,
    /// and a guided epoch needs every tile's samples.
    #[error("guiding cannot be combined with a noise target")]
    GuidingAdaptive,
    /// A film side of 0 pixels.
    #[error("resolution {0}×{1}: each side must be at least 1 pixel")]
    Resolution(u32, u32),
}

/// The renderer's settings from a message's: an unset strategy is MIS, as the protocol says,
/// and an unset batch stays 0, for the coordinator to choose at admission by the rule that
/// `tessera render` follows ([`tessera_render::unit_batch`]), which needs the scene's size. The rest of [`RenderSettings`] is not on the wire: every
/// peer uses the renderer's defaults, which [`tessera_render::IMAGE_REVISION`] pins. Bounds
/// that depend on a coordinator's configuration (the largest spp) are the coordinator's to
/// check. A noise target's tiles are not in this message: they are the job's `tile_size`, which
/// the coordinator puts in at admission; until then they are [`DEFAULT_TILE`].
impl TryFrom<&pb::RenderSettings> for RenderSettings {
    type Error = BadSettings;

    fn try_from(s: &pb::RenderSettings) -> Result<Self, BadSettings> {
        if s.spp == 0 {
            return Err(BadSettings::NoSamples);
        }
        let batch = s.batch;
        if batch != 0 && !BATCH_RANGE.contains(&batch) {
            return Err(BadSettings::Batch(batch));
        }
        if s.guiding && s.noise_target != 0.0 {
            return Err(BadSettings::GuidingAdaptive);
        }
        let resolution = s.resolution.map(|r| (r.width, r.height));
        if let Some((w, h)) = resolution.filter(|&(w, h)| w == 0 || h == 0) {
            return Err(BadSettings::Resolution(w, h));
        }
        Ok(RenderSettings {
            seed: s.seed,
            spp: s.spp,
            batch,
            strategy: strategy_from_wire(s.strategy)?,
            adaptive: if s.noise_target == 0.0 {
                None
            } else {
                Some(Adaptive::new(s.noise_target, DEFAULT_TILE)?)
            },
            frame: s.frame,
            aovs: Aovs::parse(&s.aovs).map_err(BadSettings::Aovs)?,
            guiding: s.guiding,
            resolution,
            ..RenderSettings::default()
        })
    }
}

/// The settings of a message whose `settings` field is optional on the wire but required.
pub fn settings_from_wire(s: Option<&pb::RenderSettings>) -> Result<RenderSettings, BadSettings> {
    s.ok_or(BadSettings::Missing)
        .and_then(RenderSettings::try_from)
}

impl From<&TileSums> for pb::TileResult {
    fn from(t: &TileSums) -> Self {
        let flat = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<f64>>();
        Self {
            rect: Some(t.rect.into()),
            sample_start: t.samples.start,
            sample_end: t.samples.end,
            sum: flat(&t.sum),
            sum_sq: flat(&t.sum_sq),
            count: t.count.clone(),
            nonfinite: t.nonfinite,
            aov_albedo: t.aov.as_ref().map_or_else(Vec::new, |a| flat(&a.albedo)),
            aov_normal: t.aov.as_ref().map_or_else(Vec::new, |a| flat(&a.normal)),
            aov_depth: t.aov.as_ref().map_or_else(Vec::new, |a| a.depth.clone()),
            aov_hits: t.aov.as_ref().map_or_else(Vec::new, |a| a.hits.clone()),
            aov_count: t.aov.as_ref().map_or_else(Vec::new, |a| a.count.clone()),
            // A guided unit's worker sets it: sums alone do not carry training.
            guide_train: Vec::new(),
        }
    }
}

/// Why a result's arrays cannot be the sums of its rectangle (what can be told without the
/// job; the coordinator checks the rest against the unit).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BadResult {
    /// No rectangle.
    #[error("result has no rect")]
    NoRect,
    /// Arrays of other lengths than the rectangle's.
    #[error(
        "result for a {width}×{height} rect has {sums} sums, {squares} squared sums and {counts} counts (want {}, {}, {})",
        3 * width * height, 3 * width * height, width * height
    )]
    Lengths {
        /// Rectangle width.
        width: u64,
        /// Rectangle height.
        height: u64,
        /// Sums sent.
        sums: usize,
        /// Squared sums sent.
        squares: usize,
        /// Counts sent.
        counts: usize,
    },
    /// A sample range that ends before it starts.
    #[error("result sample range {0}..{1} is backwards")]
    Backwards(u32, u32),
    /// AOV arrays of other lengths than the rectangle's (all five are sent, or none).
    #[error(
        "result for a {pixels}-pixel rect has AOV arrays of {albedo}, {normal}, {depth}, {hits} and {count} values (want {}, {}, {pixels}, {pixels}, {pixels}, or none)",
        3 * pixels, 3 * pixels
    )]
    AovLengths {
        /// Pixels in the rectangle.
        pixels: u64,
        /// Albedo sums sent.
        albedo: usize,
        /// Normal sums sent.
        normal: usize,
        /// Depth sums sent.
        depth: usize,
        /// Hit counts sent.
        hits: usize,
        /// Sample counts sent.
        count: usize,
    },
}

/// A flat array of RGB values as per-pixel triples, moved rather than copied, so that a large
/// result is in memory once beside its wire bytes, not twice. The allocation must hold whole
/// triples: a decoded array's capacity is whatever prost grew it to, so it is first shrunk to
/// its length (a realloc that shrinks in place).
fn triples(mut v: Vec<f64>) -> Vec<[f64; 3]> {
    if !v.capacity().is_multiple_of(3) {
        v.shrink_to_fit();
    }
    bytemuck::allocation::try_cast_vec(v)
        .unwrap_or_else(|(_, v)| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

impl TryFrom<pb::TileResult> for TileSums {
    type Error = BadResult;

    fn try_from(r: pb::TileResult) -> Result<Self, BadResult> {
        let rect = PixelRect::from(r.rect.ok_or(BadResult::NoRect)?);
        let (width, height) = (u64::from(rect.width), u64::from(rect.height));
        let n = width * height;
        if r.sum.len() as u64 != 3 * n
            || r.sum_sq.len() as u64 != 3 * n
            || r.count.len() as u64 != n
        {
            return Err(BadResult::Lengths {
                width,
                height,
                sums: r.sum.len(),
                squares: r.sum_sq.len(),
                counts: r.count.len(),
            });
        }
        if r.sample_start > r.sample_end {
            return Err(BadResult::Backwards(r.sample_start, r.sample_end));
        }
        let lens = [
            r.aov_albedo.len(),
            r.aov_normal.len(),
            r.aov_depth.len(),
            r.aov_hits.len(),
            r.aov_count.len(),
        ];
        let aov = if lens == [0; 5] {
            None
        } else if lens.map(|l| l as u64) == [3 * n, 3 * n, n, n, n] {
            Some(Box::new(AovSums {
                albedo: triples(r.aov_albedo),
                normal: triples(r.aov_normal),
                depth: r.aov_depth,
                hits: r.aov_hits,
                count: r.aov_count,
            }))
        } else {
            return Err(BadResult::AovLengths {
                pixels: n,
                albedo: lens[0],
                normal: lens[1],
                depth: lens[2],
                hits: lens[3],
                count: lens[4],
            });
        };
        Ok(TileSums {
            rect,
            samples: r.sample_start..r.sample_end,
            sum: triples(r.sum),
            sum_sq: triples(r.sum_sq),
            count: r.count,
            nonfinite: r.nonfinite,
            aov,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strategies_and_rects_round_trip_and_unknown_values_are_errors() {
        for s in [Strategy::Mis, Strategy::Bsdf, Strategy::Nee] {
            assert_eq!(strategy_from_wire(pb::Strategy::from(s) as i32), Ok(s));
        }
        assert_eq!(strategy_from_wire(0), Ok(Strategy::Mis));
        assert_eq!(strategy_from_wire(99), Err(UnknownStrategy(99)));
        let r = PixelRect {
            x0: 1,
            y0: 2,
            width: 3,
            height: 4,
        };
        assert_eq!(PixelRect::from(pb::Rect::from(r)), r);
    }

    #[test]
    fn render_settings_round_trip_and_defaults_and_bad_values_are_named() {
        let s = RenderSettings {
            seed: 7,
            spp: 33,
            batch: 5,
            strategy: Strategy::Nee,
            ..RenderSettings::default()
        };
        let back = RenderSettings::try_from(&pb::RenderSettings::from(&s)).expect("round trip");
        assert_eq!(
            (back.seed, back.spp, back.batch, back.strategy),
            (7, 33, 5, Strategy::Nee)
        );
        let unset = RenderSettings::try_from(&pb::RenderSettings {
            spp: 1,
            ..Default::default()
        })
        .expect("defaults");
        assert_eq!((unset.batch, unset.strategy), (0, Strategy::Mis));
        let bad = |m: pb::RenderSettings| RenderSettings::try_from(&m).map(|_| ());
        assert_eq!(
            bad(pb::RenderSettings::default()),
            Err(BadSettings::NoSamples)
        );
        let big = pb::RenderSettings {
            spp: 1,
            batch: 70_000,
            ..Default::default()
        };
        assert_eq!(
            RenderSettings::try_from(&big)
                .map(|_| ())
                .map_err(|e| e.to_string()),
            Err("batch 70000 must be between 1 and 65536".to_string())
        );
        let unknown = pb::RenderSettings {
            spp: 1,
            strategy: 42,
            ..Default::default()
        };
        assert_eq!(
            bad(unknown),
            Err(BadSettings::Strategy(UnknownStrategy(42)))
        );
        assert_eq!(
            settings_from_wire(None).map(|_| ()),
            Err(BadSettings::Missing)
        );
    }

    #[test]
    fn tile_sums_round_trip_bit_exactly_and_bad_shapes_are_named() {
        let rect = PixelRect {
            x0: 2,
            y0: 1,
            width: 2,
            height: 3,
        };
        let mut t = TileSums::empty(rect, 4);
        t.samples = 4..8;
        for (i, s) in t.sum.iter_mut().enumerate() {
            *s = [i as f64 * 0.1, -0.0, f64::MIN_POSITIVE];
        }
        t.count[1] = 3;
        t.nonfinite = 1;
        let wire = pb::TileResult::from(&t);
        assert_eq!(TileSums::try_from(wire.clone()), Ok(t));
        let mut short = wire.clone();
        short.count.pop();
        let e = TileSums::try_from(short).expect_err("short");
        assert_eq!(
            e.to_string(),
            "result for a 2×3 rect has 18 sums, 18 squared sums and 5 counts (want 18, 18, 6)"
        );
        let backwards = pb::TileResult {
            sample_start: 9,
            ..wire.clone()
        };
        assert_eq!(
            TileSums::try_from(backwards),
            Err(BadResult::Backwards(9, 8))
        );
        let no_rect = pb::TileResult { rect: None, ..wire };
        assert_eq!(TileSums::try_from(no_rect), Err(BadResult::NoRect));
    }

    #[test]
    fn triples_are_the_flat_values_in_order_whatever_the_capacity() {
        let flat: Vec<f64> = (0..12).map(f64::from).collect();
        let at = flat.as_ptr() as usize;
        let moved = triples(flat);
        assert_eq!(
            moved.as_ptr() as usize,
            at,
            "a decoded array is moved, not copied"
        );
        assert_eq!(moved[3], [9.0, 10.0, 11.0]);
        let mut odd = Vec::with_capacity(7);
        odd.extend([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert_eq!(triples(odd), vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    }

    #[test]
    fn a_decoded_result_becomes_sums_without_a_copy() {
        use prost::Message;
        let rect = PixelRect {
            x0: 0,
            y0: 0,
            width: 37,
            height: 5,
        };
        let mut t = TileSums::empty(rect, 0);
        t.samples = 0..4;
        t.count.fill(4);
        let bytes = pb::TileResult::from(&t).encode_to_vec();
        let wire = pb::TileResult::decode(bytes.as_slice()).expect("decode");
        let (sum, sq) = (wire.sum.as_ptr() as usize, wire.sum_sq.as_ptr() as usize);
        let back = TileSums::try_from(wire).expect("valid");
        assert_eq!(back, t);
        assert_eq!(
            (back.sum.as_ptr() as usize, back.sum_sq.as_ptr() as usize),
            (sum, sq),
            "prost's packed arrays are moved into the sums"
        );
    }
}
