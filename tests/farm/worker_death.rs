//! A worker killed mid-job costs only its leased units.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_killed_mid_job_does_not_break_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_millis(800)).await;
    let text = scene_text(48);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 64, 4, 0).await;
    let doomed = worker(&coord.url(), "doomed");
    // Let it merge some units and hold some leases, then kill it without a goodbye.
    let s = wait_for("10 units merged", async || {
        Some(job_status(&mut client, &job).await).filter(|s| s.units_done >= 10)
    })
    .await;
    assert!(
        s.units_done < s.units_total,
        "the job finished too fast to test"
    );
    doomed.abort();
    let _ = doomed.await;
    let held = job_status(&mut client, &job).await;
    let survivor = worker(&coord.url(), "survivor");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert!(
        held.units_leased > 0,
        "the killed worker held no lease, so nothing was tested"
    );
    let farm = fetch(&mut client, &job).await;
    assert!(farm == local_exr(&text, 64, 4, dir.path()));
    survivor.abort();
    coord.stop().await;
}
