//! Sharing workers between users: equal-priority jobs are offered by how many units their
//! users hold, fewest first, so two users' jobs alternate; priority still goes first; a cap
//! stops one user's jobs at so many units; without named users the order is submission's.

use std::time::{Duration, Instant};

mod common;

use common::LIMITS;
use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::{Admission, Policy, Scheduler};
use tessera_proto::ids::JobId;

fn by(user: &str, priority: i32) -> Admission {
    Admission {
        submitter: user.into(),
        priority,
        ..common::admission(None, None, None)
    }
}

/// A scheduler holding the jobs `jobs` (submitter, priority), admitted in order.
fn farm(jobs: &[(&str, i32)], cap: usize) -> (Scheduler, Vec<JobId>, tempfile::TempDir) {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut policy = Policy::new(Duration::from_secs(5));
    policy.max_leases_per_worker = 1000;
    policy.max_leases_per_user = cap;
    let mut core = Scheduler::new(1, policy);
    let ids = jobs
        .iter()
        .map(|&(u, p)| core.admit(by(u, p), LIMITS, &names, 1).expect("job").0)
        .collect();
    (core, ids, dir)
}

/// The submitters of the jobs of `n` units leased one a call (each kept).
fn users(core: &mut Scheduler, n: usize) -> Vec<String> {
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    (0..n)
        .map(|_| {
            let g = core.lease(w, 1, now);
            let job = g.first().expect("a unit").job;
            core.job(job).expect("job").rec.submitter.clone()
        })
        .collect()
}

#[test]
fn two_users_jobs_of_equal_priority_share_the_units_whoever_submitted_first() {
    // Alice submitted two jobs before Bob's one: first come, first served would give Alice
    // all 16 of her units before Bob's first.
    let (mut core, _, _dir) = farm(&[("alice", 0), ("alice", 0), ("bob", 0)], 0);
    let got = users(&mut core, 8);
    assert_eq!(
        got,
        ["alice", "bob", "alice", "bob", "alice", "bob", "alice", "bob"],
        "{got:?}"
    );
    // Bob's job has 8 units; once it has none left, Alice's take every worker.
    let got = users(&mut core, 8);
    assert_eq!(got.iter().filter(|u| *u == "bob").count(), 4, "{got:?}");
    let got = users(&mut core, 4);
    assert!(got.iter().all(|u| u == "alice"), "{got:?}");
}

#[test]
fn a_higher_priority_goes_first_whoever_holds_more() {
    let (mut core, _, _dir) = farm(&[("alice", 5), ("bob", 0)], 0);
    let got = users(&mut core, 8);
    assert!(got.iter().all(|u| u == "alice"), "{got:?}");
    assert_eq!(users(&mut core, 1), ["bob"]);
}

#[test]
fn without_named_users_jobs_go_in_submission_order() {
    let (mut core, ids, _dir) = farm(&[("", 0), ("", 0)], 0);
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let jobs: Vec<JobId> = (0..9).map(|_| core.lease(w, 1, now)[0].job).collect();
    assert!(jobs[..8].iter().all(|&j| j == ids[0]), "{jobs:?}");
    assert_eq!(jobs[8], ids[1]);
}

#[test]
fn the_per_user_cap_stops_one_users_jobs_at_so_many_units() {
    let (mut core, _, _dir) = farm(&[("alice", 0), ("alice", 0), ("bob", 0)], 3);
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let granted = core.lease(w, 100, now);
    let user = |core: &Scheduler, job: JobId| core.job(job).expect("job").rec.submitter.clone();
    let got: Vec<String> = granted.iter().map(|g| user(&core, g.job)).collect();
    assert_eq!(got.iter().filter(|u| *u == "alice").count(), 3, "{got:?}");
    assert_eq!(got.iter().filter(|u| *u == "bob").count(), 3, "{got:?}");
    assert!(
        core.lease(w, 100, now).is_empty(),
        "both users are at the cap"
    );
    // A unit handed back frees a place for its user alone.
    let alices = granted
        .iter()
        .find(|g| user(&core, g.job) == "alice")
        .expect("one of alice's");
    core.release(w, &[alices.lease]);
    let again = core.lease(w, 100, now);
    assert_eq!(again.len(), 1);
    assert_eq!(user(&core, again[0].job), "alice");
}
