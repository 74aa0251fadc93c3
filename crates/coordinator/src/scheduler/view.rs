//! The read model ([`tessera_proto::view`]) built from the scheduler's state: the one place
//! that says what a job's state, progress, rate and ETA are, and how a frame range folds its
//! frames into one. The gRPC handlers send these views as protobuf, the dashboard as JSON.

use std::time::Instant;

use tessera_proto::ids::JobId;
use tessera_proto::view::{CheckView, FrameView, JobState, SettingsView, WorkerState};
pub use tessera_proto::view::{JobView, WorkerView};

use super::{Scheduler, Worker};
use crate::job::Job;
use crate::metrics::{Gauges, WorkerLine};
use crate::store::JobPhase;

impl Scheduler {
    /// The view of job `id`: a one-frame job, one frame of a range, or a range folded into one.
    pub fn job_view(&self, id: JobId, now: Instant) -> Option<JobView> {
        match self.ranges.get(&id) {
            Some(members) => self.range_view(id, members, now),
            None => self.jobs.get(&id).map(|j| self.frame_view(j, now)),
        }
    }

    /// Every job in scheduling order, a frame range as one row where its first frame would be.
    pub fn job_views(&self, now: Instant) -> Vec<JobView> {
        self.schedule_order(false)
            .into_iter()
            .filter_map(|id| match self.jobs.get(&id)?.rec.range {
                None => self.job_view(id, now),
                Some(r) if self.ranges.get(&JobId(r.id))?.first() == Some(&id) => {
                    self.job_view(JobId(r.id), now)
                }
                Some(_) => None,
            })
            .collect()
    }

    /// Up to `size` of the jobs as [`Scheduler::listing`] orders them, from `offset`, and
    /// the offset of the next page if there is more.
    pub fn job_page(
        &self,
        now: Instant,
        offset: usize,
        size: usize,
    ) -> (Vec<JobView>, Option<usize>) {
        let mut all = self.listing(now);
        let more = all.len() > offset.saturating_add(size);
        let page = all.drain(offset.min(all.len())..).take(size).collect();
        (page, more.then_some(offset + size))
    }

    /// Every job as a listing shows them: those still to finish first, in scheduling order
    /// (priority, then submission), then the ended ones, most recently ended first. A user
    /// looks for what is running, not for last week's highest-priority job.
    pub fn listing(&self, now: Instant) -> Vec<JobView> {
        let (mut live, mut ended): (Vec<JobView>, Vec<JobView>) = self
            .job_views(now)
            .into_iter()
            .partition(|v| v.finished_unix_ms.is_none());
        ended.sort_by_key(|v| std::cmp::Reverse((v.finished_unix_ms, v.job_id)));
        live.append(&mut ended);
        live
    }

    /// Every worker registered in this boot, by number.
    pub fn worker_views(&self, now: Instant) -> Vec<WorkerView> {
        self.workers
            .iter()
            .map(|(&n, w)| {
                let alive = w.alive(now, self.policy.lease_time);
                WorkerView {
                    worker_id: self.worker_id(n),
                    name: w.name.clone(),
                    host: (!w.host.is_empty()).then(|| w.host.clone()),
                    cores: w.cores,
                    version: w.version.clone(),
                    state: WorkerState::of(
                        w.convicted.is_some(),
                        w.quarantined,
                        !w.disputes.is_empty(),
                        w.draining,
                        alive,
                    ),
                    alive,
                    leases: self.leases_of(n) as u32,
                    units_done: w.units_done,
                    samples_done: w.samples_done,
                    samples_per_second: w.rate.per_second(now),
                    bad_results: w.bad_results,
                    audits_passed: w.audits_passed,
                    convicted: w.convicted.clone(),
                    last_seen_seconds_ago: now.duration_since(w.last_seen).as_secs_f64(),
                    memory_bytes: w.caps.memory_bytes,
                    cpu_features: w.caps.cpu_features.clone(),
                    tags: w.caps.tags.clone(),
                    denoise_version: w.caps.denoise_version,
                }
            })
            .collect()
    }

    /// The gauges of `/metrics`: jobs by state, workers, leases, and the counters.
    pub fn gauges(&self, now: Instant) -> Gauges {
        let states = [
            JobState::Queued,
            JobState::Running,
            JobState::Done,
            JobState::Cancelled,
            JobState::Failed,
        ];
        let alive = |w: &Worker| w.alive(now, self.policy.lease_time);
        Gauges {
            jobs: states
                .into_iter()
                .map(|s| {
                    (
                        s.name(),
                        self.jobs.values().filter(|j| j.state() == s).count() as u64,
                    )
                })
                .collect(),
            workers_active: self.workers.values().filter(|w| alive(w)).count() as u64,
            workers_quarantined: self.workers.values().filter(|w| w.quarantined).count() as u64,
            log_bytes: self.log_bytes(),
            leases: self.leases_live(),
            counters: self.counters,
            workers: self
                .workers
                .iter()
                .filter(|(_, w)| alive(w))
                .map(|(&n, w)| WorkerLine {
                    id: self.worker_id(n).to_string(),
                    name: w.name.clone(),
                    rate: w.rate.per_second(now),
                    samples: w.samples_done,
                })
                .collect(),
            store_file_bytes: None,
        }
    }

    /// A job of one frame (or one frame of a range) as it stands.
    fn frame_view(&self, job: &Job, now: Instant) -> JobView {
        let rec = &job.rec;
        let state = job.state();
        let (units_total, units_done, samples_total, samples_done) = job.progress();
        let rate = job.rate(now);
        // A paused job keeps its recent rate for a while, but is going nowhere: no ETA.
        let eta = match state {
            JobState::Done => Some(0.0),
            JobState::Queued | JobState::Running if rate > 0.0 && !rec.paused => {
                Some(samples_total.saturating_sub(samples_done) as f64 / rate)
            }
            _ => None,
        };
        let (noise_rms, noise_relative) = job.noise();
        let sampled = samples_done > 0;
        JobView {
            job_id: job.id(),
            state,
            error: rec.error.clone(),
            scene: rec.scene_name.clone(),
            scene_sha256: rec.scene_hash.clone(),
            width: rec.width,
            height: rec.height,
            settings: SettingsView::from(&job.settings()),
            tile_size: rec.tile_size,
            priority: rec.priority,
            units_done,
            units_total,
            units_leased: self.units_leased(job),
            samples_done,
            samples_total,
            samples_per_second: rate,
            eta_seconds: eta,
            noise_rms: sampled.then_some(noise_rms),
            noise_relative: sampled.then_some(noise_relative),
            // A done job's count is kept in its record, since its sums (which count them) are
            // gone after a restart.
            nonfinite_samples: job.nonfinite.max(rec.checks.nonfinite),
            output: rec.output_name.clone(),
            submitted_unix_ms: rec.submitted_ms,
            finished_unix_ms: (rec.phase != JobPhase::Active).then_some(rec.finished_ms),
            range_job_id: rec.range.map(|r| JobId(r.id)),
            frame_range: None,
            frames: Vec::new(),
            checks: CheckView::failed(&rec.checks, ""),
            after: rec.after.map(JobId),
            paused: rec.paused && rec.phase == JobPhase::Active,
            require: rec.require.clone(),
            min_memory_bytes: rec.min_memory,
            progressive: rec.progressive,
            failures: rec.failures.len() as u32,
            blocklist: rec.blocklist.clone(),
            retries: rec.retries,
            retryable: job.retryable,
            submitter: rec.submitter.clone(),
            waiting: self.denoise_waiting(job.id(), now).or_else(|| {
                (job.is_live() && !self.held(job.id()))
                    .then(|| self.waiting(rec, now))
                    .flatten()
            }),
        }
    }

    /// A frame-range job: its frames' views folded into one, and each frame's own.
    fn range_view(&self, id: JobId, members: &[JobId], now: Instant) -> Option<JobView> {
        let frames: Vec<JobView> = members
            .iter()
            .filter_map(|m| self.jobs.get(m))
            .map(|j| self.frame_view(j, now))
            .collect();
        let first = frames.first()?;
        let range = self.jobs.get(&members[0])?.rec.range?;
        let state = JobState::of_range(frames.iter().map(|f| f.state));
        let error = range_error(&frames);
        let sum = |f: fn(&JobView) -> u64| frames.iter().map(f).sum::<u64>();
        let (samples_total, samples_done) = (sum(|s| s.samples_total), sum(|s| s.samples_done));
        // Ended frames keep their last rate for a while; only the frames still going add up.
        let rate: f64 = frames
            .iter()
            .filter(|f| !f.state.is_final())
            .map(|f| f.samples_per_second)
            .sum();
        let eta = range_eta(
            state,
            &frames,
            samples_total.saturating_sub(samples_done),
            rate,
        );
        // The worst frame's noise: the figure a user waiting for the whole range needs.
        let worst = frames
            .iter()
            .filter_map(|f| Some((f.noise_relative?, f)))
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, f)| f);
        let mut settings = first.settings;
        settings.frame = None;
        Some(JobView {
            job_id: id,
            state,
            error,
            scene: first.scene.clone(),
            scene_sha256: first.scene_sha256.clone(),
            width: first.width,
            height: first.height,
            settings,
            tile_size: first.tile_size,
            priority: first.priority,
            units_done: sum(|s| s.units_done),
            units_total: sum(|s| s.units_total),
            units_leased: sum(|s| s.units_leased),
            samples_done,
            samples_total,
            samples_per_second: rate,
            eta_seconds: eta,
            noise_rms: worst.and_then(|w| w.noise_rms),
            noise_relative: worst.and_then(|w| w.noise_relative),
            nonfinite_samples: sum(|s| s.nonfinite_samples),
            output: range_output_pattern(&first.output),
            submitted_unix_ms: first.submitted_unix_ms,
            finished_unix_ms: if state.is_final() {
                frames.iter().filter_map(|f| f.finished_unix_ms).max()
            } else {
                None
            },
            range_job_id: None,
            frame_range: Some(range.frames),
            after: first.after,
            paused: frames.iter().any(|f| f.paused),
            require: first.require.clone(),
            min_memory_bytes: first.min_memory_bytes,
            progressive: first.progressive,
            failures: frames.iter().map(|f| f.failures).sum(),
            retries: frames.iter().map(|f| f.retries).sum(),
            submitter: first.submitter.clone(),
            retryable: frames.iter().any(|f| f.retryable),
            blocklist: {
                let mut names: Vec<String> =
                    frames.iter().flat_map(|f| f.blocklist.clone()).collect();
                names.sort();
                names.dedup();
                names
            },
            waiting: frames.iter().find_map(|f| f.waiting.clone()),
            checks: range_checks(&frames),
            frames: frames.into_iter().map(frame_of_range).collect(),
        })
    }
}

/// `shot.0001.exr` → `shot.####.exr`: how a range's output names are shown.
fn range_output_pattern(first_frame_name: &str) -> String {
    let stem = first_frame_name
        .strip_suffix(".exr")
        .unwrap_or(first_frame_name);
    let stem = stem.rsplit_once('.').map_or(stem, |(s, _)| s);
    format!("{stem}.####.exr")
}
/// A frame range's error: how many frames failed, and the first one's reason.
fn range_error(frames: &[JobView]) -> String {
    let failed: Vec<String> = frames
        .iter()
        .filter(|f| f.state == JobState::Failed)
        .map(|f| {
            format!(
                "frame {} ({}): {}",
                f.settings.frame.unwrap_or_default(),
                f.job_id,
                f.error
            )
        })
        .collect();
    match failed.len() {
        0 => String::new(),
        n => format!(
            "{n} of {} frames failed; {}",
            frames.len(),
            failed.first().map_or("", |f| f.as_str())
        ),
    }
}

/// A frame range's ETA: `left` samples at the frames' summed `rate`, none while every frame
/// still to finish is paused.
fn range_eta(state: JobState, frames: &[JobView], left: u64, rate: f64) -> Option<f64> {
    match state {
        JobState::Done => Some(0.0),
        JobState::Running | JobState::Queued
            if rate > 0.0 && !frames.iter().all(|f| f.paused || f.state.is_final()) =>
        {
            Some(left as f64 / rate)
        }
        _ => None,
    }
}

/// Every flagged frame's checks, named, so that one flagged frame of 240 is seen.
fn range_checks(frames: &[JobView]) -> Vec<CheckView> {
    frames
        .iter()
        .flat_map(|f| {
            let frame = f.settings.frame.unwrap_or_default();
            f.checks.iter().map(move |c| CheckView {
                code: c.code.clone(),
                message: format!("frame {frame}: {}", c.message),
            })
        })
        .collect()
}

/// A frame's line in its range's view.
fn frame_of_range(f: JobView) -> FrameView {
    FrameView {
        frame: f.settings.frame.unwrap_or_default(),
        job_id: f.job_id,
        state: f.state,
        units_done: f.units_done,
        units_total: f.units_total,
        output: f.output,
        error: f.error,
        checks: f.checks,
    }
}
