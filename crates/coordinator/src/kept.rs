//! Finished frames kept on disk while they wait for a worker to denoise them
//! (`denoise.rs`): the whole [`Image`] of each, since the EXR written at the end holds
//! every channel of it, under `DATA_DIR/denoise/JOB.frame`.
//!
//! They are derived state: a coordinator that restarts deletes the folder
//! ([`crate::config::Config::kept_frames_dir`]) and gathers each finished, unwritten frame
//! again from the store, as it does for any frame whose file is not written.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use tessera_proto::ids::JobId;
use tessera_render::film::{AovPlanes, Image};

use crate::config::Config;
use crate::shared::Shared;

/// Where job `id`'s frame is kept.
pub(crate) fn frame_path(config: &Config, id: JobId) -> PathBuf {
    config.kept_frames_dir().join(format!("{id}.frame"))
}

/// Keeps finished job `id`'s frame for a denoising worker, and queues it.
pub(crate) fn park(shared: &Shared, id: JobId, frame: &Image) -> std::io::Result<()> {
    sweep(shared);
    let path = frame_path(&shared.config, id);
    write_frame(&path, frame)?;
    let queued = shared.scheduler().await_denoise(id);
    if !queued {
        // Cancelled while it was being gathered.
        let _ = std::fs::remove_file(&path);
    }
    Ok(())
}

/// Forgets job `id`'s kept frame (written, or the job ended).
pub(crate) fn forget(config: &Config, id: JobId) {
    let _ = std::fs::remove_file(frame_path(config, id));
}

/// Deletes kept frames whose jobs no longer wait for a denoising worker (cancelled, or
/// failed): run after a cancel, and before each frame is kept.
pub(crate) fn sweep(shared: &Shared) {
    let Ok(entries) = std::fs::read_dir(shared.config.kept_frames_dir()) else {
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
pub(crate) fn read_frame(path: &Path) -> std::io::Result<Image> {
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
}
