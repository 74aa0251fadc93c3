//! A coordinator restart: workers register again, once.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_registers_once_after_a_coordinator_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start(&data, Duration::from_secs(30)).await;
    let addr = coord.addr;
    let text = scene_text(64);
    let mut client = coord.client().await;
    // Many tiny units, so results are in flight when the coordinator goes: the fetcher and
    // the submitter both learn at once that their worker id is unknown.
    let job = submit(&mut client, &text, 256, 1, 0).await;
    let w = worker(&coord.url(), "once");
    wait_for("20 units merged", async || {
        (job_status(&mut client, &job).await.units_done >= 20).then_some(())
    })
    .await;
    coord.stop().await;
    // The same address, as a restarted coordinator would have.
    let coord = Coordinator::restart_at(addr, &data, Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Done as i32);
    let listed = list_workers(&mut client).await;
    assert_eq!(listed.len(), 1, "ghost registrations: {listed:?}");
    w.abort();
    coord.stop().await;
}
