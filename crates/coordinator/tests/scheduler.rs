//! The scheduler's rules, call by call: batch-major order, in-order merging, refusal and
//! quarantine of bad results, lapsed leases, speculation past slow and hoarding holders, ids
//! bound to their registration, units no worker can render, and admission.

use std::time::{Duration, Instant};

mod common;

use tessera_coordinator::error::Refusal;
use tessera_coordinator::job::{Job, Unit};
use tessera_coordinator::names::OutputNames;
use tessera_coordinator::scheduler::{Admission, AdmissionLimits, Merged, Policy, Scheduler};
use tessera_coordinator::store::{JobPhase, JobRecord, Op};
use tessera_proto::ids::{JobId, LeaseId, WorkerCredential, WorkerId};
use tessera_render::{Strategy, TileSums};

const JOB: JobId = JobId(1);

fn record(spp: u32, batch: u32) -> JobRecord {
    JobRecord {
        id: 1,
        spp,
        batch,
        width: 4,
        height: 2,
        seed: 0,
        strategy: Strategy::Mis,
        tile_size: 2,
        output_name: "o.exr".into(),
        submitted_ms: 0,
        ..JobRecord::default()
    }
}

fn result(job: &Job, u: Unit, value: f64) -> TileSums {
    let rect = job.tiles.get(u.tile).expect("tile");
    let mut t = TileSums::empty(rect, 0);
    t.samples = job.batch_range(u.batch);
    let k = t.samples.len() as u32;
    for i in 0..rect.area() {
        t.sum[i] = [value; 3];
        t.sum_sq[i] = [value * value; 3];
        t.count[i] = k;
    }
    t
}

#[test]
fn units_are_batch_major_and_the_last_batch_is_short() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    core.insert_job(Job::new(record(5, 2)));
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let got: Vec<Unit> = core.lease(w, 100, now).iter().map(|g| g.unit).collect();
    assert_eq!(got.len(), 6);
    let want: Vec<Unit> = [(0, 0), (1, 0), (0, 1), (1, 1), (0, 2), (1, 2)]
        .map(|(tile, batch)| Unit { tile, batch })
        .to_vec();
    assert_eq!(got, want);
    assert_eq!(core.job(JOB).expect("job").batch_range(2), 4..5);
}

#[test]
fn out_of_order_results_merge_in_batch_order_once() {
    let mut core = Scheduler::new(3, Policy::new(Duration::from_secs(5)));
    core.insert_job(Job::new(record(6, 2)));
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let granted = core.lease(w, 100, now);
    let names: Vec<(LeaseId, Unit)> = granted.iter().map(|g| (g.lease, g.unit)).collect();
    // Tile 0's batches arrive 2, 0, 1; a copy of batch 0 arrives again.
    let order = [2u32, 0, 1];
    for b in order {
        let (name, u) = names
            .iter()
            .find(|(_, u)| u.tile == 0 && u.batch == b)
            .cloned()
            .expect("leased");
        let r = result(core.job(JOB).expect("job"), u, b as f64 + 1.0);
        let m = core.submit(w, name, JOB, u, r, now).expect("merged");
        assert!(matches!(m, Merged::New { .. }));
    }
    let (name, u) = names[0];
    let r = result(core.job(JOB).expect("job"), u, 1.0);
    assert!(matches!(
        core.submit(w, name, JOB, u, r, now),
        Ok(Merged::Duplicate)
    ));
    let acc = &core.job(JOB).expect("job").acc[&0];
    assert_eq!(acc.next, 3);
    let sums = acc.sums.as_ref().expect("sums");
    assert_eq!(sums.sum[0], [((0.0 + 1.0) + 2.0) + 3.0; 3]);
    assert_eq!(sums.samples, 0..6);
}

#[test]
fn bad_results_are_refused_and_counted() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    core.insert_job(Job::new(record(4, 2)));
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let g = core.lease(w, 1, now).remove(0);
    let name = g.lease;
    let job = &core.job(JOB).expect("job");
    let mut nan = result(job, g.unit, 1.0);
    nan.sum[1][2] = f64::NAN;
    let mut short = result(job, g.unit, 1.0);
    short.count.pop();
    let mut wrong_range = result(job, g.unit, 1.0);
    wrong_range.samples = 1..3;
    let mut lying = result(job, g.unit, 1.0);
    lying.count[0] = 1;
    for bad in [nan, short, wrong_range, lying] {
        assert!(matches!(
            core.submit(w, name, JOB, g.unit, bad, now),
            Err(Refusal::Invalid(_))
        ));
    }
    assert_eq!(core.worker(w).expect("worker").bad_results, 4);
    let other = Unit { tile: 1, batch: 0 };
    let r = result(core.job(JOB).expect("job"), other, 1.0);
    assert!(matches!(
        core.submit(w, name, JOB, other, r, now),
        Err(Refusal::Precondition(_))
    ));
    let r = result(core.job(JOB).expect("job"), g.unit, 1.0);
    assert!(matches!(
        core.submit(w, LeaseId { epoch: 0, n: 1 }, JOB, g.unit, r, now),
        Err(Refusal::Precondition(_))
    ));
    assert_eq!(core.job(JOB).expect("job").units_done, 0);
}

#[test]
fn lapsed_leases_requeue_and_late_results_still_count_once() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    core.insert_job(Job::new(record(2, 2)));
    let t0 = Instant::now();
    let a = core.register("a".into(), 1, "v".into(), "s".into(), t0);
    let b = core.register("b".into(), 1, "v".into(), "s".into(), t0);
    let first = core.lease(a, 1, t0).remove(0);
    let later = t0 + Duration::from_secs(6);
    let again = core.lease(b, 1, later).remove(0);
    assert_eq!(first.unit, again.unit, "the lapsed unit is served first");
    let r = result(core.job(JOB).expect("job"), first.unit, 1.0);
    let name = first.lease;
    assert!(matches!(
        core.submit(a, name, JOB, first.unit, r.clone(), later),
        Ok(Merged::New { .. })
    ));
    let name = again.lease;
    assert!(matches!(
        core.submit(b, name, JOB, again.unit, r, later),
        Ok(Merged::Duplicate)
    ));
    assert_eq!(core.heartbeat(b, &[name], later), vec![name]);
}

#[test]
fn idle_workers_race_the_oldest_outstanding_unit_once_the_queue_is_empty() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.insert_job(Job::new(record(2, 2)));
    let now = Instant::now();
    let slow = core.register("slow".into(), 1, "v".into(), "s".into(), now);
    let fast = core.register("fast".into(), 1, "v".into(), "s".into(), now);
    let held = core.lease(slow, 2, now);
    assert_eq!(held.len(), 2);
    // No fresh unit is left: the fast worker gets a copy of the oldest unit, then of the
    // other, and nothing more (each unit is raced at most once).
    let copies = core.lease(fast, 5, now);
    let units: Vec<Unit> = copies.iter().map(|g| g.unit).collect();
    assert_eq!(units, vec![held[0].unit, held[1].unit]);
    assert!(core.lease(fast, 5, now).is_empty());
    // The copy's result wins; the slow original is then a duplicate.
    let r = result(core.job(JOB).expect("job"), copies[0].unit, 1.0);
    let name = copies[0].lease;
    assert!(matches!(
        core.submit(fast, name, JOB, copies[0].unit, r.clone(), now),
        Ok(Merged::New { .. })
    ));
    let name = held[0].lease;
    assert!(matches!(
        core.submit(slow, name, JOB, held[0].unit, r, now),
        Ok(Merged::Duplicate)
    ));
}

#[test]
fn a_worker_that_keeps_sending_bad_results_is_quarantined() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.policy_mut().quarantine_after = 3;
    core.insert_job(Job::new(record(8, 2)));
    let now = Instant::now();
    let w = core.register("bad".into(), 1, "v".into(), "s".into(), now);
    let id = core.worker_credential(w).expect("registered");
    let g = core.lease(w, 2, now);
    let name = g[0].lease;
    for _ in 0..3 {
        let mut r = result(core.job(JOB).expect("job"), g[0].unit, 1.0);
        r.sum[0][0] = f64::INFINITY;
        assert!(matches!(
            core.submit(w, name, JOB, g[0].unit, r, now),
            Err(Refusal::Invalid(_))
        ));
    }
    assert!(core.worker(w).expect("worker").quarantined);
    assert!(matches!(
        core.touch_worker(&id, now),
        Err(Refusal::Denied(_))
    ));
    assert!(core.lease(w, 1, now).is_empty());
    assert_eq!(core.leases_of(w), 0, "its leases were taken back");
    let other = core.register("good".into(), 1, "v".into(), "s".into(), now);
    let mut units: Vec<Unit> = core.lease(other, 2, now).iter().map(|g| g.unit).collect();
    units.sort();
    let mut want = vec![g[0].unit, g[1].unit];
    want.sort();
    assert_eq!(units, want, "its units are handed out again first");
}

#[test]
fn admission_allocates_nothing_per_tile() {
    // 8192² at tile 4: 4M tiles. The job is accepted and leased with no per-tile memory;
    // only the tiles that get results have accumulators.
    let mut rec = record(1, 1);
    rec.width = 8192;
    rec.height = 8192;
    rec.tile_size = 4;
    let job = Job::new(rec);
    assert_eq!(job.units_total(), 4 << 20);
    assert!(job.acc.is_empty());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    core.insert_job(job);
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let g = core.lease(w, 1, now).remove(0);
    let r = result(core.job(JOB).expect("job"), g.unit, 1.0);
    let name = g.lease;
    assert!(matches!(
        core.submit(w, name, JOB, g.unit, r, now),
        Ok(Merged::New { .. })
    ));
    assert_eq!(core.job(JOB).expect("job").acc.len(), 1);
    let (rms, _) = core.job(JOB).expect("job").noise();
    assert!(rms.is_finite());
}

#[test]
fn forged_finite_sums_that_would_overflow_when_merged_are_refused() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    core.insert_job(Job::new(record(4, 2)));
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let g = core.lease(w, 8, now);
    // Two results of 1.7e308 each are finite, but their sum is not.
    for unit in [g[0].unit, g[2].unit] {
        let name = g.iter().find(|x| x.unit == unit).expect("leased").lease;
        let mut r = result(core.job(JOB).expect("job"), unit, 1.0);
        r.sum_sq[0] = [1.7e308; 3];
        assert!(
            matches!(core.submit(w, name, JOB, unit, r, now), Err(Refusal::Invalid(m)) if m.contains("f32::MAX")),
        );
        let mut r = result(core.job(JOB).expect("job"), unit, 1.0);
        r.sum[1] = [1e300, 0.0, 0.0];
        assert!(matches!(
            core.submit(w, name, JOB, unit, r, now),
            Err(Refusal::Invalid(_))
        ));
    }
    // The largest honest values merge, and stay finite through every batch.
    for unit in [g[0].unit, g[2].unit] {
        let name = g.iter().find(|x| x.unit == unit).expect("leased").lease;
        let mut r = result(core.job(JOB).expect("job"), unit, 1.0);
        let k = r.count[0] as f64;
        let m = f32::MAX as f64;
        r.sum[0] = [k * m; 3];
        r.sum_sq[0] = [k * m * m; 3];
        assert!(matches!(
            core.submit(w, name, JOB, unit, r, now),
            Ok(Merged::New { .. })
        ));
    }
    let sums = core.job(JOB).expect("job").acc[&0]
        .sums
        .as_ref()
        .expect("sums");
    assert!(sums.sum_sq[0].iter().all(|v| v.is_finite()));
    let (rms, rel) = core.job(JOB).expect("job").noise();
    assert!(rms.is_finite() && rel.is_finite());
    // What is stored of a job with such noise loads again.
    let ops = core.end_job(JOB, JobPhase::Done, String::new(), 1);
    let Some(Op::PutJob(rec)) = ops.first() else {
        panic!("no record")
    };
    let mut rec = rec.clone();
    rec.final_noise = (f64::INFINITY, f64::NAN);
    let json = serde_json::to_vec(&rec).expect("json");
    let back: JobRecord = serde_json::from_slice(&json).expect("loads");
    assert_eq!(back.final_noise, (0.0, 0.0));
    let nulls: JobRecord = serde_json::from_slice(
        &String::from_utf8(json)
            .expect("utf8")
            .replace("[0.0,0.0]", "[null,null]")
            .into_bytes(),
    )
    .expect("a null noise loads");
    assert_eq!(nulls.final_noise, (0.0, 0.0));
}

#[test]
fn ids_are_bound_to_the_registration_that_got_them() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    core.insert_job(Job::new(record(4, 2)));
    let now = Instant::now();
    let honest = core.register("honest".into(), 1, "v".into(), "secret-a".into(), now);
    let thief = core.register("thief".into(), 1, "v".into(), "secret-b".into(), now);
    // The public id alone, or with another secret, is an unknown worker.
    let public = core.worker_id(honest);
    for secret in ["secret-b", "", "secret-a-longer"] {
        let forged = WorkerCredential {
            id: public,
            secret: secret.into(),
        };
        assert!(
            matches!(
                core.touch_worker(&forged, now),
                Err(Refusal::UnknownWorker(_))
            ),
            "{secret}"
        );
    }
    // The right secret under another boot's id is unknown too.
    let stale = WorkerCredential {
        id: WorkerId { epoch: 0, ..public },
        secret: "secret-a".into(),
    };
    assert!(matches!(
        core.touch_worker(&stale, now),
        Err(Refusal::UnknownWorker(_))
    ));
    let cred = core.worker_credential(honest).expect("registered");
    assert_eq!(core.touch_worker(&cred, now), Ok(honest));
    // A result under another worker's lease is refused, and does not count against it.
    let g = core.lease(honest, 1, now).remove(0);
    let name = g.lease;
    let r = result(core.job(JOB).expect("job"), g.unit, 1.0);
    assert!(matches!(
        core.submit(thief, name, JOB, g.unit, r.clone(), now),
        Err(Refusal::Precondition(_))
    ));
    assert_eq!(core.worker(honest).expect("worker").bad_results, 0);
    assert_eq!(core.job(JOB).expect("job").units_done, 0);
    assert!(matches!(
        core.submit(honest, name, JOB, g.unit, r, now),
        Ok(Merged::New { .. })
    ));
    // Nor can another worker renew, release or refuse the honest worker's leases.
    let g = core.lease(honest, 1, now).remove(0);
    let name = g.lease;
    assert_eq!(core.heartbeat(thief, &[name], now), vec![name]);
    assert_eq!(core.release(thief, &[name]), 0);
    assert!(core.cannot_render(thief, &[name], "no", now, 1).is_empty());
    assert!(core.job(JOB).expect("job").is_live());
}

#[test]
fn hoarding_registrations_cannot_stall_a_job() {
    let lease = Duration::from_secs(5);
    let mut core = Scheduler::new(1, Policy::new(lease));
    core.policy_mut().max_leases_per_worker = 8;
    core.insert_job(Job::new(record(8, 2)));
    let t0 = Instant::now();
    let h1 = core.register("h1".into(), 1, "v".into(), "a".into(), t0);
    let h2 = core.register("h2".into(), 1, "v".into(), "b".into(), t0);
    // Each asks for everything and gets its share, no more: h1 all 8 units, h2 a racing
    // copy of each (each had one live lease), so every unit now has two holders.
    let a = core.lease(h1, 64, t0);
    assert_eq!(a.len(), 8);
    assert!(core.lease(h1, 64, t0).is_empty(), "h1 is at its share");
    let b = core.lease(h2, 64, t0);
    assert_eq!(b.len(), 8);
    let honest = core.register("honest".into(), 1, "v".into(), "c".into(), t0);
    assert!(
        core.lease(honest, 4, t0).is_empty(),
        "fresh hoards are not raced yet: the holders may just be busy"
    );
    // The hoarders keep renewing and never send anything.
    let mut t = t0;
    let mut all: Vec<LeaseId> = a.iter().chain(&b).map(|g| g.lease).collect();
    all.sort();
    for _ in 0..3 {
        t += lease / 2;
        core.heartbeat(h1, &all, t);
        core.heartbeat(h2, &all, t);
    }
    // Past a lease time since they were issued, the hoarded units are slow: the honest
    // worker gets copies, up to its share, and finishes every unit.
    let mut done = 0;
    let total = core.job(JOB).expect("job").units_total() as usize;
    while done < total {
        let got = core.lease(honest, 4, t);
        assert!(
            !got.is_empty(),
            "the honest worker starves after {done} units"
        );
        for g in got {
            let r = result(core.job(JOB).expect("job"), g.unit, 1.0);
            let name = g.lease;
            if let Ok(Merged::New { .. }) = core.submit(honest, name, JOB, g.unit, r, t) {
                done += 1;
            }
        }
        t += Duration::from_millis(10);
    }
    assert!(
        core.job(JOB).expect("job").finishing,
        "the job finished without the hoarders"
    );
}

/// Found by the `rpc_sequence` fuzz target (job 1 stalled with 19 of 20 units): three hoarding
/// registrations took the first lease and two racing copies of a unit, the most copies a unit
/// could have, and renewed them for ever, so no honest worker could ever race it. Copies are
/// now limited in rate (one more each time every holder has had the unit a lease time), not in
/// number, so however many hoarders there are, an honest worker gets a copy.
#[test]
fn any_number_of_hoarders_cannot_keep_a_unit_from_an_honest_worker() {
    let lease = Duration::from_secs(5);
    let mut core = Scheduler::new(1, Policy::new(lease));
    core.insert_job(Job::new(record(2, 2)));
    let total = core.job(JOB).expect("job").units_total() as usize;
    let mut t = Instant::now();
    let hoarders: Vec<u64> = (0..5)
        .map(|i| core.register(format!("h{i}"), 1, "v".into(), format!("s{i}"), t))
        .collect();
    let mut held: Vec<Vec<LeaseId>> = vec![Vec::new(); hoarders.len()];
    // Each hoarder takes whatever it can, renews everything it holds, and never sends a result.
    for _ in 0..20 {
        for (h, mine) in hoarders.iter().zip(&mut held) {
            mine.extend(core.lease(*h, 64, t).iter().map(|g| g.lease));
            core.heartbeat(*h, mine, t);
        }
        t += lease / 2;
    }
    let copies = core
        .job(JOB)
        .expect("job")
        .issued
        .values()
        .map(Vec::len)
        .max();
    assert!(
        copies >= Some(3),
        "the hoarders hold {copies:?} copies of a unit"
    );
    let honest = core.register("honest".into(), 1, "v".into(), "c".into(), t);
    let mut done = 0;
    for _ in 0..10 {
        for (h, mine) in hoarders.iter().zip(&held) {
            core.heartbeat(*h, mine, t);
        }
        for g in core.lease(honest, 4, t) {
            let r = result(core.job(JOB).expect("job"), g.unit, 1.0);
            if let Ok(Merged::New { .. }) = core.submit(honest, g.lease, JOB, g.unit, r, t) {
                done += 1;
            }
        }
        t += lease / 2;
    }
    assert_eq!(done, total, "the honest worker got {done} of {total} units");
    assert!(core.job(JOB).expect("job").finishing);
}

/// A lone worker that cannot render a unit fails it three times (the unit comes back to it,
/// as nobody else is there), is blocklisted, and the job fails with the reason, once.
#[test]
fn a_unit_a_lone_worker_cannot_render_fails_its_job_with_the_reason() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    core.insert_job(Job::new(record(4, 2)));
    let now = Instant::now();
    let w = core.register("small".into(), 1, "v".into(), "s".into(), now);
    let mut ops = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let g = core.lease(w, 1, now).remove(0);
        ops = core.cannot_render(
            w,
            &[g.lease],
            "scene.toml: film.width 20000 is above 16384",
            now,
            5,
        );
        core.release(w, &[g.lease]);
        last = Some(g.lease);
    }
    assert!(ops
        .iter()
        .any(|o| matches!(o, Op::PutJob(r) if r.phase == JobPhase::Failed)));
    let job = &core.job(JOB).expect("job");
    assert_eq!(job.rec.phase, JobPhase::Failed);
    assert!(
        job.rec.error.contains("cannot render tile"),
        "{}",
        job.rec.error
    );
    assert!(
        job.rec.error.contains("film.width 20000"),
        "{}",
        job.rec.error
    );
    // The unit is not handed out again, and a late refusal changes nothing.
    assert!(core.lease(w, 8, now).is_empty());
    let last = last.expect("a lease");
    assert!(core.cannot_render(w, &[last], "again", now, 6).is_empty());
}

/// An 8×8 job in 4-pixel tiles at 4 spp in batches of 2 (8 units a frame), named `name` (or
/// not), of the frames `frames` (or one).
fn admission(name: Option<&str>, frames: Option<&str>) -> Admission {
    common::admission(name, frames, None)
}

#[test]
fn admission_checks_its_bounds_and_names_each_job_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let job = |name: Option<&str>| admission(name, None);
    let limits = AdmissionLimits {
        max_active_jobs: 2,
        max_units_per_job: 8,
        max_frames_per_job: 100,
    };
    // 4 tiles × 2 batches: 8 units, at the limit.
    let (a, ops) = core.admit(job(None), limits, &names, 1).expect("admitted");
    assert_eq!(a, JobId(1));
    assert_eq!(core.job(a).expect("job").rec.output_name, "job-000001.exr");
    assert_eq!(core.job(a).expect("job").units_total(), 8);
    assert!(matches!(&ops[..], [Op::PutScene(..), Op::PutJob(r)] if r.id == 1));
    let fewer = AdmissionLimits {
        max_units_per_job: 7,
        ..limits
    };
    assert!(matches!(
        core.admit(job(None), fewer, &names, 1),
        Err(Refusal::Exhausted(m)) if m.contains("8 work units")
    ));
    let (b, _) = core
        .admit(job(Some("shot.exr")), limits, &names, 1)
        .expect("named");
    assert_eq!(b, JobId(2), "a refused job takes no id");
    assert!(matches!(
        core.admit(job(None), limits, &names, 1),
        Err(Refusal::Exhausted(m)) if m.contains("2 jobs")
    ));
    core.end_job(a, JobPhase::Cancelled, String::new(), 2);
    assert!(matches!(
        core.admit(job(Some("shot.exr")), limits, &names, 2),
        Err(Refusal::Exists(m)) if m.contains("job-000002")
    ));
    let (c, _) = core
        .admit(job(None), limits, &names, 3)
        .expect("room again");
    assert_eq!(c, JobId(3));
}

#[test]
fn a_frame_range_is_one_job_of_frame_jobs_in_frame_order() {
    let dir = tempfile::tempdir().expect("tempdir");
    let names = OutputNames::new(dir.path());
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    let job = admission;
    let limits = AdmissionLimits {
        max_active_jobs: 2,
        max_units_per_job: 8,
        max_frames_per_job: 4,
    };
    let (range, ops) = core
        .admit(job(None, Some("3-9:3")), limits, &names, 1)
        .expect("admitted");
    assert_eq!(range, JobId(1));
    assert!(core.job(range).is_none(), "a range has no job of its own");
    let members = core.members(range);
    assert_eq!(members, [JobId(2), JobId(3), JobId(4)]);
    let got: Vec<_> = members
        .iter()
        .map(|m| {
            let r = &core.job(*m).expect("job").rec;
            (r.frame, r.output_name.as_str(), r.range.map(|x| x.id))
        })
        .collect();
    assert_eq!(
        got,
        [
            (Some(3), "job-000001.0003.exr", Some(1)),
            (Some(6), "job-000001.0006.exr", Some(1)),
            (Some(9), "job-000001.0009.exr", Some(1)),
        ]
    );
    assert!(matches!(
        &ops[..],
        [
            Op::PutScene(..),
            Op::PutJob(_),
            Op::PutJob(_),
            Op::PutJob(_)
        ]
    ));
    // The first frame's units go first: a user sees frame 3 before frame 9 is started.
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let g = core.lease(w, 4, now);
    assert!(g.iter().all(|g| g.job == JobId(2)), "{g:?}");
    // Too many frames, or a name a frame of another range has, are refused and take no id.
    assert!(matches!(
        core.admit(job(None, Some("1-5")), limits, &names, 1),
        Err(Refusal::Exhausted(m)) if m.contains("5 frames") && m.contains("limit of 4")
    ));
    let (named, _) = core
        .admit(job(Some("shot.exr"), Some("1-2")), limits, &names, 1)
        .expect("named range");
    assert_eq!(named, JobId(5));
    assert_eq!(
        core.job(JobId(7)).expect("job").rec.output_name,
        "shot.0002.exr"
    );
    // Two ranges of three and two frames are two jobs against the active limit.
    assert!(matches!(
        core.admit(job(None, None), limits, &names, 1),
        Err(Refusal::Exhausted(m)) if m.contains("2 jobs")
    ));
    for m in core.members(named) {
        core.end_job(m, JobPhase::Cancelled, String::new(), 2);
    }
    assert!(matches!(
        core.admit(job(Some("shot.exr"), Some("2-3")), limits, &names, 2),
        Err(Refusal::Exists(m)) if m.contains("shot.0002.exr") && m.contains("job-000007")
    ));
    // A file in the output directory with a range frame's default name moves the range on.
    std::fs::write(dir.path().join("job-000008.0001.exr"), b"x").expect("squat");
    let (next, _) = core
        .admit(job(None, Some("1-2")), limits, &names, 3)
        .expect("room again");
    assert_eq!(
        next,
        JobId(11),
        "past job-000008 and the two ids its frames would take"
    );
    assert_eq!(
        core.job(JobId(12)).expect("job").rec.output_name,
        "job-000011.0001.exr"
    );
}

#[test]
fn an_adaptive_job_past_its_pilots_without_a_kept_scale_fails_at_restore_and_others_resume() {
    // 256 spp in batches of 32: a pilot of 2 batches (64 samples), then decisions.
    let adaptive = |id: u64, end: u32, scale: Option<f64>| {
        let rec = JobRecord {
            id,
            noise_target: 0.05,
            adaptive_scale: scale,
            phase: JobPhase::Active,
            image_revision: tessera_render::IMAGE_REVISION,
            output_name: format!("o{id}.exr"),
            ..record(256, 32)
        };
        let job = Job::new(rec.clone());
        let tiles = (0..job.tiles.len() as u32)
            .map(|t| {
                let rect = job.tiles.get(t).expect("tile");
                let mut sums = TileSums::empty(rect, 0);
                sums.samples = 0..end;
                for i in 0..rect.area() {
                    sums.sum[i] = [end as f64 * 0.5; 3];
                    sums.sum_sq[i] = [end as f64 * 0.5; 3];
                    sums.count[i] = end;
                }
                (t, tessera_coordinator::store::encode_sums(&sums))
            })
            .collect();
        tessera_coordinator::store::LoadedJob {
            record: rec,
            tiles,
            pending: Vec::new(),
            log: None,
            log_bytes: 0,
            guides: Vec::new(),
        }
    };
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(5)));
    // Job 1 went past its pilots with no scale kept; job 2 has every pilot in and no scale
    // yet (the scale is computed at restore and kept); job 3 kept its scale.
    let (ops, _) = core
        .restore(
            vec![
                adaptive(1, 96, None),
                adaptive(2, 64, None),
                adaptive(3, 96, Some(40.0)),
            ],
            Vec::new(),
            5,
        )
        .expect("restore");
    let j1 = &core.job(JobId(1)).expect("job");
    assert_eq!(j1.rec.phase, JobPhase::Failed);
    assert!(
        j1.rec.error.contains("earlier adaptive rule"),
        "{}",
        j1.rec.error
    );
    let j2 = &core.job(JobId(2)).expect("job");
    assert_eq!(j2.rec.phase, JobPhase::Active);
    let scale = j2
        .rec
        .adaptive_scale
        .expect("scale computed from the pilots");
    assert!(scale > 0.0);
    assert!(ops
        .iter()
        .any(|op| matches!(op, Op::PutJob(r) if r.id == 2 && r.adaptive_scale == Some(scale))));
    let j3 = &core.job(JobId(3)).expect("job");
    assert_eq!(
        (j3.rec.phase, j3.rec.adaptive_scale),
        (JobPhase::Active, Some(40.0))
    );
}
