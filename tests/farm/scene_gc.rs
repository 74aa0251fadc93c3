//! An ended job's scene leaves the store.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_ended_jobs_scene_leaves_the_store() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start(&data, Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let mut workers = workers_client(&coord.url());
    let id = register_as(&mut workers, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let text = scene_text(16);
    let shared_a = submit(&mut client, &text, 4, 2, 0).await;
    let shared_b = submit(&mut client, &text, 4, 2, 0).await;
    let hash = job_status(&mut client, &shared_a).await.scene_hash;
    let scene = |hash: String| pb::GetSceneRequest {
        scene_hash: hash,
        worker_id: id.clone(),
    };
    client
        .cancel_job(pb::CancelJobRequest { job_id: shared_a })
        .await
        .expect("cancel");
    // Still needed by the other job, whose unit the worker now holds.
    let units = lease_now(&mut workers, &id, 1).await.expect("lease");
    assert_eq!(units.len(), 1);
    assert_eq!(units[0].job_id, shared_b);
    workers.get_scene(scene(hash.clone())).await.expect("kept");
    client
        .cancel_job(pb::CancelJobRequest { job_id: shared_b })
        .await
        .expect("cancel");
    // No live job reads it now: not even the worker that held a lease may read it.
    let e = workers
        .get_scene(scene(hash.clone()))
        .await
        .expect_err("gone");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    coord.stop().await;
    let store = Store::open(&data).expect("store");
    assert!(store.scene_hashes().expect("hashes").is_empty());
}
