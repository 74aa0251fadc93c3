//! Worker tags against job requirements, and drains, on the scheduler: a job that requires a
//! tag, a CPU feature or memory goes only to workers that have them, says why it waits when no
//! connected worker does, and a drained worker is leased nothing more.

use std::time::{Duration, Instant};

mod common;

use tessera_coordinator::error::Refusal;
use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::{Admission, AdmissionLimits, Capabilities, Policy, Scheduler};
use tessera_proto::ids::JobId;
use tessera_proto::view::WorkerState;

const LIMITS: AdmissionLimits = AdmissionLimits {
    max_active_jobs: 100,
    max_units_per_job: 100,
    max_frames_per_job: 100,
};

fn requiring(require: &[&str], min_memory: u64) -> Admission {
    Admission {
        require: require.iter().map(|s| s.to_string()).collect(),
        min_memory,
        ..common::admission(None, None, None)
    }
}

fn caps(tags: &[&str], cpu: &[&str], memory_bytes: u64) -> Capabilities {
    Capabilities {
        memory_bytes,
        cpu_features: cpu.iter().map(|s| s.to_string()).collect(),
        tags: tags.iter().map(|s| s.to_string()).collect(),
        denoise_version: 0,
    }
}

fn leased(core: &mut Scheduler, w: u64, now: Instant) -> Vec<JobId> {
    let mut jobs: Vec<JobId> = core.lease(w, 1000, now).iter().map(|g| g.job).collect();
    jobs.dedup();
    jobs
}

fn waiting(core: &Scheduler, job: JobId, now: Instant) -> Option<String> {
    core.job_view(job, now).expect("view").waiting
}

#[test]
fn a_job_goes_only_to_workers_that_meet_its_requirements_and_says_why_it_waits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let now = Instant::now();
    let (big, _) = core
        .admit(requiring(&["big-mem"], 0), LIMITS, &names, 1)
        .expect("big");
    assert_eq!(
        waiting(&core, big, now).as_deref(),
        Some("no worker is connected")
    );
    let plain = core.register("plain".into(), 1, "v".into(), "a".into(), now);
    core.set_capabilities(plain, caps(&["pool=fast"], &["avx2"], 8 << 30));
    assert_eq!(
        waiting(&core, big, now).as_deref(),
        Some("no worker has tag big-mem")
    );
    assert!(
        leased(&mut core, plain, now).is_empty(),
        "plain lacks big-mem"
    );
    // A job anyone can take goes to the plain worker past the one it cannot.
    let (any, _) = core
        .admit(requiring(&[], 0), LIMITS, &names, 1)
        .expect("any");
    assert_eq!(waiting(&core, any, now), None);
    assert_eq!(leased(&mut core, plain, now), [any]);
    let strong = core.register("strong".into(), 1, "v".into(), "b".into(), now);
    core.set_capabilities(strong, caps(&["big-mem", "pool=slow"], &[], 64 << 30));
    assert_eq!(waiting(&core, big, now), None);
    assert_eq!(leased(&mut core, strong, now), [big]);

    // Each kind of requirement, and the one that no worker meets named.
    let cases: [(&[&str], u64, Option<&str>); 6] = [
        (&["pool"], 0, None),
        (&["pool=fast"], 0, None),
        (&["pool=medium"], 0, Some("no worker has tag pool=medium")),
        (&["cpu:avx2"], 0, None),
        (
            &["cpu:avx512f"],
            0,
            Some("no worker has CPU feature avx512f"),
        ),
        (
            &[],
            128 << 30,
            Some("no worker has 128 GiB of memory (the most any has is 64 GiB)"),
        ),
    ];
    for (require, memory, why) in cases {
        let (j, _) = core
            .admit(requiring(require, memory), LIMITS, &names, 2)
            .expect("job");
        assert_eq!(
            waiting(&core, j, now).as_deref(),
            why,
            "{require:?} {memory}"
        );
    }
    // Met one by one, but by no one worker.
    let (both, _) = core
        .admit(requiring(&["big-mem", "cpu:avx2"], 0), LIMITS, &names, 3)
        .expect("both");
    assert_eq!(
        waiting(&core, both, now).as_deref(),
        Some("no one worker has all of: big-mem, cpu:avx2")
    );
    let view = core.job_view(both, now).expect("view");
    assert_eq!(view.require, ["big-mem", "cpu:avx2"]);
    // The requirement is kept in the job's record, so a restart keeps it.
    assert_eq!(core.job(both).expect("job").rec.require, view.require);
    // A paused job waits because it is paused, not for a worker.
    core.update(big, Some(true), None).expect("pause");
    assert_eq!(waiting(&core, big, now), None);
}

#[test]
fn a_drained_worker_is_leased_nothing_and_shows_as_draining() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let now = Instant::now();
    let (job, _) = core
        .admit(requiring(&[], 0), LIMITS, &names, 1)
        .expect("job");
    let a = core.register("render-01".into(), 1, "v".into(), "a".into(), now);
    let b = core.register("render-02".into(), 1, "v".into(), "b".into(), now);
    let held = core.lease(a, 1, now);
    assert_eq!(held.len(), 1);
    let drained = core.drain("render-01", now).expect("drain by name");
    assert_eq!(drained, [core.worker_id(a)]);
    assert!(core.draining(a) && !core.draining(b));
    assert!(
        leased(&mut core, a, now).is_empty(),
        "a drained worker gets nothing"
    );
    // What it held stays its own: its result still merges (the lease is live).
    assert_eq!(core.heartbeat(a, &[held[0].lease], now), Vec::new());
    let states: Vec<WorkerState> = core.worker_views(now).iter().map(|w| w.state).collect();
    assert_eq!(states, [WorkerState::Draining, WorkerState::Alive]);
    assert_eq!(leased(&mut core, b, now), [job]);
    // By public id too; and a name nobody has is refused, naming it.
    let id = core.worker_id(b).to_string();
    assert_eq!(core.drain(&id, now).expect("by id"), [core.worker_id(b)]);
    match core.drain("render-99", now) {
        Err(Refusal::NotFound(m)) => assert!(m.contains("\"render-99\""), "{m}"),
        other => panic!("{other:?}"),
    }
    // A worker that registers again while draining (the coordinator restarted) says so.
    let c = core.register("render-01".into(), 1, "v".into(), "c".into(), now);
    core.set_draining(c);
    assert!(leased(&mut core, c, now).is_empty());
    // With every worker draining, a job with work left says no worker can take it, and why.
    assert_eq!(
        waiting(&core, job, now).as_deref(),
        Some("no connected worker may work: 3 draining")
    );
}

/// Quarantined workers are named in a waiting job's reason (not "no worker is connected" while
/// two are), and an admin's release lets them lease again with their count of invalid
/// results cleared; releasing one that is not quarantined is refused by name.
#[test]
fn a_waiting_job_names_quarantined_workers_and_a_release_lets_them_work() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut policy = Policy::new(Duration::from_secs(5));
    policy.quarantine_after = 2;
    let mut core = Scheduler::new(1, policy);
    let now = Instant::now();
    let (job, _) = core
        .admit(requiring(&[], 0), LIMITS, &names, 1)
        .expect("job");
    let a = core.register("gltf-a".into(), 1, "v".into(), "a".into(), now);
    let b = core.register("gltf-b".into(), 1, "v".into(), "b".into(), now);
    for w in [a, b] {
        core.count_bad_result(w);
        core.count_bad_result(w);
    }
    let why = waiting(&core, job, now).expect("waits");
    assert!(
        why.starts_with(
            "no connected worker may work: 2 quarantined: gltf-a (after 2 invalid results), gltf-b"
        ) && why.contains("tessera workers --release NAME"),
        "{why}"
    );
    assert!(leased(&mut core, a, now).is_empty());
    assert!(matches!(
        core.release_quarantine("nobody"),
        Err(Refusal::NotFound(_))
    ));
    let released = core.release_quarantine("gltf-a").expect("released");
    assert_eq!(released, vec![core.worker_id(a)]);
    assert!(
        matches!(core.release_quarantine("gltf-a"), Err(Refusal::NotFound(_))),
        "not quarantined now"
    );
    assert_eq!(waiting(&core, job, now), None);
    assert_eq!(leased(&mut core, a, now), vec![job]);
    // Its count starts again: one more invalid result does not quarantine it.
    core.count_bad_result(a);
    let view = core.worker_views(now);
    let a_view = view.iter().find(|v| v.name == "gltf-a").expect("listed");
    assert_eq!(a_view.bad_results, 1);
    assert_eq!(a_view.state, WorkerState::Alive);
}
