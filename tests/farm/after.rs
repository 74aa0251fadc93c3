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
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let settings = job_settings(4, 4);
    let mut hand = workers_client(&url);
    let id = register_as(&mut hand, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    // However often the worker asks, no unit of the waiting job goes out before the first job
    // is done (its EXR written), although the waiting job has the higher priority. The first
    // job may be done by the time the lease after its last result is asked for, so the check
    // is made when a waiting job's unit is seen, not by when it arrives.
    let mut client = coord.client().await;
    let (mut of_first, mut of_then, mut waited_first) = (0, 0, false);
    loop {
        let units = lease_now(&mut hand, &id, 4).await.expect("lease");
        if units.is_empty() {
            if of_then > 0 || waited_first {
                break;
            }
            // The first job's results are in but its EXR may not be written yet.
            assert_eq!(
                wait(&mut client, &first).await.state,
                pb::JobState::Done as i32
            );
            waited_first = true;
            continue;
        }
        for u in units {
            if u.job_id == then {
                if of_then == 0 {
                    assert_eq!(
                        job_status(&mut client, &first).await.state,
                        pb::JobState::Done as i32,
                        "a unit of the waiting job went out before the first job was done"
                    );
                }
                of_then += 1;
            } else {
                assert_eq!(u.job_id, first, "a unit of an unknown job");
                assert_eq!(
                    of_then, 0,
                    "the first job leased after the waiting one started"
                );
                of_first += 1;
            }
            let r = honest_result(&scene, &settings, &u);
            hand.submit_result(result_for(&id, &u, r))
                .await
                .expect("merged");
        }
    }
    assert!(
        of_first > 0 && of_then > 0,
        "{of_first} and {of_then} units"
    );
    for job in [&first, &then] {
        let s = wait(&mut client, job).await;
        assert_eq!(s.state, pb::JobState::Done as i32, "{job}: {}", s.error);
    }
    coord.stop().await;
}
