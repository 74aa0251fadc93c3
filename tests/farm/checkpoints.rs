//! Checkpoints: a closed tile's sums leave memory once the store holds them, are read back for
//! the frame, and change no bit, across a restart too.

use crate::common::*;

/// `tessera_sums_evicted_bytes_total` from the coordinator's `/metrics`.
async fn evicted_bytes(coord: &Coordinator) -> f64 {
    let reply = get(coord.http.expect("dashboard"), "/metrics").await;
    reply
        .text()
        .lines()
        .find_map(|l| l.strip_prefix("tessera_sums_evicted_bytes_total "))
        .and_then(|v| v.trim().parse().ok())
        .expect("the metric is exported")
}

/// Merges `n` units of the coordinator's job rendered by hand, as a worker `by-hand`.
async fn merge_by_hand(coord: &Coordinator, scene: &Scene, n: usize) {
    let mut workers = workers_client(&coord.url());
    let id = register_as(
        &mut workers,
        "by-hand",
        env!("CARGO_PKG_VERSION"),
        IMAGE_REVISION,
    )
    .await
    .expect("register");
    let units = lease_now(&mut workers, &id, n as u32).await.expect("lease");
    assert_eq!(units.len(), n);
    for u in units {
        let result = honest_result(scene, &job_settings(16, 16), &u);
        workers
            .submit_result(result_for(&id, &u, result))
            .await
            .expect("merged");
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
    let scene = Scene::from_str(&text, Format::Toml, "cornell", &Limits::default()).expect("scene");
    merge_by_hand(&coord, &scene, 8).await;
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    let mut evicted = evicted_bytes(&coord).await;
    while evicted < 52.0 * 16.0 * 16.0 && std::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
        evicted = evicted_bytes(&coord).await;
    }
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
    let scene = Scene::from_str(&text, Format::Toml, "cornell", &Limits::default()).expect("scene");
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
