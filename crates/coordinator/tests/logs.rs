//! A job's log on the scheduler: a worker's rate refills with time, and a job keeps its last
//! 200 lines, counting those it let go.

use std::time::{Duration, Instant};

mod common;

use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::Reported;

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
    let (got, dropped, ended) = core.logs(job, None, 0).expect("logs");
    assert!(!ended);
    assert_eq!(got.len(), 200, "a job keeps its last 200 lines");
    // 350 kept in all, 150 of them pushed out; 71 over the rate.
    assert_eq!(dropped, 150 + 10 + 1 + 6 * 10);
    assert_eq!(got.last().expect("last").2.message, "r5 49");
    let seqs: Vec<u64> = got.iter().map(|(_, _, l)| l.seq).collect();
    assert!(seqs.windows(2).all(|p| p[0] < p[1]));
}
