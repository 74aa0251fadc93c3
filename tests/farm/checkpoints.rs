//! Checkpoints: a closed tile's sums leave memory once the store holds them, are read back for
//! the frame, and change no bit, across a restart too.

use crate::common::*;

/// A counter from the coordinator's `/metrics`.
async fn metric(coord: &Coordinator, name: &str) -> f64 {
    let reply = get(coord.http.expect("dashboard"), "/metrics").await;
    let prefix = format!("{name} ");
    reply
        .text()
        .lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("{name} is exported"))
}

/// `tessera_sums_evicted_bytes_total`.
async fn evicted_bytes(coord: &Coordinator) -> f64 {
    metric(coord, "tessera_sums_evicted_bytes_total").await
}

/// Waits (up to a minute: checkpoints run on the coordinator's timer) until at least
/// `bytes` of sums have left memory, and returns how many have.
async fn wait_evicted(coord: &Coordinator, bytes: f64) -> f64 {
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    let mut evicted = evicted_bytes(coord).await;
    while evicted < bytes && std::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
        evicted = evicted_bytes(coord).await;
    }
    evicted
}

/// Merges `n` units of the coordinator's 16-spp job rendered by hand, as a worker `by-hand`.
async fn merge_by_hand(coord: &Coordinator, scene: &Scene, n: usize) {
    merge_by_hand_in(coord, scene, n, 16).await
}

/// [`merge_by_hand`] for a job of 16 spp in batches of `batch`.
async fn merge_by_hand_in(coord: &Coordinator, scene: &Scene, n: usize, batch: u32) {
    let mut workers = workers_client(&coord.url());
    let id = register_as(
        &mut workers,
        "by-hand",
        env!("CARGO_PKG_VERSION"),
        IMAGE_REVISION,
    )
    .await
    .expect("register");
    // In rounds of at most 8, the leases one worker may hold.
    let mut left = n;
    while left > 0 {
        let units = lease_now(&mut workers, &id, left.min(8) as u32)
            .await
            .expect("lease");
        assert_eq!(units.len(), left.min(8));
        left -= units.len();
        for u in units {
            let result = honest_result(scene, &job_settings(16, batch), &u);
            workers
                .submit_result(result_for(&id, &u, result))
                .await
                .expect("merged");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn closed_tiles_leave_memory_once_stored_and_the_frame_keeps_its_bits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.checkpoint_interval = Duration::from_millis(20)
        })
        .await;
    // 16 tiles of 16², one batch each: every tile closes at its first merge.
    let text = scene_text(64);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 16, 16, 0).await;
    // Half the tiles merged by hand while the job is still open; the next checkpoints must
    // take them out of memory. Waited for, since when a checkpoint runs is the coordinator's
    // timer's business: with a worker racing through the job, a job that ended before any
    // checkpoint left nothing to evict, and the test failed on a loaded machine.
    let scene = Scene::text(&text, Format::Toml, "cornell", &Limits::default())
        .load()
        .expect("scene");
    merge_by_hand(&coord, &scene, 8).await;
    let evicted = wait_evicted(&coord, 52.0 * 16.0 * 16.0).await;
    assert!(
        evicted >= 52.0 * 16.0 * 16.0,
        "no tile left memory: {evicted} bytes"
    );
    let w = worker(&coord.url(), "w0");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    let farm = fetch(&mut client, &job).await;
    assert!(
        farm == local_exr(&text, 16, 16, dir.path()),
        "the frame written from stored tiles differs from the local render"
    );
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_restart_reads_stored_tiles_back_for_the_frame() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let checkpoints = |c: &mut Config| c.checkpoint_interval = Duration::from_millis(20);
    let coord = Coordinator::start_with(&data, Duration::from_secs(30), checkpoints).await;
    let text = scene_text(64);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 16, 16, 0).await;
    // Half the tiles rendered by hand, then a clean stop: they are stored, and after the
    // restart they are closed tiles that leave memory at once.
    let scene = Scene::text(&text, Format::Toml, "cornell", &Limits::default())
        .load()
        .expect("scene");
    merge_by_hand(&coord, &scene, 8).await;
    let addr = coord.addr;
    coord.stop().await;
    let coord = Coordinator::restart_at(addr, &data, Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    assert_eq!(job_status(&mut client, &job).await.units_done, 8);
    let w = worker(&coord.url(), "w0");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert!(
        fetch(&mut client, &job).await == local_exr(&text, 16, 16, dir.path()),
        "the frame after the restart differs from the local render"
    );
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn open_tiles_of_a_large_job_leave_memory_between_batches_and_are_read_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Every job counts as large here; at the default only frames of over 64 MiB of sums do.
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.checkpoint_interval = Duration::from_millis(20);
            c.evict_open_over = 0;
        })
        .await;
    // 16 tiles of 16², 16 spp in batches of 2: every tile is open until its eighth batch.
    let text = scene_text(64);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 16, 2, 0).await;
    // Batch-major: the first 16 units are every tile's batch 0. Once stored, all 16 open
    // tiles leave memory, and each tile's batch 1 must read it back before it merges.
    let scene = Scene::text(&text, Format::Toml, "cornell", &Limits::default())
        .load()
        .expect("scene");
    merge_by_hand_in(&coord, &scene, 16, 2).await;
    let evicted = wait_evicted(&coord, 16.0 * 52.0 * 16.0 * 16.0).await;
    assert!(
        evicted >= 16.0 * 52.0 * 16.0 * 16.0,
        "the open tiles stayed in memory: {evicted} bytes left"
    );
    let w = worker(&coord.url(), "w0");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    let reloaded = metric(&coord, "tessera_tiles_reloaded_total").await;
    assert!(reloaded >= 16.0, "only {reloaded} tiles were read back");
    assert!(
        fetch(&mut client, &job).await == local_exr(&text, 16, 2, dir.path()),
        "the frame whose open tiles went through the store differs from the local render"
    );
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn results_wait_while_merged_sums_wait_for_the_store_and_the_frame_keeps_its_bits() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Any merged tile not yet stored holds the next result back until a checkpoint commits:
    // every result but the first after each checkpoint is deferred, and the worker retries.
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.checkpoint_interval = Duration::from_millis(50);
            c.max_unstored_bytes = 1;
        })
        .await;
    let text = scene_text(64);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 16, 4, 0).await;
    let w = worker(&coord.url(), "w0");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    let deferred = metric(&coord, "tessera_results_deferred_total").await;
    assert!(deferred >= 1.0, "no result was deferred");
    assert_eq!(
        metric(&coord, "tessera_results_refused_total").await,
        0.0,
        "a deferral is not a refusal"
    );
    assert!(
        fetch(&mut client, &job).await == local_exr(&text, 16, 4, dir.path()),
        "the frame whose results were deferred differs from the local render"
    );
    w.abort();
    coord.stop().await;
}
