//! Bad submissions are refused with the reason.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_submissions_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let bad_scene = scene_text(32).replace("fov = 39.3077", "fov = 390");
    let mut req = pb::SubmitJobRequest {
        scene_text: bad_scene,
        scene_format: pb::SceneFormat::Toml as i32,
        scene_name: "box.toml".into(),
        settings: Some(pb::RenderSettings {
            spp: 4,
            ..Default::default()
        }),
        ..Default::default()
    };
    let err = client.submit_job(req.clone()).await.expect_err("bad fov");
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    assert!(
        err.message().starts_with("box.toml:10:7: camera.fov"),
        "{}",
        err.message()
    );
    req.scene_text = scene_text(32);
    req.output_name = "../escape.exr".into();
    let err = client.submit_job(req.clone()).await.expect_err("bad name");
    assert!(err.message().contains("output name"), "{}", err.message());
    req.output_name = String::new();
    req.settings = Some(pb::RenderSettings::default());
    let err = client.submit_job(req.clone()).await.expect_err("spp 0");
    assert!(err.message().contains("spp 0"), "{}", err.message());
    let err = client
        .get_job(pb::GetJobRequest {
            job_id: "job-999999".into(),
        })
        .await
        .expect_err("unknown job");
    assert_eq!(err.code(), tonic::Code::NotFound);
    assert!(client
        .list_jobs(pb::ListJobsRequest::default())
        .await
        .expect("list")
        .into_inner()
        .jobs
        .is_empty());
    coord.stop().await;

    // Limits: units per job, active jobs, scene bytes.
    let coord = Coordinator::start_with(&dir.path().join("limits"), Duration::from_secs(30), |c| {
        c.max_units_per_job = 100;
        c.max_active_jobs = 1;
        c.limits.max_bytes = 4096;
    })
    .await;
    let mut client = coord.client().await;
    let small = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 40\n[film]\nwidth = 8\nheight = 8\n";
    let mut req = pb::SubmitJobRequest {
        scene_text: small.into(),
        settings: Some(pb::RenderSettings {
            spp: 1024,
            batch: 1,
            ..Default::default()
        }),
        ..Default::default()
    };
    let err = client
        .submit_job(req.clone())
        .await
        .expect_err("too many units");
    assert_eq!(err.code(), tonic::Code::ResourceExhausted);
    assert!(
        err.message().contains("1024 work units"),
        "{}",
        err.message()
    );
    req.settings = Some(pb::RenderSettings {
        spp: 4,
        ..Default::default()
    });
    client.submit_job(req.clone()).await.expect("first job");
    let err = client
        .submit_job(req.clone())
        .await
        .expect_err("second job");
    assert_eq!(err.code(), tonic::Code::ResourceExhausted);
    req.scene_text = format!("{small}# {}\n", "x".repeat(5000));
    let err = client.submit_job(req).await.expect_err("big scene");
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    assert!(
        err.message().contains("above the limit of 4096"),
        "{}",
        err.message()
    );
    coord.stop().await;
}
