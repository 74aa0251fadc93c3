//! `tessera pause`, `resume` and `priority` over the wire (`UpdateJob`): a paused job's held
//! leases still merge but it is leased nothing new, across a restart, until resumed; a new
//! priority reorders what is leased next; an ended or unknown job is refused.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_paused_job_finishes_its_leases_takes_no_new_ones_and_resumes_after_a_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start(&data, lease).await;
    // 32² in 16-pixel tiles, 4 spp in batches of 2: eight units a job.
    let text = scene_text(32);
    let mut client = coord.client().await;
    let first = submit(&mut client, &text, 4, 2, 0).await;
    let second = submit(&mut client, &text, 4, 2, 0).await;
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let settings = job_settings(4, 2);
    let mut hand = workers_client(&coord.url());
    let id = register_as(&mut hand, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let update = |job: &str, paused: Option<bool>, priority: Option<i32>| pb::UpdateJobRequest {
        job_id: job.into(),
        paused,
        priority,
    };
    // Two units of the first job out, then the first job paused.
    let held = lease_now(&mut hand, &id, 2).await.expect("lease");
    assert!(held.iter().all(|u| u.job_id == first));
    let s = client
        .update_job(update(&first, Some(true), None))
        .await
        .expect("pause")
        .into_inner();
    assert!(s.paused);
    // Its held leases still merge; the next units are the second job's.
    for u in &held {
        let r = honest_result(&scene, &settings, u);
        let ok = hand
            .submit_result(result_for(&id, u, r))
            .await
            .expect("merged")
            .into_inner();
        assert_eq!(ok.outcome, pb::ResultOutcome::Merged as i32);
    }
    let next = lease_now(&mut hand, &id, 2).await.expect("lease");
    assert!(!next.is_empty() && next.iter().all(|u| u.job_id == second));
    let s = job_status(&mut client, &first).await;
    assert!(s.paused, "before the restart");
    // It merged samples a moment ago, but is going nowhere: no ETA (it once showed one).
    assert!(s.samples_done > 0 && s.eta_seconds < 0.0, "{s:?}");
    // A restart keeps the pause; the second job's leases lapse with the old process.
    let coord = coord.restarted(&data, lease).await;
    let mut client = coord.client().await;
    let s = job_status(&mut client, &first).await;
    assert!(s.paused, "{s:?}");
    let mut hand = workers_client(&coord.url());
    let id = register_as(&mut hand, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut hand, &id, 100).await.expect("lease");
    assert!(
        units.iter().all(|u| u.job_id == second),
        "a paused job leased"
    );
    // Resumed, and put first by priority: its units come before the second job's.
    client
        .update_job(update(&first, Some(false), Some(5)))
        .await
        .expect("resume");
    let s = job_status(&mut client, &first).await;
    assert!(!s.paused);
    assert_eq!(s.priority, 5);
    let rendered = |units: Vec<pb::WorkUnit>, hand: WorkersClient<Channel>| {
        let (scene, settings, id) = (&scene, &settings, id.clone());
        async move {
            let mut hand = hand;
            for u in units {
                let r = honest_result(scene, settings, &u);
                hand.submit_result(result_for(&id, &u, r))
                    .await
                    .expect("merged");
            }
        }
    };
    rendered(units, hand.clone()).await;
    let units = lease_now(&mut hand, &id, 1).await.expect("lease");
    assert_eq!(units[0].job_id, first, "the higher priority comes first");
    rendered(units, hand.clone()).await;
    loop {
        let units = lease_now(&mut hand, &id, 8).await.expect("lease");
        if units.is_empty() {
            break;
        }
        rendered(units, hand.clone()).await;
    }
    for job in [&first, &second] {
        assert_eq!(
            wait(&mut client, job).await.state,
            pb::JobState::Done as i32
        );
    }
    // An ended job and an unknown one are refused.
    let e = client
        .update_job(update(&first, Some(true), None))
        .await
        .expect_err("ended");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("has ended"), "{e:?}");
    let e = client
        .update_job(update("job-000999", None, Some(1)))
        .await
        .expect_err("unknown");
    assert_eq!(e.code(), tonic::Code::NotFound, "{e:?}");
    coord.stop().await;
}
