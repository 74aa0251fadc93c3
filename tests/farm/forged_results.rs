//! Forged results are refused and never reach the image.

use crate::common::*;

/// A forged worker sends NaN sums, wrong dimensions, a lease issued for another unit, a lease
/// from before a restart, and a duplicate. Each is refused or deduplicated, the worker is
/// quarantined, and the image is still bit-identical.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn forged_results_are_refused_and_leave_the_image_unaffected() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let url = coord.url();
    let text = scene_text(32);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 8, 4, 0).await;
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let settings = job_settings(8, 4);

    let mut forger = workers_client(&url);
    let id = register_as(&mut forger, "forger", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut forger, &id, 2).await.expect("lease");
    assert_eq!(units.len(), 2);
    let honest = |u: &pb::WorkUnit| honest_result(&scene, &settings, u);
    let send = |lease: &str, u: &pb::WorkUnit, result: pb::TileResult| pb::SubmitResultRequest {
        worker_id: id.clone(),
        lease_id: lease.into(),
        job_id: u.job_id.clone(),
        tile_index: u.tile_index,
        batch_index: u.batch_index,
        result: Some(result),
    };
    let (a, b) = (&units[0], &units[1]);
    let mut nan = honest(a);
    nan.sum[5] = f64::NAN;
    let mut short = honest(a);
    short.sum.truncate(9);
    let mut wrong_rect = honest(a);
    wrong_rect.rect = b.rect;
    let cases = [
        (
            "NaN sums",
            send(&a.lease_id, a, nan),
            tonic::Code::InvalidArgument,
        ),
        (
            "wrong dimensions",
            send(&a.lease_id, a, short),
            tonic::Code::InvalidArgument,
        ),
        (
            "another tile's rect",
            send(&a.lease_id, a, wrong_rect),
            tonic::Code::InvalidArgument,
        ),
        (
            "lease of another unit",
            send(&b.lease_id, a, honest(a)),
            tonic::Code::FailedPrecondition,
        ),
        (
            "stale lease",
            send("L0-1", a, honest(a)),
            tonic::Code::FailedPrecondition,
        ),
    ];
    for (what, req, code) in cases {
        let e = forger.submit_result(req).await.expect_err(what);
        assert_eq!(e.code(), code, "{what}: {e:?}");
    }
    // The honest result is merged once; its copy is a duplicate.
    let ok = forger
        .submit_result(send(&b.lease_id, b, honest(b)))
        .await
        .expect("honest")
        .into_inner();
    assert_eq!(ok.outcome, pb::ResultOutcome::Merged as i32);
    let dup = forger
        .submit_result(send(&b.lease_id, b, honest(b)))
        .await
        .expect("duplicate")
        .into_inner();
    assert_eq!(dup.outcome, pb::ResultOutcome::Duplicate as i32);
    // Three invalid results so far (a foreign or stale lease is not counted: it happens
    // honestly after restarts); two more reach the quarantine limit (5).
    for _ in 0..2 {
        let mut nan = honest(a);
        nan.sum_sq[0] = f64::INFINITY;
        let _ = forger.submit_result(send(&a.lease_id, a, nan)).await;
    }
    let e = lease_now(&mut forger, &id, 1)
        .await
        .expect_err("quarantined");
    assert_eq!(e.code(), tonic::Code::PermissionDenied);
    let listed = list_workers(&mut client).await;
    let f = listed.iter().find(|w| w.name == "forger").expect("listed");
    assert!(f.quarantined);
    assert_eq!(f.bad_results, 5);

    let w = worker(&url, "honest");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32);
    assert!(fetch(&mut client, &job).await == local_exr(&text, 8, 4, dir.path()));
    w.abort();
    coord.stop().await;
}

/// A job with AOVs: a result whose AOV sums no samples could give, or that leaves them out,
/// is refused with a message naming them; the honest one merges, and the EXR is the local
/// render's bytes.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn forged_aov_sums_are_refused_and_leave_the_image_unaffected() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let url = coord.url();
    let text = scene_text(32);
    let settings = RenderSettings {
        aovs: tessera_render::Aovs::ALL,
        ..job_settings(8, 4)
    };
    let mut client = coord.client().await;
    let job = submit_job(&mut client, submit_request_with(&text, &settings)).await;
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let mut forger = workers_client(&url);
    let id = register_as(&mut forger, "forger", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut forger, &id, 1).await.expect("lease");
    let u = &units[0];
    let honest = || honest_result(&scene, &settings, u);
    let send = |result: pb::TileResult| pb::SubmitResultRequest {
        worker_id: id.clone(),
        lease_id: u.lease_id.clone(),
        job_id: u.job_id.clone(),
        tile_index: u.tile_index,
        batch_index: u.batch_index,
        result: Some(result),
    };
    let mut bright = honest();
    bright.aov_albedo[4] = 1e6;
    let mut deep = honest();
    deep.aov_depth[0] = -1.0;
    let mut bare = honest();
    bare.aov_albedo.clear();
    bare.aov_normal.clear();
    bare.aov_depth.clear();
    bare.aov_hits.clear();
    bare.aov_count.clear();
    let mut short = honest();
    short.aov_hits.pop();
    for (what, forged, needle) in [
        ("albedo above its count", bright, "AOV sums"),
        ("negative depth", deep, "AOV sums"),
        ("no AOV sums", bare, "no AOV sums"),
        ("a short array", short, "AOV arrays"),
    ] {
        let e = forger.submit_result(send(forged)).await.expect_err(what);
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{what}: {e:?}");
        assert!(e.message().contains(needle), "{what}: {}", e.message());
    }
    let ok = forger
        .submit_result(send(honest()))
        .await
        .expect("honest")
        .into_inner();
    assert_eq!(ok.outcome, pb::ResultOutcome::Merged as i32);
    let w = worker(&url, "honest");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    let channels = ExrChannels {
        aovs: settings.aovs,
        ..ExrChannels::default()
    };
    assert!(
        fetch(&mut client, &job).await == local_exr_with(&text, &settings, channels, dir.path()),
        "forged AOV sums reached the image"
    );
    w.abort();
    coord.stop().await;
}
