//! Image output: OpenEXR (the product) and an optional PNG preview.

use std::path::{Path, PathBuf};

use exr::prelude::{
    read_first_rgba_layer_from_file, AttributeValue, ReadChannels, ReadLayers, Text,
};

use crate::film::Image;
use crate::util::files::{self, Access, Place};

mod rows;

pub use rows::{write_new_exr_strips, write_new_exr_strips_denoised};

/// Errors writing or reading images.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Filesystem error.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// EXR encoding or decoding error.
    #[error("{path}: EXR: {message}")]
    Exr {
        /// File.
        path: PathBuf,
        /// Cause.
        message: String,
    },
    /// PNG encoding error.
    #[error("{path}: PNG: {message}")]
    Png {
        /// File.
        path: PathBuf,
        /// Cause.
        message: String,
    },
}

/// Which extra channels to write besides R, G, B.
#[derive(Clone, Copy, Debug, Default)]
pub struct ExrChannels {
    /// `variance.R`, `variance.G`, `variance.B`: the variance of each pixel's mean.
    pub variance: bool,
    /// `samples`: the sample count per pixel.
    pub samples: bool,
    /// The AOVs' channels ([`crate::settings::Aovs`]): `albedo.R/G/B`, `normal.X/Y/Z`, `Z`.
    pub aovs: crate::settings::Aovs,
}

/// The header metadata of a render: everything that decides its pixels. The local renderer and
/// the farm both write exactly this, so the same job gives the same file bytes either way.
pub fn render_metadata(
    scene_hash: &str,
    settings: &crate::RenderSettings,
) -> Vec<(String, String)> {
    let mut meta = vec![
        ("scene_sha256".to_string(), scene_hash.to_string()),
        ("spp".to_string(), settings.spp.to_string()),
        ("seed".to_string(), settings.seed.to_string()),
        ("batch".to_string(), settings.batch.to_string()),
        ("strategy".to_string(), settings.strategy.name().to_string()),
    ];
    // Only an adaptive render names its target and tiles, so the header (and the bytes) of
    // every other render stay what they were.
    if let Some(f) = settings.frame {
        meta.push(("frame".to_string(), f.to_string()));
    }
    if let Some(a) = settings.adaptive {
        meta.push(("noise_target".to_string(), a.noise_target.to_string()));
        meta.push(("adaptive_tile".to_string(), a.tile.to_string()));
    }
    if settings.aovs.any() {
        meta.push(("aovs".to_string(), settings.aovs.list()));
    }
    if settings.guiding {
        meta.push(("guiding".to_string(), "sd-tree".to_string()));
    }
    meta.push((
        "renderer".to_string(),
        format!(
            "tessera {} image revision {}",
            env!("CARGO_PKG_VERSION"),
            crate::IMAGE_REVISION
        ),
    ));
    meta
}

/// Writes `image` as a float32 OpenEXR file, atomically (a temporary file in the same
/// directory, then a rename), so a reader never sees a half-written frame.
///
/// `metadata` pairs go into one `tessera` text-vector header attribute as `key=value`. One
/// attribute, because the `exr` crate keeps custom attributes in a hash map whose order varies
/// between processes, and the same job must give the same file bytes.
pub fn write_exr(
    path: &Path,
    image: &Image,
    channels: ExrChannels,
    metadata: &[(String, String)],
) -> Result<(), OutputError> {
    write_whole(path, image, channels, metadata, None)
}

/// A denoised frame: what `tessera render --denoise` adds to its EXR as the `denoised` layer
/// (`denoised.R/G/B`), with the auxiliary images the filter used (`denoised.albedo.R/G/B`,
/// `denoised.normal.X/Y/Z`). Row-major, the frame's size.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DenoisedPlanes {
    /// The denoised beauty.
    pub color: Vec<[f32; 3]>,
    /// The albedo the filter used.
    pub albedo: Vec<[f32; 3]>,
    /// The normal the filter used.
    pub normal: Vec<[f32; 3]>,
}

/// [`write_exr`] with the denoised layer after the image's own channels; the beauty and every
/// other channel are written exactly as [`write_exr`] writes them.
pub fn write_exr_with_denoised(
    path: &Path,
    image: &Image,
    channels: ExrChannels,
    metadata: &[(String, String)],
    denoised: &DenoisedPlanes,
) -> Result<(), OutputError> {
    write_whole(path, image, channels, metadata, Some(denoised))
}

/// A whole frame to a file, replacing any there.
fn write_whole(
    path: &Path,
    image: &Image,
    channels: ExrChannels,
    metadata: &[(String, String)],
    denoised: Option<&DenoisedPlanes>,
) -> Result<(), OutputError> {
    let size = (image.width, image.height);
    let frame = std::iter::once(image);
    rows::write(path, size, channels, metadata, frame, denoised, false)
}

/// An RGB float image read from an EXR file.
#[derive(Clone, Debug)]
pub struct RgbImage {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Pixels, row-major, row 0 at the top.
    pub rgb: Vec<[f32; 3]>,
}

/// Reads the R, G, B channels of the first layer of an EXR file.
pub fn read_exr_rgb(path: &Path) -> Result<RgbImage, OutputError> {
    let img = read_first_rgba_layer_from_file(
        path,
        |res, _| (res.width(), vec![[0f32; 3]; res.width() * res.height()]),
        |(w, px), pos, (r, g, b, _a): (f32, f32, f32, f32)| px[pos.y() * *w + pos.x()] = [r, g, b],
    )
    .map_err(|e| OutputError::Exr {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let size = img.layer_data.size;
    let (_, rgb) = img.layer_data.channel_data.pixels;
    Ok(RgbImage {
        width: size.width(),
        height: size.height(),
        rgb,
    })
}

/// The channel `name` of an EXR file's first layer (`R`, `albedo.G`, `Z`, …) as f32s,
/// row-major: how a pipeline tool (or a test) reads one AOV back. A channel that is not there
/// is an error naming the ones that are.
pub fn read_exr_channel(path: &Path, name: &str) -> Result<Vec<f32>, OutputError> {
    let exr_error = |message: String| OutputError::Exr {
        path: path.to_path_buf(),
        message,
    };
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| exr_error(e.to_string()))?;
    let channels = &image.layer_data.channel_data.list;
    let channel = channels.iter().find(|c| c.name.eq(name)).ok_or_else(|| {
        let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
        exr_error(format!("no channel {name:?} (it has {})", names.join(", ")))
    })?;
    Ok(channel.sample_data.values_as_f32().collect())
}

/// How a PNG preview maps radiance to display values.
#[derive(Clone, Copy, Debug)]
pub struct Preview {
    /// Exposure in stops (multiplies radiance by 2^exposure).
    pub exposure: f32,
}

/// Writes an 8-bit sRGB PNG preview: exposure, then the ACES filmic curve (Narkowicz's fit),
/// then the sRGB transfer function.
pub fn write_png_preview(path: &Path, image: &Image, preview: Preview) -> Result<(), OutputError> {
    write_png(path, (image.width, image.height), &image.rgb, preview)
}

/// [`write_png_preview`] of an image read from an EXR file ([`read_exr_rgb`]): the same PNG a
/// render of it with `--preview` writes (`tessera preview`, `fetch --preview`).
pub fn write_png_of_exr(
    path: &Path,
    image: &RgbImage,
    preview: Preview,
) -> Result<(), OutputError> {
    let size = |n: usize| {
        u32::try_from(n).map_err(|_| OutputError::Png {
            path: path.to_path_buf(),
            message: format!("an image {n} pixels wide or high is too large for a PNG"),
        })
    };
    write_png(
        path,
        (size(image.width)?, size(image.height)?),
        &image.rgb,
        preview,
    )
}

/// The PNG of `rgb`, `width` × `height` pixels row-major, tone-mapped as previews are.
fn write_png(
    path: &Path,
    (width, height): (u32, u32),
    rgb: &[[f32; 3]],
    preview: Preview,
) -> Result<(), OutputError> {
    let io = |source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut encoded: Option<png::EncodingError> = None;
    let mut png_step = |r: Result<(), png::EncodingError>| {
        r.map_err(|e| {
            let io = std::io::Error::other(e.to_string());
            encoded = Some(e);
            io
        })
    };
    let placed = files::place(path, Place::Replace, Access::Shared, |w| {
        let mut enc = png::Encoder::new(w, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = match enc.write_header() {
            Ok(writer) => writer,
            Err(e) => return png_step(Err(e)),
        };
        png_step(writer.write_image_data(&tone_map(rgb, preview)))?;
        png_step(writer.finish())
    });
    match (placed, encoded) {
        (Ok(()), _) => Ok(()),
        (Err(_), Some(e)) => Err(OutputError::Png {
            path: path.to_path_buf(),
            message: e.to_string(),
        }),
        (Err(source), None) => Err(io(source)),
    }
}

/// 8-bit sRGB values (R, G, B per pixel) of linear radiance, as previews show it: exposure,
/// then the ACES filmic curve (Narkowicz's fit), then the sRGB transfer function. The farm's
/// dashboard maps its previews with this too, so they show what `--preview` would.
pub fn tone_map(rgb: &[[f32; 3]], preview: Preview) -> Vec<u8> {
    let scale = preview.exposure.exp2();
    let codes = Srgb8::get();
    let mut out = Vec::with_capacity(rgb.len() * 3);
    for p in rgb {
        for c in p {
            out.push(codes.code(aces(c * scale)));
        }
    }
    out
}

/// Buckets of [0, 1] for [`Srgb8`]: fine enough that a bucket spans at most a few codes.
const BUCKETS: usize = 4096;

/// [`to_srgb8`] without its `powf`, which was most of a preview's cost (a dashboard encodes
/// previews many times a second): `bounds[k]` is the least `x` in [0, 1] that [`to_srgb8`]
/// maps to more than `k`, and `start[i]` the code at the start of bucket `i`. The code of `x`
/// is the number of bounds at or below it, since [`to_srgb8`] never decreases; counting on
/// from its bucket's start takes a step or two.
struct Srgb8 {
    bounds: [f32; 255],
    start: [u8; BUCKETS],
}

impl Srgb8 {
    fn get() -> &'static Self {
        static TABLE: std::sync::OnceLock<Srgb8> = std::sync::OnceLock::new();
        TABLE.get_or_init(|| {
            let bounds: [f32; 255] = std::array::from_fn(|k| {
                // The least f32 bit pattern in [0, 1] whose code exceeds k: non-negative
                // floats order as their bits do.
                let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
                while lo < hi {
                    let mid = lo + (hi - lo) / 2;
                    if to_srgb8(f32::from_bits(mid)) as usize > k {
                        hi = mid;
                    } else {
                        lo = mid + 1;
                    }
                }
                f32::from_bits(lo)
            });
            let start = std::array::from_fn(|i| {
                let x = i as f32 / BUCKETS as f32;
                bounds.partition_point(|&b| b <= x) as u8
            });
            Srgb8 { bounds, start }
        })
    }

    /// The code of `x` in [0, 1] (as [`aces`] gives).
    fn code(&self, x: f32) -> u8 {
        let i = ((x * BUCKETS as f32) as usize).min(BUCKETS - 1);
        let mut k = self.start[i] as usize;
        while k < 255 && self.bounds[k] <= x {
            k += 1;
        }
        k as u8
    }
}

fn aces(x: f32) -> f32 {
    let x = if x.is_finite() { x.max(0.0) } else { 0.0 };
    ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0)
}

fn to_srgb8(x: f32) -> u8 {
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// One line saying where an EXR file came from, for reports that compare against it: tessera's
/// own metadata when it has them, else its standard `comments` and `software` attributes and
/// `generatedBy` (which Mitsuba writes). `None` when the file says nothing of its origin.
pub fn read_exr_provenance(path: &Path) -> Result<Option<String>, OutputError> {
    let meta = read_exr_header(path)?;
    let tessera = tessera_attribute(&meta);
    if !tessera.is_empty() {
        return Ok(Some(format!("tessera render: {}", tessera.join(", "))));
    }
    let mut parts: Vec<String> = Vec::new();
    let mut add = |t: &Text| {
        let t = t.to_string();
        if !t.is_empty() && !parts.contains(&t) {
            parts.push(t);
        }
    };
    for h in &meta.headers {
        let own = &h.own_attributes;
        own.comments
            .iter()
            .chain(&own.software_name)
            .for_each(&mut add);
        for other in [&own.other, &h.shared_attributes.other] {
            if let Some(AttributeValue::Text(t)) = other.get(&Text::from("generatedBy")) {
                add(t);
            }
        }
    }
    Ok((!parts.is_empty()).then(|| parts.join("; ")))
}

/// Reads the `tessera` metadata attribute of an EXR file as `key=value` strings.
pub fn read_exr_metadata(path: &Path) -> Result<Vec<String>, OutputError> {
    Ok(tessera_attribute(&read_exr_header(path)?))
}

fn read_exr_header(path: &Path) -> Result<exr::meta::MetaData, OutputError> {
    exr::meta::MetaData::read_from_file(path, false).map_err(|e| OutputError::Exr {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// The `key=value` strings of every header's `tessera` attribute.
fn tessera_attribute(meta: &exr::meta::MetaData) -> Vec<String> {
    let mut out = Vec::new();
    for h in &meta.headers {
        if let Some(AttributeValue::TextVector(v)) =
            h.own_attributes.other.get(&Text::from("tessera"))
        {
            out.extend(v.iter().map(|t| t.to_string()));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    /// The table gives `to_srgb8`'s own code: at every bound and 2048 floats either side of
    /// it, around the curve's junction, at every bucket's edge, and at every 61st float of
    /// [0, 1].
    #[test]
    fn srgb8_by_bounds_is_to_srgb8() {
        let table = Srgb8::get();
        let check = |bits: u32| {
            let x = f32::from_bits(bits);
            assert_eq!(table.code(x), to_srgb8(x), "x = {x:e} ({bits:#x})");
        };
        let one = 1.0f32.to_bits();
        for b in &table.bounds {
            let c = b.to_bits();
            for bits in c.saturating_sub(2048)..=(c + 2048).min(one) {
                check(bits);
            }
        }
        let junction = 0.003_130_8f32.to_bits();
        for bits in junction - (1 << 16)..junction + (1 << 16) {
            check(bits);
        }
        for bits in (0..=one).step_by(61) {
            check(bits);
        }
        for i in 0..=BUCKETS {
            check((i as f32 / BUCKETS as f32).to_bits());
        }
        assert_eq!(table.code(0.0), 0);
        assert_eq!(table.code(1.0), 255);
    }

    #[test]
    fn provenance_names_tessera_mitsuba_or_nothing() {
        let dir = std::env::temp_dir().join(format!("tessera-prov-{}", std::process::id()));
        fs::create_dir_all(&dir).expect("tmp");
        let img = Image {
            width: 2,
            height: 1,
            rgb: vec![[0.5; 3]; 2],
            variance: vec![[0.0; 3]; 2],
            count: vec![1; 2],
            nonfinite: 0,
            aov: None,
        };
        let settings = crate::RenderSettings::default();
        let ours = dir.join("ours.exr");
        let meta = render_metadata("abc", &settings);
        write_exr(&ours, &img, ExrChannels::default(), &meta).expect("write");
        let bare = dir.join("bare.exr");
        write_exr(&bare, &img, ExrChannels::default(), &[]).expect("write");
        let (ours, bare) = (read_exr_provenance(&ours), read_exr_provenance(&bare));
        fs::remove_dir_all(&dir).ok();
        let ours = ours.expect("read").expect("tessera's metadata");
        assert!(
            ours.starts_with("tessera render: scene_sha256=abc, spp=64"),
            "{ours}"
        );
        assert_eq!(bare.expect("read"), None);
        // The bundled reference was written by Mitsuba, which records itself in `generatedBy`.
        let mitsuba = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data/cornell-box-reference.exr");
        let origin = read_exr_provenance(&mitsuba).expect("read");
        assert!(
            origin
                .as_deref()
                .is_some_and(|o| o.starts_with("Mitsuba version 3")),
            "{origin:?}"
        );
    }
}
