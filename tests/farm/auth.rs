//! A configured token guards every RPC of both services.

use crate::common::*;

/// A coordinator that requires a token refuses calls without it or with a wrong one, on both
/// services, and works with the right one.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_token_is_required_on_every_service() {
    let dir = tempfile::tempdir().expect("tempdir");
    let token = Secret::new("farm-token-0123456789abcdef");
    let t = token.clone();
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.token = Some(t)
    })
    .await;
    let url = coord.url();
    let good = ClientOptions {
        token: Some(token.clone()),
        ..ClientOptions::default()
    };
    let wrong = ClientOptions {
        token: Some(Secret::new("farm-token-0123456789abcdeX")),
        ..ClientOptions::default()
    };
    let text = scene_text(16);
    for options in [ClientOptions::default(), wrong.clone()] {
        let mut client = client_with(&url, &options).await;
        let req = pb::SubmitJobRequest {
            scene_text: text.clone(),
            settings: Some(pb::RenderSettings {
                spp: 1,
                ..Default::default()
            }),
            ..Default::default()
        };
        let e = client
            .submit_job(req)
            .await
            .expect_err("submit without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated, "{e:?}");
        let e = client
            .fetch_result(pb::FetchResultRequest {
                job_id: "job-000001".into(),
                frame: None,
            })
            .await
            .expect_err("fetch without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = client
            .list_jobs(pb::ListJobsRequest::default())
            .await
            .expect_err("list without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = client
            .update_job(pb::UpdateJobRequest {
                job_id: "job-000001".into(),
                paused: Some(true),
                priority: None,
            })
            .await
            .expect_err("pause without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = client
            .drain_worker(pb::DrainWorkerRequest {
                worker: "render-01".into(),
            })
            .await
            .expect_err("drain without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = client
            .get_asset_status(pb::GetAssetStatusRequest {
                sha256: "a".repeat(64),
            })
            .await
            .expect_err("asset status without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let chunk = pb::AssetChunk {
            sha256: "a".repeat(64),
            offset: 0,
            total_size: 1,
            data: vec![1],
        };
        let e = client
            .upload_asset(tokio_stream::iter(vec![chunk]))
            .await
            .expect_err("upload without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let channel = endpoint(&url, &options).expect("ep").connect_lazy();
        let mut workers = WorkersClient::with_interceptor(channel, Bearer::new(&options));
        let e = workers
            .lease(pb::LeaseRequest {
                worker_id: "w1-1".into(),
                max_units: 1,
                wait_ms: 0,
            })
            .await
            .expect_err("lease without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = workers
            .register(pb::RegisterRequest::default())
            .await
            .expect_err("register without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = workers
            .fetch_asset(pb::FetchAssetRequest {
                sha256: "a".repeat(64),
                offset: 0,
                worker_id: "w1-1".into(),
            })
            .await
            .expect_err("fetch_asset without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
    }
    // A worker with the wrong token stops with an error instead of retrying forever.
    let mut config = tessera_worker::Config::new(url.clone());
    config.client = wrong;
    let err = tessera_worker::run(config, std::future::pending())
        .await
        .expect_err("refused");
    assert!(err.to_string().contains("wrong token"), "{err}");

    render_one_job(&url, &good, &text, dir.path()).await;
    coord.stop().await;
}
