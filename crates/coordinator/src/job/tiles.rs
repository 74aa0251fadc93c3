//! A job's tiles as arithmetic, and the bounds a result's sums must keep to before they are
//! merged into them.

use tessera_render::film::AovSums;
use tessera_render::{PixelRect, TileSums};

/// A job's tiles, row-major, as arithmetic: a rectangle is computed when asked for, so a job
/// of millions of tiles costs nothing at admission (or at a restart) for tiles not yet
/// rendered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGrid {
    width: u32,
    height: u32,
    size: u32,
    cols: u32,
    rows: u32,
}

impl TileGrid {
    /// The grid [`PixelRect::tiles`] cuts a `width` × `height` image into.
    pub fn new(width: u32, height: u32, size: u32) -> Self {
        let size = size.max(1);
        Self {
            width,
            height,
            size,
            cols: width.div_ceil(size),
            rows: height.div_ceil(size),
        }
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.cols as usize * self.rows as usize
    }

    /// Whether the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Tile `i`'s rectangle, if there is such a tile.
    pub fn get(&self, i: u32) -> Option<PixelRect> {
        if i as usize >= self.len() {
            return None;
        }
        let (x0, y0) = ((i % self.cols) * self.size, (i / self.cols) * self.size);
        Some(PixelRect {
            x0,
            y0,
            width: self.size.min(self.width - x0),
            height: self.size.min(self.height - y0),
        })
    }
}

/// Whether one pixel's sums could come from `k` finite samples. The renderer's samples are
/// f32, so each adds at most `f32::MAX` to a sum and `f32::MAX²` to a squared sum: a result
/// inside these bounds cannot overflow an f64 total however many batches are merged, since a
/// pixel has at most `u32::MAX` samples. Forged finite values near `f64::MAX` are refused
/// here, before they can add up to infinity.
pub fn pixel_in_range(sum: &[f64; 3], sum_sq: &[f64; 3], k: u32) -> bool {
    let max = f32::MAX as f64;
    let k = k as f64;
    sum.iter().all(|v| (0.0..=k * max).contains(v))
        && sum_sq.iter().all(|v| (0.0..=k * max * max).contains(v))
}

/// [`pixel_in_range`] for every pixel of a tile's sums.
pub fn sums_in_range(t: &TileSums) -> bool {
    t.sum
        .iter()
        .zip(&t.sum_sq)
        .zip(&t.count)
        .all(|((s, q), k)| pixel_in_range(s, q, *k))
}

/// Why a result's AOV sums cannot be `per_pixel` samples' of AOVs: each pixel's albedo
/// within [0, count] (an albedo is in [0, 1]), each normal component within [−count, count],
/// depth within [0, hits × f32::MAX], hits at most count and count at most `per_pixel`.
/// Whether the job asks for AOVs at all is the caller's to check.
pub fn check_aov_sums(a: &AovSums, per_pixel: u64) -> Result<(), String> {
    let max = f64::from(f32::MAX);
    for i in 0..a.count.len() {
        let (k, h) = (f64::from(a.count[i]), f64::from(a.hits[i]));
        let ok = u64::from(a.count[i]) <= per_pixel
            && a.hits[i] <= a.count[i]
            && a.albedo[i].iter().all(|v| (0.0..=k).contains(v))
            && a.normal[i].iter().all(|v| (-k..=k).contains(v))
            && (0.0..=h * max).contains(&a.depth[i]);
        if !ok {
            return Err(format!(
                "pixel {i}'s AOV sums (albedo {:?}, normal {:?}, depth {}, {} hits of {} samples) \
                 are not what {per_pixel} samples can give",
                a.albedo[i], a.normal[i], a.depth[i], a.hits[i], a.count[i]
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tile_grid_matches_pixel_rect_tiles() {
        for (w, h, size) in [
            (1, 1, 4),
            (17, 5, 4),
            (64, 64, 16),
            (100, 3, 7),
            (3, 100, 128),
        ] {
            let grid = TileGrid::new(w, h, size);
            let all = PixelRect::tiles(w, h, size);
            assert_eq!(grid.len(), all.len());
            for (i, r) in all.iter().enumerate() {
                assert_eq!(grid.get(i as u32), Some(*r), "{w}×{h}/{size} tile {i}");
            }
            assert_eq!(grid.get(all.len() as u32), None);
        }
    }
}
