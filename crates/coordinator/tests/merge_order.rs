//! Property: whatever order unit results arrive in, and however many copies of them, each
//! tile's merged sums are the same bits as merging every batch once, in batch order.

use std::time::{Duration, Instant};

use proptest::prelude::*;
use tessera_coordinator::job::{Job, Unit};
use tessera_coordinator::scheduler::{Merged, Policy, Scheduler};
use tessera_coordinator::store::JobRecord;
use tessera_proto::ids::JobId;
use tessera_render::TileSums;

fn record(width: u32, spp: u32, batch: u32) -> JobRecord {
    JobRecord {
        id: 1,
        width,
        spp,
        batch,
        height: 3,
        seed: 0,
        strategy: tessera_render::Strategy::Mis,
        tile_size: 2,
        output_name: "o.exr".into(),
        submitted_ms: 0,
        ..JobRecord::default()
    }
}

/// A unit's result: values of very different magnitudes, so that adding them in another
/// order would change the low bits.
fn result(job: &Job, u: Unit) -> TileSums {
    let rect = job.tiles.get(u.tile).expect("tile");
    let mut t = TileSums::empty(rect, 0);
    t.samples = job.batch_range(u.batch);
    let k = t.samples.len() as u32;
    for i in 0..rect.area() {
        let h = (u.tile as u64 * 1_000_003 + u.batch as u64 * 7919 + i as u64)
            .wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let v = (h >> 40) as f64 * 10f64.powi((h % 13) as i32 - 6);
        t.sum[i] = [v, v * 0.5, v * 0.25];
        t.sum_sq[i] = [v * v; 3];
        t.count[i] = k;
    }
    t
}

/// Leases every unit, submits them in `order` (indices into the lease order, repeats allowed),
/// and returns each tile's sums as bits.
fn merge(width: u32, spp: u32, batch: u32, order: &[usize]) -> Vec<Vec<u64>> {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.insert_job(Job::new(record(width, spp, batch)));
    let now = Instant::now();
    // One worker holds every unit here, to submit them in any order.
    core.policy_mut().max_leases_per_worker = usize::MAX;
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let granted = core.lease(w, usize::MAX, now);
    let n = granted.len();
    let mut merged = 0;
    for &i in order {
        let g = &granted[i % n];
        let r = result(core.job(JobId(1)).expect("job"), g.unit);
        match core
            .submit(w, g.lease, JobId(1), g.unit, r, now)
            .expect("accepted")
        {
            Merged::New { .. } => merged += 1,
            Merged::Duplicate => {}
            // Once every unit is in, the job stops taking results.
            Merged::Discarded => assert_eq!(merged, n, "discarded before the job finished"),
            Merged::Held => panic!("held for an audit in a job that is not audited"),
        }
    }
    assert_eq!(merged, n, "every unit merged exactly once");
    core.job(JobId(1))
        .expect("job")
        .acc
        .values()
        .map(|a| {
            let s = a.sums.as_ref().expect("merged");
            s.sum
                .iter()
                .chain(&s.sum_sq)
                .flatten()
                .map(|v| v.to_bits())
                .chain(s.count.iter().map(|&c| c as u64))
                .collect()
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn merged_bits_do_not_depend_on_arrival_order_or_duplicates(
        width in 1u32..6,
        spp in 1u32..20,
        batch in 1u32..6,
        perm_seed in any::<u64>(),
        dups in proptest::collection::vec(any::<usize>(), 0..12),
    ) {
        let tiles = width.div_ceil(2) * 2;
        let n = (tiles * spp.div_ceil(batch)) as usize;
        let in_order: Vec<usize> = (0..n).collect();
        // Fisher–Yates with splitmix64, then duplicates spliced in at random places.
        let mut order = in_order.clone();
        let mut s = perm_seed;
        let mut next = || {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        for i in (1..n).rev() {
            order.swap(i, (next() % (i as u64 + 1)) as usize);
        }
        for d in dups {
            let at = (next() % (order.len() as u64 + 1)) as usize;
            order.insert(at, d % n);
        }
        prop_assert_eq!(merge(width, spp, batch, &in_order), merge(width, spp, batch, &order));
    }
}
