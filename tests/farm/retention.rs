//! Ended jobs are kept for a while, not forever (#79.8): past `max_ended_jobs` (or their
//! retention) the oldest are forgotten, in memory and in the store, and a restart does not
//! bring them back; their EXRs stay where they were written.

use crate::common::*;

async fn listed(client: &mut Client) -> Vec<String> {
    list_jobs(client)
        .await
        .into_iter()
        .map(|j| j.job_id)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn ended_jobs_past_the_limit_are_forgotten_oldest_first() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start_with(&data, lease, |c| {
        c.max_ended_jobs = 2;
        // The collector that forgets them runs every quarter of this (at least a second).
        c.asset_retention = Duration::from_secs(4);
    })
    .await;
    let mut client = coord.client().await;
    let w = worker(&coord.url(), "w");
    let text = scene_text(16);
    let mut ids = Vec::new();
    for _ in 0..4 {
        let id = submit(&mut client, &text, 4, 2, 0).await;
        assert_eq!(
            wait(&mut client, &id).await.state,
            pb::JobState::Done as i32
        );
        ids.push(id);
    }
    let first_exr = coord.out.join(format!("{}.exr", ids[0]));
    let kept = vec![ids[3].clone(), ids[2].clone()];
    wait_for("the two oldest jobs to be forgotten", async || {
        let now = listed(&mut client).await;
        (now == kept).then_some(())
    })
    .await;
    let e = client
        .get_job(pb::GetJobRequest {
            job_id: ids[0].clone(),
        })
        .await
        .expect_err("forgotten");
    assert_eq!(e.code(), tonic::Code::NotFound, "{e:?}");
    assert!(first_exr.exists(), "{} was deleted", first_exr.display());
    w.abort();
    let addr = coord.addr;
    drop(client);
    coord.stop().await;
    {
        let store = Store::open(&data).expect("store");
        let mut stored: Vec<u64> = store
            .load()
            .expect("load")
            .iter()
            .map(|j| j.record.id)
            .collect();
        stored.sort_unstable();
        let want: Vec<u64> = [&ids[2], &ids[3]]
            .iter()
            .map(|id| id.trim_start_matches("job-").parse().expect("id"))
            .collect();
        assert_eq!(stored, want);
    }
    let coord = Coordinator::restart_at(addr, &data, lease).await;
    let mut client = coord.client().await;
    assert_eq!(listed(&mut client).await, kept);
    coord.stop().await;
}
