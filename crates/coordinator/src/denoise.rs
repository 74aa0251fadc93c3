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

use crate::kept::{forget, frame_path, read_frame};
use crate::scheduler::DenoiseClaim;
use crate::shared::{durable, now_ms, Shared};

/// Bytes of input or output in one stream message.
pub(crate) const CHUNK_BYTES: usize = 1 << 20;

/// Longest a stream waits for a frame before it ends empty (the worker opens another).
const MAX_WAIT: Duration = Duration::from_secs(30);

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
    let Some((w, claim)) = wait_for_frame(shared, &cred, wait_ms, tx).await? else {
        return Ok(());
    };
    let mut claimed = Claimed {
        open: Open(shared, stream),
        claim,
        done: false,
    };
    let claim = claimed.claim.clone();
    shared.bump_changed();
    // A worker that holds the stream open and sends nothing would hold the frame for good.
    let pixels = claim.size.0 as usize * claim.size.1 as usize;
    let limit = claim_limit(pixels, shared.config.lease_timeout);
    let until = tokio::time::Instant::now() + limit;
    let late = || {
        Status::deadline_exceeded(format!(
            "{}: not denoised within {} s; it goes to another worker",
            claim.job,
            limit.as_secs()
        ))
    };
    if !lend(shared, &claim, tx, until).await.ok_or_else(late)?? {
        return Ok(());
    }
    info!("{} lent to a worker to denoise", claim.job);
    let output = match receive_output(&claim, inbound, until)
        .await
        .ok_or_else(late)?
    {
        Received::Output(bytes) => bytes,
        Received::Gone => return Ok(()),
        Received::Failed(why) => return filter_failed(shared, &mut claimed, &why).await,
        Received::Surplus(e) => {
            shared.scheduler().refuse_result(w);
            return Err(e);
        }
        Received::Invalid(e) => return Err(e),
    };
    let planes = match to_planes(&output, pixels) {
        Ok(p) => p,
        Err(why) => {
            shared.scheduler().refuse_result(w);
            return Err(Status::invalid_argument(format!("{}: {why}", claim.job)));
        }
    };
    drop(output);
    // The claim ends here either way; the stream closes before the worker hears the outcome.
    let holds = shared.scheduler().holds_denoise(w, claim.job, claim.token);
    claimed.done = true;
    drop(claimed);
    // Not held: the job was cancelled while the worker filtered it.
    let written = holds && crate::output::finish_denoised(shared.clone(), claim, planes).await;
    let outcome = pb::denoise_down::Msg::Outcome(pb::DenoiseOutcome { written });
    let _ = tx.send(Ok(pb::DenoiseDown { msg: Some(outcome) })).await;
    Ok(())
}

/// Waits up to `wait_ms` for a frame that worker `cred` may claim, and claims it: the
/// worker's number and the claim, or `None` when no frame came or the worker went away.
async fn wait_for_frame(
    shared: &Shared,
    cred: &WorkerCredential,
    wait_ms: u32,
    tx: &mpsc::Sender<Result<pb::DenoiseDown, Status>>,
) -> Result<Option<(u64, DenoiseClaim)>, Status> {
    let deadline = Instant::now() + Duration::from_millis(u64::from(wait_ms)).min(MAX_WAIT);
    let mut work = shared.work.subscribe();
    loop {
        work.borrow_and_update();
        {
            let mut core = shared.scheduler();
            let now = Instant::now();
            let w = core.touch_worker(cred, now)?;
            if let Some(c) = core.claim_denoise(w, now)? {
                return Ok(Some((w, c)));
            }
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(None);
        }
        tokio::select! {
            woke = tokio::time::timeout(left, work.changed()) => {
                if woke.is_err() {
                    return Ok(None);
                }
            }
            // The worker went away while it waited: its stream closes now, not at the wait's end.
            () = tx.closed() => return Ok(None),
        }
    }
}

/// Sends the claimed frame's unit and its beauty, albedo and normal, read from the kept frame
/// (which is let go before the worker's answer: the write reads it again, one frame at a
/// time). `Some(false)` if the worker went away, `None` past `until`.
async fn lend(
    shared: &Shared,
    claim: &DenoiseClaim,
    tx: &mpsc::Sender<Result<pb::DenoiseDown, Status>>,
    until: tokio::time::Instant,
) -> Option<Result<bool, Status>> {
    let input = match kept_input(shared, claim).await {
        Ok(input) => input,
        Err(e) => return Some(Err(e)),
    };
    let unit = pb::DenoiseUnit {
        job_id: claim.job.to_string(),
        width: claim.size.0,
        height: claim.size.1,
        options: Some(pb::DenoiseOptions {
            quality: claim.options.quality.clone(),
            ldr: !claim.options.hdr,
        }),
    };
    let messages = std::iter::once(pb::denoise_down::Msg::Unit(unit)).chain(
        input
            .chunks(CHUNK_BYTES)
            .map(|c| pb::denoise_down::Msg::Input(c.to_vec())),
    );
    for m in messages {
        let sent = tokio::time::timeout_at(until, tx.send(Ok(pb::DenoiseDown { msg: Some(m) })));
        if sent.await.ok()?.is_err() {
            return Some(Ok(false));
        }
    }
    Some(Ok(true))
}

/// The claimed frame's beauty, albedo and normal as the stream carries them.
async fn kept_input(shared: &Shared, claim: &DenoiseClaim) -> Result<Vec<u8>, Status> {
    let path = frame_path(&shared.config, claim.job);
    let read = {
        let path = path.clone();
        tokio::task::spawn_blocking(move || read_frame(&path))
            .await
            .map_err(|e| Status::internal(e.to_string()))?
    };
    let frame = read.map_err(|e| {
        // The frame stays queued; a restart gathers it again from the store.
        warn!(
            "{}: the finished frame kept for denoising ({}) cannot be read: {e}",
            claim.job,
            path.display()
        );
        Status::unavailable(format!("{}: its frame cannot be read now", claim.job))
    })?;
    let aov = frame.aov.as_ref().ok_or_else(|| {
        Status::internal(format!(
            "{}: the kept frame has no albedo and normal",
            claim.job
        ))
    })?;
    Ok(tessera_denoise::planes_to_bytes(&[
        &frame.rgb,
        &aov.albedo,
        &aov.normal,
    ]))
}

/// What a worker answered to a lent frame.
enum Received {
    /// All of its output's bytes (their size is the frame's; their values are not checked).
    Output(Vec<u8>),
    /// Its filter failed, saying why.
    Failed(String),
    /// It sent more output than the frame holds: a bad result.
    Surplus(Status),
    /// It broke the protocol otherwise (a second hello).
    Invalid(Status),
    /// It went away.
    Gone,
}

/// Reads the worker's answer to the lent frame; `None` past `until`.
async fn receive_output(
    claim: &DenoiseClaim,
    inbound: &mut Streaming<pb::DenoiseUp>,
    until: tokio::time::Instant,
) -> Option<Received> {
    let want = claim.size.0 as usize * claim.size.1 as usize * 36;
    let mut output: Vec<u8> = Vec::new();
    while output.len() < want {
        let Ok(Some(msg)) = tokio::time::timeout_at(until, inbound.message())
            .await
            .ok()?
        else {
            return Some(Received::Gone);
        };
        match msg.msg {
            Some(pb::denoise_up::Msg::Output(bytes)) if output.len() + bytes.len() <= want => {
                output.extend_from_slice(&bytes);
            }
            Some(pb::denoise_up::Msg::Output(_)) => {
                return Some(Received::Surplus(Status::invalid_argument(format!(
                    "{}: more output than the frame's {want} bytes (three planes of {}×{}×3 f32)",
                    claim.job, claim.size.0, claim.size.1
                ))));
            }
            Some(pb::denoise_up::Msg::Failed(why)) => return Some(Received::Failed(why)),
            Some(pb::denoise_up::Msg::Hello(_)) | None => {
                return Some(Received::Invalid(Status::invalid_argument(
                    "a Denoise stream's hello comes first and once; then only output or failed",
                )));
            }
        }
    }
    Some(Received::Output(output))
}

/// The worker's filter failed on the claimed frame: it waits again, or its job fails after
/// [`crate::scheduler::FAIL_DENOISE_AFTER`] failures.
async fn filter_failed(
    shared: &Shared,
    claimed: &mut Claimed<'_>,
    why: &str,
) -> Result<(), Status> {
    let job = claimed.claim.job;
    let why = crate::error::truncate(why);
    warn!("{job}: a worker's filter failed: {why}");
    let ops = shared
        .scheduler()
        .denoise_failed(job, claimed.claim.token, &why, now_ms());
    claimed.done = true;
    if !ops.is_empty() {
        forget(&shared.config, job);
        durable(shared.queue_write(ops))
            .await
            .map_err(|e| Status::internal(format!("coordinator state store: {e}")))?;
    }
    shared.bump_work();
    shared.bump_changed();
    Ok(())
}

/// How long a worker may hold a frame of `pixels`: a minute for every megapixel (several times
/// what Open Image Denoise's `high` takes on two cores: docs/renderer.md), and two lease times
/// besides for the transfers.
fn claim_limit(pixels: usize, lease: Duration) -> Duration {
    let megapixels = pixels.div_ceil(1_000_000) as u32;
    Duration::from_secs(60) * megapixels.max(1) + lease * 2
}

/// A worker's output as planes: exactly three of `n` pixels, every value finite.
fn to_planes(bytes: &[u8], n: usize) -> Result<DenoisedPlanes, String> {
    let Some(mut planes) = tessera_denoise::planes_from_bytes(bytes, n, 3) else {
        return Err(format!(
            "the output is {} bytes; three planes of {n} pixels are {}",
            bytes.len(),
            n.saturating_mul(36)
        ));
    };
    for (plane, name) in planes.iter().zip(["denoised beauty", "albedo", "normal"]) {
        if let Some((pixel, v)) = plane
            .iter()
            .enumerate()
            .find_map(|(i, p)| p.iter().find(|c| !c.is_finite()).map(|c| (i, *c)))
        {
            return Err(format!(
                "the output's {name} is not finite at pixel {pixel} ({v})"
            ));
        }
    }
    let (normal, albedo, color) = (
        planes.pop().unwrap_or_default(),
        planes.pop().unwrap_or_default(),
        planes.pop().unwrap_or_default(),
    );
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
