//! `tessera retry` over the wire: a job that failed (a worker could not render its unit) is
//! put back after a coordinator restart, renders on a worker that can, and gives the bits of a
//! job that never failed; past the retry window its scene is gone and a retry says so.

use crate::common::*;

/// Registers a hand-driven worker that leases one unit of the only job and says it cannot
/// render it; with `fail_frame_after = 1` that fails the job.
async fn fail_by_hand(url: &str) {
    let mut hand = workers_client(url);
    let id = register_as(&mut hand, "flaky", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut hand, &id, 1).await.expect("lease");
    let lease = units.first().expect("a unit").lease_id.clone();
    hand.release_leases(pb::ReleaseLeasesRequest {
        worker_id: id,
        lease_ids: vec![lease],
        goodbye: true,
        cannot_render: "out of memory".into(),
    })
    .await
    .expect("release");
}

async fn retry(client: &mut Client, job: &str) -> Result<Vec<String>, tonic::Status> {
    client
        .retry_job(pb::RetryJobRequest {
            job_id: job.into(),
            frame: None,
        })
        .await
        .map(|r| r.into_inner().job_ids)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_failed_job_retried_after_a_restart_renders_the_bits_of_one_that_never_failed() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start_with(&data, lease, |c| c.fail_frame_after = 1).await;
    let text = scene_text(16);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 4, 2, 0).await;
    // Nothing to retry while it runs, and an unknown job is not found.
    let e = retry(&mut client, &job).await.expect_err("active");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("no failed frame"), "{e:?}");
    let e = retry(&mut client, "job-000999").await.expect_err("unknown");
    assert_eq!(e.code(), tonic::Code::NotFound, "{e:?}");
    fail_by_hand(&coord.url()).await;
    let s = job_status(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(s.error.contains("out of memory"), "{}", s.error);
    assert!(s.retryable, "a failed job is retryable");

    // The scene and the failure survive a restart; the retry clears the failures.
    let coord = coord.restarted(&data, lease).await;
    let mut client = coord.client().await;
    assert!(job_status(&mut client, &job).await.retryable);
    assert_eq!(
        retry(&mut client, &job).await.expect("retry"),
        std::slice::from_ref(&job)
    );
    let s = job_status(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Queued as i32);
    assert_eq!((s.retries, s.failures, s.retryable), (1, 0, false));
    assert!(s.error.is_empty() && s.blocklist.is_empty(), "{s:?}");
    let w = worker(&coord.url(), "good");
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    assert_eq!(s.retries, 1);
    assert_eq!(
        fetch(&mut client, &job).await,
        local_exr(&text, 4, 2, dir.path()),
        "the retried job's EXR differs from tessera render's"
    );
    let e = retry(&mut client, &job).await.expect_err("done");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn past_the_retry_window_a_failed_jobs_scene_is_gone_and_a_retry_says_so() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start_with(&data, Duration::from_secs(30), |c| {
        c.fail_frame_after = 1;
        c.retry_window = Duration::ZERO;
    })
    .await;
    let text = scene_text(16);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 4, 2, 0).await;
    fail_by_hand(&coord.url()).await;
    let s = job_status(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(!s.retryable);
    let e = retry(&mut client, &job).await.expect_err("past the window");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("--retry-window"), "{e:?}");
    assert!(e.message().contains("submit it again"), "{e:?}");
    coord.stop().await;
    let store = Store::open(&data).expect("store");
    assert!(
        store.scene_hashes().expect("scenes").is_empty(),
        "the failed job's scene was kept"
    );
}
