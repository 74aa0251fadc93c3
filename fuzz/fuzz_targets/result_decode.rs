//! Any bytes as a SubmitResult request, through the coordinator's decoding and validation
//! against a live job, and as a stored tile record: errors are fine, panics are not, and a
//! merged result must have passed every check.
#![no_main]

use std::time::{Duration, Instant};

use libfuzzer_sys::fuzz_target;
use prost::Message;
use tessera_coordinator::job::{Job, Unit};
use tessera_coordinator::scheduler::{Merged, Policy, Scheduler};
use tessera_coordinator::store::{decode_sums, JobRecord};
use tessera_proto::ids::JobId;
use tessera_proto::v1 as pb;

fn job() -> Job {
    Job::new(JobRecord {
        id: 1,
        width: 5,
        height: 3,
        spp: 7,
        seed: 0,
        batch: 3,
        strategy: tessera_render::Strategy::Mis,
        tile_size: 4,
        output_name: "o.exr".into(),
        submitted_ms: 0,
        ..JobRecord::default()
    })
}

fuzz_target!(|data: &[u8]| {
    let j = job();
    let _ = decode_sums(data, j.tiles.get(0).expect("tile 0"));
    let Ok(req) = pb::SubmitResultRequest::decode(data) else {
        return;
    };
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.insert_job(j);
    let now = Instant::now();
    let w = core.register("fuzz".into(), 1, "0".into(), "s".into(), now);
    let _ = core.lease(w, 64, now);
    let Some(result) = req.result else { return };
    let Ok(sums) = tessera_coordinator::decode_result(result) else {
        return;
    };
    let unit = Unit {
        tile: req.tile_index,
        batch: req.batch_index,
    };
    // Lease ids of this scheduler are "L1-1".."L1-6": the fuzzer can find them. They are
    // parsed as the handlers parse them.
    let Ok(lease) = req.lease_id.parse() else {
        return;
    };
    if let Ok(Merged::New { .. }) = core.submit(w, lease, JobId(1), unit, sums.clone(), now) {
        let job = &core.job(JobId(1)).expect("job");
        assert!(job.check_result(unit, &sums).is_ok());
    }
});
