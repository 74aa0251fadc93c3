//! Priorities order jobs; cancelling frees their units.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn priorities_order_jobs_and_cancel_frees_units() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let text = scene_text(32);
    let mut client = coord.client().await;
    // Submitted before any worker exists, so the scheduler alone decides the order.
    let low = submit(&mut client, &text, 32, 4, 0).await;
    let doomed = submit(&mut client, &text, 4096, 4, 5).await;
    let high = submit(&mut client, &text, 32, 4, 10).await;
    let jobs = client
        .list_jobs(pb::ListJobsRequest::default())
        .await
        .expect("list")
        .into_inner()
        .jobs;
    let order: Vec<&str> = jobs.iter().map(|j| j.job_id.as_str()).collect();
    assert_eq!(order, [high.as_str(), doomed.as_str(), low.as_str()]);
    assert!(jobs.iter().all(|j| j.state == pb::JobState::Queued as i32));

    let workers: Vec<_> = (0..2)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    let high_status = wait(&mut client, &high).await;
    assert_eq!(high_status.state, pb::JobState::Done as i32);
    // The big job runs next; cancel it while it holds leases.
    wait_for("the big job's first unit", async || {
        (job_status(&mut client, &doomed).await.units_done > 0).then_some(())
    })
    .await;
    let cancelled = client
        .cancel_job(pb::CancelJobRequest {
            job_id: doomed.clone(),
        })
        .await
        .expect("cancel")
        .into_inner();
    assert_eq!(cancelled.state, pb::JobState::Cancelled as i32);
    let low_status = wait(&mut client, &low).await;
    assert_eq!(low_status.state, pb::JobState::Done as i32);
    assert!(high_status.finished_unix_ms <= low_status.finished_unix_ms);
    let d = job_status(&mut client, &doomed).await;
    assert_eq!(d.state, pb::JobState::Cancelled as i32);
    assert_eq!(d.units_leased, 0, "cancel left leases behind");
    assert!(d.units_done < d.units_total);
    let err = client
        .fetch_result(pb::FetchResultRequest {
            job_id: doomed.clone(),
            frame: None,
        })
        .await
        .expect_err("a cancelled job has no result");
    assert_eq!(err.code(), tonic::Code::FailedPrecondition);
    assert!(!coord.out.join(format!("{doomed}.exr")).exists());
    assert!(fetch(&mut client, &low).await == local_exr(&text, 32, 4, dir.path()));
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}
