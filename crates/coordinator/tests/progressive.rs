//! A frame range leased progressively (`submit --progressive`): every frame's batch b is handed
//! out before any frame's batch b + 1; without it, frame after frame.

use std::time::{Duration, Instant};

mod common;

use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::{Admission, AdmissionLimits, Policy, Scheduler};

const LIMITS: AdmissionLimits = AdmissionLimits {
    max_active_jobs: 10,
    max_units_per_job: 100,
    max_frames_per_job: 10,
};

/// The (frame's position in the range, batch) of every unit, one lease call at a time.
fn order(progressive: bool) -> Vec<(u64, u32)> {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut policy = Policy::new(Duration::from_secs(5));
    policy.max_leases_per_worker = 1000;
    let mut core = Scheduler::new(1, policy);
    let a = Admission {
        progressive,
        ..common::admission(None, Some("1-3"), None)
    };
    let (range, _) = core.admit(a, LIMITS, &names, 1).expect("range");
    let first = core.members(range)[0].0;
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let mut out = Vec::new();
    // One unit a call, each kept: the order a farm of busy workers sees.
    while let Some(g) = core.lease(w, 1, now).first() {
        out.push((g.job.0 - first, g.unit.batch));
    }
    out
}

#[test]
fn a_progressive_range_hands_out_every_frames_first_batch_before_any_second() {
    // 8×8 in 4-pixel tiles at 4 spp in batches of 2: 4 tiles × 2 batches a frame, 3 frames.
    let p = order(true);
    assert_eq!(p.len(), 24);
    let batches: Vec<u32> = p.iter().map(|&(_, b)| b).collect();
    assert!(
        batches.windows(2).all(|w| w[0] <= w[1]),
        "a second batch before every first one: {p:?}"
    );
    assert_eq!(p[..12].iter().filter(|&&(f, _)| f == 2).count(), 4, "{p:?}");
    // Without: the first frame's units all come before the second frame's.
    let plain = order(false);
    assert_eq!(plain.len(), 24);
    let frames: Vec<u64> = plain.iter().map(|&(f, _)| f).collect();
    assert!(frames.windows(2).all(|w| w[0] <= w[1]), "{plain:?}");
}

#[test]
fn a_frame_paused_on_its_own_does_not_hold_back_a_progressive_range() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut policy = Policy::new(Duration::from_secs(5));
    policy.max_leases_per_worker = 1000;
    let mut core = Scheduler::new(1, policy);
    let a = Admission {
        progressive: true,
        ..common::admission(None, Some("1-2"), None)
    };
    let (range, _) = core.admit(a, LIMITS, &names, 1).expect("range");
    let frames = core.members(range);
    core.update(frames[0], Some(true), None)
        .expect("pause frame 1");
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    // Frame 2 hands out its batches (4 tiles each), one level a call; frame 1 nothing until
    // resumed.
    for batch in 0..2 {
        let got = core.lease(w, 1000, now);
        assert_eq!(got.len(), 4, "{got:?}");
        assert!(got
            .iter()
            .all(|g| g.job == frames[1] && g.unit.batch == batch));
    }
    assert!(core.lease(w, 1000, now).is_empty());
}
