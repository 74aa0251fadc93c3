//! Sequences of worker calls from several fake workers, honest and hostile, against the
//! coordinator's scheduling state ([`Scheduler`], which every `Workers` RPC goes through under the
//! coordinator's lock): register, lease, heartbeat, release, refuse, submit (honest, forged,
//! under another worker's lease), time passing, and a second job being cancelled.
//!
//! After every call: no worker holds more than its share, nothing merged is non-finite, every
//! tile's sums cover batches 0..next, and the noise estimate is finite. At the end an honest
//! worker must be able to finish the main job while the hostile ones keep renewing their
//! leases and never send anything; if no forged result was merged, the main job's sums must be
//! bit-identical to merging the honest results in order.
//!
//! An input of odd length runs with audits (`--audit 0.5`, audited jobs): then every liar whose
//! undetectable lie was merged and who was convicted must have had it taken back, so if every
//! such liar is convicted by the end the sums must still be the honest bits. Workers register
//! from one of three hosts (chosen by the input); the coordinator's referee, played here by the
//! honest sums, settles disputes when time passes and while the honest worker finishes.
#![no_main]

use std::time::{Duration, Instant};

use libfuzzer_sys::fuzz_target;
use tessera_coordinator::job::{Job, Unit};
use tessera_coordinator::scheduler::{Merged, Policy, Scheduler};
use tessera_coordinator::store::{JobPhase, JobRecord};
use tessera_proto::ids::{JobId, LeaseId};
use tessera_render::TileSums;

const LEASE: Duration = Duration::from_secs(4);

fn record(id: u64, audited: bool) -> JobRecord {
    JobRecord {
        audited,
        id,
        width: 6,
        height: 5,
        spp: 9,
        seed: 0,
        batch: 2,
        strategy: tessera_render::Strategy::Mis,
        tile_size: 4,
        output_name: format!("o{id}.exr"),
        ..JobRecord::default()
    }
}

/// The result an honest worker sends for a unit: values that differ per unit and pixel, of
/// very different magnitudes, so another merge order would change the low bits.
fn honest(job: &Job, u: Unit) -> TileSums {
    let rect = job.tiles.get(u.tile).expect("leased tiles exist");
    let mut t = TileSums::empty(rect, 0);
    t.samples = job.batch_range(u.batch);
    let k = t.samples.len() as u32;
    for i in 0..rect.area() {
        let v = ((u.tile * 31 + u.batch * 7 + i as u32) % 97) as f64 * 0.37 + 1e-3;
        t.sum[i] = [v, v * 0.5, v * 1e6];
        t.sum_sq[i] = [v * v, v * v * 0.25, v * v * 1e12];
        t.count[i] = k;
    }
    t
}

/// A forged result: one of several lies about an otherwise honest one. The undetectable one
/// differs by worker `w`, so that two liars never agree on it (an audit settled by two liars
/// agreeing is a limit of audits, documented, not a bug to find).
fn forged(job: &Job, u: Unit, how: u8, w: u64) -> TileSums {
    let mut t = honest(job, u);
    match how % 7 {
        0 => t.sum_sq[0] = [1.7e308; 3],
        1 => t.sum[0][1] = f64::NAN,
        2 => t.sum[0][2] = -1.0,
        3 => {
            t.count.pop();
        }
        4 => t.samples = t.samples.start..t.samples.end + 1,
        5 => t.count[0] = 0,
        // In range and the right shape: undetectable without rendering again.
        _ => t.sum[0][0] *= 2.0 + w as f64,
    }
    t
}

struct Fake {
    id: u64,
    hostile: bool,
    leases: Vec<(LeaseId, JobId, Unit)>,
}

fn check(core: &Scheduler) {
    for (w, _) in core.workers() {
        assert!(
            core.leases_of(w) <= core.policy().max_leases_per_worker,
            "worker {w} holds {} leases",
            core.leases_of(w)
        );
    }
    for (w, x) in core.workers() {
        if x.convicted.is_some() {
            assert_eq!(core.leases_of(w), 0, "convicted worker {w} holds leases");
        }
    }
    for job in core.jobs() {
        assert!(job.units_done <= job.units_total());
        if job.is_live() {
            let held: u64 = job
                .acc
                .values()
                .map(|a| a.next as u64 + a.pending.len() as u64)
                .sum();
            assert_eq!(
                job.units_done, held,
                "units counted done and units held differ"
            );
        }
        let (rms, rel) = job.noise();
        assert!(rms.is_finite() && rel.is_finite());
        for (t, acc) in &job.acc {
            if let Some(s) = &acc.sums {
                assert_eq!(s.samples.start, 0);
                assert_eq!(s.samples.end, job.batch_range(acc.next - 1).end, "tile {t}");
                assert!(s
                    .sum
                    .iter()
                    .chain(&s.sum_sq)
                    .flatten()
                    .all(|v| v.is_finite()));
            }
        }
    }
}

/// Plays the coordinator's referee: renders (honestly) each unit the scheduler wants settled.
fn referee(core: &mut Scheduler, now: Instant) {
    for (job, unit) in core.take_referee_work() {
        let Some(j) = core.job(job) else {
            continue;
        };
        let sums = honest(j, unit);
        let r = core.referee(job, unit, sums, now, &(), 1);
        assert!(r.is_ok(), "the referee's honest result was refused: {r:?}");
    }
}

fuzz_target!(|data: &[u8]| {
    let audited = data.len() % 2 == 1;
    let mut core = Scheduler::new(1, Policy::new(LEASE));
    core.policy_mut().max_leases_per_worker = 4;
    if audited {
        core.policy_mut().audit = 0.5;
    }
    core.insert_job(Job::new(record(1, audited)));
    core.insert_job(Job::new(record(2, audited)));
    let mut now = Instant::now();
    let mut fakes: Vec<Fake> = Vec::new();
    let mut tainted = false;
    let mut tainted_by = std::collections::BTreeSet::new();
    // Liars convicted while job 1 was still live: only their results are taken back from it (a
    // conviction after a job finished is recorded, not undone).
    let mut caught = std::collections::BTreeSet::new();
    let mut note_caught = |core: &Scheduler, tainted_by: &std::collections::BTreeSet<u64>| {
        if core.job(JobId(1)).expect("job").is_live() {
            for w in tainted_by {
                if core.worker(*w).expect("worker").convicted.is_some() {
                    caught.insert(*w);
                }
            }
        }
    };
    let mut bytes = data.iter().copied();
    let mut next = || bytes.next();
    while let (Some(op), Some(arg)) = (next(), next()) {
        let pick = |n: usize| (arg as usize) % n.max(1);
        match op % 9 {
            0 if fakes.len() < 6 => {
                let hostile = arg % 2 == 1;
                let id = core.register(
                    format!("f{}", fakes.len()),
                    1,
                    "v".into(),
                    format!("s{arg}"),
                    now,
                );
                core.set_host(id, format!("10.0.0.{}", (arg >> 1) % 3));
                fakes.push(Fake {
                    id,
                    hostile,
                    leases: Vec::new(),
                });
            }
            1 if !fakes.is_empty() => {
                let f = pick(fakes.len());
                let w = fakes[f].id;
                for g in core.lease(w, (arg % 8) as usize + 1, now) {
                    fakes[f].leases.push((g.lease, g.job, g.unit));
                }
            }
            2 if !fakes.is_empty() => {
                let f = &fakes[pick(fakes.len())];
                let mut ids: Vec<LeaseId> = f.leases.iter().map(|l| l.0).collect();
                // A lease number of this boot that may be another worker's, and one of
                // another boot.
                ids.push(LeaseId {
                    epoch: 1,
                    n: arg.into(),
                });
                ids.push(LeaseId { epoch: 0, n: 1 });
                core.heartbeat(f.id, &ids, now);
            }
            3 if !fakes.is_empty() => {
                let i = pick(fakes.len());
                let f = &mut fakes[i];
                if let Some(l) = f.leases.pop() {
                    core.release(f.id, &[l.0]);
                }
            }
            4 | 5 if !fakes.is_empty() => {
                // Submit for one of this worker's leases, or (arg's high bit) another's.
                let f = pick(fakes.len());
                let owner = if arg & 0x80 != 0 {
                    (f + 1) % fakes.len()
                } else {
                    f
                };
                let Some((name, job, unit)) = fakes[owner].leases.first().cloned() else {
                    continue;
                };
                let w = fakes[f].id;
                let Some(j) = core.job(job) else {
                    continue;
                };
                let lie = op % 9 == 5 || fakes[f].hostile;
                let sums = if lie {
                    forged(j, unit, arg, w)
                } else {
                    honest(j, unit)
                };
                let in_range_lie = lie && arg % 7 == 6;
                let r = core.submit(w, name, job, unit, sums, now);
                if owner != f {
                    assert!(
                        !matches!(r, Ok(Merged::New { .. })),
                        "a result under another worker's lease was merged"
                    );
                }
                if lie && !in_range_lie {
                    assert!(
                        !matches!(r, Ok(Merged::New { .. })),
                        "a forged result (lie {}) was merged",
                        arg % 7
                    );
                }
                if in_range_lie && job == JobId(1) && matches!(r, Ok(Merged::New { .. })) {
                    tainted = true;
                    tainted_by.insert(w);
                }
                if owner == f {
                    fakes[f].leases.remove(0);
                }
            }
            6 => {
                now += Duration::from_millis(arg as u64 * 40);
                core.expire(now);
                referee(&mut core, now);
            }
            7 if !fakes.is_empty() => {
                // A worker that says it cannot render one of job 2's units fails job 2 only.
                let i = pick(fakes.len());
                let f = &mut fakes[i];
                if let Some(i) = f.leases.iter().position(|l| l.1 == JobId(2)) {
                    let l = f.leases.remove(i);
                    core.cannot_render(f.id, &[l.0], "too big", now, 1);
                }
            }
            8 => {
                core.end_job(JobId(2), JobPhase::Cancelled, String::new(), 1);
            }
            _ => {}
        }
        check(&core);
        note_caught(&core, &tainted_by);
    }

    // Liveness: the hostile workers keep their leases alive and never finish; a fresh honest
    // worker must still get job 1 done.
    let honest_workers: Vec<u64> = (0..if audited { 2 } else { 1 })
        .map(|i| {
            let w = core.register(format!("honest{i}"), 1, "v".into(), format!("h{i}"), now);
            core.set_host(w, format!("10.0.1.{i}"));
            w
        })
        .collect();
    let total = core.job(JobId(1)).expect("job").units_total();
    for round in 0.. {
        if !core.job(JobId(1)).expect("job").is_live() {
            break;
        }
        assert!(
            round < 20 * total + 50,
            "job 1 stalled with {} of {total} units",
            core.job(JobId(1)).expect("job").units_done
        );
        for f in fakes.iter().filter(|f| f.hostile) {
            let ids: Vec<LeaseId> = f.leases.iter().map(|l| l.0).collect();
            core.heartbeat(f.id, &ids, now);
        }
        for &h in &honest_workers {
            for g in core.lease(h, 4, now) {
                let j = &core.job(g.job).expect("job");
                let sums = honest(j, g.unit);
                let _ = core.submit(h, g.lease, g.job, g.unit, sums, now);
                note_caught(&core, &tainted_by);
            }
        }
        check(&core);
        now += LEASE / 2;
        core.expire(now);
        referee(&mut core, now);
        note_caught(&core, &tainted_by);
    }
    for &h in &honest_workers {
        assert!(
            core.worker(h).expect("worker").convicted.is_none(),
            "an honest worker was convicted"
        );
    }
    // A merged lie is taken back when its liar is convicted.
    let taken_back = audited && tainted_by.iter().all(|w| caught.contains(w));
    if tainted && !taken_back {
        return;
    }
    // Every merged result was honest: the sums are the in-order fold, bit for bit.
    let job = &core.job(JobId(1)).expect("job");
    if job.rec.phase != JobPhase::Active {
        return;
    }
    for (&t, acc) in &job.acc {
        let rect = job.tiles.get(t).expect("tile");
        let mut want = TileSums::empty(rect, 0);
        for b in 0..job.n_batches {
            want.merge(&honest(job, Unit { tile: t, batch: b }))
                .expect("in order");
        }
        let got = acc.sums.as_ref().expect("finished tiles have sums");
        assert_eq!(got.as_ref(), &want, "tile {t}");
    }
});
