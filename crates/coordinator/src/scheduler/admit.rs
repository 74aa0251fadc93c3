//! Admission and restore: a new job is checked against the coordinator's bounds and given an
//! id and an output name no other job or file has; at start-up, the store's jobs are taken
//! back. The checks on a job's own shape are pure ([`Admission::check`]); those that depend on
//! what is running are made under the lock ([`Scheduler::admit`]).

use tessera_proto::ids::JobId;
use tessera_render::scene::FrameRange;
use tessera_render::{
    unit_batch, RenderSettings, DEFAULT_UNIT_SAMPLES, IMAGE_REVISION, TILE_RANGE,
};

use super::Scheduler;
use crate::error::Refusal;
use crate::job::Job;
use crate::names::{check_output_name, OutputNames};
use crate::store::{GuidingRecord, JobPhase, JobRecord, LoadedJob, Op, RangeRef, StoredScene};

/// A job to admit: a parsed scene and checked settings.
#[derive(Debug)]
pub struct Admission {
    /// The scene's content hash.
    pub scene_hash: String,
    /// The scene as submitted (kept for workers to fetch).
    pub scene: StoredScene,
    /// Image width, from the scene.
    pub width: u32,
    /// Image height, from the scene.
    pub height: u32,
    /// Render settings, checked against the coordinator's limits.
    pub settings: RenderSettings,
    /// Tile edge, checked.
    pub tile_size: u32,
    /// The output name asked for (checked for form), or none for the job's own.
    pub output_name: Option<String>,
    /// Priority (higher first).
    pub priority: i32,
    /// Write variance channels.
    pub variance: bool,
    /// Write the sample-count channel.
    pub sample_count: bool,
    /// Denoise the finished frame (checked by the caller: this coordinator denoises).
    pub denoise: Option<crate::store::DenoiseRecord>,
    /// The frames of a frame-range job (`settings.frame` is then each frame's own); `None`
    /// for a job of one frame.
    pub frames: Option<FrameRange>,
    /// The job this one starts after, if any.
    pub after: Option<JobId>,
    /// Tags a worker needs for it (checked by the caller with [`tessera_proto::tags`]).
    pub require: Vec<String>,
    /// Least memory a worker needs for it, in bytes.
    pub min_memory: u64,
    /// Lease a range's frames progressively (checked by the caller: only with frames, and
    /// not adaptive).
    pub progressive: bool,
    /// The box a guided job's guides start from
    /// ([`tessera_render::guiding::guide_bounds`] of its scene); not read for other jobs.
    pub guide_bounds: [[f32; 3]; 2],
    /// The user whose token submitted it ([`crate::auth`]; empty without named tokens).
    pub submitter: String,
}

/// Bounds admission enforces.
#[derive(Clone, Copy, Debug)]
pub struct AdmissionLimits {
    /// Most jobs queued or running at once.
    pub max_active_jobs: usize,
    /// Most work units one job may have (one frame of a frame-range job).
    pub max_units_per_job: u64,
    /// Most frames one frame-range job may have.
    pub max_frames_per_job: u64,
}

/// What a client asked for, as the wire carried it: typed, not yet checked.
#[derive(Debug, Clone)]
pub struct Asked {
    /// Render settings.
    pub settings: RenderSettings,
    /// Tile edge; 0 for the coordinator's default.
    pub tile_size: u32,
    /// A frame range as (first, last, step), for a frame-range job.
    pub frames: Option<(u32, u32, u32)>,
    /// The output name asked for, if any.
    pub output_name: Option<String>,
}

/// What a client asked for, checked: what admission builds the job from once its scene is
/// parsed.
#[derive(Debug, Clone)]
pub struct Checked {
    /// Render settings; an adaptive job's noise tiles are its tiles.
    pub settings: RenderSettings,
    /// Tile edge.
    pub tile_size: u32,
    /// The frames of a frame-range job.
    pub frames: Option<FrameRange>,
    /// The output name asked for, of an acceptable form.
    pub output_name: Option<String>,
}

impl Admission {
    /// Checks what a client asked for against the coordinator's fixed bounds (its largest spp,
    /// the tile sizes, one frame or a range, the output name's form), before its scene is
    /// parsed. Pure: the checks that depend on what is running are [`Scheduler::admit`]'s.
    pub fn check(asked: Asked, max_spp: u32, default_tile_size: u32) -> Result<Checked, Refusal> {
        let Asked {
            mut settings,
            tile_size,
            frames,
            output_name,
        } = asked;
        if settings.spp > max_spp {
            return Err(Refusal::Invalid(format!(
                "spp {} must be between 1 and {max_spp}",
                settings.spp
            )));
        }
        let tile_size = if tile_size == 0 {
            default_tile_size
        } else {
            tile_size
        };
        if !TILE_RANGE.contains(&tile_size) {
            return Err(Refusal::Invalid(format!(
                "tile size {tile_size} must be between {} and {}",
                TILE_RANGE.start(),
                TILE_RANGE.end()
            )));
        }
        if let Some(a) = &mut settings.adaptive {
            // Noise decisions are per unit tile: the job's tiles are the target's.
            a.tile = tile_size;
        }
        let frames = match frames {
            // Each frame's guide starts from that frame's box, which admission, parsing the
            // first frame only, does not know.
            Some(_) if settings.guiding => {
                return Err(Refusal::Invalid(
                    "guiding renders one frame per job, not a frame range".into(),
                ))
            }
            Some(_) if settings.frame.is_some() => {
                return Err(Refusal::Invalid(
                    "a job names either one frame or a frame range, not both".into(),
                ))
            }
            Some((first, last, step)) => Some(
                FrameRange::new(first, last, step).map_err(|e| Refusal::Invalid(e.to_string()))?,
            ),
            None => None,
        };
        if let Some(name) = &output_name {
            check_output_name(name)?;
        }
        Ok(Checked {
            settings,
            tile_size,
            frames,
            output_name,
        })
    }

    /// The record of this job (of its frame `frame`, for a frame range), neither numbered nor
    /// named yet.
    fn record(&self, frame: Option<u32>, now_ms: i64, audited: bool) -> JobRecord {
        let s = &self.settings;
        // A request that leaves the batch to the coordinator gets the rule `tessera render`
        // follows, so that its bits are render's for the same flags.
        let batch = if s.batch == 0 {
            unit_batch(
                self.width,
                self.height,
                s.spp,
                s.adaptive.is_some(),
                DEFAULT_UNIT_SAMPLES,
            )
        } else {
            s.batch
        };
        JobRecord {
            id: 0,
            scene_hash: self.scene_hash.clone(),
            scene_name: self.scene.name.clone(),
            width: self.width,
            height: self.height,
            spp: s.spp,
            seed: s.seed,
            batch,
            strategy: s.strategy,
            tile_size: self.tile_size,
            output_name: String::new(),
            priority: self.priority,
            variance: self.variance,
            sample_count: self.sample_count,
            denoise: self.denoise.clone(),
            phase: JobPhase::Active,
            error: String::new(),
            submitted_ms: now_ms,
            finished_ms: 0,
            final_noise: (0.0, 0.0),
            image_revision: IMAGE_REVISION,
            noise_target: s.adaptive.map_or(0.0, |a| a.noise_target),
            final_counts: (0, 0),
            frame,
            resolution: s.resolution,
            range: None,
            adaptive_scale: None,
            aovs: s.aovs.list(),
            checks: Default::default(),
            after: self.after.map(|j| j.0),
            require: self.require.clone(),
            min_memory: self.min_memory,
            progressive: self.progressive && self.frames.is_some(),
            failures: Vec::new(),
            blocklist: Vec::new(),
            paused: false,
            retries: 0,
            submitter: self.submitter.clone(),
            guiding: s.guiding.then(|| GuidingRecord {
                bounds: self.guide_bounds,
                guides: Vec::new(),
            }),
            audited,
        }
    }
}

impl Scheduler {
    /// Takes back the jobs a store held at start-up. Returns the store changes to make (a job
    /// of another renderer revision fails; scenes no live job needs go) and the jobs whose
    /// units were all in at the last stop, whose EXR is still to be written.
    pub fn restore(
        &mut self,
        loaded: Vec<LoadedJob>,
        stored_scenes: Vec<String>,
        now_ms: i64,
    ) -> Result<(Vec<Op>, Vec<JobId>), String> {
        let mut to_finish = Vec::new();
        let mut ops = Vec::new();
        let mut failing = Vec::new();
        for mut loaded in loaded {
            let id = JobId(loaded.record.id);
            if let Some(log) = loaded.log.take() {
                self.restore_log(id, &log);
            } else if loaded.log_bytes > 0 && loaded.record.phase != JobPhase::Active {
                self.note_stored_log(id, loaded.record.finished_ms, loaded.log_bytes);
            }
            let scale = loaded.record.adaptive_scale;
            let mut job = Job::restore(loaded).map_err(|e| format!("{id}: {e}"))?;
            if job.rec.adaptive_scale != scale {
                // The last pilot was merged just before the stop; the scale is computed once
                // more from the same sums, and kept now.
                ops.push(Op::PutJob(job.rec.clone()));
            }
            if job.rec.phase == JobPhase::Active && job.lost_scale() {
                failing.push((
                    id,
                    "an adaptive job accepted by a coordinator with an earlier adaptive rule, \
                     whose tiles went past their pilots under it: its decisions cannot be made \
                     again; resubmit the job"
                        .to_string(),
                ));
            } else if job.rec.phase == JobPhase::Active && job.all_closed() {
                job.finishing = true;
                to_finish.push(id);
            } else if job.rec.phase == JobPhase::Active && job.rec.image_revision != IMAGE_REVISION
            {
                // Accepted by a coordinator of another renderer revision. Its merged sums are
                // that revision's bits; adding this revision's would give an image neither
                // renders.
                if job.started {
                    failing.push((
                        id,
                        format!(
                            "rendered in part by renderer image revision {}, and this \
                             coordinator renders revision {IMAGE_REVISION}: its results cannot \
                             be mixed; resubmit the job",
                            job.rec.image_revision
                        ),
                    ));
                } else {
                    job.rec.image_revision = IMAGE_REVISION;
                    ops.push(Op::PutJob(job.rec.clone()));
                }
            }
            self.next_job = self.next_job.max(id.0 + 1);
            if let Some(r) = job.rec.range {
                // Loaded in id order, which is frame order.
                self.ranges.entry(JobId(r.id)).or_default().push(id);
            }
            self.jobs.insert(id, job);
        }
        // A failed job stays retryable for the window, if its scene is still stored.
        let window = self.policy.retry_window.as_millis() as i64;
        let stored: std::collections::HashSet<&str> =
            stored_scenes.iter().map(String::as_str).collect();
        for job in self.jobs.values_mut() {
            job.retryable = job.rec.phase == JobPhase::Failed
                && job.rec.finished_ms.saturating_add(window) > now_ms
                && stored.contains(job.rec.scene_hash.as_str());
        }
        // Failed once every job is in, so that a scene another job still needs is kept.
        for (id, why) in failing {
            tracing::warn!("{id}: {why}");
            ops.extend(self.end_job(id, JobPhase::Failed, why, now_ms));
        }
        // Scenes that no live or retryable job needs (left by a coordinator that kept them
        // all, or whose retry window passed while it was down) go.
        for hash in stored_scenes {
            if !self.scene_is_kept(&hash) {
                ops.push(Op::DropScene(hash));
            }
        }
        Ok((ops, to_finish))
    }

    /// Admits a job: checks the coordinator's bounds, gives it an id and an output name no
    /// other job or file has, and returns the store changes that record it. A frame-range job
    /// becomes one job per frame, in frame order (the scheduling order then finishes the first
    /// frames first), under the range's id, which is returned.
    pub fn admit(
        &mut self,
        a: Admission,
        limits: AdmissionLimits,
        names: &OutputNames<'_>,
        now_ms: i64,
    ) -> Result<(JobId, Vec<Op>), Refusal> {
        self.check_bounds(&a, &limits)?;
        // An adaptive job's decisions follow its merged sums; taking results back would need
        // them made again from the start, which is not built: such jobs are not audited
        // (docs/farm.md). A guided job is audited: a conviction rewinds it to the first epoch
        // whose guide the convict's training shaped (`Job::take_back`).
        let audited = self.policy.audit > 0.0 && a.settings.adaptive.is_none();
        // The job's own count, so that admission and scheduling cannot disagree on it; a job
        // costs nothing per unit until its units render, so making it first is free. Every
        // frame of a range has the same count.
        let first_frame = a.frames.map_or(a.settings.frame, |r| Some(r.first));
        let first = Job::new(a.record(first_frame, now_ms, audited));
        let units = first.units_total();
        if units > limits.max_units_per_job {
            return Err(Refusal::Exhausted(format!(
                "the job would have {units} work units{}, above the limit of {} (use larger \
                 tiles or batches)",
                if a.frames.is_some() { " per frame" } else { "" },
                limits.max_units_per_job
            )));
        }
        let taken = self
            .jobs
            .values()
            .map(|j| (j.id(), j.rec.output_name.as_str()));
        let Some(frames) = a.frames else {
            let (id, output_name) =
                names.choose(JobId(self.next_job), a.output_name.clone(), taken)?;
            let mut job = first;
            self.next_job = id.0 + 1;
            job.rec.id = id.0;
            job.rec.output_name = output_name;
            let ops = vec![
                Op::PutScene(a.scene_hash, a.scene),
                Op::PutJob(job.rec.clone()),
            ];
            self.jobs.insert(id, job);
            return Ok((id, ops));
        };
        let (range_id, output_names) =
            names.choose_range(JobId(self.next_job), a.output_name.clone(), frames, taken)?;
        let range = RangeRef {
            id: range_id.0,
            frames,
        };
        let mut ops = vec![Op::PutScene(a.scene_hash.clone(), a.scene.clone())];
        let mut members = Vec::with_capacity(output_names.len());
        for ((frame, output_name), id) in frames.iter().zip(output_names).zip(range_id.0 + 1..) {
            let mut job = Job::new(a.record(Some(frame), now_ms, audited));
            job.rec.id = id;
            job.rec.output_name = output_name;
            job.rec.range = Some(range);
            ops.push(Op::PutJob(job.rec.clone()));
            members.push(JobId(id));
            self.jobs.insert(JobId(id), job);
        }
        self.next_job = members.last().map_or(range_id.0, |m| m.0) + 1;
        self.ranges.insert(range_id, members);
        Ok((range_id, ops))
    }

    /// The coordinator's bounds a new job must keep to before it is made: active jobs (a
    /// frame range counts once, as its user submitted it), a dependency that can still be
    /// met, frames per job.
    fn check_bounds(&self, a: &Admission, limits: &AdmissionLimits) -> Result<(), Refusal> {
        let active = self.active_jobs();
        if active >= limits.max_active_jobs {
            return Err(Refusal::Exhausted(format!(
                "{active} jobs are already queued or running, the limit is {}",
                limits.max_active_jobs
            )));
        }
        if let Some(after) = a.after {
            self.check_dependency(after)?;
        }
        if let Some(r) = a.frames {
            if r.len() > limits.max_frames_per_job {
                return Err(Refusal::Exhausted(format!(
                    "frames {r} are {} frames, above the limit of {} per job",
                    r.len(),
                    limits.max_frames_per_job
                )));
            }
        }
        Ok(())
    }

    /// The jobs `id` names: a frame-range job's frames, or the job itself.
    pub fn members(&self, id: JobId) -> Vec<JobId> {
        self.ranges.get(&id).cloned().unwrap_or_else(|| vec![id])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_render::Adaptive;

    fn asked() -> Asked {
        Asked {
            settings: RenderSettings {
                spp: 64,
                ..RenderSettings::default()
            },
            tile_size: 0,
            frames: None,
            output_name: None,
        }
    }

    fn refused(a: Asked) -> String {
        match Admission::check(a, 1024, 128) {
            Err(Refusal::Invalid(m)) => m,
            other => panic!("{other:?}"),
        }
    }

    /// What a request asks for is checked before its scene is parsed, each bound by name.
    #[test]
    fn a_request_is_checked_against_the_fixed_bounds_by_name() {
        let ok = Admission::check(asked(), 1024, 128).expect("fine");
        assert_eq!(ok.tile_size, 128, "0 is the coordinator's default");
        let mut a = asked();
        a.settings.spp = 2048;
        assert!(refused(a).contains("spp 2048 must be between 1 and 1024"));
        let mut a = asked();
        a.tile_size = 1;
        assert!(refused(a).contains("tile size 1 must be between"));
        let mut a = asked();
        a.settings.frame = Some(3);
        a.frames = Some((1, 9, 1));
        assert!(refused(a).contains("either one frame or a frame range"));
        let mut a = asked();
        a.frames = Some((9, 1, 1));
        assert!(refused(a).contains('9'));
        let mut a = asked();
        a.output_name = Some("../x.exr".into());
        assert!(refused(a).contains("output name"));
        // An adaptive job's noise tiles are its tiles.
        let mut a = asked();
        a.tile_size = 32;
        a.settings.adaptive = Some(Adaptive::new(0.05, 128).expect("target"));
        let ok = Admission::check(a, 1024, 128).expect("fine");
        assert_eq!(ok.settings.adaptive.map(|x| x.tile), Some(32));
        let ok = Admission::check(
            Asked {
                frames: Some((1, 9, 4)),
                ..asked()
            },
            1024,
            128,
        )
        .expect("fine");
        assert_eq!(ok.frames.map(|r| r.len()), Some(3));
    }
}
