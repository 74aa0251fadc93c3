//! Retrying failed frames in the scheduler: what a retry clears and keeps, which jobs come
//! back with it, what it refuses, and the retry window.

use std::time::{Duration, Instant};

mod common;

use common::LIMITS;
use tessera_coordinator::error::Refusal;
use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::Scheduler;
use tessera_coordinator::store::{JobPhase, Op};
use tessera_proto::ids::JobId;

/// Fails job `job` at Unix ms `now_ms`: worker `w` cannot render its first unit, and one
/// failure fails a frame.
fn fail(core: &mut Scheduler, w: u64, job: JobId, now_ms: i64) -> Vec<Op> {
    core.policy_mut().fail_frame_after = 1;
    let now = Instant::now();
    let g = core.lease(w, 1, now);
    let g = g.first().expect("a unit");
    assert_eq!(g.job, job);
    let ops = core.cannot_render(w, &[g.lease], "out of memory", now, now_ms);
    core.release(w, &[g.lease]);
    assert_eq!(core.job(job).expect("job").rec.phase, JobPhase::Failed);
    ops
}

fn precondition(r: Result<(Vec<JobId>, Vec<Op>), Refusal>) -> String {
    match r {
        Err(Refusal::Precondition(m)) => m,
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_retry_puts_a_failed_job_back_as_admitted_and_keeps_its_scene_meanwhile() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    assert!(precondition(core.retry(job, None, 1000)).contains("no failed frame"));
    assert!(matches!(
        core.retry(JobId(99), None, 1000),
        Err(Refusal::NotFound(_))
    ));
    let ops = fail(&mut core, w, job, 1000);
    assert!(
        !ops.iter().any(|op| matches!(op, Op::DropScene(_))),
        "the scene of a failed job is kept for a retry: {ops:?}"
    );
    assert!(core.job_view(job, now).expect("view").retryable);
    let (back, ops) = core.retry(job, None, 1000).expect("retry");
    assert_eq!(back, [job]);
    let rec = &core.job(job).expect("job").rec;
    assert_eq!(rec.phase, JobPhase::Active);
    assert_eq!((rec.retries, rec.finished_ms), (1, 0));
    assert!(rec.failures.is_empty() && rec.blocklist.is_empty() && rec.error.is_empty());
    assert!(
        matches!(&ops[..], [Op::PutJob(r)] if r.phase == JobPhase::Active && r.retries == 1),
        "{ops:?}"
    );
    // From the first batch, to the worker that failed it too (its blocklist is cleared).
    let g = core.lease(w, 8, now);
    assert_eq!(g.len(), 8, "every unit is handed out again");
    assert!(g.iter().all(|g| g.job == job));
    assert!(precondition(core.retry(job, None, 1000)).contains("no failed frame"));
}

#[test]
fn past_the_window_the_scene_goes_and_a_retry_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    core.policy_mut().retry_window = Duration::from_secs(10);
    let w = core.register("w".into(), 1, "v".into(), "s".into(), Instant::now());
    fail(&mut core, w, job, 1000);
    assert!(
        core.sweep_failed(1000 + 9_999).is_empty(),
        "within the window"
    );
    let ops = core.sweep_failed(1000 + 10_000);
    assert!(
        matches!(&ops[..], [Op::DropScene(h)] if h == "h"),
        "{ops:?}"
    );
    assert!(core.sweep_failed(1000 + 20_000).is_empty(), "dropped once");
    let why = precondition(core.retry(job, None, 1000));
    assert!(
        why.contains("--retry-window") && why.contains("submit it again"),
        "{why}"
    );
    // A scene another live job still needs stays.
    let (other, _) = core
        .admit(common::admission(None, None, None), LIMITS, &names, 2)
        .expect("other");
    fail(&mut core, w, other, 5000);
    let (third, _) = core
        .admit(common::admission(None, None, None), LIMITS, &names, 6)
        .expect("third");
    assert!(
        core.sweep_failed(5000 + 10_000).is_empty(),
        "{third} needs it"
    );
}

#[test]
fn jobs_that_failed_waiting_for_a_retried_one_come_back_waiting_for_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, first) = common::one_job(&names);
    let (then, _) = core
        .admit(
            common::admission(None, None, Some(first)),
            LIMITS,
            &names,
            2,
        )
        .expect("then");
    let w = core.register("w".into(), 1, "v".into(), "s".into(), Instant::now());
    fail(&mut core, w, first, 1000);
    let rec = &core.job(then).expect("then").rec;
    assert_eq!(rec.phase, JobPhase::Failed);
    // Retrying the dependent alone would fail it again at once.
    let why = precondition(core.retry(then, None, 1000));
    assert!(why.contains("retry that one first"), "{why}");
    let (back, _) = core.retry(first, None, 1000).expect("retry");
    assert_eq!(back, [first, then]);
    let view = core.job_view(then, Instant::now()).expect("view");
    assert_eq!(view.after, Some(first));
    assert!(core.job(then).expect("then").rec.error.is_empty());
    assert!(
        core.lease(w, 8, Instant::now())
            .iter()
            .all(|g| g.job == first),
        "the dependent waits for it again"
    );
}

#[test]
fn a_frame_of_a_range_is_retried_by_its_number() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(
        1,
        tessera_coordinator::scheduler::Policy::new(Duration::from_secs(5)),
    );
    let (range, _) = core
        .admit(
            common::admission(None, Some("1-3"), None),
            LIMITS,
            &names,
            1,
        )
        .expect("range");
    let frames = core.members(range);
    let w = core.register("w".into(), 1, "v".into(), "s".into(), Instant::now());
    // Frames are leased in order: the first unit is frame 1's.
    fail(&mut core, w, frames[0], 1000);
    assert!(
        core.job_view(range, Instant::now())
            .expect("view")
            .retryable
    );
    assert!(
        matches!(core.retry(range, Some(9), 1000), Err(Refusal::NotFound(m)) if m.contains("no frame 9"))
    );
    assert!(precondition(core.retry(range, Some(2), 1000)).contains(&format!("{range} frame 2")));
    let (back, _) = core.retry(range, Some(1), 1000).expect("retry");
    assert_eq!(back, [frames[0]]);
    assert_eq!(
        core.job(frames[0]).expect("frame").rec.phase,
        JobPhase::Active
    );
}

/// A retry counts against the active-job limit as a submission does, the jobs that come back
/// with it too: over a full queue it is refused, saying how many it would put back.
#[test]
fn a_retry_keeps_to_the_active_job_limit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, first) = common::one_job(&names);
    let mut chain = vec![first];
    for i in 0..2 {
        let after = *chain.last().expect("one");
        let (j, _) = core
            .admit(
                common::admission(None, None, Some(after)),
                LIMITS,
                &names,
                2 + i,
            )
            .expect("link");
        chain.push(j);
    }
    let w = core.register("w".into(), 1, "v".into(), "s".into(), Instant::now());
    fail(&mut core, w, first, 1000);
    assert!(chain
        .iter()
        .all(|&j| core.job(j).expect("job").rec.phase == JobPhase::Failed));
    core.admit(common::admission(None, None, None), LIMITS, &names, 5)
        .expect("another");
    // One active, three to come back: a limit of 3 refuses, 4 takes them.
    match core.retry(first, None, 3) {
        Err(Refusal::Exhausted(m)) => assert!(m.contains("put back 3 jobs"), "{m}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(core.job(first).expect("first").rec.phase, JobPhase::Failed);
    let (back, _) = core.retry(first, None, 4).expect("retry");
    assert_eq!(back, chain);
}
