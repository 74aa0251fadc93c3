//! What the dashboard's preview reads of a job: its phase and size, the per-tile noise kept at
//! its end, and each tile's means as memory holds them (full sums, or only the preview-sized
//! [`Thumb`] once the sums have left for the store). The preview copies these out a few tiles
//! per hold of the scheduler's lock; how it draws them is its own.

use tessera_render::{PixelRect, TileSums};

use super::{relative_noise, Job, Thumb};
use crate::store::JobPhase;

/// A job as a preview starts from it.
#[derive(Clone, Debug)]
pub struct PreviewSource {
    /// Running, done (its EXR holds the frame), or ended without one.
    pub phase: JobPhase,
    /// The frame's size in pixels.
    pub width: u32,
    /// The frame's height in pixels.
    pub height: u32,
    /// Its tiles, each read by [`Job::preview_tile`].
    pub tiles: u32,
    /// The name of its EXR in the output folder.
    pub output: String,
    /// Per tile, its rectangle and relative noise when it ended (empty while it runs, or
    /// where the noise was not kept).
    pub kept_noise: Vec<(PixelRect, f32)>,
    /// How it asked to be denoised (`submit --denoise`), if it did.
    pub denoise: Option<crate::store::DenoiseRecord>,
}

/// One tile's means as memory holds them.
pub enum TileMeans<'a> {
    /// No result merged yet.
    Empty,
    /// Its full sums.
    Sums(&'a TileSums),
    /// Its sums are in the store; what stays is their means at the preview's resolution.
    Thumb(&'a Thumb),
}

impl Job {
    /// What changes whenever the preview would: its phase and the units merged.
    pub fn preview_version(&self) -> (JobPhase, u64) {
        (self.rec.phase, self.units_done)
    }

    /// The job as a preview starts from it.
    pub fn preview_source(&self) -> PreviewSource {
        let kept_noise = (self.final_tile_noise.iter().flatten().enumerate())
            .filter_map(|(t, &rel)| Some((self.tiles.get(t as u32)?, rel)))
            .collect();
        PreviewSource {
            phase: self.rec.phase,
            width: self.rec.width,
            height: self.rec.height,
            tiles: self.tiles.len() as u32,
            output: self.rec.output_name.clone(),
            denoise: self.rec.denoise.clone(),
            kept_noise,
        }
    }

    /// Tile `t`'s rectangle, relative noise (NaN without samples) and means; `None` past the
    /// last tile.
    pub fn preview_tile(&self, t: u32) -> Option<(PixelRect, f32, TileMeans<'_>)> {
        let rect = self.tiles.get(t)?;
        let acc = self.acc.get(&t);
        let rel = relative_noise(acc.map(|a| a.noise).unwrap_or_default());
        let means = match acc {
            Some(a) => match (&a.sums, &a.thumb) {
                (Some(s), _) => TileMeans::Sums(s),
                (None, Some(thumb)) => TileMeans::Thumb(thumb),
                (None, None) => TileMeans::Empty,
            },
            None => TileMeans::Empty,
        };
        Some((rect, rel, means))
    }
}
