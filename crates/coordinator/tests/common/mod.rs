//! Helpers shared by the scheduler's integration tests.
#![allow(dead_code)]

use tessera_coordinator::scheduler::Admission;
use tessera_coordinator::store::StoredScene;
use tessera_proto::ids::JobId;
use tessera_render::scene::FrameRange;
use tessera_render::RenderSettings;

/// An 8×8 job in 4-pixel tiles at 4 spp in batches of 2 (8 units a frame), named `name` (or
/// not), of the frames `frames` (or one), started after `after` (or at once).
pub fn admission(name: Option<&str>, frames: Option<&str>, after: Option<JobId>) -> Admission {
    Admission {
        scene_hash: "h".into(),
        scene: StoredScene {
            text: String::new(),
            json: false,
            name: "s".into(),
            assets: Vec::new(),
        },
        width: 8,
        height: 8,
        settings: RenderSettings {
            spp: 4,
            batch: 2,
            ..RenderSettings::default()
        },
        tile_size: 4,
        output_name: name.map(Into::into),
        priority: 0,
        variance: false,
        sample_count: false,
        denoise: None,
        frames: frames.map(|f| f.parse::<FrameRange>().expect("range")),
        after,
        require: Vec::new(),
        min_memory: 0,
        progressive: false,
        guide_bounds: [[0.0; 3], [1.0; 3]],
        submitter: String::new(),
    }
}

/// Admission bounds no test here comes near.
pub const LIMITS: tessera_coordinator::scheduler::AdmissionLimits =
    tessera_coordinator::scheduler::AdmissionLimits {
        max_active_jobs: 10,
        max_units_per_job: 100,
        max_frames_per_job: 10,
    };

/// A scheduler of boot 1 with 5-second leases and one job of [`admission`] admitted, its
/// output named from `names`.
pub fn one_job(
    names: &tessera_coordinator::names::OutputNames,
) -> (tessera_coordinator::scheduler::Scheduler, JobId) {
    use tessera_coordinator::scheduler::{Policy, Scheduler};
    let mut core = Scheduler::new(1, Policy::new(std::time::Duration::from_secs(5)));
    let (job, _) = core
        .admit(admission(None, None, None), LIMITS, names, 1)
        .expect("job");
    (core, job)
}
