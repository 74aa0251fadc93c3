//! The dashboard's progressive preview: a snapshot of a job's merged means (or, once it is
//! done, of its EXR), tone-mapped and encoded as PNG.
//!
//! A snapshot is taken at most every [`MIN_INTERVAL`] per job however many people watch, and
//! each (exposure, view) of it is encoded once. Taking it copies means out of the scheduler a
//! few tiles per lock, so a merge never waits behind a whole frame; tone-mapping and encoding
//! run on the blocking pool with no lock held.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tessera_proto::ids::JobId;
use tessera_render::output::{read_exr_channel, read_exr_rgb, tone_map, Preview};
use tessera_render::PixelRect;

use crate::job::{aov_means, preview_step, PreviewSource, Thumb, TileMeans, MAX_KEPT_TILE_NOISE};
use crate::shared::Shared;
use crate::store::JobPhase;

/// The least time between two snapshots of one job.
pub const MIN_INTERVAL: Duration = Duration::from_millis(250);

/// Jobs whose snapshots are kept: the ones being watched. A snapshot of a frame at the
/// largest preview size holds 1600² means (31 MB), so this bounds the cache to about 120 MB.
const KEPT: usize = 4;

/// Encodings kept per snapshot: a few people at a few exposures. A client asking for many
/// exposures gets each encoded, but the cache does not grow with them.
const PNGS_PER_SNAPSHOT: usize = 8;

/// Tiles copied per hold of the scheduler's lock.
const TILES_PER_LOCK: u32 = 4;

/// What a preview shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum View {
    /// The image, tone-mapped.
    Color,
    /// Each tile coloured by its relative noise (blue low, red high), shaded by the image.
    Noise,
    /// The denoised image of a job submitted with `--denoise`, tone-mapped: a finished job's
    /// layer, or, while it runs, its preview filtered here (see [`Previews::png`]).
    Denoised,
}

/// Why there is no preview.
#[derive(Debug)]
pub enum NoPreview {
    /// No such job.
    Unknown,
    /// It is a frame range: its frames have previews, not the range.
    Range,
    /// It ended without an image, or (for the noise view) its per-tile noise was not kept.
    Gone(String),
    /// Reading its EXR or encoding failed.
    Failed(String),
}

/// Means of a frame, averaged down by `step`, and each tile's relative noise.
struct Frame {
    width: u32,
    height: u32,
    step: u32,
    rgb: Vec<[f32; 3]>,
    /// Per tile: its rectangle and relative noise (NaN where it has no samples yet).
    tiles: Vec<(PixelRect, f32)>,
    /// The denoised layer's means, averaged down as `rgb` is: a finished job's that was
    /// denoised (`submit --denoise`), none otherwise.
    denoised: Option<Vec<[f32; 3]>>,
    /// A running job's albedo and normal means, averaged down as `rgb` is, when it gathers
    /// them (a job submitted with `--denoise`), and how it is denoised: what a live denoised
    /// preview is filtered with.
    aux: Option<(Vec<[[f32; 3]; 2]>, crate::store::DenoiseRecord)>,
}

impl Frame {
    fn new(width: u32, height: u32) -> (Self, Vec<u32>) {
        let step = preview_step(width, height);
        let (w, h) = (width.div_ceil(step), height.div_ceil(step));
        let n = w as usize * h as usize;
        (
            Self {
                width: w,
                height: h,
                step,
                rgb: vec![[0.0; 3]; n],
                tiles: Vec::new(),
                denoised: None,
                aux: None,
            },
            vec![0; n],
        )
    }

    /// A whole `width` × `height` image averaged down to its preview.
    fn down(width: u32, height: u32, rgb: &[[f32; 3]]) -> Self {
        let (mut frame, mut weights) = Frame::new(width, height);
        for (i, p) in rgb.iter().enumerate() {
            let (x, y) = ((i % width as usize) as u32, (i / width as usize) as u32);
            frame.add(&mut weights, x, y, *p);
        }
        frame.finish(&weights);
        frame
    }

    /// Adds the full-resolution pixel (x, y)'s mean to its preview pixel.
    fn add(&mut self, weights: &mut [u32], x: u32, y: u32, m: [f32; 3]) {
        let i = (y / self.step) as usize * self.width as usize + (x / self.step) as usize;
        if let (Some(p), Some(k)) = (self.rgb.get_mut(i), weights.get_mut(i)) {
            for c in 0..3 {
                p[c] += m[c];
            }
            *k += 1;
        }
    }

    /// Adds the full-resolution pixel (x, y)'s albedo and normal means to its preview pixel
    /// (after [`Frame::add`] of its colour, which counts it).
    fn add_aux(&mut self, x: u32, y: u32, m: [[f32; 3]; 2]) {
        let i = (y / self.step) as usize * self.width as usize + (x / self.step) as usize;
        if let Some(p) = self.aux.as_mut().and_then(|(a, _)| a.get_mut(i)) {
            add_pair(p, &m);
        }
    }

    /// Adds a tile's kept means ([`Thumb`], made at this preview's step) to their preview
    /// pixels.
    fn add_thumb(&mut self, weights: &mut [u32], t: &Thumb) {
        for (j, (s, &k)) in t.sum.iter().zip(&t.count).enumerate() {
            let (x, y) = (
                t.origin.0 + j as u32 % t.width,
                t.origin.1 + j as u32 / t.width,
            );
            let i = y as usize * self.width as usize + x as usize;
            if let (Some(p), Some(w)) = (self.rgb.get_mut(i), weights.get_mut(i)) {
                for c in 0..3 {
                    p[c] += s[c];
                }
                *w += k;
            }
            if let (Some(p), Some(m)) = (
                self.aux.as_mut().and_then(|(a, _)| a.get_mut(i)),
                t.aux.get(j),
            ) {
                add_pair(p, m);
            }
        }
    }

    /// Divides each preview pixel by the full-resolution pixels it gathered; with a step of
    /// 1 that is a division by 1, so a preview of a small frame holds its exact means.
    fn finish(&mut self, weights: &[u32]) {
        if self.step == 1 {
            return;
        }
        for (p, &k) in self.rgb.iter_mut().zip(weights) {
            if k > 1 {
                for c in p.iter_mut() {
                    *c /= k as f32;
                }
            }
        }
        if let Some((aux, _)) = &mut self.aux {
            for (p, &k) in aux.iter_mut().zip(weights) {
                if k > 1 {
                    for c in p.as_flattened_mut() {
                        *c /= k as f32;
                    }
                }
            }
        }
    }
}

fn add_pair(to: &mut [[f32; 3]; 2], from: &[[f32; 3]; 2]) {
    for (a, b) in to.iter_mut().zip(from) {
        for c in 0..3 {
            a[c] += b[c];
        }
    }
}

/// A PNG's exposure (in tenths of a stop) and view.
type PngKey = (i32, View);

/// A job's latest snapshot and the PNGs made from it.
struct Cached {
    /// The job's phase and merged units when it was taken.
    version: (JobPhase, u64),
    frame: Arc<Frame>,
    taken: Instant,
    pngs: tokio::sync::Mutex<HashMap<PngKey, Arc<Vec<u8>>>>,
}

/// The previews of the jobs being watched.
#[derive(Default)]
pub struct Previews {
    jobs: tokio::sync::Mutex<HashMap<JobId, Arc<Cached>>>,
    /// Running jobs' denoised previews: when each was made, what it cost, and the image;
    /// and when the coordinator may filter the next one, whatever the job.
    live: tokio::sync::Mutex<(HashMap<JobId, Live>, Option<Instant>)>,
}

/// A running job's preview as the filter gave it.
struct Live {
    made: Instant,
    cost: Duration,
    rgb: Arc<Vec<[f32; 3]>>,
}

/// The least time between two denoised previews of one running job, and the share of its
/// time the coordinator may spend filtering them: one is made again only once ten times what
/// the last one cost has passed, for that job and for any job (a client that asks for many
/// jobs' in turn gets each job's last one, or none yet, rather than the coordinator's cores).
const LIVE_INTERVAL: Duration = Duration::from_secs(2);
const LIVE_COST_SHARE: u32 = 10;

impl Previews {
    /// The PNG of job `id` at `exposure` stops in `view`.
    pub async fn png(
        &self,
        shared: &Arc<Shared>,
        id: JobId,
        exposure: f32,
        view: View,
    ) -> Result<Arc<Vec<u8>>, NoPreview> {
        let cached = self.snapshot(shared, id).await?;
        if view == View::Noise && cached.frame.tiles.is_empty() {
            return Err(NoPreview::Gone(format!(
                "{id} has ended and its per-tile noise is not kept (it ended before the \
                 coordinator's last start, or has more than {MAX_KEPT_TILE_NOISE} tiles)"
            )));
        }
        let live = match (view, &cached.frame.denoised, &cached.frame.aux) {
            (View::Denoised, None, Some(_)) => Some(self.live(id, &cached).await?),
            (View::Denoised, None, None) => {
                return Err(NoPreview::Gone(format!(
                    "{id} has no denoised image (it was not submitted with --denoise)"
                )))
            }
            _ => None,
        };
        // Tenths of a stop: finer steps look the same and would only fill the cache.
        let key = ((exposure.clamp(-20.0, 20.0) * 10.0).round() as i32, view);
        let mut pngs = cached.pngs.lock().await;
        if let Some(p) = pngs.get(&key) {
            return Ok(p.clone());
        }
        let frame = cached.frame.clone();
        let png = tokio::task::spawn_blocking(move || {
            encode(
                &frame,
                live.as_deref().map(Vec::as_slice),
                key.0 as f32 / 10.0,
                view,
            )
        })
        .await
        .map_err(|e| NoPreview::Failed(e.to_string()))??;
        let png = Arc::new(png);
        if pngs.len() >= PNGS_PER_SNAPSHOT {
            pngs.clear();
        }
        pngs.insert(key, png.clone());
        Ok(png)
    }

    /// Job `id`'s running preview, denoised on this machine (Open Image Denoise at `fast`,
    /// on the preview's pixels: a picture of where the frame is going, not its final denoised
    /// layer): the last one made while it is recent (see [`LIVE_COST_SHARE`]), else one of
    /// `cached`. Without the library here, none, saying so.
    async fn live(&self, id: JobId, cached: &Cached) -> Result<Arc<Vec<[f32; 3]>>, NoPreview> {
        let mut guard = self.live.lock().await;
        let (live, next) = &mut *guard;
        let busy = next.is_some_and(|t| Instant::now() < t);
        if let Some(l) = live.get(&id) {
            if busy || l.made.elapsed() < LIVE_INTERVAL.max(l.cost * LIVE_COST_SHARE) {
                return Ok(l.rgb.clone());
            }
        } else if let (true, Some(t)) = (busy, *next) {
            return Err(NoPreview::Gone(format!(
                "the coordinator spends at most a tenth of its time on denoised previews; this \
                 job's is made in {:.0} s",
                t.saturating_duration_since(Instant::now())
                    .as_secs_f64()
                    .ceil()
            )));
        }
        let frame = Arc::clone(&cached.frame);
        let started = Instant::now();
        let rgb = tokio::task::spawn_blocking(move || denoise_preview(&frame))
            .await
            .map_err(|e| NoPreview::Failed(e.to_string()))??;
        let rgb = Arc::new(rgb);
        if live.len() >= KEPT && !live.contains_key(&id) {
            if let Some(oldest) = live.iter().min_by_key(|(_, l)| l.made).map(|(k, _)| *k) {
                live.remove(&oldest);
            }
        }
        let cost = started.elapsed();
        *next = Some(Instant::now() + cost * LIVE_COST_SHARE);
        live.insert(
            id,
            Live {
                made: Instant::now(),
                cost,
                rgb: rgb.clone(),
            },
        );
        Ok(rgb)
    }

    /// The job's snapshot: the cached one while it is fresh (or nothing changed), else a new one. One
    /// caller at a time takes it, and those who waited get it from the cache.
    async fn snapshot(&self, shared: &Arc<Shared>, id: JobId) -> Result<Arc<Cached>, NoPreview> {
        let mut jobs = self.jobs.lock().await;
        let version = shared.scheduler().job(id).map(|j| j.preview_version());
        if let Some(c) = jobs.get(&id) {
            // Nothing merged since, or a fresh snapshot of a job still in the same phase: a
            // job that has just ended is shown as it ended, at once.
            let same_phase = version.is_some_and(|v| v.0 == c.version.0);
            if Some(c.version) == version || (same_phase && c.taken.elapsed() < MIN_INTERVAL) {
                return Ok(c.clone());
            }
        }
        let frame = Arc::new(take(shared, id).await?);
        shared
            .metrics
            .previews
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let cached = Arc::new(Cached {
            version: version.unwrap_or((JobPhase::Active, 0)),
            frame,
            taken: Instant::now(),
            pngs: Default::default(),
        });
        if jobs.len() >= KEPT && !jobs.contains_key(&id) {
            if let Some(oldest) = jobs.iter().min_by_key(|(_, c)| c.taken).map(|(k, _)| *k) {
                jobs.remove(&oldest);
            }
        }
        jobs.insert(id, cached.clone());
        Ok(cached)
    }
}

/// Takes a snapshot of job `id`: its merged means while it runs, its EXR once it is done.
async fn take(shared: &Arc<Shared>, id: JobId) -> Result<Frame, NoPreview> {
    let PreviewSource {
        phase,
        width,
        height,
        tiles: n_tiles,
        output,
        kept_noise,
        denoise,
    } = {
        let core = shared.scheduler();
        if core.is_range(id) {
            return Err(NoPreview::Range);
        }
        core.job(id).ok_or(NoPreview::Unknown)?.preview_source()
    };
    match phase {
        JobPhase::Active => {}
        JobPhase::Done => {
            let path = shared.config.output_path(&output);
            let mut frame = tokio::task::spawn_blocking(move || from_exr(&path))
                .await
                .map_err(|e| NoPreview::Failed(e.to_string()))??;
            frame.tiles = kept_noise;
            return Ok(frame);
        }
        JobPhase::Cancelled | JobPhase::Failed => {
            return Err(NoPreview::Gone(format!(
                "{id} ended without an image ({phase:?})"
            )))
        }
    }
    let (mut frame, mut weights) = Frame::new(width, height);
    if let Some(how) = denoise {
        frame.aux = Some((vec![[[0.0; 3]; 2]; frame.rgb.len()], how));
    }
    let mut first = 0;
    while first < n_tiles {
        let last = (first + TILES_PER_LOCK).min(n_tiles);
        copy_tiles(shared, id, first..last, &mut frame, &mut weights)?;
        first = last;
        // Lets merges waiting for the lock in between.
        tokio::task::yield_now().await;
    }
    frame.finish(&weights);
    Ok(frame)
}

/// Copies the means and noise of job `id`'s `tiles` into `frame`, under one hold of the
/// scheduler's lock.
fn copy_tiles(
    shared: &Shared,
    id: JobId,
    tiles: std::ops::Range<u32>,
    frame: &mut Frame,
    weights: &mut [u32],
) -> Result<(), NoPreview> {
    let core = shared.scheduler();
    let job = core.job(id).ok_or(NoPreview::Unknown)?;
    for t in tiles {
        let Some((rect, rel, means)) = job.preview_tile(t) else {
            continue;
        };
        frame.tiles.push((rect, rel));
        let sums = match means {
            TileMeans::Empty => continue,
            TileMeans::Thumb(thumb) => {
                frame.add_thumb(weights, thumb);
                continue;
            }
            TileMeans::Sums(sums) => sums,
        };
        for (i, (s, &k)) in sums.sum.iter().zip(&sums.count).enumerate() {
            let x = rect.x0 + i as u32 % rect.width;
            let y = rect.y0 + i as u32 / rect.width;
            // The mean as the EXR will hold it: f64 division, then f32.
            let m = if k > 0 {
                s.map(|c| (c / k as f64) as f32)
            } else {
                [0.0; 3]
            };
            frame.add(weights, x, y, m);
            if let Some(aov) = &sums.aov {
                frame.add_aux(x, y, aov_means(aov, i));
            }
        }
    }
    Ok(())
}

/// A finished job's frame from its EXR.
fn from_exr(path: &std::path::Path) -> Result<Frame, NoPreview> {
    let img = read_exr_rgb(path).map_err(|e| NoPreview::Failed(e.to_string()))?;
    let (w, h) = (img.width as u32, img.height as u32);
    let mut frame = Frame::down(w, h, &img.rgb);
    // A file without the layer (most jobs') simply has no denoised view.
    let layer = ["R", "G", "B"].map(|c| read_exr_channel(path, &format!("denoised.{c}")).ok());
    if let [Some(r), Some(g), Some(b)] = layer {
        let rgb: Vec<[f32; 3]> = (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect();
        if rgb.len() == img.rgb.len() {
            frame.denoised = Some(Frame::down(w, h, &rgb).rgb);
        }
    }
    Ok(frame)
}

/// A running frame's preview filtered with its albedo and normal.
fn denoise_preview(frame: &Frame) -> Result<Vec<[f32; 3]>, NoPreview> {
    let Some((aux, how)) = &frame.aux else {
        return Err(NoPreview::Gone(
            "no albedo and normal to denoise with".into(),
        ));
    };
    let albedo: Vec<[f32; 3]> = aux.iter().map(|a| a[0]).collect();
    let normal: Vec<[f32; 3]> = aux.iter().map(|a| a[1]).collect();
    let options = tessera_denoise::Options {
        quality: tessera_denoise::Quality::Fast,
        hdr: how.hdr,
        threads: None,
    };
    let input = tessera_denoise::Frame {
        width: frame.width,
        height: frame.height,
        color: &frame.rgb,
        albedo: &albedo,
        normal: &normal,
    };
    match tessera_denoise::denoise(&input, &options) {
        Ok(d) => Ok(d.color),
        Err(
            e @ (tessera_denoise::DenoiseError::Missing { .. }
            | tessera_denoise::DenoiseError::Unusable { .. }),
        ) => Err(NoPreview::Gone(format!(
            "a running job's denoised preview is made by the coordinator, which cannot load \
             Open Image Denoise ({e}); the finished frame has its denoised layer"
        ))),
        Err(e) => Err(NoPreview::Failed(e.to_string())),
    }
}

/// Relative noise mapped to a colour: log scale from 0.1% (blue) to 100% (red).
fn heat(rel: f32) -> [f32; 3] {
    if !rel.is_finite() {
        return [0.15, 0.15, 0.15];
    }
    let t = ((rel.max(1e-3).log10() + 3.0) / 3.0).clamp(0.0, 1.0);
    // Blue, cyan, green, yellow, red.
    let stops = [
        [0.10, 0.20, 0.90],
        [0.10, 0.80, 0.90],
        [0.20, 0.85, 0.20],
        [0.95, 0.90, 0.15],
        [0.90, 0.15, 0.10],
    ];
    let x = t * (stops.len() - 1) as f32;
    let i = (x.floor() as usize).min(stops.len() - 2);
    let f = x - i as f32;
    let (a, b) = (stops[i], stops[i + 1]);
    [0, 1, 2].map(|c| a[c] + (b[c] - a[c]) * f)
}

/// The PNG of `frame` in `view`.
fn encode(
    frame: &Frame,
    live: Option<&[[f32; 3]]>,
    exposure: f32,
    view: View,
) -> Result<Vec<u8>, NoPreview> {
    let shown = match (view, live, &frame.denoised) {
        (View::Denoised, Some(d), _) => d,
        (View::Denoised, None, Some(d)) => d,
        _ => &frame.rgb,
    };
    let mut rgb = tone_map(shown, Preview { exposure });
    if view == View::Noise {
        let w = frame.width as usize;
        for &(rect, rel) in &frame.tiles {
            let col = heat(rel);
            let s = frame.step;
            for y in rect.y0 / s..(rect.y0 + rect.height).div_ceil(s).min(frame.height) {
                for x in rect.x0 / s..(rect.x0 + rect.width).div_ceil(s).min(frame.width) {
                    let i = 3 * (y as usize * w + x as usize);
                    let Some(px) = rgb.get_mut(i..i + 3) else {
                        continue;
                    };
                    let luma = (px[0] as f32 + px[1] as f32 + px[2] as f32) / (3.0 * 255.0);
                    // Tiles' top and left edges darker, so that tiles of one colour are told
                    // apart.
                    let edge = x == rect.x0 / s || y == rect.y0 / s;
                    let shade = if edge { 0.3 } else { 0.45 + 0.55 * luma };
                    for c in 0..3 {
                        px[c] = (col[c] * shade * 255.0).round().clamp(0.0, 255.0) as u8;
                    }
                }
            }
        }
    }
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, frame.width, frame.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    // A preview is fetched again and again: fast beats small.
    enc.set_compression(png::Compression::Fast);
    let fail = |e: png::EncodingError| NoPreview::Failed(format!("PNG: {e}"));
    let mut w = enc.write_header().map_err(fail)?;
    w.write_image_data(&rgb).map_err(fail)?;
    w.finish().map_err(fail)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_frame_keeps_its_pixels_and_a_large_one_is_averaged_down() {
        let (f, _) = Frame::new(640, 480);
        assert_eq!((f.width, f.height, f.step), (640, 480, 1));
        let (mut f, mut w) = Frame::new(4000, 10);
        assert_eq!((f.width, f.height, f.step), (1334, 4, 3));
        for x in 0..3 {
            f.add(&mut w, x, 0, [x as f32, 0.0, 0.0]);
        }
        f.finish(&w);
        assert_eq!(f.rgb[0], [1.0, 0.0, 0.0]);
    }

    #[test]
    fn the_heat_map_runs_from_blue_to_red_and_greys_out_tiles_without_samples() {
        assert!(heat(0.001)[2] > 0.8 && heat(0.001)[0] < 0.2);
        assert!(heat(1.0)[0] > 0.8 && heat(1.0)[2] < 0.2);
        assert_eq!(heat(f32::NAN), [0.15, 0.15, 0.15]);
    }
}
