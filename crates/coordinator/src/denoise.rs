//! Denoising on workers: a finished frame whose job asks to be denoised, on a coordinator that
//! does not denoise itself, is kept on disk and lent to a worker that loaded Open Image
//! Denoise (`tessera worker --denoise`), over one `Workers.Denoise` stream per frame.
//!
//! The story of a frame: its last merge gathers it ([`crate::output::finish_job`]), which
//! keeps it ([`crate::kept`]) and queues it (`Scheduler::await_denoise`). A
//! denoising worker's stream claims it, gets its beauty, albedo and normal, and sends back the
//! filter's three planes; they are checked (size, finite), and the EXR is written from the
//! kept frame and the planes exactly as a denoising coordinator writes it, so the file is the
//! same bytes as `tessera render --denoise` gives with the same library on the same kind of
//! machine. The open stream is the claim: a worker that dies, or a stream that breaks, puts
//! the frame back in the queue.
//!
//! Nothing here needs to be durable: the kept frame is made again from the store's sums.

use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_proto::ids::WorkerCredential;
use tessera_proto::v1 as pb;
use tessera_render::output::DenoisedPlanes;
use tokio::sync::mpsc;
use tonic::{Status, Streaming};
use tracing::{info, warn};

use crate::kept::{forget, frame_path, read_frame, triples};
use crate::scheduler::DenoiseClaim;
use crate::shared::{durable, now_ms, Shared};

/// Bytes of input or output in one stream message.
pub(crate) const CHUNK_BYTES: usize = 1 << 20;

/// Longest a stream waits for a frame before it ends empty (the worker opens another).
const MAX_WAIT: Duration = Duration::from_secs(30);

/// Little-endian bytes of planes of triples, one after the other.
fn plane_bytes(planes: &[&[[f32; 3]]]) -> Vec<u8> {
    planes
        .iter()
        .flat_map(|p| p.as_flattened())
        .flat_map(|x| x.to_le_bytes())
        .collect()
}

/// The denoising worker's side of one `Denoise` stream, served until the frame it claimed is
/// written or the stream ends: `stream`, worker w's stream and its token (the handler opened
/// it), `cred` (from its hello) asking for a frame within `wait_ms`; what the coordinator
/// sends goes to `tx`.
pub(crate) async fn serve(
    shared: Arc<Shared>,
    (stream, cred, wait_ms): ((u64, u64), WorkerCredential, u32),
    mut inbound: Streaming<pb::DenoiseUp>,
    tx: mpsc::Sender<Result<pb::DenoiseDown, Status>>,
) {
    let _open = Open(&shared, stream);
    let result = serve_inner(&shared, (stream, cred, wait_ms), &mut inbound, &tx).await;
    if let Err(status) = result {
        let _ = tx.send(Err(status)).await;
    }
}

/// Closes a worker's stream however its task ends; closed earlier (before the last message
/// the worker waits for), so that the worker's next stream is never refused as a second one.
struct Open<'a>(&'a Shared, (u64, u64));

impl Open<'_> {
    fn close(&self) {
        let (w, token) = self.1;
        self.0.scheduler().close_denoise_stream(w, token);
    }
}

impl Drop for Open<'_> {
    fn drop(&mut self) {
        self.close();
    }
}

/// Takes the claim back unless the output was taken: whatever ends the stream early. The
/// stream is closed first, so that a worker that learns the frame waits again may open
/// another at once.
struct Claimed<'a> {
    open: Open<'a>,
    claim: DenoiseClaim,
    done: bool,
}

impl Drop for Claimed<'_> {
    fn drop(&mut self) {
        self.open.close();
        if !self.done {
            let shared = self.open.0;
            shared
                .scheduler()
                .unclaim_denoise(self.claim.job, self.claim.token);
            shared.bump_work();
            shared.bump_changed();
        }
    }
}

async fn serve_inner(
    shared: &Arc<Shared>,
    (stream, cred, wait_ms): ((u64, u64), WorkerCredential, u32),
    inbound: &mut Streaming<pb::DenoiseUp>,
    tx: &mpsc::Sender<Result<pb::DenoiseDown, Status>>,
) -> Result<(), Status> {
    let deadline = Instant::now() + Duration::from_millis(u64::from(wait_ms)).min(MAX_WAIT);
    let mut work = shared.work.subscribe();
    let (w, claim) = loop {
        work.borrow_and_update();
        let (w, claim) = {
            let mut core = shared.scheduler();
            let now = Instant::now();
            let w = core.touch_worker(&cred, now)?;
            (w, core.claim_denoise(w, now)?)
        };
        if let Some(c) = claim {
            break (w, c);
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(());
        }
        tokio::select! {
            woke = tokio::time::timeout(left, work.changed()) => {
                if woke.is_err() {
                    return Ok(());
                }
            }
            // The worker went away while it waited: its stream closes now, not at the wait's end.
            () = tx.closed() => return Ok(()),
        }
    };
    let mut claimed = Claimed {
        open: Open(shared, stream),
        claim,
        done: false,
    };
    let claim = claimed.claim.clone();
    shared.bump_changed();
    let path = frame_path(&shared.config, claim.job);
    let frame = {
        let path = path.clone();
        tokio::task::spawn_blocking(move || read_frame(&path))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
    };
    let frame = match frame {
        Ok(f) => f,
        Err(e) => {
            // The frame stays queued; a restart gathers it again from the store.
            warn!(
                "{}: the finished frame kept for denoising ({}) cannot be read: {e}",
                claim.job,
                path.display()
            );
            return Err(Status::unavailable(format!(
                "{}: its frame cannot be read now",
                claim.job
            )));
        }
    };
    let Some(aov) = &frame.aov else {
        return Err(Status::internal(format!(
            "{}: the kept frame has no albedo and normal",
            claim.job
        )));
    };
    let input = plane_bytes(&[&frame.rgb, &aov.albedo, &aov.normal]);
    let unit = pb::DenoiseUnit {
        job_id: claim.job.to_string(),
        width: claim.size.0,
        height: claim.size.1,
        options: Some(pb::DenoiseOptions {
            quality: claim.options.quality.clone(),
            ldr: !claim.options.hdr,
        }),
    };
    let send = |m: pb::denoise_down::Msg| pb::DenoiseDown { msg: Some(m) };
    // A worker that holds the stream open and sends nothing would hold the frame for good.
    let limit = claim_limit(frame.rgb.len(), shared.config.lease_timeout);
    let until = tokio::time::Instant::now() + limit;
    let late = || {
        Status::deadline_exceeded(format!(
            "{}: not denoised within {} s; it goes to another worker",
            claim.job,
            limit.as_secs()
        ))
    };
    let unit = send(pb::denoise_down::Msg::Unit(unit));
    match tokio::time::timeout_at(until, tx.send(Ok(unit))).await {
        Err(_) => return Err(late()),
        Ok(Err(_)) => return Ok(()),
        Ok(Ok(())) => {}
    }
    for chunk in input.chunks(CHUNK_BYTES) {
        let msg = send(pb::denoise_down::Msg::Input(chunk.to_vec()));
        match tokio::time::timeout_at(until, tx.send(Ok(msg))).await {
            Err(_) => return Err(late()),
            Ok(Err(_)) => return Ok(()),
            Ok(Ok(())) => {}
        }
    }
    drop(input);
    info!("{} lent to a worker to denoise", claim.job);
    let want = frame.rgb.len() * 9 * 4;
    let mut output: Vec<u8> = Vec::new();
    while output.len() < want {
        let msg = match tokio::time::timeout_at(until, inbound.message()).await {
            Err(_) => return Err(late()),
            Ok(Ok(Some(m))) => m,
            // The worker went away: the claim goes back (`Claimed`).
            Ok(Ok(None) | Err(_)) => return Ok(()),
        };
        match msg.msg {
            Some(pb::denoise_up::Msg::Output(bytes)) => {
                if output.len() + bytes.len() > want {
                    shared.scheduler().refuse_result(w);
                    return Err(Status::invalid_argument(format!(
                        "{}: more output than the frame's {want} bytes (three planes of \
                         {}×{}×3 f32)",
                        claim.job, claim.size.0, claim.size.1
                    )));
                }
                output.extend_from_slice(&bytes);
            }
            Some(pb::denoise_up::Msg::Failed(why)) => {
                let why = crate::error::truncate(&why);
                warn!("{}: a worker's filter failed: {why}", claim.job);
                let ops = {
                    let mut core = shared.scheduler();
                    core.denoise_failed(claim.job, claim.token, &why, now_ms())
                };
                claimed.done = true;
                if !ops.is_empty() {
                    forget(&shared.config, claim.job);
                    let rx = shared.queue_write(ops);
                    durable(rx)
                        .await
                        .map_err(|e| Status::internal(format!("coordinator state store: {e}")))?;
                }
                shared.bump_work();
                shared.bump_changed();
                return Ok(());
            }
            Some(pb::denoise_up::Msg::Hello(_)) | None => {
                return Err(Status::invalid_argument(
                    "a Denoise stream's hello comes first and once; then only output or failed",
                ));
            }
        }
    }
    let planes = match to_planes(&output, frame.rgb.len()) {
        Ok(p) => p,
        Err(why) => {
            shared.scheduler().refuse_result(w);
            return Err(Status::invalid_argument(format!("{}: {why}", claim.job)));
        }
    };
    drop(output);
    if !shared.scheduler().holds_denoise(w, claim.job, claim.token) {
        // Cancelled while the worker filtered it.
        claimed.done = true;
        drop(claimed);
        let msg = send(pb::denoise_down::Msg::Outcome(pb::DenoiseOutcome {
            written: false,
        }));
        let _ = tx.send(Ok(msg)).await;
        return Ok(());
    }
    claimed.done = true;
    let written =
        crate::output::finish_denoised(shared.clone(), claim.clone(), frame, planes).await;
    drop(claimed);
    let msg = send(pb::denoise_down::Msg::Outcome(pb::DenoiseOutcome {
        written,
    }));
    let _ = tx.send(Ok(msg)).await;
    Ok(())
}

/// How long a worker may hold a frame of `pixels`: a minute for every megapixel (Open Image
/// Denoise's `high` took 9 s a megapixel on two cores of the development machine), and two
/// lease times besides for the transfers.
fn claim_limit(pixels: usize, lease: Duration) -> Duration {
    let megapixels = pixels.div_ceil(1_000_000) as u32;
    Duration::from_secs(60) * megapixels.max(1) + lease * 2
}

/// A worker's output as planes: exactly three of `n` pixels, every value finite.
fn to_planes(bytes: &[u8], n: usize) -> Result<DenoisedPlanes, String> {
    if bytes.len() != n * 9 * 4 {
        return Err(format!(
            "the output is {} bytes; three planes of {n} pixels are {}",
            bytes.len(),
            n * 36
        ));
    }
    let v: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if let Some(k) = v.iter().position(|x| !x.is_finite()) {
        let plane = ["denoised beauty", "albedo", "normal"][k / (3 * n)];
        let pixel = k % (3 * n) / 3;
        return Err(format!(
            "the output's {plane} is not finite at pixel {pixel} ({})",
            v[k]
        ));
    }
    let mut planes = v.chunks_exact(3 * n).map(|p| triples(p.to_vec()));
    let (Some(color), Some(albedo), Some(normal)) = (planes.next(), planes.next(), planes.next())
    else {
        return Err("the output does not hold three planes".into());
    };
    Ok(DenoisedPlanes {
        color,
        albedo,
        normal,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_of_the_wrong_size_or_not_finite_is_refused_naming_where() {
        let n = 4;
        let good: Vec<f32> = (0..n * 9).map(|i| i as f32).collect();
        let bytes = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let p = to_planes(&bytes(&good), n).expect("good");
        assert_eq!(p.color[1], [3.0, 4.0, 5.0]);
        assert_eq!(p.albedo[0], [12.0, 13.0, 14.0]);
        assert_eq!(p.normal[3], [33.0, 34.0, 35.0]);
        assert!(to_planes(&bytes(&good[1..]), n)
            .expect_err("short")
            .contains("three planes of 4 pixels are 144"));
        let mut nan = good.clone();
        nan[3 * n + 4] = f32::NAN;
        let e = to_planes(&bytes(&nan), n).expect_err("nan");
        assert!(e.contains("albedo") && e.contains("pixel 1"), "{e}");
        let mut inf = good;
        inf[2] = f32::INFINITY;
        assert!(to_planes(&bytes(&inf), n)
            .expect_err("inf")
            .contains("denoised beauty"));
    }
}
