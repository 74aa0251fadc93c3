//! Which sums stay in memory: a tile leaves it only once it is closed and a checkpoint wrote
//! it, and the frame is written from both kinds of tile.

use std::time::{Duration, Instant};

use tessera_coordinator::error::Refusal;
use tessera_coordinator::job::{FrameTile, Job, Unit};
use tessera_coordinator::scheduler::{Merged, Policy, Scheduler};
use tessera_coordinator::store::{decode_sums, encode_sums, JobRecord, Op};
use tessera_proto::ids::JobId;
use tessera_render::TileSums;

/// A 16×16 job in 4-pixel tiles (16 tiles), 4 spp in batches of 2.
fn record(audited: bool) -> JobRecord {
    JobRecord {
        id: 1,
        width: 16,
        height: 16,
        spp: 4,
        batch: 2,
        tile_size: 4,
        output_name: "o.exr".into(),
        audited,
        ..JobRecord::default()
    }
}

fn result(job: &Job, u: Unit) -> TileSums {
    let rect = job.tiles.get(u.tile).expect("tile");
    let mut t = TileSums::empty(rect, 0);
    t.samples = job.batch_range(u.batch);
    t.count.fill(t.samples.len() as u32);
    for (i, s) in t.sum.iter_mut().enumerate() {
        *s = [i as f64, 1.0, 2.0];
    }
    t
}

/// Tiles whose sums are in memory.
fn resident(core: &Scheduler) -> Vec<u32> {
    let job = core.job(JobId(1)).expect("job");
    job.acc
        .iter()
        .filter(|(_, a)| a.sums.is_some())
        .map(|(t, _)| *t)
        .collect()
}

/// A checkpoint as the writer makes one: the changes, then (as if committed) the eviction of
/// the tiles it wrote.
fn checkpoint(core: &mut Scheduler) -> u64 {
    let written: Vec<(u64, u32)> = core
        .checkpoint()
        .ops()
        .iter()
        .filter_map(Op::written_tile)
        .collect();
    core.evict(&written)
}

#[test]
fn only_closed_and_stored_tiles_leave_memory() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.insert_job(Job::new(record(false)));
    core.policy_mut().max_leases_per_worker = usize::MAX;
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let granted = core.lease(w, usize::MAX, now);
    assert_eq!(granted.len(), 32);
    let submit = |core: &mut Scheduler, i: usize| {
        let g = &granted[i];
        let r = result(core.job(JobId(1)).expect("job"), g.unit);
        let merged = core
            .submit(w, g.lease, JobId(1), g.unit, r, now)
            .expect("ok");
        assert!(matches!(merged, Merged::New { .. }));
    };
    // Batch-major: the first 16 leases are every tile's batch 0. Open tiles stay.
    for i in 0..16 {
        submit(&mut core, i);
    }
    // A snapshot keeps the moment's sums: a merge into its tile after it copies the tile.
    let before = encode_sums(
        core.job(JobId(1)).expect("job").acc[&0]
            .sums
            .as_deref()
            .expect("sums"),
    );
    let snapshot = core.checkpoint();
    submit(&mut core, 16);
    let ops = snapshot.ops();
    let tile0 = ops
        .iter()
        .find_map(|op| match op {
            Op::PutTile(1, 0, bytes) => Some(bytes.clone()),
            _ => None,
        })
        .expect("tile 0 was dirty");
    assert_eq!(tile0, before, "the snapshot changed after it was taken");
    assert_eq!(ops.len(), 16);
    assert_eq!(
        checkpoint(&mut core),
        16 * 52,
        "tile 0, closed since, leaves"
    );
    assert_eq!(resident(&core).len(), 15);
    // Seven more tiles close; a checkpoint writes them and they leave, keeping preview means.
    for i in 17..24 {
        submit(&mut core, i);
    }
    assert_eq!(checkpoint(&mut core), 7 * 16 * 52);
    assert_eq!(resident(&core), (8..16).collect::<Vec<_>>());
    let job = core.job(JobId(1)).expect("job");
    assert!(job.acc[&0].thumb.is_some() && job.acc[&8].thumb.is_none());
    // A tile merged after the checkpoint's snapshot is not evicted by it.
    let written: Vec<(u64, u32)> = core
        .checkpoint()
        .ops()
        .iter()
        .filter_map(Op::written_tile)
        .collect();
    assert!(written.is_empty(), "nothing merged since: nothing to write");
    submit(&mut core, 24);
    assert_eq!(core.evict(&[(1, 8)]), 0, "dirty since the snapshot");
    assert_eq!(checkpoint(&mut core), 16 * 52);
    // The rest; the frame takes the stored tiles from the store, the others from memory.
    for i in 25..32 {
        submit(&mut core, i);
    }
    let (frame, ops) = core.take_frame(JobId(1)).expect("finishing");
    assert_eq!(
        ops.len(),
        7,
        "the tiles merged since the last checkpoint are checkpointed"
    );
    let (_, _, tiles) = frame;
    let stored = tiles
        .iter()
        .filter(|t| matches!(t, FrameTile::Stored(..)))
        .count();
    assert_eq!(stored, 9);
    assert_eq!(tiles.len(), 16);
}

#[test]
fn an_audited_job_keeps_its_sums() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.insert_job(Job::new(record(true)));
    core.policy_mut().max_leases_per_worker = usize::MAX;
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    for g in core.lease(w, usize::MAX, now) {
        let r = result(core.job(JobId(1)).expect("job"), g.unit);
        let _ = core.submit(w, g.lease, JobId(1), g.unit, r, now);
    }
    assert_eq!(resident(&core).len(), 16, "every tile merged and closed");
    assert_eq!(checkpoint(&mut core), 0);
    assert_eq!(resident(&core).len(), 16);
}

/// The sums a checkpoint's changes hold for `tile` of job 1, decoded as the store would give
/// them back.
fn stored(ops: &[Op], core: &Scheduler, tile: u32) -> TileSums {
    let rect = core
        .job(JobId(1))
        .expect("job")
        .tiles
        .get(tile)
        .expect("tile");
    ops.iter()
        .find_map(|op| match op {
            Op::PutTile(1, t, bytes) if *t == tile => {
                Some(decode_sums(bytes, rect).expect("decodes"))
            }
            _ => None,
        })
        .expect("the tile was written")
}

#[test]
fn open_tiles_of_a_large_job_leave_memory_and_are_read_back_before_they_merge() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.policy_mut().max_leases_per_worker = usize::MAX;
    core.policy_mut().evict_open_over = 0;
    core.insert_job(Job::new(record(false)));
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let granted = core.lease(w, usize::MAX, now);
    // Every tile's batch 0; then a checkpoint, which stores them, and all 16 open tiles leave.
    for g in &granted[..16] {
        let r = result(core.job(JobId(1)).expect("job"), g.unit);
        core.submit(w, g.lease, JobId(1), g.unit, r, now)
            .expect("merged");
    }
    let ops = core.checkpoint().ops();
    let written: Vec<(u64, u32)> = ops.iter().filter_map(Op::written_tile).collect();
    assert_eq!(core.evict(&written), 16 * 16 * 52);
    assert!(resident(&core).is_empty());
    // Tile 3's batch 1 cannot merge into nothing: it is refused for a retry, and the lease
    // stays. Only the lease's holder makes the coordinator read the tile.
    let g = &granted[16 + 3];
    assert_eq!(g.unit, Unit { tile: 3, batch: 1 });
    let rect = core
        .needs_reload(w, g.lease, JobId(1), g.unit)
        .expect("read back first");
    assert_eq!(
        core.needs_reload(w, granted[3].lease, JobId(1), g.unit),
        None,
        "another lease"
    );
    let stranger = core.register("x".into(), 1, "v".into(), "s".into(), now);
    assert_eq!(core.needs_reload(stranger, g.lease, JobId(1), g.unit), None);
    let r = result(core.job(JobId(1)).expect("job"), g.unit);
    assert!(matches!(
        core.submit(w, g.lease, JobId(1), g.unit, r, now),
        Err(Refusal::Unavailable(_))
    ));
    // A read that does not cover the merged batches (a stale or foreign copy) is not put back.
    let mut wrong = stored(&ops, &core, 3);
    wrong.samples = 0..4;
    assert!(!core.reload(JobId(1), 3, wrong));
    assert!(
        !core.reload(JobId(1), 3, stored(&ops, &core, 2)),
        "tile 2's sums"
    );
    // The store's copy goes back, and the merge then gives what never leaving memory gives.
    assert_eq!(stored(&ops, &core, 3).rect, rect);
    assert!(core.reload(JobId(1), 3, stored(&ops, &core, 3)));
    assert!(
        !core.reload(JobId(1), 3, stored(&ops, &core, 3)),
        "already back"
    );
    let r = result(core.job(JobId(1)).expect("job"), g.unit);
    core.submit(w, g.lease, JobId(1), g.unit, r, now)
        .expect("merged");
    let mut kept = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    kept.policy_mut().max_leases_per_worker = usize::MAX;
    kept.insert_job(Job::new(record(false)));
    let kw = kept.register("w".into(), 1, "v".into(), "s".into(), now);
    let kg = kept.lease(kw, usize::MAX, now);
    for i in [3, 16 + 3] {
        let r = result(kept.job(JobId(1)).expect("job"), kg[i].unit);
        kept.submit(kw, kg[i].lease, JobId(1), kg[i].unit, r, now)
            .expect("merged");
    }
    let sums = |c: &Scheduler| {
        encode_sums(
            c.job(JobId(1)).expect("job").acc[&3]
                .sums
                .as_deref()
                .expect("in memory"),
        )
    };
    assert_eq!(sums(&core), sums(&kept));
    // A job under the bound keeps its open tiles, as before.
    let mut small = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    small.policy_mut().max_leases_per_worker = usize::MAX;
    small.policy_mut().evict_open_over = 16 * 16 * 52;
    small.insert_job(Job::new(record(false)));
    let sw = small.register("w".into(), 1, "v".into(), "s".into(), now);
    for g in small.lease(sw, 16, now) {
        let r = result(small.job(JobId(1)).expect("job"), g.unit);
        small
            .submit(sw, g.lease, JobId(1), g.unit, r, now)
            .expect("merged");
    }
    assert_eq!(checkpoint(&mut small), 0);
}

#[test]
fn merged_sums_count_as_unstored_until_a_commit_and_results_wait_past_the_bound() {
    let mut core = Scheduler::new(1, Policy::new(Duration::from_secs(60)));
    core.policy_mut().max_leases_per_worker = usize::MAX;
    core.policy_mut().max_unstored_bytes = 3 * 16 * 52;
    core.insert_job(Job::new(record(false)));
    let now = Instant::now();
    let w = core.register("w".into(), 1, "v".into(), "s".into(), now);
    let granted = core.lease(w, usize::MAX, now);
    let merge = |core: &mut Scheduler, i: usize| {
        let r = result(core.job(JobId(1)).expect("job"), granted[i].unit);
        core.submit(w, granted[i].lease, JobId(1), granted[i].unit, r, now)
            .expect("merged");
    };
    for i in 0..2 {
        merge(&mut core, i);
    }
    assert_eq!(core.unstored_bytes(), 2 * 16 * 52);
    assert!(!core.defer_result());
    // A checkpoint's snapshot still counts until the commit; the tiles merged meanwhile too.
    let ops = core.checkpoint().ops();
    merge(&mut core, 2);
    assert_eq!(core.unstored_bytes(), 3 * 16 * 52);
    assert!(core.defer_result(), "at the bound");
    assert_eq!(core.counters().results_deferred, 1);
    let written: Vec<(u64, u32)> = ops.iter().filter_map(Op::written_tile).collect();
    core.evict(&written);
    assert_eq!(
        core.unstored_bytes(),
        16 * 52,
        "the commit let the snapshot go"
    );
    assert!(!core.defer_result());
}

/// A job that asks for AOVs keeps 64 more bytes a pixel (what the store writes for them), and
/// its memory is counted at that size: the frame against `--evict-open-over`.
#[test]
fn a_job_with_aovs_counts_their_bytes() {
    let plain = Job::new(record(false));
    let with = Job::new(JobRecord {
        aovs: "albedo,normal".into(),
        ..record(false)
    });
    assert_eq!(plain.frame_bytes(), 16 * 16 * 52);
    assert_eq!(with.frame_bytes(), 16 * 16 * (52 + 64));
    let rect = with.tiles.get(0).expect("tile");
    let mut sums = TileSums::empty(rect, 0);
    sums.aov = Some(Box::new(tessera_render::film::AovSums::zeros(rect.area())));
    assert_eq!(
        encode_sums(&sums).len() as u64 - 20,
        rect.area() as u64 * with.pixel_bytes(),
        "the count is what the store writes"
    );
}
