//! A job's output: the EXR written once every unit is in (its name is chosen at admission,
//! [`crate::names`]).

use std::sync::Arc;

use tessera_proto::ids::JobId;
use tessera_render::film::Image;
use tessera_render::output::{
    render_metadata, write_new_exr_strips, write_new_exr_strips_denoised, DenoisedPlanes,
    ExrChannels,
};
use tessera_render::{NoiseSum, RenderSettings, Strips};
use tracing::{error, info, warn};

use crate::job::FrameTile;
use crate::shared::{durable, now_ms, Shared};
use crate::store::{DenoiseRecord, JobPhase, JobRecord};

/// Why a finished job's EXR could not be written.
#[derive(Debug, thiserror::Error)]
enum FinishError {
    /// Its tiles do not make an image (a bug: every merge was checked).
    #[error(transparent)]
    Assemble(#[from] tessera_render::MergeError),
    /// The file could not be written.
    #[error(transparent)]
    Write(#[from] tessera_render::output::OutputError),
    /// A tile's sums could not be read back from the store.
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    /// The task writing it panicked.
    #[error("{0}")]
    Task(#[from] tokio::task::JoinError),
    /// The frame could not be denoised.
    #[error("denoising: {0}")]
    Denoise(#[from] tessera_denoise::DenoiseError),
    /// The frame could not be kept for a denoising worker.
    #[error("keeping the frame for a denoising worker: {0}")]
    Keep(std::io::Error),
}

/// Writes a finished job's EXR, then records it as done (or failed).
pub(crate) async fn finish_job(shared: Arc<Shared>, id: JobId) {
    // Closed only if the coordinator is stopping, when the job finishes after its restart.
    let Ok(_one_at_a_time) = shared.finishing.acquire().await else {
        return;
    };
    let started = std::time::Instant::now();
    let gathered = {
        let mut scheduler = shared.scheduler();
        scheduler.take_frame(id).map(|(frame, ops)| {
            shared.queue_checkpointed(ops);
            frame
        })
    };
    let Some((rec, settings, tiles)) = gathered else {
        return;
    };
    let dir = shared.config.output_dir();
    let path = dir.join(&rec.output_name);
    let store = shared.store.clone();
    // A job that asks to be denoised on a coordinator that does not denoise is finished by a
    // worker that does (`denoise.rs`): its frame is kept for one ([`crate::kept`]).
    let here = shared.config.denoise;
    let keeper = shared.clone();
    let written = tokio::task::spawn_blocking(move || -> Result<_, FinishError> {
        // Tiles the store holds are read back one at a time, as the strips take them, and
        // each strip of rows is dropped once the encoder has compressed it: writing a frame
        // holds one band of tiles, not the image.
        let mut unread = None;
        let sums = tiles.into_iter().map_while(|t| match t {
            FrameTile::Here(s) => Some(s),
            FrameTile::Stored(i, rect) => store
                .tile(rec.id, i, rect)
                .map_err(|e| unread = Some(e))
                .ok(),
        });
        let mut unfit = None;
        let mut noise = NoiseSum::default();
        let strips = Strips::new(&settings, rec.width, rec.height, sums)
            .map_while(|s| s.map_err(|e| unfit = Some(e)).ok())
            .inspect(|s| noise.add(s));
        let channels = channels_of(&rec, &settings);
        // Never over another file: output names are unique among the coordinator's jobs, so a
        // file already there was put there by someone else, and is theirs.
        let size = (rec.width, rec.height);
        let metadata = render_metadata(&rec.scene_hash, &settings);
        let written = match &rec.denoise {
            None => write_new_exr_strips(&path, size, channels, &metadata, strips).map(drop),
            Some(how) => {
                // The filter sees the frame at once: it is gathered whole, checked, denoised,
                // then written with its layer as `tessera render --denoise` writes it.
                let frame = whole(strips);
                if let Some(e) = unread.take() {
                    return Err(e.into());
                }
                if let Some(e) = unfit.take() {
                    return Err(e.into());
                }
                if !here {
                    crate::kept::park(&keeper, JobId(rec.id), &frame).map_err(FinishError::Keep)?;
                    return Ok(None);
                }
                let (entry, planes) = denoise(&frame, how)?;
                return write_denoised(&path, &rec, &settings, &frame, (entry, &planes)).map(Some);
            }
        };
        // A strip source that failed explains why the strips fell short.
        if let Some(e) = unread {
            return Err(e.into());
        }
        if let Some(e) = unfit {
            return Err(e.into());
        }
        written?;
        Ok(Some((noise.noise(), noise.black())))
    })
    .await
    .map_err(FinishError::from)
    .and_then(|r| r);
    if let Ok(None) = written {
        info!("{id} rendered; its frame waits for a worker that denoises");
        shared.bump_work();
        shared.bump_changed();
        return;
    }
    record_written(&shared, id, written.map(Option::unwrap_or_default), started).await;
}

/// Which channels a job's EXR holds.
fn channels_of(rec: &JobRecord, settings: &RenderSettings) -> ExrChannels {
    ExrChannels {
        variance: rec.variance,
        samples: rec.sample_count,
        aovs: settings.aovs,
    }
}

/// Writes a whole frame with its denoised layer (`entry` is the header's account of the
/// filter): the same bytes `tessera render --denoise` writes. Returns the frame's noise and
/// whether it is black.
fn write_denoised(
    path: &std::path::Path,
    rec: &JobRecord,
    settings: &RenderSettings,
    frame: &Image,
    (entry, planes): (String, &DenoisedPlanes),
) -> Result<((f64, f64), bool), FinishError> {
    let mut metadata = render_metadata(&rec.scene_hash, settings);
    metadata.push(("denoise".to_string(), entry));
    let size = (rec.width, rec.height);
    let channels = channels_of(rec, settings);
    write_new_exr_strips_denoised(
        path,
        size,
        channels,
        &metadata,
        std::iter::once(frame),
        planes,
    )?;
    let mut noise = NoiseSum::default();
    noise.add(frame);
    Ok((noise.noise(), noise.black()))
}

/// Ends job `id` as its EXR's writing went: done with the frame's noise, or failed.
async fn record_written(
    shared: &Arc<Shared>,
    id: JobId,
    written: Result<((f64, f64), bool), FinishError>,
    started: std::time::Instant,
) {
    let dir = shared.config.output_dir();
    let (rx, releases) = {
        let mut scheduler = shared.scheduler();
        let releases = scheduler.has_dependents(id);
        let ops = match &written {
            Ok((noise, black)) => scheduler.written(id, *noise, *black, now_ms()),
            Err(e) => scheduler.end_job(
                id,
                JobPhase::Failed,
                format!("writing the EXR: {e}"),
                now_ms(),
            ),
        };
        (shared.queue_write(ops), releases)
    };
    match (&written, durable(rx).await) {
        (Ok(_), Ok(())) => info!(
            "{id} done → {} (EXR written in {:.3} s)",
            dir.display(),
            started.elapsed().as_secs_f64()
        ),
        (Err(e), _) => warn!("{id} failed: {e}"),
        (_, Err(e)) => error!("{id}: recording completion: {e}"),
    }
    shared.bump_changed();
    if releases {
        // A job that waited for this one (`--after`) may start now: wake workers that are
        // long-polling for units.
        shared.bump_work();
    }
}

/// Writes the EXR of a frame a worker denoised (`planes`, under `claim`) from the frame kept
/// for it (read here, under the one-frame-at-a-time permit), and ends its job; returns whether
/// the file was written.
pub(crate) async fn finish_denoised(
    shared: Arc<Shared>,
    claim: crate::scheduler::DenoiseClaim,
    planes: DenoisedPlanes,
) -> bool {
    let Ok(_one_at_a_time) = shared.finishing.acquire().await else {
        return false;
    };
    let started = std::time::Instant::now();
    let id = claim.job;
    let Some((rec, settings)) = shared
        .scheduler()
        .job(id)
        .filter(|j| j.finishing && j.rec.phase == JobPhase::Active)
        .map(|j| (j.rec.clone(), j.settings()))
    else {
        crate::kept::forget(&shared.config, id);
        return false;
    };
    let path = shared.config.output_dir().join(&rec.output_name);
    let kept = crate::kept::frame_path(&shared.config, id);
    let written = tokio::task::spawn_blocking(move || {
        let frame = crate::kept::read_frame(&kept).map_err(FinishError::Keep)?;
        let options = options_of(rec.denoise.as_ref().unwrap_or(&DenoiseRecord {
            quality: claim.options.quality.clone(),
            hdr: claim.options.hdr,
        }));
        let entry = tessera_denoise::header_entry(claim.version, &options);
        write_denoised(&path, &rec, &settings, &frame, (entry, &planes))
    })
    .await
    .map_err(FinishError::from)
    .and_then(|r| r);
    let ok = written.is_ok();
    record_written(&shared, id, written, started).await;
    crate::kept::forget(&shared.config, id);
    ok
}

/// The strips of a frame as one image.
fn whole(strips: impl Iterator<Item = Image>) -> Image {
    let mut frame: Option<Image> = None;
    for s in strips {
        match &mut frame {
            Some(f) => f.append(&s),
            None => frame = Some(s),
        }
    }
    frame.unwrap_or_default()
}

/// A finished frame denoised as its job asked (every core of this machine: the result is the
/// same on any number), with the header entry that says how.
fn denoise(frame: &Image, how: &DenoiseRecord) -> Result<(String, DenoisedPlanes), FinishError> {
    let options = options_of(how);
    let planes = tessera_denoise::denoise_image(frame, &options)?;
    let entry = tessera_denoise::header_entry(tessera_denoise::library_version()?, &options);
    Ok((entry, planes))
}

/// The filter's options as a job's record keeps them (every core of the machine).
fn options_of(how: &DenoiseRecord) -> tessera_denoise::Options {
    tessera_denoise::Options {
        quality: tessera_denoise::Quality::parse(&how.quality).unwrap_or_default(),
        hdr: how.hdr,
        threads: None,
    }
}
