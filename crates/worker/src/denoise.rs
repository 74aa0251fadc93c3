//! Denoising finished frames for the coordinator, on a worker started with `--denoise` (which
//! loaded Open Image Denoise before registering, and said so): one `Denoise` stream at a time,
//! beside the render pipeline. The stream is the lease: the coordinator takes the frame back
//! if it breaks, so a worker that stops mid-filter only drops it.

use std::sync::Arc;

use tessera_proto::v1 as pb;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::Code;
use tracing::{info, warn};

use crate::pipeline::Worker;
use crate::session::transient;

/// How long one stream waits for a frame before the coordinator ends it and another opens.
const WAIT_MS: u32 = 20_000;

/// Bytes of output in one message.
const CHUNK_BYTES: usize = 1 << 20;

/// Asks for frames to denoise until shutdown.
pub(crate) async fn run(worker: Arc<Worker>) {
    let session = worker.session();
    let mut attempt = 0;
    while !session.stopping() {
        let id = session.id();
        let mut stop = session.stop.clone();
        let served = tokio::select! {
            r = serve_one(&worker, &id) => r,
            _ = stop.wait_for(|s| *s) => return,
        };
        match served {
            Ok(()) => attempt = 0,
            Err(e) if e.code() == Code::NotFound => {
                if !session.reregister(&id).await {
                    return;
                }
            }
            Err(e) if transient(&e) => {
                if !session.backoff(&mut attempt).await {
                    return;
                }
            }
            Err(e) => {
                // A refusal retrying cannot fix soon (the coordinator does not count this
                // worker as one that denoises, or refused its output): said, then asked again
                // after a while.
                warn!("denoising: {}", e.message());
                attempt = attempt.max(6);
                if !session.backoff(&mut attempt).await {
                    return;
                }
            }
        }
    }
}

/// One stream: waits for a frame, denoises it, and sends it back.
async fn serve_one(worker: &Worker, id: &str) -> Result<(), tonic::Status> {
    let session = worker.session();
    let (tx, rx) = mpsc::channel(4);
    let hello = pb::DenoiseHello {
        worker_id: id.to_string(),
        wait_ms: WAIT_MS,
    };
    let _ = tx.send(up(pb::denoise_up::Msg::Hello(hello))).await;
    let mut down = session
        .client
        .clone()
        .denoise(ReceiverStream::new(rx))
        .await?
        .into_inner();
    let Some((unit, input)) = receive_frame(&mut down).await? else {
        return Ok(());
    };
    let options = unit.options.clone().unwrap_or_default();
    let quality = tessera_denoise::Quality::parse(&options.quality).unwrap_or_default();
    let opts = tessera_denoise::Options {
        quality,
        hdr: !options.ldr,
        threads: session.config.threads.map(|t| t as u32),
    };
    let (width, height) = (unit.width, unit.height);
    info!("denoising {} ({width}×{height}, {quality})", unit.job_id);
    let started = std::time::Instant::now();
    let filtered = tokio::task::spawn_blocking(move || filter((width, height), &input, &opts))
        .await
        .map_err(|e| tonic::Status::internal(e.to_string()))?;
    let out = match filtered {
        Ok(out) => out,
        Err(e) => {
            warn!("denoising {} failed: {e}", unit.job_id);
            let _ = tx
                .send(up(pb::denoise_up::Msg::Failed(e.to_string())))
                .await;
            let _ = down.message().await;
            return Ok(());
        }
    };
    for chunk in out.chunks(CHUNK_BYTES) {
        if tx
            .send(up(pb::denoise_up::Msg::Output(chunk.to_vec())))
            .await
            .is_err()
        {
            break;
        }
    }
    match down.message().await? {
        Some(pb::DenoiseDown {
            msg: Some(pb::denoise_down::Msg::Outcome(o)),
        }) => info!(
            "denoised {} in {:.2} s{}",
            unit.job_id,
            started.elapsed().as_secs_f64(),
            if o.written {
                ""
            } else {
                " (its job had ended)"
            }
        ),
        _ => warn!(
            "denoised {}, and the coordinator did not say what became of it",
            unit.job_id
        ),
    }
    // The stream's sender lives until the answer is in: dropped earlier, it would end the
    // stream under the coordinator before it wrote the frame.
    drop(tx);
    Ok(())
}

fn up(m: pb::denoise_up::Msg) -> pb::DenoiseUp {
    pb::DenoiseUp { msg: Some(m) }
}

/// The frame a stream lends, with all its input's bytes; `None` when no frame came (the
/// coordinator had none within the wait) or the stream ended before its input was in.
async fn receive_frame(
    down: &mut tonic::Streaming<pb::DenoiseDown>,
) -> Result<Option<(pb::DenoiseUnit, Vec<u8>)>, tonic::Status> {
    let Some(first) = down.message().await? else {
        return Ok(None);
    };
    let Some(pb::denoise_down::Msg::Unit(unit)) = first.msg else {
        return Err(tonic::Status::internal(
            "a Denoise stream began without its unit",
        ));
    };
    let (width, height) = (unit.width, unit.height);
    let want = (width as usize)
        .checked_mul(height as usize)
        .and_then(|n| n.checked_mul(36))
        .ok_or_else(|| {
            tonic::Status::internal(format!("a {width}×{height} frame is too large to denoise"))
        })?;
    let mut input = Vec::with_capacity(want);
    while input.len() < want {
        match down.message().await? {
            Some(pb::DenoiseDown {
                msg: Some(pb::denoise_down::Msg::Input(b)),
            }) if input.len() + b.len() <= want => input.extend_from_slice(&b),
            Some(_) => {
                return Err(tonic::Status::internal(
                    "a Denoise stream's input is malformed",
                ))
            }
            None => return Ok(None),
        }
    }
    Ok(Some((unit, input)))
}

/// Filters a lent frame's input (beauty, albedo, normal) into the output the stream carries
/// back (denoised beauty, albedo, normal).
fn filter(
    (width, height): (u32, u32),
    input: &[u8],
    opts: &tessera_denoise::Options,
) -> Result<Vec<u8>, tessera_denoise::DenoiseError> {
    let n = width as usize * height as usize;
    let planes = tessera_denoise::planes_from_bytes(input, n, 3).ok_or_else(|| {
        tessera_denoise::DenoiseError::Input(format!(
            "{} bytes of input for a {width}×{height} frame",
            input.len()
        ))
    })?;
    let frame = tessera_denoise::Frame {
        width,
        height,
        color: &planes[0],
        albedo: &planes[1],
        normal: &planes[2],
    };
    let out = tessera_denoise::denoise(&frame, opts)?;
    Ok(tessera_denoise::planes_to_bytes(&[
        &out.color,
        &out.albedo,
        &out.normal,
    ]))
}
