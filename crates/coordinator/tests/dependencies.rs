//! Jobs that start after another (`submit --after`): a job waits, taking no lease, until the
//! job it names (every frame of a range) is done, and fails with the reason when that one fails
//! or is cancelled, down a chain of them; a dependency on an unknown or ended job is refused.

use std::time::{Duration, Instant};

mod common;

use tessera_coordinator::error::Refusal;
use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::{Admission, AdmissionLimits, Policy, Scheduler};
use tessera_coordinator::store::{JobPhase, Op};
use tessera_proto::ids::JobId;

/// An 8×8 job of `frames` (or one), after `after`.
fn admission(frames: Option<&str>, after: Option<JobId>) -> Admission {
    common::admission(None, frames, after)
}

const LIMITS: AdmissionLimits = AdmissionLimits {
    max_active_jobs: 100,
    max_units_per_job: 100,
    max_frames_per_job: 100,
};

/// The jobs whose units a worker gets when it asks for everything.
fn leased(core: &mut Scheduler, w: u64, now: Instant) -> Vec<JobId> {
    let mut jobs: Vec<JobId> = core.lease(w, 1000, now).iter().map(|g| g.job).collect();
    jobs.dedup();
    jobs
}

#[test]
fn a_job_after_another_waits_for_it_and_a_chain_fails_when_it_is_cancelled() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let (a, _) = core
        .admit(admission(None, None), LIMITS, &names, 1)
        .expect("a");
    let (b, _) = core
        .admit(admission(None, Some(a)), LIMITS, &names, 1)
        .expect("b");
    let (c, _) = core
        .admit(admission(None, Some(b)), LIMITS, &names, 1)
        .expect("c");
    assert_eq!(core.job(b).expect("b").rec.after, Some(a.0));
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    assert_eq!(
        leased(&mut core, w, now),
        [a],
        "only the first job's units go out"
    );
    core.end_job(a, JobPhase::Done, String::new(), 2);
    assert_eq!(
        leased(&mut core, w, now),
        [b],
        "b starts once a is done; c still waits"
    );
    // b cancelled: c, waiting for it, fails in the same store changes, saying why.
    let ops = core.end_job(b, JobPhase::Cancelled, String::new(), 3);
    let failed = |id: JobId| {
        ops.iter()
            .any(|o| matches!(o, Op::PutJob(r) if r.id == id.0 && r.phase == JobPhase::Failed))
    };
    assert!(failed(c), "{ops:?}");
    let c = core.job(c).expect("c");
    assert_eq!(c.rec.phase, JobPhase::Failed);
    assert!(
        c.rec.error.contains(&format!("{b} was cancelled")),
        "{}",
        c.rec.error
    );
    assert!(leased(&mut core, w, now).is_empty());
    // A job that could never start is refused, and so is one after a job nobody knows.
    match core.admit(admission(None, Some(b)), LIMITS, &names, 4) {
        Err(Refusal::Precondition(m)) => assert!(m.contains("was cancelled"), "{m}"),
        other => panic!("{other:?}"),
    }
    match core.admit(admission(None, Some(JobId(999))), LIMITS, &names, 4) {
        Err(Refusal::NotFound(m)) => assert!(m.contains("--after job-000999"), "{m}"),
        other => panic!("{other:?}"),
    }
    // After a job that is done already, a job starts at once.
    let (d, _) = core
        .admit(admission(None, Some(a)), LIMITS, &names, 5)
        .expect("d");
    assert_eq!(leased(&mut core, w, now), [d]);
}

#[test]
fn a_job_after_a_frame_range_waits_for_every_frame_and_fails_with_any() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let (range, _) = core
        .admit(admission(Some("1-2"), None), LIMITS, &names, 1)
        .expect("r");
    let frames = core.members(range);
    assert_eq!(frames.len(), 2);
    let (after, _) = core
        .admit(admission(None, Some(range)), LIMITS, &names, 1)
        .expect("j");
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    core.end_job(frames[0], JobPhase::Done, String::new(), 2);
    assert_eq!(
        leased(&mut core, w, now),
        [frames[1]],
        "one frame is not the range"
    );
    core.end_job(frames[1], JobPhase::Done, String::new(), 3);
    assert_eq!(leased(&mut core, w, now), [after]);
    // A second range whose frame fails fails the job after it, naming the range.
    let (range, _) = core
        .admit(admission(Some("1-2"), None), LIMITS, &names, 4)
        .expect("r2");
    let (after, _) = core
        .admit(admission(None, Some(range)), LIMITS, &names, 4)
        .expect("j2");
    let frame = core.members(range)[1];
    core.end_job(frame, JobPhase::Failed, "the scene broke".into(), 5);
    let job = core.job(after).expect("job");
    assert_eq!(job.rec.phase, JobPhase::Failed);
    assert!(
        job.rec
            .error
            .contains(&format!("{range} failed: the scene broke")),
        "{}",
        job.rec.error
    );
}

/// A long chain whose head fails: each job's error names the job it waits for and the chain's
/// first cause once, in bounded text, instead of nesting every error before it (a 998-job
/// chain once made a 57 KB error and a `ListJobs` answer past the gRPC limit).
#[test]
fn a_chain_names_its_first_cause_once_in_bounded_text() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let limits = AdmissionLimits {
        max_active_jobs: 1000,
        ..LIMITS
    };
    let (head, _) = core
        .admit(admission(None, None), limits, &names, 1)
        .expect("head");
    let mut chain = vec![head];
    for i in 0..200 {
        let after = *chain.last().expect("one");
        let (j, _) = core
            .admit(admission(None, Some(after)), limits, &names, 2 + i)
            .expect("link");
        chain.push(j);
    }
    let reason = "x".repeat(5000);
    core.end_job(head, JobPhase::Failed, reason, 300);
    let second = &core.job(chain[1]).expect("second").rec.error;
    assert!(
        second.starts_with(&format!(
            "the job it waits for (--after) ended: {head} failed: xxx"
        )) && second.ends_with('…')
            && second.len() < 400,
        "{second}"
    );
    for (i, &id) in chain.iter().enumerate().skip(2) {
        let e = &core.job(id).expect("link").rec.error;
        assert_eq!(core.job(id).expect("link").rec.phase, JobPhase::Failed);
        assert!(e.len() < 500, "link {i}: {} bytes", e.len());
        assert!(
            e.starts_with(&format!(
                "the job it waits for (--after) ended: {} failed waiting for another job; \
                 first cause: {head} failed: xxx",
                chain[i - 1]
            )),
            "link {i}: {e}"
        );
    }
}

/// Listings put jobs still to finish first (scheduling order), then ended ones, most recently
/// ended first, and come a page at a time, the pages together the whole list once.
#[test]
fn listings_show_live_jobs_first_a_page_at_a_time() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let ids: Vec<JobId> = (0..5)
        .map(|i| {
            let a = tessera_coordinator::scheduler::Admission {
                priority: i as i32,
                ..admission(None, None)
            };
            core.admit(a, LIMITS, &names, 1).expect("job").0
        })
        .collect();
    // The highest-priority job ended first, then the lowest.
    core.end_job(ids[4], JobPhase::Cancelled, String::new(), 10);
    core.end_job(ids[0], JobPhase::Cancelled, String::new(), 20);
    let now = Instant::now();
    let order: Vec<JobId> = core.listing(now).iter().map(|v| v.job_id).collect();
    assert_eq!(order, [ids[3], ids[2], ids[1], ids[0], ids[4]]);
    let mut paged = Vec::new();
    let mut offset = Some(0);
    while let Some(o) = offset {
        let (page, next) = core.job_page(now, o, 2);
        assert!(page.len() <= 2);
        paged.extend(page.iter().map(|v| v.job_id));
        offset = next;
    }
    assert_eq!(paged, order);
    assert!(core.job_page(now, 99, 2).0.is_empty());
}
