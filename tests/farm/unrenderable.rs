//! A unit the only worker cannot render: it fails there three times (the unit comes back to it,
//! as nobody else is there), the worker is blocklisted for the job, and the job fails once, with
//! the reason.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_unit_the_workers_cannot_render_fails_the_job_once_with_the_reason() {
    // The coordinator accepts wider images than the worker (its default limit is 16384).
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.limits.max_resolution = 20_000;
    })
    .await;
    let text = scene_text(16)
        .replace("width = 16", "width = 20000")
        .replace("height = 16", "height = 1");
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 1, 1, 0).await;
    let w = worker(&coord.url(), "small");
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(s.error.contains("cannot render"), "{}", s.error);
    assert!(
        s.error.contains("20000 is above the limit of 16384"),
        "{}",
        s.error
    );
    assert!(s.error.contains("small"), "{}", s.error);
    w.abort();
    coord.stop().await;
}
