//! `submit --after` over the wire: a job that waits for another takes no lease until that one
//! is done, across a coordinator restart, and its status names what it waits for.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_job_after_another_waits_for_it_across_a_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start(&data, lease).await;
    let text = scene_text(16);
    let mut client = coord.client().await;
    let first = submit(&mut client, &text, 4, 4, 0).await;
    let then = submit_job(
        &mut client,
        pb::SubmitJobRequest {
            after: first.clone(),
            // A higher priority does not let it jump the job it waits for.
            priority: 10,
            ..submit_request(&text, 4, 4)
        },
    )
    .await;
    assert_eq!(job_status(&mut client, &then).await.after, first);
    // Malformed and unknown ids are refused by name.
    for (after, code) in [
        ("yesterday", tonic::Code::InvalidArgument),
        ("job-000999", tonic::Code::NotFound),
    ] {
        let e = client
            .submit_job(pb::SubmitJobRequest {
                after: after.into(),
                ..submit_request(&text, 4, 4)
            })
            .await
            .expect_err(after);
        assert_eq!(e.code(), code, "{after}: {e:?}");
        assert!(e.message().contains("after"), "{e:?}");
    }
    let coord = coord.restarted(&data, lease).await;
    let url = coord.url();
    let scene = Scene::from_str(&text, Format::Toml, "c", &Limits::default()).expect("scene");
    let settings = job_settings(4, 4);
    let mut hand = workers_client(&url);
    let id = register_as(&mut hand, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    // Renders every unit a lease gives, checking it belongs to `job`, until none is left.
    let mut render_all = async |job: &str| {
        let mut n = 0;
        loop {
            let units = lease_now(&mut hand, &id, 4).await.expect("lease");
            if units.is_empty() {
                return n;
            }
            for u in units {
                assert_eq!(u.job_id, job, "a unit of the wrong job went out");
                let r = honest_result(&scene, &settings, &u);
                hand.submit_result(result_for(&id, &u, r))
                    .await
                    .expect("merged");
                n += 1;
            }
        }
    };
    // However often the worker asks, every unit is the first job's until it is done (its EXR
    // written), although the waiting job has the higher priority.
    assert!(render_all(&first).await > 0);
    let mut client = coord.client().await;
    assert_eq!(
        wait(&mut client, &first).await.state,
        pb::JobState::Done as i32
    );
    assert!(render_all(&then).await > 0, "the waiting job never started");
    let mut client = coord.client().await;
    let s = wait(&mut client, &then).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    coord.stop().await;
}
