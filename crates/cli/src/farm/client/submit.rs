//! `tessera submit`: a scene and its files to the coordinator, and with `--wait` the job
//! followed to its EXR.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use tessera_proto::v1 as pb;
use tessera_render::scene::assets::sha256_hex;
use tessera_render::scene::{scene_source, FrameRange, Limits, Scene, FIRST_FRAME};
use tessera_render::DEFAULT_TILE;

use super::{
    check_frames_dir, connect, download, download_frames, follow, follow_to_end, rpc_error, Client,
};
use crate::args::{check_extension, check_output_dir, tile_range, SettingsArgs};
use crate::farm::{runtime, CoordinatorUrl};

/// Arguments of `tessera submit`.
#[derive(Debug, clap::Args)]
pub struct SubmitArgs {
    /// Scene file: TOML, JSON (by its .json extension), or glTF 2.0 (.gltf, .glb).
    scene: PathBuf,
    #[command(flatten)]
    gltf: crate::args::GltfArgs,
    #[command(flatten)]
    url: CoordinatorUrl,
    #[command(flatten)]
    settings: SettingsArgs,
    /// Tile edge in pixels (default: the coordinator's).
    #[arg(long, value_parser = tile_range())]
    tile_size: Option<u32>,
    /// Higher runs first.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    priority: i32,
    /// File name of the EXR in the coordinator's output directory (default: JOB.exr).
    #[arg(long)]
    name: Option<String>,
    /// Start only when this job (a frame-range job: all its frames) is done; fail, with the
    /// reason, if it fails or is cancelled.
    #[arg(long, value_name = "JOB")]
    after: Option<String>,
    /// Lease its units only to workers with this tag (repeatable): NAME matches a worker's
    /// NAME or NAME=anything, NAME=VALUE only that, cpu:FEATURE a CPU feature (cpu:avx2).
    #[arg(long = "require", value_name = "TAG", value_parser = crate::args::tag)]
    require: Vec<String>,
    /// Lease its units only to workers with at least this much memory (e.g. 16G).
    #[arg(long, value_name = "SIZE", value_parser = crate::args::memory_size)]
    min_memory: Option<u64>,
    /// With --frames: every frame's first batch of samples before any frame's second, and so
    /// on (the whole shot to look at early); each frame's EXR is the same bits as without.
    #[arg(long, requires = "frames", conflicts_with = "noise_target")]
    progressive: bool,
    /// Add variance-of-the-mean channels to the EXR.
    #[arg(long)]
    variance: bool,
    /// Add a per-pixel sample-count channel to the EXR.
    #[arg(long)]
    sample_count: bool,
    #[command(flatten)]
    denoise: crate::denoise::DenoiseArgs,
    /// Render frames FIRST-LAST or FIRST-LAST:STEP of the scene's `[animation]` as one job,
    /// one EXR per frame (NAME.####.exr); the first frames finish first.
    #[arg(long, value_name = "FIRST-LAST[:STEP]", conflicts_with = "frame")]
    frames: Option<FrameRange>,
    /// Follow the job with a progress bar, then fetch its EXR (a frame range's EXRs).
    #[arg(long)]
    wait: bool,
    /// Where `--wait` saves the EXR (default: the job's output name, here); for `--frames`,
    /// the directory the frames' EXRs go to.
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// With `--wait` (one frame): the PNG preview beside the EXR, as `render --preview`.
    #[command(flatten)]
    preview: crate::args::PreviewArgs,
}

/// A file a scene names: (name in the scene, SHA-256, path here).
type SceneFile = (String, String, PathBuf);

/// The files the scene names (meshes, textures), as (name, SHA-256, path), and the image's
/// size (which the batch rule reads): found by loading the scene here, at the frame the job
/// starts with. A scene that does not load here is
/// refused here with the error `tessera render` prints (a mesh that is missing or truncated, a
/// texture that is a directory: the cause, not "not among the files sent"). Only the limits a
/// coordinator may raise (resolution, spp, sizes) are lifted for this check, so a scene within
/// its coordinator's limits but above the defaults is still sent, for it to decide.
fn scene_files(
    args: &SubmitArgs,
    gltf: &tessera_render::scene::GltfOptions,
) -> Result<(Vec<SceneFile>, (u32, u32))> {
    let shot = tessera_render::scene::Shot {
        frame: args
            .frames
            .map_or(args.settings.frame.unwrap_or(FIRST_FRAME), |r| r.first),
        resolution: args.settings.resolution,
    };
    let lifted = Limits {
        max_resolution: u32::MAX,
        max_pixels: u64::MAX,
        max_bytes: usize::MAX,
        max_spp: u32::MAX,
        max_asset_bytes: u64::MAX,
        ..Limits::default()
    };
    let scene = Scene::file(&args.scene, &lifted)
        .gltf(gltf)
        .at(shot)
        .load()?;
    for w in &scene.warnings {
        errln!("warning: {w}");
    }
    let dir = args.scene.parent().unwrap_or(Path::new("")).to_path_buf();
    let size = (scene.width, scene.height);
    let files = scene
        .files
        .into_iter()
        .map(|(name, hash)| {
            let path = dir.join(&name);
            (name, hash, path)
        })
        .collect();
    Ok((files, size))
}

/// Uploads one file unless the coordinator holds it already, resuming from the bytes it holds
/// of an earlier, interrupted upload.
async fn upload(client: &mut Client, url: &str, name: &str, hash: &str, path: &Path) -> Result<()> {
    let status = client
        .get_asset_status(pb::GetAssetStatusRequest {
            sha256: hash.to_string(),
        })
        .await
        .map_err(|e| rpc_error(url, "asset status refused", e))?
        .into_inner();
    if status.complete {
        return Ok(());
    }
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    if sha256_hex(&bytes) != hash {
        bail!(
            "{}: changed while it was being submitted; submit again",
            path.display()
        );
    }
    let total = bytes.len() as u64;
    let from = usize::try_from(status.received)
        .unwrap_or(usize::MAX)
        .min(bytes.len());
    if from > 0 {
        errln!("{name}: resuming the upload at byte {from} of {total}");
    }
    // Chunks are cut as the stream is read, so a large file is in memory once, not twice.
    const CHUNK: usize = 1 << 20;
    let count = (bytes.len() - from).div_ceil(CHUNK).max(1);
    let sha = hash.to_string();
    let chunks = (0..count).map(move |i| {
        let start = from + i * CHUNK;
        let end = (start + CHUNK).min(bytes.len());
        pb::AssetChunk {
            sha256: sha.clone(),
            offset: start as u64,
            total_size: total,
            data: bytes[start..end].to_vec(),
        }
    });
    let done = client
        .upload_asset(tokio_stream::iter(chunks))
        .await
        .map_err(|e| rpc_error(url, &format!("upload of {name} refused"), e))?
        .into_inner();
    if !done.complete {
        bail!(
            "upload of {name}: the coordinator holds {} of {total} bytes; submit again to resume",
            done.received
        );
    }
    errln!("{name}: uploaded ({total} bytes, sha256 {hash})");
    Ok(())
}

/// Runs `tessera submit`.
pub fn submit(args: SubmitArgs) -> Result<()> {
    check_flags(&args)?;
    let gltf = args.gltf.options(&args.scene)?;
    // A glTF file is sent as the scene text it stands for, with the file among its assets.
    let (text, format) = scene_source(
        &args.scene,
        &gltf,
        &Limits {
            max_asset_bytes: u64::MAX,
            ..Limits::default()
        },
    )?;
    let json = format == tessera_render::scene::Format::Json;
    let (files, (width, height)) = scene_files(&args, &gltf)?;
    let url = args.url.coordinator.clone();
    runtime()?.block_on(async {
        let mut client = connect(&args.url).await?;
        let req = request(&args, text, json, &files, (width, height));
        let resp = submit_with_files(&mut client, &url, &files, req).await?;
        if !args.wait {
            outln!("{}", resp.job_id);
            return Ok(());
        }
        errln!("{} submitted ({} units)", resp.job_id, resp.units);
        // Ctrl-C stops the following, not the job: say so, with the id to pick it up again.
        let job = resp.job_id.clone();
        tokio::select! {
            r = follow_and_fetch(&args, &mut client, &url, resp) => r,
            _ = tokio::signal::ctrl_c() => bail!(
                "interrupted: {job} goes on rendering on the farm; follow it with `tessera \
                 status {job}`, fetch it with `tessera fetch {job} --wait`, or stop it with \
                 `tessera cancel {job}`"
            ),
        }
    })
}

/// The flags that cannot go together, and the output checked before anything is sent.
fn check_flags(args: &SubmitArgs) -> Result<()> {
    if args.settings.guiding && args.settings.noise_target.is_some() {
        bail!(
            "--guiding takes every sample it is given; it cannot be combined with --noise-target"
        );
    }
    if args.settings.guiding && args.frames.is_some() {
        bail!("--guiding renders one frame per job; it cannot be combined with --frames");
    }
    if let Some(o) = &args.output {
        if !args.wait {
            bail!("--output needs --wait (or use `tessera fetch JOB --output FILE` later)");
        }
        if args.frames.is_some() {
            check_frames_dir(o)?;
        } else {
            check_extension("--output", o, "exr")?;
            check_output_dir(o)?;
        }
    }
    args.preview.check()?;
    if args.preview.preview.is_some() && (!args.wait || args.frames.is_some()) {
        bail!("--preview needs --wait and one frame (or `tessera preview FRAME.exr` later)");
    }
    Ok(())
}

/// The submission of `text` (JSON or TOML) with `files`, at the film size `width`×`height`.
fn request(
    args: &SubmitArgs,
    text: String,
    json: bool,
    files: &[SceneFile],
    (width, height): (u32, u32),
) -> pb::SubmitJobRequest {
    let assets = files
        .iter()
        .map(|(name, hash, _)| pb::AssetRef {
            name: name.clone(),
            sha256: hash.clone(),
        })
        .collect();
    pb::SubmitJobRequest {
        assets,
        scene_text: text,
        scene_format: if json {
            pb::SceneFormat::Json
        } else {
            pb::SceneFormat::Toml
        } as i32,
        scene_name: args.scene.display().to_string(),
        settings: Some(pb::RenderSettings::from(&args.settings.to_settings(
            args.tile_size.unwrap_or(DEFAULT_TILE),
            width,
            height,
        ))),
        tile_size: args.tile_size.unwrap_or(0),
        output_name: args.name.clone().unwrap_or_default(),
        priority: args.priority,
        channels: Some(pb::OutputChannels {
            variance: args.variance,
            sample_count: args.sample_count,
            denoise: args.denoise.proto(),
        }),
        frames: args.frames.map(|r| pb::FrameRange {
            first: r.first,
            last: r.last,
            step: r.step,
        }),
        after: args.after.clone().unwrap_or_default(),
        require: args.require.clone(),
        min_memory_bytes: args.min_memory.unwrap_or(0),
        progressive: args.progressive,
    }
}

/// Uploads `files` and submits `req`.
async fn submit_with_files(
    client: &mut Client,
    url: &str,
    files: &[SceneFile],
    req: pb::SubmitJobRequest,
) -> Result<pb::SubmitJobResponse> {
    // The coordinator deletes files no active job has used for a while; one it held when
    // `upload` asked may be gone by the submission. Uploading again and resubmitting settles
    // that (twice at most: a file deleted every time is a misconfigured farm).
    let mut tries = 0;
    loop {
        for (name, hash, path) in files {
            upload(client, url, name, hash, path).await?;
        }
        match client.submit_job(req.clone()).await {
            Err(e)
                if e.code() == tonic::Code::FailedPrecondition
                    && e.message().starts_with("not uploaded")
                    && tries < 2 =>
            {
                tries += 1;
                errln!(
                    "the coordinator no longer holds a file ({}); uploading again",
                    e.message()
                );
            }
            r => {
                return Ok(r
                    .map_err(|e| rpc_error(url, "submit refused", e))?
                    .into_inner())
            }
        }
    }
}

/// Follows a submitted job to its end and fetches its EXR (a range's frames into the
/// output folder), with the preview if asked.
async fn follow_and_fetch(
    args: &SubmitArgs,
    client: &mut Client,
    url: &str,
    resp: pb::SubmitJobResponse,
) -> Result<()> {
    if args.frames.is_some() {
        errln!("{} frames", resp.frames);
        let s = follow_to_end(client, url, &resp.job_id).await?;
        let dir = args.output.clone().unwrap_or_else(|| PathBuf::from("."));
        return download_frames(client, url, &s, &dir).await;
    }
    let s = follow(client, url, &resp.job_id).await?;
    let out = args
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from(&s.output_name));
    let bytes = download(client, url, &resp.job_id, None, &out).await?;
    let secs = (s.finished_unix_ms - s.submitted_unix_ms) as f64 / 1000.0;
    outln!(
        "{} done: {}×{} at {} in {:.2} s, {} → {} ({bytes} bytes)",
        s.job_id,
        s.width,
        s.height,
        spp_said(&s),
        secs,
        crate::render::noise_said(
            s.noise_rms,
            s.noise_relative,
            s.settings.as_ref().is_some_and(|r| r.spp > 1)
        ),
        out.display()
    );
    args.preview.write_of_exr(&out)
}

/// The samples a finished job took, as `tessera render` says them: "N spp", or for an
/// adaptive job the average per pixel with its target and cap.
fn spp_said(s: &pb::JobStatus) -> String {
    let settings = s.settings.clone().unwrap_or_default();
    if settings.noise_target > 0.0 {
        let pixels = (f64::from(s.width) * f64::from(s.height)).max(1.0);
        format!(
            "{:.1} spp on average (noise target {}, cap {})",
            s.samples_done as f64 / pixels,
            settings.noise_target,
            settings.spp
        )
    } else {
        format!("{} spp", settings.spp)
    }
}
