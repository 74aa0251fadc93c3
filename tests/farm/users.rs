//! Named tokens (`--tokens-file`): each job records the user whose token submitted it, only
//! that user or an admin may change it (on the gRPC API and the dashboard alike), only an
//! admin may drain workers, and a reload withdraws a token at once.

use crate::common::*;
use tessera_coordinator::Tokens;

const ALICE: &str = "alice-token-0123456789abcdef";
const BOB: &str = "bob-token-0123456789abcdef";
const OPS: &str = "ops-token-0123456789abcdef";
const CAROL: &str = "carol-token-0123456789abcdef";

async fn as_user(url: &str, token: &str) -> Client {
    let options = ClientOptions {
        token: Some(Secret::new(token)),
        ..ClientOptions::default()
    };
    client_with(url, &options).await
}

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_user_changes_only_their_own_jobs_and_a_reload_withdraws_a_token() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("tokens");
    std::fs::write(
        &file,
        format!("alice {ALICE}\nbob {BOB}\nops {OPS} admin\n"),
    )
    .expect("write");
    let tokens = Tokens::load(&file).expect("tokens");
    let t = tokens.clone();
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.tokens = Some(t)
        })
        .await;
    let url = coord.url();
    let text = scene_text(16);
    let mut alice = as_user(&url, ALICE).await;
    let mut bob = as_user(&url, BOB).await;
    let mut ops = as_user(&url, OPS).await;
    let job = submit(&mut alice, &text, 4, 2, 0).await;
    let s = job_status(&mut bob, &job).await;
    assert_eq!(s.submitter, "alice", "anyone may read it");

    // Bob may not change Alice's job, by any verb; the refusal says whose it is.
    let e = bob
        .cancel_job(pb::CancelJobRequest {
            job_id: job.clone(),
        })
        .await
        .expect_err("bob cancels alice's job");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    assert!(
        e.message()
            .contains("was submitted by alice; only alice or an admin may cancel it"),
        "{e:?}"
    );
    let e = bob
        .update_job(pb::UpdateJobRequest {
            job_id: job.clone(),
            paused: Some(true),
            priority: None,
        })
        .await
        .expect_err("bob pauses alice's job");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    let e = bob
        .retry_job(pb::RetryJobRequest {
            job_id: job.clone(),
            frame: None,
        })
        .await
        .expect_err("bob retries alice's job");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    // Nor through the dashboard with his token.
    let http_addr = coord.http.expect("dashboard");
    let bearer = format!("Bearer {BOB}");
    let r = http(
        http_addr,
        "POST",
        &format!("/api/jobs/{job}/cancel"),
        &[("authorization", bearer.as_str())],
        "",
    )
    .await;
    assert_eq!(r.status, 403, "{}", r.text());
    assert_eq!(
        job_status(&mut ops, &job).await.state,
        pb::JobState::Queued as i32
    );
    // Alice may, and so may an admin.
    alice
        .update_job(pb::UpdateJobRequest {
            job_id: job.clone(),
            paused: Some(true),
            priority: None,
        })
        .await
        .expect("alice pauses her job");
    ops.update_job(pb::UpdateJobRequest {
        job_id: job.clone(),
        paused: Some(false),
        priority: Some(3),
    })
    .await
    .expect("an admin resumes it");
    // Workers are the farm's: only an admin drains them.
    let e = alice
        .drain_worker(pb::DrainWorkerRequest {
            worker: "render-01".into(),
        })
        .await
        .expect_err("alice drains");
    assert_eq!(e.code(), tonic::Code::PermissionDenied, "{e:?}");
    let e = ops
        .drain_worker(pb::DrainWorkerRequest {
            worker: "render-01".into(),
        })
        .await
        .expect_err("no such worker");
    assert_eq!(e.code(), tonic::Code::NotFound, "{e:?}");

    // Bob's token is withdrawn and Carol's added by a reload: at once, on both ports.
    std::fs::write(
        &file,
        format!("alice {ALICE}\ncarol {CAROL}\nops {OPS} admin\n"),
    )
    .expect("write");
    assert_eq!(tokens.reload(&file), Ok(3));
    let e = bob
        .list_jobs(pb::ListJobsRequest::default())
        .await
        .expect_err("a withdrawn token");
    assert_eq!(e.code(), tonic::Code::Unauthenticated, "{e:?}");
    let r = http(
        http_addr,
        "GET",
        "/api/jobs",
        &[("authorization", bearer.as_str())],
        "",
    )
    .await;
    assert_eq!(r.status, 401);
    let mut carol = as_user(&url, CAROL).await;
    let mine = submit(&mut carol, &text, 4, 2, 0).await;
    assert_eq!(job_status(&mut carol, &mine).await.submitter, "carol");
    coord.stop().await;
}
