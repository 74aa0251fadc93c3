//! A tile's partial sums as stored: a compact little-endian encoding, and its checked
//! decoding (a value that does not fit its tile is refused, not guessed).

use std::ops::Range;

use tessera_render::film::AovSums;
use tessera_render::{PixelRect, TileSums};

/// Bytes a pixel's sums take: sum and sum of squares (6 f64) and count (u32).
pub const PIXEL_BYTES: usize = 52;
/// Bytes a pixel's AOV sums add: albedo and normal (6 f64), depth (f64), hits and count (2 u32).
pub const AOV_BYTES: usize = 64;

/// Serialises partial sums: sample range, non-finite count, then the f64 and u32 arrays,
/// little-endian, and the AOVs' arrays after them when there are any (the length tells). The
/// rectangle is the job's business and is not stored.
pub fn encode_sums(t: &TileSums) -> Vec<u8> {
    let n = t.sum.len();
    let aov = if t.aov.is_some() { AOV_BYTES } else { 0 };
    let mut out = Vec::with_capacity(20 + n * (PIXEL_BYTES + aov));
    out.extend_from_slice(&t.samples.start.to_le_bytes());
    out.extend_from_slice(&t.samples.end.to_le_bytes());
    out.extend_from_slice(&t.nonfinite.to_le_bytes());
    out.extend_from_slice(&(n as u32).to_le_bytes());
    for v in t.sum.iter().chain(&t.sum_sq) {
        for c in v {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for c in &t.count {
        out.extend_from_slice(&c.to_le_bytes());
    }
    if let Some(a) = &t.aov {
        for v in a.albedo.iter().chain(&a.normal) {
            for c in v {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        for d in &a.depth {
            out.extend_from_slice(&d.to_le_bytes());
        }
        for c in a.hits.iter().chain(&a.count) {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out
}

/// Inverse of [`encode_sums`] for a tile of rectangle `rect`.
pub fn decode_sums(bytes: &[u8], rect: PixelRect) -> Result<TileSums, String> {
    let n = rect.area();
    let with_aov = bytes.len() == 20 + n * (PIXEL_BYTES + AOV_BYTES);
    if bytes.len() != 20 + n * PIXEL_BYTES && !with_aov {
        return Err(format!(
            "{} bytes where a {}×{} tile needs {} ({} with AOVs)",
            bytes.len(),
            rect.width,
            rect.height,
            20 + n * PIXEL_BYTES,
            20 + n * (PIXEL_BYTES + AOV_BYTES)
        ));
    }
    let u32_at =
        |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let u64_at = |o: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[o..o + 8]);
        u64::from_le_bytes(b)
    };
    if u32_at(16) as usize != n {
        return Err(format!("pixel count {} where the tile has {n}", u32_at(16)));
    }
    let samples: Range<u32> = u32_at(0)..u32_at(4);
    let f = |i: usize| f64::from_bits(u64_at(20 + 8 * i));
    let sum = (0..n)
        .map(|p| [f(3 * p), f(3 * p + 1), f(3 * p + 2)])
        .collect();
    let sum_sq = (0..n)
        .map(|p| [f(3 * (n + p)), f(3 * (n + p) + 1), f(3 * (n + p) + 2)])
        .collect();
    let count = (0..n).map(|p| u32_at(20 + 48 * n + 4 * p)).collect();
    Ok(TileSums {
        rect,
        samples,
        sum,
        sum_sq,
        count,
        nonfinite: u64_at(8),
        aov: with_aov.then(|| {
            let base = 20 + PIXEL_BYTES * n;
            let g = |i: usize| f64::from_bits(u64_at(base + 8 * i));
            let triple = |at: usize| {
                (0..n).map(move |p| [g(at + 3 * p), g(at + 3 * p + 1), g(at + 3 * p + 2)])
            };
            let ints = base + 56 * n;
            Box::new(AovSums {
                albedo: triple(0).collect(),
                normal: triple(3 * n).collect(),
                depth: (0..n).map(|p| g(6 * n + p)).collect(),
                hits: (0..n).map(|p| u32_at(ints + 4 * p)).collect(),
                count: (0..n).map(|p| u32_at(ints + 4 * (n + p))).collect(),
            })
        }),
    })
}
