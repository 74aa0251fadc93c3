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
        frames: frames.map(|f| f.parse::<FrameRange>().expect("range")),
        after,
        require: Vec::new(),
        min_memory: 0,
        progressive: false,
    }
}
