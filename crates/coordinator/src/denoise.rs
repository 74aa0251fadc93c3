//! Denoising on workers: a finished frame whose job asks to be denoised, on a coordinator that
//! does not denoise itself, is kept on disk and lent to a worker that loaded Open Image
//! Denoise (`tessera worker --denoise`), over one `Workers.Denoise` stream per frame.
//!
//! The story of a frame: its last merge gathers it ([`crate::output::finish_job`]), which
//! writes it here, to `DATA_DIR/denoise/JOB.frame` (the whole [`Image`], since the EXR written
//! at the end holds every channel of it), and queues it ([`Scheduler::await_denoise`]). A
//! denoising worker's stream claims it, gets its beauty, albedo and normal, and sends back the
//! filter's three planes; they are checked (size, finite), and the EXR is written from the
//! kept frame and the planes exactly as a denoising coordinator writes it, so the file is the
//! same bytes as `tessera render --denoise` gives with the same library on the same kind of
//! machine. The open stream is the claim: a worker that dies, or a stream that breaks, puts
//! the frame back in the queue.
//!
//! Nothing here needs to be durable: the frame file is made again from the store's sums. A
//! coordinator that restarts deletes the folder and gathers each finished, unwritten frame
//! again, as it does for any frame whose file is not written.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_proto::ids::{JobId, WorkerCredential};
use tessera_proto::v1 as pb;
use tessera_render::film::{AovPlanes, Image};
use tessera_render::output::DenoisedPlanes;
use tokio::sync::mpsc;
use tonic::{Status, Streaming};
use tracing::{info, warn};

use crate::scheduler::DenoiseClaim;
use crate::shared::{durable, now_ms, Shared};

/// Bytes of input or output in one stream message.
pub(crate) const CHUNK_BYTES: usize = 1 << 20;

/// Longest a stream waits for a frame before it ends empty (the worker opens another).
const MAX_WAIT: Duration = Duration::from_secs(30);

/// Where finished frames wait for a denoising worker.
pub(crate) fn dir(data_dir: &Path) -> PathBuf {
    data_dir.join("denoise")
}

fn frame_path(data_dir: &Path, id: JobId) -> PathBuf {
    dir(data_dir).join(format!("{id}.frame"))
}

/// Keeps finished job `id`'s frame for a denoising worker, and queues it.
pub(crate) fn park(shared: &Shared, id: JobId, frame: &Image) -> std::io::Result<()> {
    sweep(shared);
    let path = frame_path(&shared.config.data_dir, id);
    write_frame(&path, frame)?;
    let queued = shared.scheduler().await_denoise(id);
    if !queued {
        // Cancelled while it was being gathered.
        let _ = std::fs::remove_file(&path);
    }
    Ok(())
}

/// Forgets job `id`'s kept frame (written, or the job ended).
pub(crate) fn forget(data_dir: &Path, id: JobId) {
    let _ = std::fs::remove_file(frame_path(data_dir, id));
}

/// Deletes kept frames whose jobs no longer wait for a denoising worker (cancelled, or
/// failed): run after a cancel, and before each frame is kept.
pub(crate) fn sweep(shared: &Shared) {
    let Ok(entries) = std::fs::read_dir(dir(&shared.config.data_dir)) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(id) = name
            .to_str()
            .and_then(|n| n.strip_suffix(".frame"))
            .and_then(|n| n.parse::<JobId>().ok())
        else {
            continue;
        };
        if !shared.scheduler().awaits_denoise(id) {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Magic number of a kept frame file, with its format's version.
const MAGIC: &[u8; 8] = b"TSFRAME1";

/// Writes `frame` to `path` (through a temporary file, so that a crash leaves no half frame
/// under the name): every plane as little-endian numbers after a short header.
fn write_frame(path: &Path, frame: &Image) -> std::io::Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let tmp = path.with_extension("tmp");
    let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
    w.write_all(MAGIC)?;
    w.write_all(&frame.width.to_le_bytes())?;
    w.write_all(&frame.height.to_le_bytes())?;
    w.write_all(&frame.nonfinite.to_le_bytes())?;
    w.write_all(&[u8::from(frame.aov.is_some())])?;
    let f32s = |w: &mut std::io::BufWriter<_>, v: &[f32]| -> std::io::Result<()> {
        v.iter().try_for_each(|x| w.write_all(&x.to_le_bytes()))
    };
    f32s(&mut w, frame.rgb.as_flattened())?;
    f32s(&mut w, frame.variance.as_flattened())?;
    for c in &frame.count {
        w.write_all(&c.to_le_bytes())?;
    }
    if let Some(a) = &frame.aov {
        f32s(&mut w, a.albedo.as_flattened())?;
        f32s(&mut w, a.normal.as_flattened())?;
        f32s(&mut w, &a.depth)?;
    }
    w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    std::fs::rename(&tmp, path)
}

/// Reads a frame [`write_frame`] wrote, checking its size against its header.
fn read_frame(path: &Path) -> std::io::Result<Image> {
    let mut bytes = Vec::new();
    std::fs::File::open(path)?.read_to_end(&mut bytes)?;
    let mut r = Reader {
        bytes: &bytes,
        at: 0,
    };
    if r.take(8)? != MAGIC {
        return Err(invalid("not a kept frame"));
    }
    let width = r.u32s(1)?[0];
    let height = r.u32s(1)?[0];
    let nonfinite = u64::from(r.u32s(1)?[0]) | u64::from(r.u32s(1)?[0]) << 32;
    let has_aov = r.take(1)?[0] != 0;
    let n = width as usize * height as usize;
    let rgb = triples(r.f32s(3 * n)?);
    let variance = triples(r.f32s(3 * n)?);
    let count = r.u32s(n)?;
    let aov = if has_aov {
        Some(AovPlanes {
            albedo: triples(r.f32s(3 * n)?),
            normal: triples(r.f32s(3 * n)?),
            depth: r.f32s(n)?,
        })
    } else {
        None
    };
    if r.at != bytes.len() {
        return Err(invalid("the kept frame has bytes past its planes"));
    }
    Ok(Image {
        width,
        height,
        rgb,
        variance,
        count,
        nonfinite,
        aov,
    })
}

fn invalid(why: &str) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, why.to_string())
}

/// Little-endian numbers off the front of a kept frame.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> std::io::Result<&[u8]> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| invalid("the kept frame is cut short"))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u32s(&mut self, k: usize) -> std::io::Result<Vec<u32>> {
        Ok(self
            .take(k.saturating_mul(4))?
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    fn f32s(&mut self, k: usize) -> std::io::Result<Vec<f32>> {
        Ok(self.u32s(k)?.into_iter().map(f32::from_bits).collect())
    }
}

fn triples(v: Vec<f32>) -> Vec<[f32; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// Little-endian bytes of planes of triples, one after the other.
fn plane_bytes(planes: &[&[[f32; 3]]]) -> Vec<u8> {
    planes
        .iter()
        .flat_map(|p| p.as_flattened())
        .flat_map(|x| x.to_le_bytes())
        .collect()
}

/// The denoising worker's side of one `Denoise` stream, served until the frame it claimed is
/// written or the stream ends. `first` is its hello; what the coordinator sends goes to `tx`.
pub(crate) async fn serve(
    shared: Arc<Shared>,
    hello: pb::DenoiseHello,
    mut inbound: Streaming<pb::DenoiseUp>,
    tx: mpsc::Sender<Result<pb::DenoiseDown, Status>>,
) {
    let result = serve_inner(&shared, hello, &mut inbound, &tx).await;
    if let Err(status) = result {
        let _ = tx.send(Err(status)).await;
    }
}

/// Takes the claim back unless the output was taken: whatever ends the stream early.
struct Claimed<'a> {
    shared: &'a Shared,
    claim: DenoiseClaim,
    done: bool,
}

impl Drop for Claimed<'_> {
    fn drop(&mut self) {
        if !self.done {
            self.shared
                .scheduler()
                .unclaim_denoise(self.claim.job, self.claim.token);
            self.shared.bump_work();
            self.shared.bump_changed();
        }
    }
}

async fn serve_inner(
    shared: &Arc<Shared>,
    hello: pb::DenoiseHello,
    inbound: &mut Streaming<pb::DenoiseUp>,
    tx: &mpsc::Sender<Result<pb::DenoiseDown, Status>>,
) -> Result<(), Status> {
    let cred: WorkerCredential = crate::service::credential(&hello.worker_id)?;
    let deadline = Instant::now() + Duration::from_millis(u64::from(hello.wait_ms)).min(MAX_WAIT);
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
        if left.is_zero() || tokio::time::timeout(left, work.changed()).await.is_err() {
            return Ok(());
        }
    };
    let mut claimed = Claimed {
        shared,
        claim,
        done: false,
    };
    let claim = claimed.claim.clone();
    shared.bump_changed();
    let path = frame_path(&shared.config.data_dir, claim.job);
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
                    forget(&shared.config.data_dir, claim.job);
                    let rx = shared.queue_write(ops);
                    durable(rx).await.map_err(crate::service::internal)?;
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
        let msg = send(pb::denoise_down::Msg::Outcome(pb::DenoiseOutcome {
            written: false,
        }));
        let _ = tx.send(Ok(msg)).await;
        return Ok(());
    }
    claimed.done = true;
    let written =
        crate::output::finish_denoised(shared.clone(), claim.clone(), frame, planes).await;
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

    fn frame(aov: bool) -> Image {
        let n = 6;
        let t = |k: usize, s: f32| -> Vec<[f32; 3]> {
            (0..k)
                .map(|i| [i as f32 * s, -0.5 * s, f32::MIN_POSITIVE])
                .collect()
        };
        Image {
            width: 3,
            height: 2,
            rgb: t(n, 1.5),
            variance: t(n, 0.25),
            count: (0..n as u32).map(|i| i * 7 + u32::MAX / 3).collect(),
            nonfinite: 11,
            aov: aov.then(|| AovPlanes {
                albedo: t(n, 0.1),
                normal: t(n, -1.0),
                depth: vec![f32::INFINITY, 1.0, 2.0, 3.0, 4.0, 5.0],
            }),
        }
    }

    #[test]
    fn a_kept_frame_reads_back_bit_for_bit_and_a_damaged_one_is_refused() {
        let dir = tempfile::tempdir().expect("tmp");
        for aov in [true, false] {
            let path = dir.path().join("f.frame");
            let f = frame(aov);
            write_frame(&path, &f).expect("write");
            assert_eq!(read_frame(&path).expect("read"), f);
            let bytes = std::fs::read(&path).expect("bytes");
            std::fs::write(&path, &bytes[..bytes.len() - 1]).expect("cut");
            assert!(read_frame(&path)
                .expect_err("cut")
                .to_string()
                .contains("cut short"));
            let mut longer = bytes.clone();
            longer.push(0);
            std::fs::write(&path, &longer).expect("longer");
            assert!(read_frame(&path)
                .expect_err("long")
                .to_string()
                .contains("past its planes"));
            let mut other = bytes;
            other[0] = b'X';
            std::fs::write(&path, &other).expect("magic");
            assert!(read_frame(&path).is_err());
        }
    }

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
