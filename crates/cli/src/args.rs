//! The flags `tessera render` and the farm's commands share, and the checks of an output path
//! made before any work starts: one definition each, so that `render` and `submit` with the
//! same flags give the same image.

use anyhow::{bail, Context, Result};
use tessera_render::{
    unit_batch, Adaptive, Aovs, RenderSettings, Strategy, BATCH_RANGE, DEFAULT_TILE,
    DEFAULT_UNIT_SAMPLES, TILE_RANGE, UNIT_SAMPLES_RANGE,
};

/// clap's parser for a tile edge in [`TILE_RANGE`].
pub fn tile_range() -> clap::builder::RangedI64ValueParser<u32> {
    clap::value_parser!(u32).range(i64::from(*TILE_RANGE.start())..=i64::from(*TILE_RANGE.end()))
}

/// clap's parser for a batch size in [`BATCH_RANGE`].
pub fn batch_range() -> clap::builder::RangedI64ValueParser<u32> {
    clap::value_parser!(u32).range(i64::from(*BATCH_RANGE.start())..=i64::from(*BATCH_RANGE.end()))
}

/// How a glTF file is rendered as a whole scene: the same flags for `tessera render` and
/// `tessera submit`, which both turn them into the scene text the file stands for.
#[derive(Debug, Clone, clap::Args)]
pub struct GltfArgs {
    /// A glTF scene's camera: its name, or its index in the file's `cameras` (default: the
    /// first one a node places, or a framing of the whole scene when there is none).
    #[arg(long, value_name = "NAME|INDEX")]
    pub camera: Option<String>,
    /// Light a glTF scene by this equirectangular map (.exr or .hdr; .png, .jpg or .jpeg read
    /// through the sRGB curve) instead of its default (its own lights, or a uniform white sky
    /// when it has none). It must be inside the glTF file's folder.
    #[arg(long, value_name = "FILE")]
    pub environment: Option<std::path::PathBuf>,
}

impl GltfArgs {
    /// The options for `scene`: refused for a scene that is not a glTF file, whose text
    /// already says its camera and light.
    pub fn options(&self, scene: &std::path::Path) -> Result<tessera_render::scene::GltfOptions> {
        if !tessera_render::scene::is_gltf(scene) {
            for (flag, given) in [
                ("--camera", self.camera.is_some()),
                ("--environment", self.environment.is_some()),
            ] {
                if given {
                    bail!(
                        "{flag} is for glTF scenes (.gltf, .glb); {} says its own in its text",
                        scene.display()
                    );
                }
            }
        }
        let environment = match &self.environment {
            None => None,
            Some(p) => {
                if !p.is_file() {
                    bail!("--environment {}: no such file", p.display());
                }
                // The scene names files relative to the glTF file's folder, and only inside
                // it (what the farm's workers receive is that name, nothing above it).
                let dir = scene.parent().unwrap_or(std::path::Path::new(""));
                let here = |p: &std::path::Path| {
                    std::path::absolute(if p.as_os_str().is_empty() {
                        ".".as_ref()
                    } else {
                        p
                    })
                    .with_context(|| format!("--environment {}", p.display()))
                };
                let name = match here(p)?.strip_prefix(here(dir)?) {
                    Ok(rel) => rel.to_path_buf(),
                    Err(_) => std::path::PathBuf::from(".."),
                };
                let name = name.to_str().with_context(|| {
                    format!("--environment {}: the path is not UTF-8", p.display())
                })?;
                if tessera_render::scene::assets::check_file_name(name).is_err() {
                    bail!(
                        "--environment {}: the map must be inside the glTF file's folder ({}), \
                         as every file a scene reads is; copy or link it there",
                        p.display(),
                        if dir.as_os_str().is_empty() {
                            ".".into()
                        } else {
                            dir.display().to_string()
                        }
                    );
                }
                Some(name.to_string())
            }
        };
        Ok(tessera_render::scene::GltfOptions {
            camera: self.camera.clone(),
            environment,
        })
    }
}

/// The settings that decide a render's bits: the same flags, defaults and ranges for `tessera
/// render` and `tessera submit`, so that the two give the same image for the same command.
#[derive(Debug, clap::Args)]
pub struct SettingsArgs {
    /// Samples per pixel.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub spp: u32,
    /// Job seed: the same seed gives the same bits.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Samples per batch (part of the job's identity, like the seed). Unset, it follows from
    /// the image's size, --spp and --unit-samples by one rule that `render`, `submit` and the
    /// coordinator share (docs/farm.md), so a farm job with the same flags gives the same bits.
    #[arg(long, value_parser = batch_range())]
    pub batch: Option<u32>,
    /// The samples (pixels × samples per pixel) a work unit aims at when --batch is unset:
    /// larger units cost the coordinator less per sample, smaller ones spread a frame over
    /// more workers. Part of the render's identity through the batch it chooses.
    #[arg(long, default_value_t = DEFAULT_UNIT_SAMPLES, value_parser = unit_samples)]
    pub unit_samples: u64,
    /// Direct-lighting strategy (mis is the best; the others exist for comparisons).
    #[arg(long, value_enum, default_value_t = StrategyArg::Mis)]
    pub strategy: StrategyArg,
    /// Adaptive sampling: samples go to the tiles where they lower the image's relative error
    /// most, until its expected value (√relMSE, e.g. 0.02) is this, and --spp becomes the cap.
    /// Tiles are --tile-size pixels, which is then part of the render's identity.
    #[arg(long, value_parser = noise_target)]
    pub noise_target: Option<f64>,
    /// Frame of the scene's `[animation]` to render (the EXR's header then names it, and it is
    /// part of the render's identity).
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=9_999_999))]
    pub frame: Option<u32>,
    /// Auxiliary images for denoising, as EXR channels beside the beauty: a comma-separated
    /// list of albedo (albedo.R/G/B), normal (normal.X/Y/Z, world space) and depth (Z), each
    /// pixel's mean at its first non-specular surface. The beauty's bits do not change.
    #[arg(long, value_name = "LIST", value_parser = parse_aovs)]
    pub aov: Option<Aovs>,
    /// Path guiding: render in epochs of doubling sample counts, each sampling directions
    /// from where the epochs before it found light (docs/renderer.md, "Path guiding"). For
    /// light that next-event estimation cannot find: caustics, light through glass. Part of
    /// the render's identity; one path at a time whatever --tracer says. Not with
    /// --noise-target or --frames.
    #[arg(long)]
    pub guiding: bool,
    /// The film's size, WIDTHxHEIGHT (e.g. 1920x1080), in place of the scene file's own, for
    /// any scene (TOML or glTF): the camera frames it as it frames the file's. Part of the
    /// render's identity, like --spp.
    #[arg(long, value_name = "WxH", value_parser = resolution)]
    pub resolution: Option<(u32, u32)>,
}

/// `--aov`'s list ([`Aovs::parse`]).
fn parse_aovs(list: &str) -> Result<Aovs, String> {
    Aovs::parse(list)
}

/// clap's parser for a noise target in [`tessera_render::adaptive::NOISE_TARGET_RANGE`].
fn noise_target(s: &str) -> Result<f64, String> {
    let t: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number (a relative error such as 0.01)"))?;
    Adaptive::new(t, DEFAULT_TILE)
        .map(|a| a.noise_target)
        .map_err(|e| e.to_string())
}

/// clap's parser for `--unit-samples`, in [`UNIT_SAMPLES_RANGE`].
fn unit_samples(s: &str) -> Result<u64, String> {
    let n: u64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a whole number of samples"))?;
    if UNIT_SAMPLES_RANGE.contains(&n) {
        Ok(n)
    } else {
        Err(format!(
            "{n} is outside {}..={}",
            UNIT_SAMPLES_RANGE.start(),
            UNIT_SAMPLES_RANGE.end()
        ))
    }
}

impl SettingsArgs {
    /// The renderer's settings for a `width` × `height` image, with noise decisions (if any)
    /// for tiles of `tile` pixels.
    pub fn to_settings(&self, tile: u32, width: u32, height: u32) -> RenderSettings {
        RenderSettings {
            seed: self.seed,
            spp: self.spp,
            batch: self.batch.unwrap_or_else(|| {
                unit_batch(
                    width,
                    height,
                    self.spp,
                    self.noise_target.is_some(),
                    self.unit_samples,
                )
            }),
            strategy: self.strategy.to_strategy(),
            adaptive: self
                .noise_target
                .map(|noise_target| Adaptive { noise_target, tile }),
            frame: self.frame,
            aovs: self.aov.unwrap_or_default(),
            guiding: self.guiding,
            resolution: self.resolution,
            ..RenderSettings::default()
        }
    }

    /// What these flags ask of the scene file: the frame (the first where none is named) and
    /// the film's size.
    pub fn shot(&self) -> tessera_render::scene::Shot {
        tessera_render::scene::Shot {
            frame: self.frame.unwrap_or(tessera_render::scene::FIRST_FRAME),
            resolution: self.resolution,
        }
    }
}

/// clap's parser for `--resolution`: WIDTHxHEIGHT, each side 1 to 65,536 (the scene's limits,
/// 16,384 a side by default, are checked when it is built).
pub fn resolution(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("{s:?}: expected WIDTHxHEIGHT, e.g. 1920x1080");
    let (w, h) = s.split_once(['x', 'X', '×']).ok_or_else(bad)?;
    let side = |v: &str| -> Result<u32, String> {
        let n: u32 = v.trim().parse().map_err(|_| bad())?;
        if !(1..=65_536).contains(&n) {
            return Err(format!("{s:?}: each side must be 1 to 65536 pixels"));
        }
        Ok(n)
    };
    Ok((side(w)?, side(h)?))
}

/// `--strategy` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum StrategyArg {
    /// Multiple importance sampling.
    Mis,
    /// BSDF sampling only (punctual lights, which no ray can hit, are still sampled).
    Bsdf,
    /// Light sampling only.
    Nee,
}

impl StrategyArg {
    fn to_strategy(self) -> Strategy {
        match self {
            StrategyArg::Mis => Strategy::Mis,
            StrategyArg::Bsdf => Strategy::Bsdf,
            StrategyArg::Nee => Strategy::Nee,
        }
    }
}

/// Fails early, before any rendering, if `out` cannot be written: its directory does not
/// exist or is not writable, or `out` is a directory.
pub fn check_output_dir(out: &std::path::Path) -> Result<()> {
    let dir = out
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    if !dir.is_dir() {
        bail!(
            "{}: output directory {} does not exist",
            out.display(),
            dir.display()
        );
    }
    if out.is_dir() {
        bail!("{}: is a directory", out.display());
    }
    // The file is written as a new file in that directory, then renamed: try exactly that
    // now rather than after a long render.
    tempfile::Builder::new()
        .prefix(".tessera-probe-")
        .tempfile_in(dir)
        .map(drop)
        .with_context(|| format!("{}: cannot write in {}", out.display(), dir.display()))
}

/// Fails unless `out`'s name ends in `.ext` (any case): a file is read by its extension, and
/// an EXR named `.png` (or a PNG named `.jpg`) is a file no program opens as what it says.
pub fn check_extension(flag: &str, out: &std::path::Path, ext: &str) -> Result<()> {
    let ok = out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case(ext));
    if !ok {
        bail!(
            "{flag} {}: the file is written as {}, so its name must end in .{ext}",
            out.display(),
            ext.to_uppercase()
        );
    }
    Ok(())
}

/// clap's parser for a memory size: bytes, or a number with K, M, G or T (binary units, so
/// `16G` is 16 GiB; a trailing `iB` or `B` is allowed).
pub fn memory_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let t = t
        .strip_suffix("iB")
        .or_else(|| t.strip_suffix('B'))
        .unwrap_or(t);
    let (digits, shift) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() => {
            let shift = match c.to_ascii_uppercase() {
                'K' => 10,
                'M' => 20,
                'G' => 30,
                'T' => 40,
                _ => return Err(format!("{s:?}: unknown unit {c:?} (use K, M, G or T)")),
            };
            (&t[..i], shift)
        }
        _ => (t, 0),
    };
    let n: f64 = digits
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a size (e.g. 16G, 512M or a number of bytes)"))?;
    let bytes = n * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 0.0 && bytes < 2f64.powi(63)) {
        return Err(format!("{s:?} is not a size between 0 and 8 EiB"));
    }
    Ok(bytes.round() as u64)
}

/// clap's parser for a worker tag or a job requirement ([`tessera_proto::tags`]).
pub fn tag(s: &str) -> Result<String, String> {
    tessera_proto::tags::check_tag(s)?;
    Ok(s.to_string())
}

#[cfg(test)]
mod size_tests {
    use super::memory_size;

    #[test]
    fn sizes_read_in_binary_units() {
        assert_eq!(memory_size("16G"), Ok(16 << 30));
        assert_eq!(memory_size("16GiB"), Ok(16 << 30));
        assert_eq!(memory_size("512M"), Ok(512 << 20));
        assert_eq!(memory_size("1.5g"), Ok(3 << 29));
        assert_eq!(memory_size("4096"), Ok(4096));
        assert!(memory_size("16X")
            .expect_err("16X")
            .contains("unknown unit 'X'"));
        assert!(memory_size("1.2.3G")
            .expect_err("1.2.3G")
            .contains("not a size"));
        assert!(memory_size("lots")
            .expect_err("lots")
            .contains("unknown unit"));
        assert!(memory_size("-1G").expect_err("-1G").contains("between 0"));
        assert!(memory_size("1e30T")
            .expect_err("1e30T")
            .contains("between 0"));
    }
}

/// `--preview` and `--exposure`: the PNG beside an EXR, the same for `render`, `submit --wait`,
/// `fetch` and `preview`.
#[derive(Debug, Clone, clap::Args)]
pub struct PreviewArgs {
    /// Also write an 8-bit sRGB PNG preview here.
    #[arg(long)]
    pub preview: Option<std::path::PathBuf>,
    /// Preview exposure in stops.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub exposure: f32,
}

impl PreviewArgs {
    /// Refuses a non-finite exposure and a preview name that is not a .png in a directory
    /// that exists, before anything is rendered or fetched.
    pub fn check(&self) -> Result<()> {
        if !self.exposure.is_finite() {
            bail!("--exposure must be a finite number, got {}", self.exposure);
        }
        if let Some(p) = &self.preview {
            check_extension("--preview", p, "png")?;
            check_output_dir(p)?;
        }
        Ok(())
    }

    /// Writes the preview of the EXR at `exr`, if one was asked for.
    pub fn write_of_exr(&self, exr: &std::path::Path) -> Result<()> {
        let Some(p) = &self.preview else {
            return Ok(());
        };
        let image = tessera_render::output::read_exr_rgb(exr)
            .with_context(|| format!("reading {}", exr.display()))?;
        tessera_render::output::write_png_of_exr(
            p,
            &image,
            tessera_render::output::Preview {
                exposure: self.exposure,
            },
        )?;
        Ok(())
    }
}
