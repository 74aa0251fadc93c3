//! Denoising a rendered frame with Intel Open Image Denoise (OIDN), loaded at run time.
//!
//! The library is not linked: a build of tessera runs, renders and tests without it, and only
//! a render that asks for denoising needs it. [`denoise`] loads it once per process from the
//! first place that has it:
//! 1. the directory in `TESSERA_OIDN_DIR`, if that is set (and then only there);
//! 2. `oidn/lib/` beside the running executable or in one of its three parent directories:
//!    `scripts/install-oidn.sh` puts it in `target/oidn/lib/`, which `target/release/tessera`
//!    (and the test binaries under `target/release/deps/`) find; the Docker image puts it in
//!    `/usr/local/oidn/lib/` beside `/usr/local/bin/tessera`;
//! 3. the system's loader path (`libOpenImageDenoise.so.2`).
//!
//! The library must be OIDN 2 (its C ABI, checked by the device's `versionMajor`). Its CPU
//! device, core and TBB are found by the library itself, next to it (`$ORIGIN`).
//!
//! Filtering follows OIDN's advice for noisy auxiliary images: the albedo and the normal are
//! each denoised first, and the beauty is then filtered with them and `cleanAux` set, so the
//! filter trusts them. The beauty is filtered as HDR (linear radiance) unless told otherwise.

mod ffi;

use std::fmt;

use tessera_render::film::Image;
use tessera_render::output::DenoisedPlanes;

pub use ffi::LIBRARY;

/// How hard OIDN works: its `quality` parameter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Quality {
    /// For previews: the fastest filter.
    Fast,
    /// For interactive use.
    Balanced,
    /// For final frames (OIDN's default for the CPU).
    #[default]
    High,
}

impl Quality {
    /// Parses `fast`, `balanced` or `high`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "fast" => Some(Self::Fast),
            "balanced" => Some(Self::Balanced),
            "high" => Some(Self::High),
            _ => None,
        }
    }

    /// The name [`Quality::parse`] reads.
    pub fn name(self) -> &'static str {
        match self {
            Self::Fast => "fast",
            Self::Balanced => "balanced",
            Self::High => "high",
        }
    }

    /// OIDN's `OIDNQuality` value.
    fn oidn(self) -> i32 {
        match self {
            Self::Fast => 4,
            Self::Balanced => 5,
            Self::High => 6,
        }
    }
}

impl fmt::Display for Quality {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How to denoise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Options {
    /// OIDN's quality.
    pub quality: Quality,
    /// The beauty is linear radiance (any positive value); false for display-referred values
    /// in [0, 1].
    pub hdr: bool,
    /// Threads for OIDN's CPU device (`None`: every core).
    pub threads: Option<u32>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            quality: Quality::High,
            hdr: true,
            threads: None,
        }
    }
}

/// A frame's images as the denoiser takes them: row-major RGB, `width` × `height`.
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The beauty (noisy radiance).
    pub color: &'a [[f32; 3]],
    /// The first hit's albedo, in [0, 1].
    pub albedo: &'a [[f32; 3]],
    /// The first hit's shading normal, components in [−1, 1] (any fixed space).
    pub normal: &'a [[f32; 3]],
}

/// What [`denoise`] returns: the denoised beauty, and the auxiliary images it was filtered
/// with (each denoised first, as OIDN advises for noisy ones).
#[derive(Clone, Debug, PartialEq)]
pub struct Denoised {
    /// The denoised beauty.
    pub color: Vec<[f32; 3]>,
    /// The prefiltered albedo.
    pub albedo: Vec<[f32; 3]>,
    /// The prefiltered normal.
    pub normal: Vec<[f32; 3]>,
}

/// Why a frame was not denoised.
#[derive(Clone, Debug, thiserror::Error)]
pub enum DenoiseError {
    /// The library is not where tessera looks.
    #[error(
        "denoising needs Intel Open Image Denoise 2 ({LIBRARY}), which was not found ({tried}); \
         install it with scripts/install-oidn.sh (it unpacks Intel's build from PyPI's pyoidn \
         wheel into target/oidn/lib), or set TESSERA_OIDN_DIR to a directory that holds it"
    )]
    Missing {
        /// Where it looked, and why each place failed.
        tried: String,
    },
    /// A library was found, but not one tessera can call.
    #[error("{path}: {why}")]
    Unusable {
        /// The file loaded.
        path: String,
        /// What is wrong with it (a missing function, the wrong ABI version).
        why: String,
    },
    /// OIDN refused or failed the filter.
    #[error("Open Image Denoise: {0}")]
    Filter(String),
    /// The images do not make a frame.
    #[error("cannot denoise: {0}")]
    Input(String),
}

/// Denoises `frame` with OIDN's `RT` filter: the albedo and normal are filtered first, then the
/// beauty with them (`cleanAux`). Non-finite beauty values (which a finished tessera frame
/// never has) are taken as 0 rather than passed on, as OIDN's output would be undefined.
pub fn denoise(frame: &Frame<'_>, options: &Options) -> Result<Denoised, DenoiseError> {
    let n = check(frame)?;
    let api = ffi::Api::get()?;
    let color: Vec<[f32; 3]> = frame
        .color
        .iter()
        .map(|p| p.map(|c| if c.is_finite() { c } else { 0.0 }))
        .collect();
    let mut out = Denoised {
        color: vec![[0.0; 3]; n],
        albedo: vec![[0.0; 3]; n],
        normal: vec![[0.0; 3]; n],
    };
    let device = api.device(options.threads)?;
    let size = (frame.width as usize, frame.height as usize);
    let q = options.quality.oidn();
    device.filter(
        size,
        &[("albedo", frame.albedo)],
        &mut out.albedo,
        &[("quality", q)],
        &[],
    )?;
    device.filter(
        size,
        &[("normal", frame.normal)],
        &mut out.normal,
        &[("quality", q)],
        &[],
    )?;
    device.filter(
        size,
        &[
            ("color", &color),
            ("albedo", &out.albedo),
            ("normal", &out.normal),
        ],
        &mut out.color,
        &[("quality", q)],
        &[("hdr", options.hdr), ("cleanAux", true)],
    )?;
    Ok(out)
}

/// What a denoised EXR's header says of its filter (`oidn 2.5.1 high hdr`): the library's
/// version and the options, which both decide the denoised bits. The local renderer and the
/// farm write the same.
pub fn header_entry(version: i32, options: &Options) -> String {
    format!(
        "oidn {}.{}.{} {} {}",
        version / 10000,
        version / 100 % 100,
        version % 100,
        options.quality,
        if options.hdr { "hdr" } else { "ldr" }
    )
}

/// Makes a render gather what [`denoise_image`] takes besides the beauty: the albedo and
/// normal AOVs, which leave the beauty's bits as they are.
pub fn gather_inputs(settings: &mut tessera_render::RenderSettings) {
    settings.aovs.albedo = true;
    settings.aovs.normal = true;
}

/// Denoises a finished render ([`denoise`] of its beauty with its albedo and normal AOVs,
/// which it must have), as the EXR's denoised layer takes it: what `tessera render --denoise`,
/// the farm and the bench all run.
pub fn denoise_image(image: &Image, options: &Options) -> Result<DenoisedPlanes, DenoiseError> {
    let aov = image.aov.as_ref().ok_or_else(|| {
        DenoiseError::Input("the render has no albedo and normal for the filter".into())
    })?;
    let frame = Frame {
        width: image.width,
        height: image.height,
        color: &image.rgb,
        albedo: &aov.albedo,
        normal: &aov.normal,
    };
    let d = denoise(&frame, options)?;
    Ok(DenoisedPlanes {
        color: d.color,
        albedo: d.albedo,
        normal: d.normal,
    })
}

/// Planes of RGB triples as a `Workers.Denoise` stream carries them: every value a
/// little-endian f32, row-major, one plane after another. The coordinator and the worker both
/// write and read the stream with these two.
pub fn planes_to_bytes(planes: &[&[[f32; 3]]]) -> Vec<u8> {
    planes
        .iter()
        .flat_map(|p| p.as_flattened())
        .flat_map(|x| x.to_le_bytes())
        .collect()
}

/// [`planes_to_bytes`] read back as `k` planes of `n` pixels; `None` unless `bytes` is exactly
/// that long.
pub fn planes_from_bytes(bytes: &[u8], n: usize, k: usize) -> Option<Vec<Vec<[f32; 3]>>> {
    if n.checked_mul(12)?.checked_mul(k)? != bytes.len() {
        return None;
    }
    let value = |c: &[u8]| f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    Some(
        (0..k)
            .map(|p| {
                bytes[p * n * 12..(p + 1) * n * 12]
                    .chunks_exact(12)
                    .map(|c| [value(&c[0..4]), value(&c[4..8]), value(&c[8..12])])
                    .collect()
            })
            .collect(),
    )
}

/// The version of the OIDN library [`denoise`] uses (e.g. 20501 for 2.5.1), loading it if
/// need be.
pub fn library_version() -> Result<i32, DenoiseError> {
    Ok(ffi::Api::get()?.version())
}

/// The pixel count of a well-formed frame.
fn check(frame: &Frame<'_>) -> Result<usize, DenoiseError> {
    if frame.width == 0 || frame.height == 0 {
        return Err(DenoiseError::Input(format!(
            "the frame is {}×{}: there is nothing to denoise",
            frame.width, frame.height
        )));
    }
    let n = frame.width as usize * frame.height as usize;
    for (what, len) in [
        ("beauty", frame.color.len()),
        ("albedo", frame.albedo.len()),
        ("normal", frame.normal.len()),
    ] {
        if len != n {
            return Err(DenoiseError::Input(format!(
                "the {what} has {len} pixels, the {}×{} frame {n}",
                frame.width, frame.height
            )));
        }
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_header_entry_names_version_and_options() {
        let o = Options {
            quality: Quality::Fast,
            hdr: false,
            threads: Some(3),
        };
        assert_eq!(header_entry(20501, &o), "oidn 2.5.1 fast ldr");
    }

    #[test]
    fn planes_survive_the_stream_bit_for_bit_and_a_wrong_length_is_refused() {
        let a = [[1.5f32, -0.0, f32::MIN_POSITIVE], [f32::NAN, 2.0, 3.0]];
        let b = [[4.0f32, 5.0, 6.0], [7.0, 8.0, f32::INFINITY]];
        let bytes = planes_to_bytes(&[&a, &b]);
        assert_eq!(bytes.len(), 2 * 2 * 12);
        let back = planes_from_bytes(&bytes, 2, 2).expect("two planes");
        let bits = |p: &[[f32; 3]]| {
            p.as_flattened()
                .iter()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&back[0]), bits(&a));
        assert_eq!(bits(&back[1]), bits(&b));
        assert!(planes_from_bytes(&bytes[1..], 2, 2).is_none());
        assert!(planes_from_bytes(&bytes, 2, 3).is_none());
        assert!(planes_from_bytes(&bytes, usize::MAX, 2).is_none());
    }

    #[test]
    fn qualities_round_trip() {
        for q in [Quality::Fast, Quality::Balanced, Quality::High] {
            assert_eq!(Quality::parse(q.name()), Some(q));
        }
        assert_eq!(Quality::parse("best"), None);
    }

    #[test]
    fn empty_and_mismatched_frames_are_refused_before_the_library_is_needed() {
        let px = [[0.5f32; 3]; 4];
        let frame = Frame {
            width: 0,
            height: 4,
            color: &[],
            albedo: &[],
            normal: &[],
        };
        let e = denoise(&frame, &Options::default()).expect_err("empty");
        assert!(e.to_string().contains("0×4"), "{e}");
        let frame = Frame {
            width: 2,
            height: 2,
            color: &px,
            albedo: &px[..3],
            normal: &px,
        };
        let e = denoise(&frame, &Options::default()).expect_err("short albedo");
        assert!(e.to_string().contains("albedo has 3 pixels"), "{e}");
    }
}
