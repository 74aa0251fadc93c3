//! A finished frame as strips of whole rows, built from its tiles one at a time, so that the
//! farm can write a frame of any size with memory for one band of tiles rather than the whole
//! image.
//!
//! The invariant: every pixel of a strip is the pixel [`TileSums::finalize`] gives its tile,
//! and black where no tile covers it, exactly as finalizing the assembled frame would give it
//! (each pixel's mean and variance are arithmetic on its own sums alone, so where the
//! finalizing happens changes no bit). Tiles must come sorted by their top row, as a tile grid
//! lists them row-major: then once a tile starting at row `y` arrives, no later tile touches a
//! row above `y`, and those rows can leave as a finished strip.

use super::{AovPlanes, Image, MergeError, PixelRect, TileSums};

/// The rows of a frame, top to bottom, from its tiles in row-major order: an iterator of
/// strips, each `width` pixels wide, whose heights add up to the frame's. A tile that does not
/// fit the render (its samples, its rectangle, its arrays) or comes out of order ends the
/// iteration with the error.
pub struct Strips<I> {
    tiles: I,
    width: u32,
    height: u32,
    /// The sample range every tile must cover, or (adaptive) start at and stay within.
    samples: std::ops::Range<u32>,
    adaptive: bool,
    /// Whether the render has AOVs: every tile must have their sums, or none may.
    aov: bool,
    /// Rows `top..top + buf.height` of the frame, with the tiles taken so far.
    top: u32,
    buf: Image,
    /// A tile that starts below the buffer, kept while the rows above it leave.
    next: Option<TileSums>,
    done: bool,
}

impl<I: Iterator<Item = TileSums>> Strips<I> {
    /// The strips of a render with `settings`, `width` × `height`, from `tiles`.
    pub fn new(
        settings: &crate::RenderSettings,
        width: u32,
        height: u32,
        tiles: impl IntoIterator<IntoIter = I>,
    ) -> Self {
        Self {
            tiles: tiles.into_iter(),
            width,
            height,
            samples: 0..settings.spp,
            adaptive: settings.adaptive.is_some(),
            aov: settings.aovs.any(),
            top: 0,
            buf: empty(width, 0, settings.aovs.any()),
            next: None,
            done: false,
        }
    }

    fn check(&self, tile: &TileSums) -> Result<(), MergeError> {
        if tile.aov.is_some() != self.aov {
            return Err(MergeError::Aov);
        }
        let fits = if self.adaptive {
            tile.samples.start == self.samples.start && tile.samples.end <= self.samples.end
        } else {
            tile.samples == self.samples
        };
        if !fits {
            return Err(MergeError::Order {
                have: self.samples.clone(),
                got: tile.samples.clone(),
            });
        }
        let t = tile.rect;
        let below = t.y0 < self.top;
        if below
            || t.x0 as u64 + t.width as u64 > self.width as u64
            || t.y0 as u64 + t.height as u64 > self.height as u64
        {
            // Above the rows still open: out of row-major order, or outside the frame.
            return Err(MergeError::Rect {
                expected: PixelRect {
                    x0: 0,
                    y0: self.top,
                    width: self.width,
                    height: self.height - self.top.min(self.height),
                },
                got: t,
            });
        }
        tile.check_shape()
    }

    /// Puts `tile`'s finished pixels into the buffer, growing it down to the tile's bottom.
    fn insert(&mut self, tile: TileSums) {
        let t = tile.rect;
        let bottom = t.y0 + t.height - self.top;
        if bottom > self.buf.height {
            grow(&mut self.buf, bottom);
        }
        let part = tile.finalize();
        drop(tile);
        let width = self.width;
        for row in 0..t.height {
            let src = (row * t.width) as usize;
            let dst = ((t.y0 - self.top + row) * width + t.x0) as usize;
            let w = t.width as usize;
            self.buf.rgb[dst..dst + w].copy_from_slice(&part.rgb[src..src + w]);
            self.buf.variance[dst..dst + w].copy_from_slice(&part.variance[src..src + w]);
            self.buf.count[dst..dst + w].copy_from_slice(&part.count[src..src + w]);
            if let (Some(to), Some(from)) = (&mut self.buf.aov, &part.aov) {
                to.copy(dst, from, src, w);
            }
        }
        self.buf.nonfinite += part.nonfinite;
    }

    /// The buffer's first `rows` rows (black below what it holds), leaving the rest.
    fn take(&mut self, rows: u32) -> Image {
        if rows > self.buf.height {
            grow(&mut self.buf, rows);
        }
        let rest = if rows == self.buf.height {
            empty(self.width, 0, self.aov)
        } else {
            let at = (rows * self.width) as usize;
            Image {
                width: self.width,
                height: self.buf.height - rows,
                rgb: self.buf.rgb.split_off(at),
                variance: self.buf.variance.split_off(at),
                count: self.buf.count.split_off(at),
                nonfinite: 0,
                aov: self.buf.aov.as_mut().map(|a| a.split_off(at)),
            }
        };
        let mut strip = std::mem::replace(&mut self.buf, rest);
        strip.height = rows;
        self.top += rows;
        strip
    }
}

impl<I: Iterator<Item = TileSums>> Iterator for Strips<I> {
    type Item = Result<Image, MergeError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done || self.top >= self.height {
            return None;
        }
        loop {
            let tile = match self.next.take().or_else(|| self.tiles.next()) {
                Some(t) => t,
                None => {
                    // Every tile is in: the rest of the frame leaves at once.
                    self.done = true;
                    return Some(Ok(self.take(self.height - self.top)));
                }
            };
            if let Err(e) = self.check(&tile) {
                self.done = true;
                return Some(Err(e));
            }
            if tile.rect.y0 > self.top {
                // No later tile reaches above this one's top row: the rows up to it are done.
                let rows = tile.rect.y0 - self.top;
                self.next = Some(tile);
                return Some(Ok(self.take(rows)));
            }
            self.insert(tile);
        }
    }
}

fn empty(width: u32, height: u32, aov: bool) -> Image {
    let n = width as usize * height as usize;
    Image {
        width,
        height,
        rgb: vec![[0.0; 3]; n],
        variance: vec![[0.0; 3]; n],
        count: vec![0; n],
        nonfinite: 0,
        aov: aov.then(|| {
            let mut planes = AovPlanes::default();
            planes.resize(n);
            planes
        }),
    }
}

fn grow(image: &mut Image, rows: u32) {
    let n = image.width as usize * rows as usize;
    image.rgb.resize(n, [0.0; 3]);
    image.variance.resize(n, [0.0; 3]);
    image.count.resize(n, 0);
    if let Some(a) = &mut image.aov {
        a.resize(n);
    }
    image.height = rows;
}

/// The finished image of a render with `settings` from its tiles, in row-major order: the
/// same pixels as [`crate::assemble_render`]'s frame finalized, with the same checks of each
/// tile, built from [`Strips`] without a frame of sums beside the tiles. Writing a large frame
/// takes the strips themselves ([`crate::output::write_new_exr_strips`]) and never holds the image.
pub fn assemble_image(
    settings: &crate::RenderSettings,
    width: u32,
    height: u32,
    tiles: impl IntoIterator<Item = TileSums>,
) -> Result<Image, MergeError> {
    let mut image = empty(width, 0, settings.aovs.any());
    for strip in Strips::new(settings, width, height, tiles) {
        image.append(&strip?);
    }
    if image.height != height {
        // Only a zero-width frame has no rows to give.
        grow(&mut image, height);
    }
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile(rect: PixelRect, spp: u32, value: f64) -> TileSums {
        let mut t = TileSums::empty(rect, 0);
        t.samples = 0..spp;
        for (i, (s, k)) in t.sum.iter_mut().zip(&mut t.count).enumerate() {
            *k = spp;
            *s = [value + i as f64, 0.0, 1.0];
        }
        t
    }

    fn settings(spp: u32) -> crate::RenderSettings {
        crate::RenderSettings {
            spp,
            ..crate::RenderSettings::default()
        }
    }

    #[test]
    fn strips_leave_a_band_at_a_time_and_add_up_to_the_frame() {
        // 10 × 7 in tiles of 4: bands of rows 0..4 and 4..7, three tiles each.
        let rects = PixelRect::tiles(10, 7, 4);
        let tiles: Vec<_> = rects.iter().map(|r| tile(*r, 2, r.x0 as f64)).collect();
        let strips: Vec<Image> = Strips::new(&settings(2), 10, 7, tiles.clone())
            .collect::<Result<_, _>>()
            .expect("fits");
        assert_eq!(
            strips.iter().map(|s| s.height).collect::<Vec<_>>(),
            vec![4, 3]
        );
        assert!(strips
            .iter()
            .all(|s| s.width == 10 && s.rgb.len() == 10 * s.height as usize));
        let whole = assemble_image(&settings(2), 10, 7, tiles).expect("fits");
        assert_eq!(whole.rgb.len(), 70);
        // Pixel (5, 6) is in tile (4, 4), at its row 2, column 1.
        let want = (4.0 + (2 * 4 + 1) as f64) / 2.0;
        assert_eq!(whole.rgb[6 * 10 + 5][0], want as f32);
    }

    #[test]
    fn rows_no_tile_covers_are_black_and_out_of_order_tiles_are_refused() {
        let rects = PixelRect::tiles(8, 8, 4);
        // Only the last tile: rows 0..4 leave black, then the last band.
        let last = tile(rects[3], 1, 1.0);
        let image = assemble_image(&settings(1), 8, 8, vec![last.clone()]).expect("fits");
        assert!(image.rgb[..32].iter().all(|p| *p == [0.0; 3]));
        assert_eq!(image.count[4 * 8 + 4], 1);
        // The bottom band before the top one: the frame's rows above are gone by then.
        let first = tile(rects[0], 1, 1.0);
        let err = assemble_image(&settings(1), 8, 8, vec![last, first]).expect_err("out of order");
        assert!(matches!(err, MergeError::Rect { .. }), "{err}");
        // Nothing at all: a black frame of the right size.
        let black = assemble_image(&settings(1), 8, 8, Vec::new()).expect("fits");
        assert_eq!((black.height, black.rgb.len()), (8, 64));
    }
}
