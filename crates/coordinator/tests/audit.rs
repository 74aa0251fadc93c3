//! Audits, call by call: a worker whose wrong results were merged unchecked is caught by a
//! checked one, convicted when the coordinator's own render (the referee, played here by the
//! honest sums) settles the dispute, and every result it gave is taken back, its tiles folded
//! again from the kept results in the real store, so the job ends with the honest bits. Copies
//! count only from different hosts, so registrations of one host cannot outvote another.

use std::time::{Duration, Instant};

use tessera_coordinator::error::Refusal;
use tessera_coordinator::job::{same_bits, Job, KeptUnits, Unit};
use tessera_coordinator::scheduler::{Granted, Merged, Policy, Scheduler, UnitResult};
use tessera_coordinator::store::{GuidingRecord, JobRecord, Op, Store};
use tessera_proto::ids::JobId;
use tessera_render::{Strategy, TileSums};

const JOB: JobId = JobId(1);

/// An 8×2 image in 2×2 tiles (4 tiles) at 8 spp in batches of 1: 32 units.
fn record(audited: bool) -> JobRecord {
    JobRecord {
        id: 1,
        spp: 8,
        batch: 1,
        width: 8,
        height: 2,
        seed: 0,
        strategy: Strategy::Mis,
        tile_size: 2,
        output_name: "o.exr".into(),
        audited,
        ..JobRecord::default()
    }
}

/// The honest result of a unit: values that differ by pixel, tile and batch, so that any
/// batch folded twice, left out or out of order changes the bits.
fn honest(job: &Job, u: Unit) -> TileSums {
    let rect = job.tiles.get(u.tile).expect("tile");
    let mut t = TileSums::empty(rect, 0);
    t.samples = job.batch_range(u.batch);
    let k = t.samples.len() as u32;
    for i in 0..rect.area() {
        let v = 0.1 + (u.tile as f64) * 0.37 + (u.batch as f64).sqrt() * 0.11 + i as f64 * 0.013;
        t.sum[i] = [v, v * 0.5, v * 0.25];
        t.sum_sq[i] = [v * v, v * v * 0.25, v * v * 0.0625];
        t.count[i] = k;
    }
    t
}

/// A guided audited job of the same image: 8 spp in batches of 1 cut at its epochs [0,1)
/// [1,3) [3,8), so batch 0 is epoch 0, batches 1–2 epoch 1, and 3–7 the last epoch, which
/// trains nothing.
fn guided_record() -> JobRecord {
    JobRecord {
        guiding: Some(GuidingRecord {
            bounds: [[0.0; 3], [1.0; 3]],
            guides: Vec::new(),
        }),
        ..record(true)
    }
}

/// What a worker returns for `u`: `honest`'s sums (`forged`'s if it lies) and, where the
/// unit's epoch trains, a tree of that epoch's structure whose record differs by tile and
/// batch (and by the lie), as a worker's trained tree differs by what its paths found.
fn result(job: &Job, u: Unit, lie: bool) -> UnitResult {
    let sums = if lie { forged(job, u) } else { honest(job, u) };
    let train = job.guiding.as_ref().and_then(|g| {
        let (_, structure) = g.unit_inputs(u.batch).expect("the unit's guide");
        structure.map(|mut t| {
            let v = 1.0 + u.tile as f64 + 0.5 * u.batch as f64 + if lie { 7.0 } else { 0.0 };
            let at = glam::Vec3A::splat(0.1 + 0.2 * u.tile as f32);
            t.record(at, glam::Vec3A::Z, v);
            t.freeze();
            t
        })
    });
    UnitResult { sums, train }
}

/// Plausible but wrong: every sum 1% high, still finite and in range.
fn forged(job: &Job, u: Unit) -> TileSums {
    let mut t = honest(job, u);
    for p in t.sum.iter_mut().chain(t.sum_sq.iter_mut()) {
        for c in p {
            *c *= 1.01;
        }
    }
    t
}

/// The scheduler and a real store every commit goes to, as the coordinator's writer would.
struct Farm {
    core: Scheduler,
    store: Store,
    _dir: tempfile::TempDir,
    now: Instant,
}

impl Farm {
    fn new(audited: bool) -> Self {
        Self::with(record(audited))
    }

    fn with(rec: JobRecord) -> Self {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("store");
        let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
        core.insert_job(Job::new(rec));
        Farm {
            core,
            store,
            _dir: dir,
            now: Instant::now(),
        }
    }

    /// A worker on a host of its own (named after it).
    fn worker(&mut self, name: &str) -> u64 {
        self.worker_on(name, &format!("host-{name}"))
    }

    fn worker_on(&mut self, name: &str, host: &str) -> u64 {
        let w = self
            .core
            .register(name.into(), 1, "v".into(), name.into(), self.now);
        self.core.set_host(w, host.into());
        w
    }

    /// Plays the coordinator's referee: renders (honestly) every unit the scheduler asks it
    /// to, and commits what each settles. Returns the outcomes.
    fn referee(&mut self) -> Vec<Merged> {
        let wanted = self.core.take_referee_work();
        wanted
            .into_iter()
            .map(|(job, unit)| {
                let r = result(self.core.job(job).expect("job"), unit, false);
                let m = self
                    .core
                    .referee(job, unit, r, self.now, &self.store, 0)
                    .expect("the referee's result");
                if let Merged::New { ops, .. } = &m {
                    self.store.apply(ops).expect("commit");
                }
                m
            })
            .collect()
    }

    fn lease(&mut self, w: u64) -> Option<Granted> {
        self.core.lease(w, 1, self.now).into_iter().next()
    }

    /// Sends a result and commits what it changed; returns the outcome.
    fn send(&mut self, w: u64, g: &Granted, r: impl Into<UnitResult>) -> Merged {
        let m = self
            .core
            .submit(w, g.lease, g.job, g.unit, r, self.now)
            .expect("accepted");
        if let Merged::New { ops, .. } = &m {
            self.store.apply(ops).expect("commit");
        }
        m
    }

    fn job(&self) -> &Job {
        self.core.job(JOB).expect("job")
    }

    /// Honest workers `ws` render what is left, in turn, until the job finishes; the
    /// referee settles what it is asked to, and time passes a lease time a round when nobody
    /// got work (so held units no other host takes go to the referee).
    fn finish(&mut self, ws: &[u64]) {
        for _ in 0..1000 {
            let mut worked = false;
            for &w in ws {
                let Some(g) = self.lease(w) else { continue };
                worked = true;
                let r = result(self.job(), g.unit, false);
                if let Merged::New { finished: true, .. } = self.send(w, &g, r) {
                    return;
                }
            }
            if self
                .referee()
                .iter()
                .any(|m| matches!(m, Merged::New { finished: true, .. }))
            {
                return;
            }
            if !worked {
                self.now += self.core.policy().lease_time;
                self.core.expire(self.now);
            }
        }
        panic!(
            "the job does not finish: {} of {} units",
            self.job().units_done,
            self.job().units_total()
        );
    }
}

/// Each tile's honest sums, folded in batch order from zero.
fn honest_frame(job: &Job) -> Vec<TileSums> {
    (0..job.tiles.len() as u32)
        .map(|tile| {
            let rect = job.tiles.get(tile).expect("tile");
            let mut total = TileSums::empty(rect, 0);
            for batch in 0..job.n_batches {
                total
                    .merge(&honest(job, Unit { tile, batch }))
                    .expect("merge");
            }
            total
        })
        .collect()
}

fn same_frame(a: &[TileSums], b: &[TileSums]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| same_bits(x, y))
}

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[test]
fn a_convicted_worker_has_every_result_taken_back_and_the_job_ends_with_the_honest_bits() {
    let mut farm = Farm::new(true);
    let (a, b, liar) = (farm.worker("a"), farm.worker("b"), farm.worker("liar"));

    // Unaudited phase: the liar's second result is wrong, and merged unchecked.
    farm.core.policy_mut().audit = 0.0;
    let mut liar_units = Vec::new();
    let mut liar_results = 0;
    for round in 0..4 {
        for w in [a, b, liar] {
            let g = farm.lease(w).expect("a unit");
            let r = if w == liar {
                liar_results += 1;
                liar_units.push(g.unit);
                if liar_results == 2 {
                    forged(farm.job(), g.unit)
                } else {
                    honest(farm.job(), g.unit)
                }
            } else {
                honest(farm.job(), g.unit)
            };
            assert!(
                matches!(farm.send(w, &g, r), Merged::New { .. }),
                "round {round}: unaudited results merge at once"
            );
        }
    }
    assert!(
        !same_frame(&farm.job().frame_tiles(), &honest_frame(farm.job())[..]),
        "the forged unit is in the sums"
    );
    let done_before = farm.job().units_done;

    // Every unit is checked from now on. The liar forges one: it is held, not merged.
    farm.core.policy_mut().audit = 1.0;
    let g = farm.lease(liar).expect("a unit");
    let caught = g.unit;
    assert!(matches!(
        farm.send(liar, &g, forged(farm.job(), caught)),
        Merged::Held
    ));
    assert_eq!(
        farm.job().units_done,
        done_before,
        "a held result is not done"
    );
    // Its copy goes to another worker, first in line.
    let ga = farm.lease(a).expect("the copy");
    assert_eq!(ga.unit, caught);
    assert!(matches!(
        farm.send(a, &ga, honest(farm.job(), caught)),
        Merged::Held
    ));
    // The copies differ: no third worker's vote decides, the coordinator's own render does.
    // Meanwhile both keep working, and the unit is not handed out again.
    assert!(farm
        .core
        .worker(a)
        .expect("worker")
        .disputes
        .contains(&(JOB, caught)));
    let gb = farm.lease(b).expect("other work");
    assert_ne!(gb.unit, caught, "the disputed unit went to a worker");
    farm.send(b, &gb, honest(farm.job(), gb.unit));
    let ga = farm.lease(a).expect("a worker in a dispute keeps working");
    assert_ne!(ga.unit, caught);
    farm.send(a, &ga, honest(farm.job(), ga.unit));
    let wanted = farm.core.take_referee_work();
    assert_eq!(wanted, vec![(JOB, caught)]);
    let Merged::New { ops, finished } = farm
        .core
        .referee(
            JOB,
            caught,
            honest(farm.job(), caught),
            farm.now,
            &farm.store,
            0,
        )
        .expect("refereed")
    else {
        panic!("the settled unit merges");
    };
    assert!(!finished);
    farm.store.apply(&ops).expect("commit");
    let record = ops
        .iter()
        .find_map(|op| match op {
            Op::PutAudit(r) => Some(r.clone()),
            _ => None,
        })
        .expect("the conviction is recorded");
    assert_eq!(record.name, "liar");
    assert_eq!(record.caught_on, (1, caught.tile, caught.batch));
    // Every kept copy was in the store: exactly the liar's merged units render again, the
    // honest ones it had merged among them, and no one else's.
    assert_eq!(record.units_requeued, liar_units.len() as u64);
    assert_eq!(record.jobs_rebuilt, vec![1]);
    let why = farm
        .core
        .worker(liar)
        .expect("worker")
        .convicted
        .clone()
        .expect("convicted");
    assert!(why.contains("coordinator's own render"), "{why}");
    assert_eq!(farm.store.audits().expect("audits"), vec![record]);
    // The liar is out; the honest worker is cleared.
    let liar_cred = farm.core.worker_credential(liar).expect("cred");
    match farm.core.touch_worker(&liar_cred, farm.now) {
        Err(Refusal::Denied(m)) => assert!(m.contains("audit"), "{m}"),
        other => panic!("a convicted worker is refused, got {other:?}"),
    }
    assert!(farm.core.worker(a).expect("worker").disputes.is_empty());
    // Its copy of the caught unit matched the referee (and its other unit may have matched b's).
    assert!(farm.core.worker(a).expect("worker").audits_passed >= 1);

    // The honest workers finish the job, checking each other.
    farm.finish(&[a, b]);
    assert!(
        same_frame(&farm.job().frame_tiles(), &honest_frame(farm.job())),
        "the finished sums are the honest bits"
    );
    assert_eq!(farm.job().units_done, farm.job().units_total());
}

/// Without kept copies (the store lost them, or none were kept), a rebuild renders the tiles'
/// batches again: slower, and the same bits.
#[test]
fn without_kept_copies_the_touched_tiles_render_again_to_the_same_bits() {
    let mut farm = Farm::new(true);
    let (a, b, liar) = (farm.worker("a"), farm.worker("b"), farm.worker("liar"));
    farm.core.policy_mut().audit = 0.0;
    let mut liar_units = 0;
    for _ in 0..3 {
        for w in [a, b, liar] {
            let g = farm.lease(w).expect("a unit");
            let r = if w == liar {
                liar_units += 1;
                forged(farm.job(), g.unit)
            } else {
                honest(farm.job(), g.unit)
            };
            farm.send(w, &g, r);
        }
    }
    let job = JOB;
    let unit = farm.lease(a).expect("a unit").unit;
    let ops = farm.core.convict(liar, "test".into(), (job, unit), &(), 0);
    let taken = ops
        .iter()
        .find_map(|op| match op {
            Op::PutAudit(r) => Some(r.units_requeued),
            _ => None,
        })
        .expect("recorded");
    assert!(
        taken > liar_units,
        "{taken} units go back, more than the liar's {liar_units}: its tiles' other batches too"
    );
    farm.store.apply(&ops).expect("commit");
    farm.core.policy_mut().audit = 0.0;
    farm.finish(&[a, b]);
    assert!(same_frame(
        &farm.job().frame_tiles(),
        &honest_frame(farm.job())
    ));
}

/// A job admitted without audits keeps no copies: it pays nothing for the feature.
#[test]
fn an_unaudited_job_keeps_no_copies() {
    let mut farm = Farm::new(false);
    let w = farm.worker("w");
    farm.core.policy_mut().audit = 1.0;
    let g = farm.lease(w).expect("a unit");
    let Merged::New { ops, .. } = farm.send(w, &g, honest(farm.job(), g.unit)) else {
        panic!("merged at once: the job is not audited");
    };
    assert!(!ops.iter().any(|op| matches!(op, Op::PutUnit(..))));
    assert!(
        ().kept(1, 0, farm.job().tiles.get(0).expect("tile"))
            .is_empty()
    );
}

/// An audited unit never goes back to a worker that has rendered it: with one worker, it
/// waits for another (for a lease time; then the referee renders it, below).
#[test]
fn an_audit_copy_goes_to_another_worker() {
    let mut farm = Farm::new(true);
    let a = farm.worker("a");
    farm.core.policy_mut().audit = 1.0;
    let g = farm.lease(a).expect("a unit");
    assert!(matches!(
        farm.send(a, &g, honest(farm.job(), g.unit)),
        Merged::Held
    ));
    // The rest merge unchecked: only the one copy waits.
    farm.core.policy_mut().audit = 0.0;
    for _ in 0..40 {
        if let Some(next) = farm.lease(a) {
            assert_ne!(
                next.unit, g.unit,
                "the copy went to the worker that rendered it"
            );
            farm.send(a, &next, honest(farm.job(), next.unit));
        }
    }
    let b = farm.worker("b");
    let copy = farm.lease(b).expect("the copy");
    assert_eq!(copy.unit, g.unit);
    assert!(matches!(
        farm.send(b, &copy, honest(farm.job(), g.unit)),
        Merged::New { .. }
    ));
    assert_eq!(farm.core.worker(a).expect("worker").audits_passed, 1);
    assert_eq!(farm.core.worker(b).expect("worker").audits_passed, 1);
}

/// A dispute in a job that ends (cancelled here) before the referee settles it clears the
/// workers of it, and the referee's late result is discarded.
#[test]
fn a_dispute_in_a_job_that_ends_is_dropped() {
    let mut farm = Farm::new(true);
    let (a, liar) = (farm.worker("a"), farm.worker("liar"));
    farm.core.policy_mut().audit = 1.0;
    let g = farm.lease(liar).expect("a unit");
    farm.send(liar, &g, forged(farm.job(), g.unit));
    let copy = farm.lease(a).expect("the copy");
    assert_eq!(copy.unit, g.unit);
    farm.send(a, &copy, honest(farm.job(), g.unit));
    assert!(!farm.core.worker(a).expect("worker").disputes.is_empty());
    farm.core.end_job(
        JOB,
        tessera_coordinator::store::JobPhase::Cancelled,
        String::new(),
        0,
    );
    assert!(farm.core.worker(a).expect("worker").disputes.is_empty());
    assert!(farm.core.worker(liar).expect("worker").disputes.is_empty());
    assert!(matches!(farm.referee()[..], [Merged::Discarded]));
    assert!(farm.core.worker(liar).expect("worker").convicted.is_none());
}

/// #55 D1: two workers, one of them a liar, on two hosts. Before, a mismatch made both
/// suspects with no work until a third copy settled it, which nobody could give: the farm
/// stalled for ever. Now the referee decides, and the job ends with the honest bits.
#[test]
fn two_workers_and_one_liar_still_finish_with_the_honest_bits() {
    let mut farm = Farm::new(true);
    let (honest_w, liar) = (farm.worker("honest"), farm.worker("liar"));
    farm.core.policy_mut().audit = 1.0;
    for _ in 0..1000 {
        if farm.job().units_done == farm.job().units_total() {
            break;
        }
        let mut worked = false;
        for w in [honest_w, liar] {
            let Some(g) = farm.lease(w) else { continue };
            worked = true;
            let r = if w == liar {
                forged(farm.job(), g.unit)
            } else {
                honest(farm.job(), g.unit)
            };
            farm.send(w, &g, r);
        }
        farm.referee();
        if !worked {
            farm.now += farm.core.policy().lease_time;
            farm.core.expire(farm.now);
        }
    }
    assert_eq!(farm.job().units_done, farm.job().units_total(), "stalled");
    assert!(farm.core.worker(liar).expect("worker").convicted.is_some());
    assert!(farm
        .core
        .worker(honest_w)
        .expect("worker")
        .convicted
        .is_none());
    assert!(same_frame(
        &farm.job().frame_tiles(),
        &honest_frame(farm.job())
    ));
}

/// #55 D2: one token holder registers two workers on one host that lie alike. Before, they
/// were the "two other workers" whose copies matched, the honest worker was convicted and its
/// units rendered again by the liars. Now copies from one host are one vote: the second liar
/// never gets its partner's audit copy, the honest worker's copy differs, and the referee
/// convicts the liar.
#[test]
fn registrations_of_one_host_cannot_outvote_another_host() {
    let mut farm = Farm::new(true);
    let l1 = farm.worker_on("l1", "10.0.0.66");
    let l2 = farm.worker_on("l2", "10.0.0.66");
    let honest_w = farm.worker_on("honest", "10.0.0.7");
    farm.core.policy_mut().audit = 1.0;
    let g = farm.lease(l1).expect("a unit");
    let caught = g.unit;
    assert!(matches!(
        farm.send(l1, &g, forged(farm.job(), caught)),
        Merged::Held
    ));
    // The copy is at the front of the queue, but not for the same host.
    let g2 = farm.lease(l2).expect("other work");
    assert_ne!(
        g2.unit, caught,
        "the audit copy went to the liar's own host"
    );
    let copy = farm.lease(honest_w).expect("the copy");
    assert_eq!(copy.unit, caught);
    farm.send(honest_w, &copy, honest(farm.job(), caught));
    // l2's forged result for another unit cannot settle anything either.
    farm.send(l2, &g2, forged(farm.job(), g2.unit));
    farm.referee();
    assert!(farm.core.worker(l1).expect("worker").convicted.is_some());
    assert!(farm
        .core
        .worker(honest_w)
        .expect("worker")
        .convicted
        .is_none());
    farm.finish(&[honest_w]);
    assert!(
        farm.core.worker(l2).expect("worker").convicted.is_some(),
        "l2's lie is caught"
    );
    assert!(farm
        .core
        .worker(honest_w)
        .expect("worker")
        .convicted
        .is_none());
    assert!(same_frame(
        &farm.job().frame_tiles(),
        &honest_frame(farm.job())
    ));
}

/// A farm of one host (every worker behind one address) still finishes an audited job: a held
/// unit no other host takes within a lease time goes to the referee.
#[test]
fn on_one_host_held_units_go_to_the_referee_after_a_lease_time() {
    let mut farm = Farm::new(true);
    let a = farm.worker_on("a", "10.0.0.1");
    let b = farm.worker_on("b", "10.0.0.1");
    farm.core.policy_mut().audit = 1.0;
    let g = farm.lease(a).expect("a unit");
    farm.send(a, &g, honest(farm.job(), g.unit));
    assert!(farm.referee().is_empty());
    farm.now += farm.core.policy().lease_time;
    farm.core.expire(farm.now);
    assert!(matches!(farm.referee()[..], [Merged::New { .. }]));
    assert!(farm.job().is_done(g.unit));
    farm.finish(&[a, b]);
    assert!(same_frame(
        &farm.job().frame_tiles(),
        &honest_frame(farm.job())
    ));
    assert!(farm.core.worker(a).expect("worker").audits_passed > 0);
}

/// Registrations per host are bounded; another host, and one that is gone, do not count.
#[test]
fn registrations_per_host_are_bounded() {
    let mut farm = Farm::new(true);
    farm.core.policy_mut().max_workers_per_host = 2;
    farm.worker_on("a", "10.0.0.1");
    farm.worker_on("b", "10.0.0.1");
    let e = farm
        .core
        .host_may_register("10.0.0.1", farm.now)
        .expect_err("full");
    assert!(
        matches!(&e, Refusal::Exhausted(m) if m.contains("--max-workers-per-host")),
        "{e:?}"
    );
    farm.core
        .host_may_register("10.0.0.2", farm.now)
        .expect("another host");
    farm.core
        .host_may_register("", farm.now)
        .expect("an unknown host");
    farm.now += farm.core.policy().lease_time * 2;
    farm.core
        .host_may_register("10.0.0.1", farm.now)
        .expect("both have gone quiet");
}

/// A convicted worker's late result, under a lease it got before it was caught, is refused:
/// a lease taken back is otherwise still honoured once, which would let the liar's result in
/// after its others were taken out (found by the `rpc_sequence` fuzz target with audits).
#[test]
fn a_convicted_workers_late_result_is_refused() {
    let mut farm = Farm::new(true);
    let (a, b, liar) = (farm.worker("a"), farm.worker("b"), farm.worker("liar"));
    farm.core.policy_mut().audit = 1.0;
    let first = farm.lease(liar).expect("a unit");
    let late = farm.lease(liar).expect("another unit");
    farm.send(liar, &first, forged(farm.job(), first.unit));
    let copy = farm.lease(a).expect("the copy");
    assert_eq!(copy.unit, first.unit);
    farm.send(a, &copy, honest(farm.job(), first.unit));
    farm.referee();
    assert!(farm.core.worker(liar).expect("worker").convicted.is_some());
    let _ = b;
    let done = farm.job().units_done;
    let r = farm.core.submit(
        liar,
        late.lease,
        late.job,
        late.unit,
        forged(farm.job(), late.unit),
        farm.now,
    );
    assert!(matches!(r, Err(Refusal::Denied(_))), "{r:?}");
    assert_eq!(farm.job().units_done, done);
}

/// A guided job: a liar whose training went into guide 0 unchecked is caught in epoch 1. Every
/// later epoch sampled a guide its training shaped, so the job rewinds to epoch 0: its tiles
/// and guides are dropped, leases past the new barrier are refused, and the honest workers'
/// render gives the honest farm's sums and guides, bit for bit.
#[test]
fn a_convicted_worker_that_trained_a_guide_rewinds_the_job_to_that_epoch() {
    let guides = |farm: &Farm| farm.job().guiding.as_ref().expect("guided").hashes();
    // The honest farm, for the guides it trains.
    let mut clean = Farm::with(guided_record());
    let (a, b) = (clean.worker("a"), clean.worker("b"));
    clean.core.policy_mut().audit = 0.0;
    clean.finish(&[a, b]);
    let honest_guides = guides(&clean);
    assert_eq!(honest_guides.len(), 2, "epochs 0 and 1 train");

    let mut farm = Farm::with(guided_record());
    let (a, b, liar) = (farm.worker("a"), farm.worker("b"), farm.worker("liar"));
    farm.core.policy_mut().audit = 0.0;
    // Epoch 0 (batch 0 of the 4 tiles): the liar's unit, sums and training, merged unchecked.
    for w in [liar, a, b, a] {
        let g = farm.lease(w).expect("a unit of epoch 0");
        assert_eq!(g.unit.batch, 0);
        let r = result(farm.job(), g.unit, w == liar);
        assert!(matches!(farm.send(w, &g, r), Merged::New { .. }));
    }
    assert_eq!(guides(&farm).len(), 1);
    assert_ne!(guides(&farm)[0], honest_guides[0], "the lie is in guide 0");
    // Epoch 1: b holds a lease; every unit is checked from now, and the liar's next is caught.
    let stale = farm.lease(b).expect("a unit of epoch 1");
    let stale_result = result(farm.job(), stale.unit, false);
    farm.core.policy_mut().audit = 1.0;
    let g = farm.lease(liar).expect("a unit of epoch 1");
    let caught = g.unit;
    assert!(matches!(
        farm.send(liar, &g, result(farm.job(), caught, true)),
        Merged::Held
    ));
    let ga = farm.lease(a).expect("the copy");
    assert_eq!(ga.unit, caught);
    assert!(matches!(
        farm.send(a, &ga, result(farm.job(), caught, false)),
        Merged::Held
    ));
    let wanted = farm.core.take_referee_work();
    assert_eq!(wanted, vec![(JOB, caught)]);
    // The referee's render convicts the liar; the rewind leaves its render of epoch 1 with
    // no guide to have sampled, so it is not merged either.
    let outcome = farm
        .core
        .referee(
            JOB,
            caught,
            result(farm.job(), caught, false),
            farm.now,
            &farm.store,
            0,
        )
        .expect("refereed");
    assert!(matches!(outcome, Merged::Discarded), "{outcome:?}");
    assert!(farm.core.worker(liar).expect("worker").convicted.is_some());
    assert!(
        guides(&farm).is_empty(),
        "guides from epoch 0 on are dropped"
    );
    assert_eq!(farm.job().units_done, 0, "every tile rewound to batch 0");
    let audits = farm.store.audits().expect("audits");
    assert!(
        audits.is_empty(),
        "the referee's ops were not committed here"
    );
    // b's lease of epoch 1 sampled the dropped guide: refused, not counted against it.
    let late = farm.core.submit(
        b,
        stale.lease,
        stale.job,
        stale.unit,
        stale_result,
        farm.now,
    );
    assert!(matches!(late, Err(Refusal::Precondition(_))), "{late:?}");
    assert_eq!(farm.core.worker(b).expect("worker").bad_results, 0);

    farm.core.policy_mut().audit = 0.0;
    farm.finish(&[a, b]);
    assert!(
        same_frame(&farm.job().frame_tiles(), &honest_frame(farm.job())),
        "the finished sums are the honest bits"
    );
    assert_eq!(
        guides(&farm),
        honest_guides,
        "and the guides the honest farm's"
    );
}
