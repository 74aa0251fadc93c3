//! Results of two renderer revisions never meet in one job.

use crate::common::*;

/// Results of two renderer revisions never meet in one job: a worker of another image revision
/// is refused at registration (and stops, since retrying cannot help), and a job that a
/// coordinator of another revision had started is failed with the reason after an upgrade,
/// while one it had not started is simply rendered by the new revision.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn renderer_revisions_are_never_mixed() {
    let data = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(data.path(), Duration::from_secs(30)).await;
    let url = coord.url();
    let mut workers = workers_client(&url);
    let e = register_as(&mut workers, "old-build", "0.0.9", IMAGE_REVISION + 1)
        .await
        .expect_err("another revision");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    let why = e.message();
    assert!(
        why.contains("old-build")
            && why.contains(&format!("image revision {}", IMAGE_REVISION + 1))
            && why.contains(&format!("revision {IMAGE_REVISION}")),
        "{why}"
    );

    // One job gets a merged unit, the other none; then the store is made to say that another
    // revision accepted both, as after an upgrade.
    let text = scene_text(16);
    let mut client = coord.client().await;
    let started = submit(&mut client, &text, 8, 4, 1).await;
    let untouched = submit(&mut client, &text, 8, 4, 0).await;
    let id = register_as(&mut workers, "one-unit", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let unit = lease_now(&mut workers, &id, 1)
        .await
        .expect("lease")
        .remove(0);
    assert_eq!(unit.job_id, started, "the higher priority first");
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let settings = job_settings(8, 4);
    let outcome = workers
        .submit_result(pb::SubmitResultRequest {
            worker_id: id,
            lease_id: unit.lease_id.clone(),
            job_id: unit.job_id.clone(),
            tile_index: unit.tile_index,
            batch_index: unit.batch_index,
            result: Some(honest_result(&scene, &settings, &unit)),
        })
        .await
        .expect("submit")
        .into_inner()
        .outcome;
    assert_eq!(outcome, pb::ResultOutcome::Merged as i32);
    coord.stop().await;
    {
        let store = Store::open(data.path()).expect("store");
        let ops: Vec<Op> = store
            .load()
            .expect("load")
            .into_iter()
            .map(|j| {
                assert_eq!(j.record.image_revision, IMAGE_REVISION);
                Op::PutJob(JobRecord {
                    image_revision: IMAGE_REVISION + 1,
                    ..j.record
                })
            })
            .collect();
        assert_eq!(ops.len(), 2);
        store.apply(&ops).expect("rewrite");
    }

    let coord = Coordinator::start(data.path(), Duration::from_secs(30)).await;
    let url = coord.url();
    let mut client = coord.client().await;
    let s = job_status(&mut client, &started).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(
        s.error
            .contains(&format!("image revision {}", IMAGE_REVISION + 1))
            && s.error.contains("resubmit"),
        "{}",
        s.error
    );
    let w = worker(&url, "new-build");
    let s = wait(&mut client, &untouched).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    let dir = tempfile::tempdir().expect("tempdir");
    assert_eq!(
        fetch(&mut client, &untouched).await,
        local_exr(&text, 8, 4, dir.path()),
        "the job the old revision never touched renders as a fresh one"
    );
    w.abort();
    coord.stop().await;
}
