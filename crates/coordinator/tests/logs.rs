//! A job's log on the scheduler: a worker's rate refills with time, and a job keeps its last
//! 200 lines, counting those it let go.

use std::time::{Duration, Instant};

mod common;

use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::{add_stored, Reported};
use tessera_coordinator::store::{JobPhase, Op};

#[test]
fn a_job_keeps_its_last_lines_and_a_worker_its_rate() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let t0 = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), t0);
    let unit = core.lease(w, 1, t0).remove(0);
    let lines = |n: usize, tag: &str| -> Vec<Reported> {
        (0..n)
            .map(|i| Reported {
                lease: unit.lease,
                level: "warn",
                message: format!("{tag} {i}"),
            })
            .collect()
    };
    // The burst, then nothing until time refills it.
    let (kept, dropped, ops) = core.report_log(w, lines(60, "a"), t0, 0);
    assert_eq!((kept, dropped), (50, 10));
    assert_eq!(ops.len(), 1, "one write of the job's log");
    let (kept, _, _) = core.report_log(w, lines(1, "b"), t0, 0);
    assert_eq!(kept, 0);
    // Ten seconds later: fifty more (five a second).
    let mut t = t0;
    for round in 0..6 {
        t += Duration::from_secs(10);
        let (kept, _, _) = core.report_log(w, lines(60, &format!("r{round}")), t, 0);
        assert_eq!(kept, 50);
    }
    let q = core.logs(job, None, 0).expect("logs");
    let (got, dropped, ended) = (q.lines, q.dropped, q.ended);
    assert!(!ended);
    assert_eq!(got.len(), 200, "a job keeps its last 200 lines");
    // 350 kept in all, 150 of them pushed out; 71 over the rate.
    assert_eq!(dropped, 150 + 10 + 1 + 6 * 10);
    assert_eq!(got.last().expect("last").2.message, "r5 49");
    let seqs: Vec<u64> = got.iter().map(|(_, _, l)| l.seq).collect();
    assert!(seqs.windows(2).all(|p| p[0] < p[1]));
}

/// The jobs whose logs `ops` drop, every op being a drop.
fn dropped(ops: Vec<Op>) -> Vec<u64> {
    ops.iter()
        .map(|o| match o {
            Op::DropLog(j) => *j,
            other => panic!("{other:?}"),
        })
        .collect()
}

/// Once its job ends a log leaves memory (the store has it, and a query names it to be read
/// from there), and ended jobs' logs go from the store past their retention or, oldest first,
/// past the bytes all of them may hold; lines about an ended job's units are not kept.
#[test]
fn an_ended_jobs_log_leaves_memory_and_goes_after_its_retention() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let (mut core, job) = common::one_job(&names);
    let t0 = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), t0);
    let unit = core.lease(w, 1, t0).remove(0);
    let line = || {
        vec![Reported {
            lease: unit.lease,
            level: "warn",
            message: "fell back".into(),
        }]
    };
    let (_, _, ops) = core.report_log(w, line(), t0, 0);
    let Some(Op::PutLog(_, stored)) = ops.first() else {
        panic!("{ops:?}")
    };
    let stored = stored.clone();
    assert!(core.log_bytes().0 > 0);
    // Still active: the sweep keeps it.
    assert!(core.sweep_logs(1_000).is_empty());
    assert!(core.log_bytes().0 > 0);
    core.end_job(job, JobPhase::Cancelled, String::new(), 2_000);
    assert_eq!(
        core.report_log(w, line(), t0, 0).0,
        0,
        "an ended job's line"
    );
    assert!(core.sweep_logs(3_000).is_empty());
    assert_eq!(core.log_bytes(), (0, stored.len() as u64));
    let mut q = core.logs(job, None, 0).expect("logs");
    assert!(q.lines.is_empty() && q.ended);
    assert_eq!(q.stored, [(job, None)]);
    add_stored(&mut q, job, None, &stored, 0);
    assert_eq!(q.lines.len(), 1);
    assert_eq!(q.lines[0].2.message, "fell back");
    // Past the retention (two weeks by default), it goes.
    let two_weeks = 14 * 86_400 * 1000;
    assert!(core.sweep_logs(2_000 + two_weeks).is_empty());
    assert_eq!(dropped(core.sweep_logs(2_001 + two_weeks)), [job.0]);
    assert_eq!(core.log_bytes(), (0, 0));
    assert!(core.logs(job, None, 0).expect("logs").stored.is_empty());
}

/// The bytes all ended jobs' logs may hold: past them, the oldest go first.
#[test]
fn ended_logs_past_the_byte_limit_go_oldest_first() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = tessera_coordinator::scheduler::Scheduler::new(
        1,
        tessera_coordinator::scheduler::Policy::new(Duration::from_secs(5)),
    );
    let t0 = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), t0);
    let mut jobs = Vec::new();
    for i in 0..3 {
        let (job, _) = core
            .admit(
                common::admission(None, None, None),
                common::LIMITS,
                &names,
                1,
            )
            .expect("job");
        let unit = core.lease(w, 1, t0).remove(0);
        assert_eq!(unit.job, job);
        core.report_log(
            w,
            vec![Reported {
                lease: unit.lease,
                level: "warn",
                message: "z".repeat(400),
            }],
            t0,
            0,
        );
        core.end_job(job, JobPhase::Cancelled, String::new(), 10 + i);
        jobs.push(job);
    }
    assert!(core.sweep_logs(100).is_empty());
    let each = core.log_bytes().1 / 3;
    core.policy_mut().max_log_bytes = 2 * each;
    assert_eq!(dropped(core.sweep_logs(100)), [jobs[0].0]);
    core.policy_mut().max_log_bytes = 0;
    assert_eq!(dropped(core.sweep_logs(100)), [jobs[1].0, jobs[2].0]);
}
