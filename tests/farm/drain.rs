//! Draining over the wire (`DrainWorker`): the drained worker hears it from its next heartbeat
//! and lease call, its held unit still merges, it is leased nothing new, and a worker that
//! registers again as draining after a coordinator restart is leased nothing either; tags
//! and memory reach the worker list.

use crate::common::*;

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_drained_worker_is_told_keeps_its_unit_and_stays_drained_across_a_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start(&data, lease).await;
    let text = scene_text(32);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 4, 2, 0).await;
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let settings = job_settings(4, 2);
    let mut hand = workers_client(&coord.url());
    let id = hand
        .register(pb::RegisterRequest {
            name: "render-01".into(),
            cores: 1,
            version: "0".into(),
            image_revision: IMAGE_REVISION,
            memory_bytes: 8 << 30,
            cpu_features: vec!["avx2".into()],
            tags: vec!["pool=fast".into()],
            draining: false,
            denoise_version: 0,
        })
        .await
        .expect("register")
        .into_inner()
        .worker_id;
    let listed = list_workers(&mut client).await;
    assert_eq!(listed[0].tags, ["pool=fast"]);
    assert_eq!(listed[0].memory_bytes, 8 << 30);
    assert_eq!(listed[0].cpu_features, ["avx2"]);
    let held = lease_now(&mut hand, &id, 1).await.expect("lease");
    assert_eq!(held.len(), 1);
    let drained = client
        .drain_worker(pb::DrainWorkerRequest {
            worker: "render-01".into(),
        })
        .await
        .expect("drain")
        .into_inner()
        .drained;
    assert_eq!(drained, [id.split('.').next().expect("public id")]);
    let beat = hand
        .heartbeat(pb::HeartbeatRequest {
            worker_id: id.clone(),
            lease_ids: vec![held[0].lease_id.clone()],
        })
        .await
        .expect("heartbeat")
        .into_inner();
    assert!(beat.drain && beat.revoked.is_empty(), "{beat:?}");
    // A long poll answers at once with the drain, not after its wait.
    let asked = std::time::Instant::now();
    let r = hand
        .lease(pb::LeaseRequest {
            worker_id: id.clone(),
            max_units: 4,
            wait_ms: 20_000,
        })
        .await
        .expect("lease")
        .into_inner();
    assert!(r.drain && r.units.is_empty(), "{r:?}");
    assert!(asked.elapsed() < Duration::from_secs(10));
    let merged = hand
        .submit_result(result_for(
            &id,
            &held[0],
            honest_result(&scene, &settings, &held[0]),
        ))
        .await
        .expect("the held unit merges")
        .into_inner();
    assert_eq!(merged.outcome, pb::ResultOutcome::Merged as i32);
    let workers = list_workers(&mut client).await;
    assert!(workers[0].draining, "{workers:?}");

    // After a restart the worker registers again, saying it is draining: it gets nothing.
    let coord = coord.restarted(&data, lease).await;
    let mut client = coord.client().await;
    let mut hand = workers_client(&coord.url());
    let again = hand
        .register(pb::RegisterRequest {
            name: "render-01".into(),
            cores: 1,
            version: "0".into(),
            image_revision: IMAGE_REVISION,
            draining: true,
            denoise_version: 0,
            ..Default::default()
        })
        .await
        .expect("register")
        .into_inner()
        .worker_id;
    let r = hand
        .lease(pb::LeaseRequest {
            worker_id: again,
            max_units: 4,
            wait_ms: 0,
        })
        .await
        .expect("lease")
        .into_inner();
    assert!(r.drain && r.units.is_empty(), "{r:?}");
    let other = register_as(&mut hand, "render-02", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut hand, &other, 4).await.expect("lease");
    assert!(!units.is_empty() && units.iter().all(|u| u.job_id == job));
    // A drain of nobody, or of nothing, is refused saying so.
    for (who, code) in [
        ("render-99", tonic::Code::NotFound),
        ("", tonic::Code::InvalidArgument),
    ] {
        let e = client
            .drain_worker(pb::DrainWorkerRequest { worker: who.into() })
            .await
            .expect_err("refused");
        assert_eq!(e.code(), code, "{e:?}");
    }
    // Malformed tags at registration are refused, naming the tag.
    let e = hand
        .register(pb::RegisterRequest {
            name: "bad".into(),
            image_revision: IMAGE_REVISION,
            tags: vec!["big mem".into()],
            ..Default::default()
        })
        .await
        .expect_err("refused");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(
        e.message().contains("tag 1: tag \"big mem\""),
        "{}",
        e.message()
    );
    let e = client
        .submit_job(pb::SubmitJobRequest {
            require: vec!["pool".into(); 2],
            ..submit_request(&text, 4, 2)
        })
        .await
        .expect_err("refused");
    assert!(
        e.message()
            .contains("require: requirement \"pool\" is given twice"),
        "{}",
        e.message()
    );
}
