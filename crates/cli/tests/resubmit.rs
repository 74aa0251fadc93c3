//! `tessera submit` when the coordinator deletes a file between the upload and the submission.
//!
//! The coordinator collects files no active job names (docs/farm.md, "Scene files"). A file
//! `tessera submit` found held, or had just uploaded, can therefore be gone when its
//! `SubmitJob` arrives, and the submission is refused as "not uploaded". The client then
//! uploads again and resubmits, twice at most. On a real farm the window is milliseconds wide,
//! so these tests close it on purpose: the real binary talks to a `Jobs` server that is the
//! coordinator's own service (in-process, the real store) except that it runs a collection just
//! before handing a submission on, as the coordinator's periodic collection could.

mod common;

use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use common::{repo, BIN};
use tessera_coordinator::{Config, InProcess};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_server::{Jobs, JobsServer};
use tonic::{Request, Response, Status, Streaming};

/// The coordinator's `Jobs` service, with a collection before each of the first `collect`
/// submissions.
struct CollectBeforeSubmit {
    farm: Arc<InProcess>,
    collect: AtomicUsize,
    submissions: AtomicUsize,
    deleted: AtomicUsize,
}

type R<T> = Result<Response<T>, Status>;

#[tonic::async_trait]
impl Jobs for CollectBeforeSubmit {
    async fn submit_job(&self, req: Request<pb::SubmitJobRequest>) -> R<pb::SubmitJobResponse> {
        self.submissions.fetch_add(1, Ordering::SeqCst);
        let take = |n: usize| n.checked_sub(1);
        if self
            .collect
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, take)
            .is_ok()
        {
            let c = self
                .farm
                .collect_assets()
                .expect("collect")
                .expect("no submission holds collection off here");
            self.deleted.fetch_add(c.files, Ordering::SeqCst);
        }
        self.farm.service().submit_job(req).await
    }
    async fn get_job(&self, req: Request<pb::GetJobRequest>) -> R<pb::JobStatus> {
        self.farm.service().get_job(req).await
    }
    type WatchJobStream = <tessera_coordinator::Service as Jobs>::WatchJobStream;
    async fn watch_job(&self, req: Request<pb::WatchJobRequest>) -> R<Self::WatchJobStream> {
        self.farm.service().watch_job(req).await
    }
    async fn cancel_job(&self, req: Request<pb::CancelJobRequest>) -> R<pb::CancelJobResponse> {
        self.farm.service().cancel_job(req).await
    }
    async fn update_job(&self, req: Request<pb::UpdateJobRequest>) -> R<pb::JobStatus> {
        self.farm.service().update_job(req).await
    }
    async fn list_jobs(&self, req: Request<pb::ListJobsRequest>) -> R<pb::ListJobsResponse> {
        self.farm.service().list_jobs(req).await
    }
    async fn list_workers(
        &self,
        req: Request<pb::ListWorkersRequest>,
    ) -> R<pb::ListWorkersResponse> {
        self.farm.service().list_workers(req).await
    }
    async fn get_logs(&self, req: Request<pb::GetLogsRequest>) -> R<pb::GetLogsResponse> {
        self.farm.service().get_logs(req).await
    }
    async fn retry_job(&self, req: Request<pb::RetryJobRequest>) -> R<pb::RetryJobResponse> {
        self.farm.service().retry_job(req).await
    }
    async fn drain_worker(
        &self,
        req: Request<pb::DrainWorkerRequest>,
    ) -> R<pb::DrainWorkerResponse> {
        self.farm.service().drain_worker(req).await
    }
    async fn release_worker(
        &self,
        req: Request<pb::ReleaseWorkerRequest>,
    ) -> R<pb::ReleaseWorkerResponse> {
        self.farm.service().release_worker(req).await
    }
    type FetchResultStream = <tessera_coordinator::Service as Jobs>::FetchResultStream;
    async fn fetch_result(
        &self,
        req: Request<pb::FetchResultRequest>,
    ) -> R<Self::FetchResultStream> {
        self.farm.service().fetch_result(req).await
    }
    async fn upload_asset(&self, req: Request<Streaming<pb::AssetChunk>>) -> R<pb::AssetStatus> {
        self.farm.service().upload_asset(req).await
    }
    async fn get_asset_status(
        &self,
        req: Request<pb::GetAssetStatusRequest>,
    ) -> R<pb::AssetStatus> {
        self.farm.service().get_asset_status(req).await
    }
}

/// Runs `tessera submit scenes/cornell-mesh.toml` against a farm that collects before each of
/// the first `collect` submissions; returns the output, how many submissions arrived, how many
/// files the collections deleted, and the farm.
async fn submit_with_collections(
    dir: &std::path::Path,
    collect: usize,
) -> (std::process::Output, usize, usize, Arc<InProcess>) {
    let mut config = Config::new(dir);
    // A file no active job names is deleted at the next collection.
    config.asset_retention = std::time::Duration::ZERO;
    let farm = Arc::new(InProcess::open(config).expect("open the coordinator's store"));
    let jobs = Arc::new(CollectBeforeSubmit {
        farm: farm.clone(),
        collect: AtomicUsize::new(collect),
        submissions: AtomicUsize::new(0),
        deleted: AtomicUsize::new(0),
    });
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let url = format!("http://{}", listener.local_addr().expect("addr"));
    let server = tokio::spawn(
        tonic::transport::Server::builder()
            .add_service(JobsServer::from_arc(jobs.clone()))
            .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(listener)),
    );
    let out = tokio::task::spawn_blocking(move || {
        Command::new(BIN)
            .args([
                "submit",
                &repo("scenes/cornell-mesh.toml"),
                "--spp",
                "16",
                "--coordinator",
                &url,
            ])
            .output()
            .expect("run tessera submit")
    })
    .await
    .expect("join");
    server.abort();
    let submissions = jobs.submissions.load(Ordering::SeqCst);
    let deleted = jobs.deleted.load(Ordering::SeqCst);
    (out, submissions, deleted, farm)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_file_deleted_before_the_submission_is_uploaded_again() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (out, submissions, deleted, farm) = submit_with_collections(dir.path(), 1).await;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_eq!(submissions, 2, "{stderr}");
    assert_eq!(
        deleted, 1,
        "the collection did not delete the mesh: {stderr}"
    );
    assert!(
        stderr.contains("no longer holds a file") && stderr.contains("uploading again"),
        "{stderr}"
    );
    // Uploaded before each submission, so twice.
    assert_eq!(stderr.matches(": uploaded (").count(), 2, "{stderr}");
    let job = stdout.trim();
    let status = farm
        .service()
        .get_job(Request::new(pb::GetJobRequest {
            job_id: job.to_string(),
        }))
        .await
        .expect("the printed job exists")
        .into_inner();
    assert_eq!(status.job_id, job);
    // The job now names the mesh, so a collection keeps it.
    let c = farm
        .collect_assets()
        .expect("collect")
        .expect("not held off");
    assert_eq!(c.files, 0, "{c:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_file_deleted_before_every_submission_ends_in_one_clear_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (out, submissions, deleted, _farm) = submit_with_collections(dir.path(), usize::MAX).await;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    // The first submission and two more, each after an upload the collection undid.
    assert_eq!((submissions, deleted), (3, 3), "{stderr}");
    assert_eq!(stderr.matches("uploading again").count(), 2, "{stderr}");
    let last = stderr.trim().lines().last().unwrap_or_default();
    assert!(
        last.contains("submit refused") && last.contains("not uploaded") && last.contains(".obj"),
        "{stderr}"
    );
}
