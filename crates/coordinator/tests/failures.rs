//! Units that fail on workers: each goes to another worker, a worker that fails a job's units
//! three times is blocklisted for that job alone, and a frame fails with every reason after
//! five failures (one machine's counted at most three times, however many names it registers,
//! and the machine blocklisted at five), or once every connected worker that fits it is
//! blocklisted. A unit whose
//! lease lapses on three different machines fails its frame; one machine alone, however many
//! names it registers, cannot.

use std::time::{Duration, Instant};

mod common;

use common::LIMITS;
use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::Scheduler;
use tessera_coordinator::store::{JobPhase, Op};
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

/// Worker `w` leases one unit at `at` and lets it lapse; returns the unit's (tile, batch).
fn lapse_one(core: &mut Scheduler, w: u64, at: Instant) -> (u32, u32) {
    let g = core.lease(w, 1, at);
    let g = g.first().expect("a unit");
    // Past the 5-second lease: the unit goes back to the front of the queue.
    core.expire(at + Duration::from_secs(6));
    (g.unit.tile, g.unit.batch)
}

#[test]
fn a_unit_whose_lease_lapses_on_three_workers_fails_its_frame_and_one_dying_worker_does_not() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let t0 = Instant::now();
    let step = Duration::from_secs(10);
    let a = core.register("a".into(), 1, "v".into(), "s".into(), t0);
    let b = core.register("b".into(), 1, "v".into(), "t".into(), t0);
    let c = core.register("c".into(), 1, "v".into(), "u".into(), t0);
    // One worker that keeps dying with the unit (a preemptible machine, a chaos test) fails
    // nothing: it is the unit on several machines that tells.
    let unit = lapse_one(&mut core, a, t0);
    for i in 1..5 {
        assert_eq!(
            lapse_one(&mut core, a, t0 + step * i),
            unit,
            "the unit comes back first"
        );
    }
    assert_eq!(lapse_one(&mut core, b, t0 + step * 5), unit);
    assert_eq!(core.job(job).expect("job").rec.phase, JobPhase::Active);
    assert!(core.take_deferred().is_empty());
    assert_eq!(lapse_one(&mut core, c, t0 + step * 6), unit);
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Failed);
    assert!(
        rec.error.contains(&format!(
            "cannot render tile {} batch {}: its lease lapsed on 3 different machines (workers a, b, c)",
            unit.0, unit.1
        )),
        "{}",
        rec.error
    );
    assert!(
        rec.error.contains("a unit lapsed on 3 machines"),
        "{}",
        rec.error
    );
    // The ticker commits the failure: nothing else would.
    let ops = core.take_deferred();
    assert!(
        ops.iter()
            .any(|op| matches!(op, Op::PutJob(r) if r.phase == JobPhase::Failed)),
        "{ops:?}"
    );
}

#[test]
fn with_the_lapse_limit_off_a_unit_may_lapse_on_any_number_of_workers() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    core.policy_mut().fail_unit_after_lapses = 0;
    let t0 = Instant::now();
    for i in 0..6u32 {
        let w = core.register(format!("w{i}"), 1, "v".into(), format!("s{i}"), t0);
        lapse_one(&mut core, w, t0 + Duration::from_secs(10) * i);
    }
    assert_eq!(core.job(job).expect("job").rec.phase, JobPhase::Active);
    assert!(core.take_deferred().is_empty());
}

#[test]
fn one_machine_letting_a_unit_lapse_under_many_names_does_not_fail_the_frame() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let t0 = Instant::now();
    let step = Duration::from_secs(10);
    let mut at = t0;
    // Five names from one address (a hostile host, or one machine's several workers).
    for i in 0..5 {
        let w = core.register(format!("n{i}"), 1, "v".into(), format!("s{i}"), t0);
        core.set_host(w, "10.0.0.9".into());
        lapse_one(&mut core, w, at);
        at += step;
    }
    assert_eq!(core.job(job).expect("job").rec.phase, JobPhase::Active);
    // Two more machines make three.
    for (i, host) in ["10.0.0.1", "10.0.0.2"].into_iter().enumerate() {
        let w = core.register(format!("m{i}"), 1, "v".into(), format!("t{i}"), t0);
        core.set_host(w, host.into());
        lapse_one(&mut core, w, at);
        at += step;
    }
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Failed);
    assert!(
        rec.error
            .contains("3 different machines (workers n0, m0, m1)"),
        "{}",
        rec.error
    );
}

#[test]
fn one_machine_reporting_failures_under_many_names_does_not_fail_the_frame() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let now = Instant::now();
    // An honest worker elsewhere keeps "nobody left" from deciding.
    let honest = core.register("honest".into(), 1, "v".into(), "h".into(), now);
    core.set_host(honest, "10.0.0.1".into());
    // One host says it cannot render under a new name each time: its failures count three
    // times (a blocklist's worth), below the frame's five, and at five the host itself is
    // blocklisted for the job, so a sixth name gets nothing of it and the record stops
    // growing.
    for i in 0..6 {
        let w = core.register(format!("n{i}"), 1, "v".into(), format!("s{i}"), now);
        core.set_host(w, "10.0.0.9".into());
        assert_eq!(fail_one(&mut core, w, job, now), i < 5, "name {i}");
    }
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Active, "{}", rec.error);
    assert_eq!(rec.failures.len(), 5);
    assert!(
        rec.blocklist.contains(&"10.0.0.9".to_string()),
        "{:?}",
        rec.blocklist
    );
    // Failures on a second machine add to them: two more make five.
    assert!(fail_one(&mut core, honest, job, now));
    assert_eq!(core.job(job).expect("job").rec.phase, JobPhase::Active);
    assert!(fail_one(&mut core, honest, job, now));
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Failed);
    assert!(
        rec.error
            .starts_with("7 failures (the most a frame may have is 5)"),
        "{}",
        rec.error
    );
}

#[test]
fn a_farm_of_one_machine_fails_the_frame_at_its_limit_whatever_its_workers_names() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let now = Instant::now();
    // Three workers on one box, none of which can render the scene: two failures each would
    // blocklist none of them, but the box's fifth failure blocklists the box, and nobody is
    // left.
    let ws: Vec<u64> = (0..3)
        .map(|i| {
            let w = core.register(format!("box{i}"), 1, "v".into(), format!("b{i}"), now);
            core.set_host(w, "192.168.1.5".into());
            w
        })
        .collect();
    for (k, &w) in ws.iter().cycle().take(5).enumerate() {
        assert!(fail_one(&mut core, w, job, now), "failure {k}");
    }
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Failed);
    assert!(
        rec.error
            .starts_with("5 failures (every connected worker that fits it is blocklisted)"),
        "{}",
        rec.error
    );
}
