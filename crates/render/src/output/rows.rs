//! The OpenEXR writer, fed a strip of rows at a time: a frame's pixels are asked for block by
//! block, top to bottom, as the encoder compresses them, so writing a frame holds the strips a
//! block spans and the blocks in the compressor's queue, never the whole image or its planes.
//!
//! The file is the `exr` crate's own image writer's, byte for byte: the headers come from the
//! same inference over a layer with the same channels, attributes and encoding, and each
//! block's bytes are laid out as that writer lays them out (per line, each channel's samples
//! in the header's sorted channel order), so the same image gives the same file however it
//! is cut into strips. `tests::strips_give_the_image_writers_bytes` pins this.

use std::borrow::Borrow;
use std::collections::VecDeque;
use std::path::Path;

use exr::block::writer::ChunksWriter;
use exr::block::UncompressedBlock;
use exr::prelude::{
    AnyChannel, AnyChannels, AttributeValue, Encoding, FlatSamples, Layer, LayerAttributes, Text,
    WritableImage,
};

use super::{DenoisedPlanes, ExrChannels, OutputError};
use crate::film::Image;
use crate::util::files::{self, Access, Place};

/// [`super::write_exr`] of a `size.0` × `size.1` frame given as strips of whole rows, top to
/// bottom (as [`crate::film::Strips`] gives them), each taken when the encoder reaches it and
/// dropped once its rows are compressed, except that an existing file at `path` is left alone
/// and the call fails with [`std::io::ErrorKind::AlreadyExists`]: for a server that must never
/// replace a file someone else may rely on (another job's output, a file put there by hand). Fails, leaving no file, if the strips are not
/// `size.0` wide or do not add up to `size.1` rows: a caller whose strips stop early because
/// their source failed reports that failure first.
pub fn write_new_exr_strips<S: Borrow<Image>>(
    path: &Path,
    size: (u32, u32),
    channels: ExrChannels,
    metadata: &[(String, String)],
    strips: impl Iterator<Item = S>,
) -> Result<(), OutputError> {
    write(path, size, channels, metadata, strips, None, true)
}

/// [`write_new_exr_strips`] with the denoised layer ([`super::write_exr_with_denoised`]).
pub fn write_new_exr_strips_denoised<S: Borrow<Image>>(
    path: &Path,
    size: (u32, u32),
    channels: ExrChannels,
    metadata: &[(String, String)],
    strips: impl Iterator<Item = S>,
    denoised: &DenoisedPlanes,
) -> Result<(), OutputError> {
    write(path, size, channels, metadata, strips, Some(denoised), true)
}

/// One channel of the file, by what it holds.
#[derive(Clone, Copy)]
enum Plane {
    Rgb(usize),
    Variance(usize),
    Samples,
    Albedo(usize),
    Normal(usize),
    Depth,
    Denoised(usize),
    DenoisedAlbedo(usize),
    DenoisedNormal(usize),
}

/// Channel names: the beauty's, then the AOVs' as OpenEXR's conventions and Blender's passes
/// name them (`Z` is OpenEXR's standard name for depth), then the denoised layer with the
/// auxiliary images its filter used.
const NAMES: [(&str, Plane); 23] = [
    ("R", Plane::Rgb(0)),
    ("G", Plane::Rgb(1)),
    ("B", Plane::Rgb(2)),
    ("variance.R", Plane::Variance(0)),
    ("variance.G", Plane::Variance(1)),
    ("variance.B", Plane::Variance(2)),
    ("samples", Plane::Samples),
    ("albedo.R", Plane::Albedo(0)),
    ("albedo.G", Plane::Albedo(1)),
    ("albedo.B", Plane::Albedo(2)),
    ("normal.X", Plane::Normal(0)),
    ("normal.Y", Plane::Normal(1)),
    ("normal.Z", Plane::Normal(2)),
    ("Z", Plane::Depth),
    ("denoised.R", Plane::Denoised(0)),
    ("denoised.G", Plane::Denoised(1)),
    ("denoised.B", Plane::Denoised(2)),
    ("denoised.albedo.R", Plane::DenoisedAlbedo(0)),
    ("denoised.albedo.G", Plane::DenoisedAlbedo(1)),
    ("denoised.albedo.B", Plane::DenoisedAlbedo(2)),
    ("denoised.normal.X", Plane::DenoisedNormal(0)),
    ("denoised.normal.Y", Plane::DenoisedNormal(1)),
    ("denoised.normal.Z", Plane::DenoisedNormal(2)),
];

/// Writes the frame, with the denoised layer if `denoised` is given (whole-frame planes: a
/// denoiser sees the frame at once), replacing any file at `path` unless `no_clobber`.
pub(super) fn write<S: Borrow<Image>>(
    path: &Path,
    size: (u32, u32),
    channels: ExrChannels,
    metadata: &[(String, String)],
    strips: impl Iterator<Item = S>,
    denoised: Option<&DenoisedPlanes>,
    no_clobber: bool,
) -> Result<(), OutputError> {
    let exr_error = |message: String| OutputError::Exr {
        path: path.to_path_buf(),
        message,
    };
    if let Some(d) = denoised {
        check_denoised(d, size).map_err(exr_error)?;
    }
    let headers = headers(size, channels, denoised.is_some(), metadata);
    let planes = planes_of(&headers);
    let mut rows = Rows {
        strips,
        held: VecDeque::new(),
        end: 0,
        width: size.0,
        aov: channels.aovs.any(),
        problem: None,
    };
    let how = if no_clobber {
        Place::New
    } else {
        Place::Replace
    };
    let mut encoded: Option<exr::error::Error> = None;
    let placed = files::place(path, how, Access::Shared, |w| {
        let result = exr::block::write(w, headers, true, |meta, chunk_writer| {
            let list = meta.headers[0].channels.clone();
            let blocks = meta.collect_ordered_block_data(|index| {
                let top = index.pixel_position.y() as u32;
                rows.reach(top + index.pixel_size.height() as u32);
                rows.forget_above(top);
                UncompressedBlock::collect_block_data_from_lines(&list, index, |line| {
                    let y = line.location.position.y() as u32;
                    let plane = planes[line.location.channel];
                    // A row the strips did not reach stays zero; the write then fails below.
                    if let Some(row) = rows.row(y) {
                        write_line(line, plane, row, denoised, size.0);
                    }
                })
            });
            chunk_writer
                .on_progress(|_| ())
                .compress_all_blocks_parallel(&meta, blocks)
        });
        if let Err(e) = result {
            encoded = Some(e);
            return Err(std::io::Error::other("EXR encoding failed"));
        }
        let more = rows.strips.next().is_some_and(|s| s.borrow().height > 0);
        if rows.problem.is_none() && (rows.end != size.1 || more) {
            rows.problem = Some(format!(
                "the strips hold {}{} rows for a frame of {}",
                rows.end,
                if more { " and more" } else { "" },
                size.1
            ));
        }
        match &rows.problem {
            Some(p) => Err(std::io::Error::other(p.clone())),
            None => Ok(()),
        }
    });
    match (placed, encoded, rows.problem) {
        (Ok(()), _, _) => Ok(()),
        (Err(_), Some(e), _) => Err(exr_error(e.to_string())),
        (Err(_), None, Some(p)) => Err(exr_error(p)),
        (Err(source), None, None) => Err(OutputError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Each channel of the file's header, by what it holds.
fn planes_of(headers: &exr::meta::Headers) -> Vec<Plane> {
    let list = &headers[0].channels.list;
    let plane = |name: &exr::prelude::Text| {
        NAMES
            .iter()
            .find(|(n, _)| name.eq(n))
            .map(|(_, p)| *p)
            .expect("every channel is one of NAMES")
    };
    list.iter().map(|c| plane(&c.name)).collect()
}

/// One line of `plane`: from `row` (a strip and the index of the line's row in it) for the
/// strips' planes, from the whole `denoised` frame (`width` wide) by row and column for its.
fn write_line(
    line: exr::block::lines::LineRefMut<'_>,
    plane: Plane,
    (strip, first): (&Image, usize),
    denoised: Option<&DenoisedPlanes>,
    width: u32,
) {
    let (x0, y) = (line.location.position.x(), line.location.position.y());
    let at = |x: usize| first + x0 + x;
    let whole = |x: usize| y * width as usize + x0 + x;
    let _ = match (plane, &strip.aov, denoised) {
        (Plane::Rgb(c), _, _) => line.write_samples(|x| strip.rgb[at(x)][c]),
        (Plane::Variance(c), _, _) => line.write_samples(|x| strip.variance[at(x)][c]),
        (Plane::Samples, _, _) => line.write_samples(|x| strip.count[at(x)] as f32),
        (Plane::Albedo(c), Some(a), _) => line.write_samples(|x| a.albedo[at(x)][c]),
        (Plane::Normal(c), Some(a), _) => line.write_samples(|x| a.normal[at(x)][c]),
        (Plane::Depth, Some(a), _) => line.write_samples(|x| a.depth[at(x)]),
        (Plane::Denoised(c), _, Some(d)) => line.write_samples(|x| d.color[whole(x)][c]),
        (Plane::DenoisedAlbedo(c), _, Some(d)) => line.write_samples(|x| d.albedo[whole(x)][c]),
        (Plane::DenoisedNormal(c), _, Some(d)) => line.write_samples(|x| d.normal[whole(x)][c]),
        // A strip without AOV planes is refused when pulled (`reach`); denoised channels are
        // in the header only when the planes are given.
        _ => Ok(()),
    };
}

/// Refuses denoised planes that are not the frame's size.
fn check_denoised(d: &DenoisedPlanes, size: (u32, u32)) -> Result<(), String> {
    let n = size.0 as usize * size.1 as usize;
    let lens = [d.color.len(), d.albedo.len(), d.normal.len()];
    if lens == [n; 3] {
        return Ok(());
    }
    Err(format!(
        "the denoised planes hold {}, {} and {} pixels for a frame of {n}",
        lens[0], lens[1], lens[2]
    ))
}

/// The headers the `exr` crate's image writer gives a layer of these channels: inferred from a
/// layer whose planes are empty, since inference reads only the channels' names and types.
fn headers(
    size: (u32, u32),
    channels: ExrChannels,
    denoised: bool,
    metadata: &[(String, String)],
) -> exr::meta::Headers {
    let names = NAMES.iter().filter(|(_, p)| match p {
        Plane::Denoised(_) | Plane::DenoisedAlbedo(_) | Plane::DenoisedNormal(_) => denoised,
        Plane::Rgb(_) => true,
        Plane::Variance(_) => channels.variance,
        Plane::Samples => channels.samples,
        Plane::Albedo(_) => channels.aovs.albedo,
        Plane::Normal(_) => channels.aovs.normal,
        Plane::Depth => channels.aovs.depth,
    });
    let list: Vec<AnyChannel<FlatSamples>> = names
        .map(|(n, _)| AnyChannel::new(*n, FlatSamples::F32(Vec::new())))
        .collect();
    let mut attrs = LayerAttributes::default();
    let texts: Vec<Text> = metadata
        .iter()
        .filter_map(|(k, v)| Text::new_or_none(format!("{k}={v}")))
        .collect();
    if !texts.is_empty() {
        attrs
            .other
            .insert(Text::from("tessera"), AttributeValue::TextVector(texts));
    }
    let layer = Layer::new(
        (size.0 as usize, size.1 as usize),
        attrs,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list.into_iter().collect()),
    );
    exr::image::Image::from_layer(layer)
        .write()
        .infer_meta_data()
}

/// The strips the encoder's current block spans, pulled as it moves down the frame.
struct Rows<I, S> {
    strips: I,
    /// Strips still needed, each with its first row.
    held: VecDeque<(u32, S)>,
    /// The row below the last strip pulled.
    end: u32,
    width: u32,
    /// Whether the file has AOV channels, which every strip must then have planes for.
    aov: bool,
    /// Why the strips do not make the frame, once they are seen not to.
    problem: Option<String>,
}

impl<I: Iterator<Item = S>, S: Borrow<Image>> Rows<I, S> {
    /// Pulls strips until rows up to `bottom` are held (or the strips end).
    fn reach(&mut self, bottom: u32) {
        while self.end < bottom && self.problem.is_none() {
            let Some(strip) = self.strips.next() else {
                self.problem = Some(format!(
                    "the strips ended at row {} of a block reaching row {bottom}",
                    self.end
                ));
                return;
            };
            let s = strip.borrow();
            let n = s.width as usize * s.height as usize;
            if s.width != self.width
                || s.rgb.len() != n
                || s.variance.len() != n
                || s.count.len() != n
            {
                self.problem = Some(format!(
                    "a strip of {} × {} holding {}, {} and {} values, in a frame {} wide",
                    s.width,
                    s.height,
                    s.rgb.len(),
                    s.variance.len(),
                    s.count.len(),
                    self.width
                ));
                return;
            }
            let planes = s
                .aov
                .as_ref()
                .filter(|a| a.albedo.len() == n && a.normal.len() == n && a.depth.len() == n);
            if self.aov && planes.is_none() {
                self.problem = Some(format!(
                    "a strip of rows {}.. has no AOV planes for the file's AOV channels",
                    self.end
                ));
                return;
            }
            let h = s.height;
            self.held.push_back((self.end, strip));
            self.end += h;
        }
    }

    /// Drops the strips that end above row `top`.
    fn forget_above(&mut self, top: u32) {
        while let Some((y0, s)) = self.held.front() {
            if y0 + s.borrow().height > top {
                break;
            }
            self.held.pop_front();
        }
    }

    /// The strip holding row `y` and the index of the row's first pixel in it.
    fn row(&self, y: u32) -> Option<(&Image, usize)> {
        self.held.iter().find_map(|(y0, s)| {
            let s = s.borrow();
            (*y0 <= y && y < y0 + s.height).then(|| (s, ((y - y0) * s.width) as usize))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What `write_exr` wrote before it streamed: the `exr` crate's image writer over whole
    /// planes.
    fn image_writer_bytes(
        image: &Image,
        channels: ExrChannels,
        meta: &[(String, String)],
    ) -> Vec<u8> {
        let plane =
            |f: &dyn Fn(usize) -> f32| FlatSamples::F32((0..image.rgb.len()).map(f).collect());
        let mut list: Vec<AnyChannel<FlatSamples>> = vec![
            AnyChannel::new("R", plane(&|i| image.rgb[i][0])),
            AnyChannel::new("G", plane(&|i| image.rgb[i][1])),
            AnyChannel::new("B", plane(&|i| image.rgb[i][2])),
        ];
        if channels.variance {
            for (c, name) in ["variance.R", "variance.G", "variance.B"]
                .iter()
                .enumerate()
            {
                list.push(AnyChannel::new(*name, plane(&|i| image.variance[i][c])));
            }
        }
        if channels.samples {
            list.push(AnyChannel::new(
                "samples",
                plane(&|i| image.count[i] as f32),
            ));
        }
        if let Some(a) = &image.aov {
            for (c, axis) in ["R", "G", "B"].iter().enumerate() {
                if channels.aovs.albedo {
                    list.push(AnyChannel::new(
                        format!("albedo.{axis}").as_str(),
                        plane(&|i| a.albedo[i][c]),
                    ));
                }
            }
            for (c, axis) in ["X", "Y", "Z"].iter().enumerate() {
                if channels.aovs.normal {
                    list.push(AnyChannel::new(
                        format!("normal.{axis}").as_str(),
                        plane(&|i| a.normal[i][c]),
                    ));
                }
            }
            if channels.aovs.depth {
                list.push(AnyChannel::new("Z", plane(&|i| a.depth[i])));
            }
        }
        let mut attrs = LayerAttributes::default();
        let texts: Vec<Text> = meta
            .iter()
            .filter_map(|(k, v)| Text::new_or_none(format!("{k}={v}")))
            .collect();
        attrs
            .other
            .insert(Text::from("tessera"), AttributeValue::TextVector(texts));
        let layer = Layer::new(
            (image.width as usize, image.height as usize),
            attrs,
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(list.into_iter().collect()),
        );
        let mut out = std::io::Cursor::new(Vec::new());
        exr::image::Image::from_layer(layer)
            .write()
            .to_buffered(&mut out)
            .expect("encodes");
        out.into_inner()
    }

    fn image(width: u32, height: u32) -> Image {
        let n = (width * height) as usize;
        let f = |i: usize, c: usize| ((i * 7 + c * 13) % 101) as f32 / 7.0;
        Image {
            width,
            height,
            rgb: (0..n).map(|i| [f(i, 0), f(i, 1), f(i, 2)]).collect(),
            variance: (0..n).map(|i| [f(i, 3), f(i, 4), f(i, 5)]).collect(),
            count: (0..n).map(|i| (i % 5) as u32).collect(),
            nonfinite: 0,
            aov: Some(crate::film::AovPlanes {
                albedo: (0..n).map(|i| [f(i, 6), f(i, 7), f(i, 8)]).collect(),
                normal: (0..n).map(|i| [f(i, 9), -f(i, 10), f(i, 11)]).collect(),
                depth: (0..n)
                    .map(|i| if i % 9 == 0 { f32::INFINITY } else { f(i, 12) })
                    .collect(),
            }),
        }
    }

    /// The denoised layer goes in as given, its planes read by row and column from the
    /// whole frame whatever the strips, and planes not the frame's size are refused.
    #[test]
    fn the_denoised_layer_is_written_by_pixel_and_checked_for_size() {
        let dir = tempfile::tempdir().expect("tmp");
        let frame = image(9, 31);
        let n = 9 * 31;
        let plane = |k: f32| -> Vec<[f32; 3]> {
            (0..n)
                .map(|i| [i as f32 * k, 1.0 + k, -(i as f32)])
                .collect()
        };
        let d = DenoisedPlanes {
            color: plane(0.5),
            albedo: plane(0.25),
            normal: plane(-1.0),
        };
        let path = dir.path().join("d.exr");
        let strips = [rows_of(&frame, 0, 17), rows_of(&frame, 17, 31)];
        let channels = ExrChannels::default();
        write(&path, (9, 31), channels, &[], strips.iter(), Some(&d), true).expect("writes");
        for (name, plane, c) in [
            ("denoised.R", &d.color, 0),
            ("denoised.B", &d.color, 2),
            ("denoised.albedo.G", &d.albedo, 1),
            ("denoised.normal.Z", &d.normal, 2),
        ] {
            let got = super::super::read_exr_channel(&path, name).expect(name);
            let want: Vec<f32> = plane.iter().map(|p| p[c]).collect();
            assert_eq!(got, want, "{name}");
        }
        let short = DenoisedPlanes {
            albedo: plane(0.0)[1..].to_vec(),
            ..d
        };
        let path = dir.path().join("short.exr");
        let err = write(
            &path,
            (9, 31),
            channels,
            &[],
            strips.iter(),
            Some(&short),
            true,
        )
        .expect_err("short");
        assert!(err.to_string().contains("denoised planes hold"), "{err}");
        assert!(!path.exists());
    }

    fn rows_of(image: &Image, from: u32, to: u32) -> Image {
        let w = image.width as usize;
        let (a, b) = (from as usize * w, to as usize * w);
        Image {
            width: image.width,
            height: to - from,
            rgb: image.rgb[a..b].to_vec(),
            variance: image.variance[a..b].to_vec(),
            count: image.count[a..b].to_vec(),
            nonfinite: 0,
            aov: image.aov.as_ref().map(|p| crate::film::AovPlanes {
                albedo: p.albedo[a..b].to_vec(),
                normal: p.normal[a..b].to_vec(),
                depth: p.depth[a..b].to_vec(),
            }),
        }
    }

    #[test]
    fn strips_give_the_image_writers_bytes() {
        let dir = tempfile::tempdir().expect("tempdir");
        let meta = vec![("spp".to_string(), "4".to_string())];
        let frame = image(37, 53);
        for channels in [
            ExrChannels::default(),
            ExrChannels {
                variance: true,
                samples: true,
                ..ExrChannels::default()
            },
            ExrChannels {
                samples: true,
                aovs: crate::Aovs::ALL,
                ..ExrChannels::default()
            },
            ExrChannels {
                aovs: crate::Aovs {
                    normal: true,
                    ..crate::Aovs::default()
                },
                ..ExrChannels::default()
            },
        ] {
            let want = image_writer_bytes(&frame, channels, &meta);
            // Whole, in strips that end inside a 16-row block, of one row, and of 16.
            for cut in [53, 7, 1, 16] {
                let strips = (0..53u32)
                    .step_by(cut)
                    .map(|y| rows_of(&frame, y, (y + cut as u32).min(53)));
                let path = dir.path().join(format!(
                    "{cut}-{}-{}.exr",
                    channels.variance,
                    channels.aovs.list()
                ));
                write(&path, (37, 53), channels, &meta, strips, None, true).expect("writes");
                let got = std::fs::read(&path).expect("reads");
                assert!(
                    got == want,
                    "strips of {cut} rows, {channels:?}: other bytes"
                );
            }
        }
    }

    #[test]
    fn strips_that_do_not_make_the_frame_leave_no_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let frame = image(8, 40);
        let cases: Vec<(&str, Vec<Image>)> = vec![
            ("short", vec![rows_of(&frame, 0, 20)]),
            ("long", vec![frame.clone(), rows_of(&frame, 0, 3)]),
            ("narrow", vec![image(7, 40)]),
        ];
        for (name, strips) in cases {
            let path = dir.path().join(format!("{name}.exr"));
            let err = write(
                &path,
                (8, 40),
                ExrChannels::default(),
                &[],
                strips.into_iter(),
                None,
                true,
            )
            .expect_err(name);
            assert!(err.to_string().contains("strip"), "{name}: {err}");
            assert!(!path.exists(), "{name}: a file was left");
            assert_eq!(
                std::fs::read_dir(dir.path()).expect("dir").count(),
                0,
                "{name}"
            );
        }
    }
}
