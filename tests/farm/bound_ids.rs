//! Leases and ids are bound to the worker that got them. (How many a worker holds is the
//! worker crate's test: `crates/worker/tests/pipeline.rs`.)

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn ids_and_leases_are_bound_to_the_worker_that_got_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let url = coord.url();
    let text = scene_text(16);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 4, 2, 0).await;
    let mut workers = workers_client(&url);
    let honest = register_as(&mut workers, "honest", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let thief = register_as(&mut workers, "thief", "0", IMAGE_REVISION)
        .await
        .expect("register");
    // What anyone can see of the honest worker: its public id, without the secret.
    let listed = list_workers(&mut client).await;
    let public = listed
        .iter()
        .find(|w| w.name == "honest")
        .expect("listed")
        .worker_id
        .clone();
    assert!(honest.starts_with(&format!("{public}.")) && honest.len() > public.len() + 16);
    assert!(
        listed.iter().all(|w| !w.worker_id.contains('.')),
        "secrets listed"
    );
    let unit = lease_now(&mut workers, &honest, 1)
        .await
        .expect("lease")
        .remove(0);
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let result = honest_result(&scene, &job_settings(4, 2), &unit);
    let send = |who: &str, r: pb::TileResult| pb::SubmitResultRequest {
        worker_id: who.into(),
        lease_id: unit.lease_id.clone(),
        job_id: unit.job_id.clone(),
        tile_index: unit.tile_index,
        batch_index: unit.batch_index,
        result: Some(r),
    };
    // The thief quotes the honest worker's lease under its own id: refused.
    let e = workers
        .submit_result(send(&thief, result.clone()))
        .await
        .expect_err("another worker's lease");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    // The thief quotes the honest worker's public id (with or without a made-up secret):
    // unknown. Five empty results that way would once have quarantined the honest worker.
    for forged in [
        public.clone(),
        format!("{public}.00000000000000000000000000000000"),
    ] {
        for _ in 0..5 {
            let e = workers
                .submit_result(send(&forged, pb::TileResult::default()))
                .await
                .expect_err("forged id");
            assert_eq!(e.code(), tonic::Code::NotFound, "{e:?}");
        }
        let e = workers
            .heartbeat(pb::HeartbeatRequest {
                worker_id: forged.clone(),
                lease_ids: vec![unit.lease_id.clone()],
            })
            .await
            .expect_err("forged id");
        assert_eq!(e.code(), tonic::Code::NotFound);
    }
    let listed = list_workers(&mut client).await;
    let h = listed.iter().find(|w| w.name == "honest").expect("listed");
    assert_eq!((h.bad_results, h.quarantined), (0, false));
    // The honest worker's result still merges.
    let outcome = workers
        .submit_result(send(&honest, result))
        .await
        .expect("merged")
        .into_inner()
        .outcome;
    assert_eq!(outcome, pb::ResultOutcome::Merged as i32);
    assert_eq!(job_status(&mut client, &job).await.units_done, 1);
    coord.stop().await;
}
