//! `--denoise`: a denoised layer beside the unbiased beauty, by Intel Open Image Denoise
//! (`tessera-denoise`). The render is the same whether or not it is denoised; the filter runs
//! once on the finished frame.

use anyhow::{Context, Result};
use tessera_denoise::{Options, Quality};
use tessera_render::film::Image;
use tessera_render::output::DenoisedPlanes;
use tessera_render::RenderSettings;

/// `--denoise` and its options.
#[derive(Debug, Clone, clap::Args)]
pub struct DenoiseArgs {
    /// Add a denoised image to the EXR as its own layer (denoised.R/G/B, with the albedo and
    /// normal the filter used); the beauty (R, G, B) stays the unbiased render, bit for bit.
    /// Uses Intel Open Image Denoise, which scripts/install-oidn.sh installs.
    #[arg(long)]
    pub denoise: bool,
    /// The denoiser's quality: `fast` for previews, `high` for final frames.
    #[arg(long, value_enum, default_value_t = QualityArg::High, requires = "denoise")]
    pub denoise_quality: QualityArg,
    /// The beauty is display-referred (in [0, 1]): filter it as LDR, not HDR.
    #[arg(long, requires = "denoise")]
    pub denoise_ldr: bool,
}

/// `--denoise-quality` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum QualityArg {
    /// OIDN's fast filter.
    Fast,
    /// OIDN's balanced filter.
    Balanced,
    /// OIDN's high-quality filter.
    High,
}

/// A denoiser, loaded and ready for the frame.
#[derive(Debug)]
pub struct Denoiser {
    options: Options,
    version: i32,
}

impl DenoiseArgs {
    /// The denoiser, if `--denoise` was given or else the scene file asks for one
    /// (`[render] denoise`): the library is loaded here, before anything is rendered, so that
    /// a missing one fails at once. `threads` is the render's own limit.
    pub fn denoiser(
        &self,
        scene: Option<&tessera_render::scene::Denoise>,
        threads: Option<u32>,
    ) -> Result<Option<Denoiser>> {
        let (quality, hdr, asked) = match (self.denoise, scene) {
            (true, _) => (self.quality(), !self.denoise_ldr, "--denoise"),
            (false, Some(s)) => (
                Quality::parse(&s.quality).unwrap_or_default(),
                s.hdr,
                "the scene's [render] denoise",
            ),
            (false, None) => return Ok(None),
        };
        let version = tessera_denoise::library_version().context(asked)?;
        Ok(Some(Denoiser {
            options: Options {
                quality,
                hdr,
                threads,
            },
            version,
        }))
    }
}

impl DenoiseArgs {
    /// What `tessera submit` asks the farm for (the coordinator denoises; nothing is loaded
    /// here).
    pub fn proto(&self) -> Option<tessera_proto::v1::DenoiseOptions> {
        self.denoise.then(|| tessera_proto::v1::DenoiseOptions {
            quality: self.quality().name().to_string(),
            ldr: self.denoise_ldr,
        })
    }

    fn quality(&self) -> Quality {
        match self.denoise_quality {
            QualityArg::Fast => Quality::Fast,
            QualityArg::Balanced => Quality::Balanced,
            QualityArg::High => Quality::High,
        }
    }
}

impl Denoiser {
    /// Settings that also gather what the filter needs (the albedo and normal AOVs, which
    /// leave the beauty's bits as they are).
    pub fn settings(&self, mut settings: RenderSettings) -> RenderSettings {
        tessera_denoise::gather_inputs(&mut settings);
        settings
    }

    /// The header entry that says how the denoised layer was made.
    pub fn metadata(&self) -> (String, String) {
        let entry = tessera_denoise::header_entry(self.version, &self.options);
        ("denoise".to_string(), entry)
    }

    /// Denoises the finished frame.
    pub fn run(&self, image: &Image) -> Result<DenoisedPlanes> {
        tessera_denoise::denoise_image(image, &self.options).context("denoising")
    }
}
