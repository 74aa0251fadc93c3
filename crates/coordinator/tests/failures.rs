//! Units that fail on workers: each goes to another worker, a worker that fails a job's units
//! three times is blocklisted for that job alone, and a frame fails with every reason after
//! five failures, or once every connected worker that fits it is blocklisted.

use std::time::Instant;

mod common;

use common::LIMITS;
use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::Scheduler;
use tessera_coordinator::store::JobPhase;
use tessera_proto::ids::JobId;

/// Worker `w` leases one unit of `job` and says it cannot render it; returns whether it got
/// one.
fn fail_one(core: &mut Scheduler, w: u64, job: JobId, now: Instant) -> bool {
    let got = core.lease(w, 1, now);
    let Some(g) = got.first() else {
        return false;
    };
    assert_eq!(g.job, job);
    core.cannot_render(w, &[g.lease], "a texture is too big here", now, 1);
    core.release(w, &[g.lease]);
    true
}

#[test]
fn a_failing_worker_is_blocklisted_for_the_job_and_the_frame_fails_with_every_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let now = Instant::now();
    let a = core.register("a".into(), 1, "v".into(), "s".into(), now);
    let b = core.register("b".into(), 1, "v".into(), "t".into(), now);
    for _ in 0..3 {
        assert!(fail_one(&mut core, a, job, now));
    }
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Active, "b is left to try");
    assert_eq!(rec.blocklist, ["a"]);
    assert_eq!(rec.failures.len(), 3);
    assert!(core.lease(a, 8, now).is_empty(), "a is blocklisted for it");
    let view = core.job_view(job, now).expect("view");
    assert_eq!(
        (view.failures, view.blocklist.clone()),
        (3, vec!["a".to_string()])
    );
    // For that job alone: a takes another job as before.
    let (other, _) = core
        .admit(common::admission(None, None, None), LIMITS, &names, 2)
        .expect("other");
    assert!(core.lease(a, 1, now).iter().all(|g| g.job == other));
    // b fails twice more: five in all, and the frame fails with each reason once.
    assert!(fail_one(&mut core, b, job, now));
    assert_eq!(core.job(job).expect("job").rec.phase, JobPhase::Active);
    assert!(fail_one(&mut core, b, job, now));
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Failed);
    assert!(
        rec.error.starts_with("5 failures (the most a frame may have is 5): worker w1-1 (a), 3 times: cannot render tile 0 batch 0: a texture is too big here; worker w1-2 (b), 2 times:"),
        "{}",
        rec.error
    );
}

#[test]
fn a_frame_fails_once_every_connected_worker_that_fits_is_blocklisted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let now = Instant::now();
    let a = core.register("a".into(), 1, "v".into(), "s".into(), now);
    let b = core.register("b".into(), 1, "v".into(), "t".into(), now);
    for _ in 0..3 {
        assert!(fail_one(&mut core, a, job, now));
    }
    // b drains: a is then the only connected worker, and it is blocklisted.
    core.drain("b", now).expect("drain");
    assert_eq!(
        core.job_view(job, now).expect("view").waiting.as_deref(),
        Some("every connected worker is blocklisted for it after failing its units (a)")
    );
    assert!(core.lease(b, 1, now).is_empty());
    // Alone, a worker fails its third unit and nobody is left: the frame fails then.
    let (lone, _) = core
        .admit(common::admission(None, None, None), LIMITS, &names, 2)
        .expect("lone");
    for _ in 0..3 {
        assert!(fail_one(&mut core, a, lone, now));
    }
    let rec = &core.job(lone).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Failed);
    assert!(
        rec.error
            .starts_with("3 failures (every connected worker that fits it is blocklisted)"),
        "{}",
        rec.error
    );
}
