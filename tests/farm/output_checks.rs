//! A finished frame that is entirely black, or that dropped non-finite samples, is delivered as
//! rendered but flagged in its status, and still flagged after a restart.

use crate::common::*;

/// The Cornell box with its light switched off: every pixel black.
fn unlit(size: u32) -> String {
    let text = scene_text(size);
    let off = text.replace("emission = [18.387, 13.9873, 6.75357]\n", "");
    assert_ne!(off, text, "the light's emission line moved");
    off
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_black_frame_is_delivered_flagged_and_still_flagged_after_a_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let (coord, http) = dashboard_farm(dir.path()).await;
    let w = worker(&coord.url(), "w");
    let mut client = coord.client().await;
    let dark = submit(&mut client, &unlit(16), 4, 2, 0).await;
    let lit = submit(&mut client, &scene_text(16), 4, 2, 0).await;
    let s = wait(&mut client, &dark).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    let codes = |s: &pb::JobStatus| s.checks.iter().map(|c| c.code.clone()).collect::<Vec<_>>();
    assert_eq!(codes(&s), ["black"]);
    assert!(
        s.checks[0].message.contains("entirely black"),
        "{:?}",
        s.checks
    );
    // Delivered as rendered: the local render's bytes.
    assert!(fetch(&mut client, &dark).await == local_exr(&unlit(16), 4, 2, dir.path()));
    let s = wait(&mut client, &lit).await;
    assert!(
        s.checks.is_empty(),
        "a lit frame is flagged: {:?}",
        s.checks
    );
    // The dashboard's API says the same, for the job's page and the list's mark.
    let page: serde_json::Value =
        serde_json::from_slice(&get(http, &format!("/api/jobs/{dark}")).await.body).expect("JSON");
    assert_eq!(page["checks"][0]["code"], "black", "{page}");
    let list: serde_json::Value =
        serde_json::from_slice(&get(http, "/api/jobs").await.body).expect("JSON");
    let flagged: Vec<&str> = list
        .as_array()
        .expect("a list")
        .iter()
        .filter(|j| j["checks"].as_array().is_some_and(|c| !c.is_empty()))
        .filter_map(|j| j["job_id"].as_str())
        .collect();
    assert_eq!(flagged, [dark.as_str()]);
    w.abort();
    let coord = coord.restarted(&data, lease).await;
    let mut client = coord.client().await;
    assert_eq!(codes(&job_status(&mut client, &dark).await), ["black"]);
    assert!(job_status(&mut client, &lit).await.checks.is_empty());
    coord.stop().await;
}

/// A worker that reports one sample of each unit as non-finite (and leaves it out, as the
/// renderer does): the frame is done, its status counts the samples and flags them, and a
/// restart keeps both.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn dropped_non_finite_samples_flag_the_frame() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(30);
    let coord = Coordinator::start(&data, lease).await;
    let url = coord.url();
    let text = scene_text(16);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 4, 4, 0).await;
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let settings = job_settings(4, 4);
    let mut hand = workers_client(&url);
    let id = register_as(&mut hand, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let mut dropped = 0u64;
    loop {
        let units = lease_now(&mut hand, &id, 4).await.expect("lease");
        if units.is_empty() {
            break;
        }
        for u in units {
            let mut r = honest_result(&scene, &settings, &u);
            // Pixel 0 lost one sample to a NaN: one fewer counted, one reported.
            r.count[0] -= 1;
            r.nonfinite += 1;
            dropped += 1;
            let ok = hand
                .submit_result(result_for(&id, &u, r))
                .await
                .expect("a result that reports its dropped sample is accepted")
                .into_inner();
            assert_eq!(ok.outcome, pb::ResultOutcome::Merged as i32);
        }
    }
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    assert_eq!(s.nonfinite_samples, dropped);
    let want = format!("{dropped} non-finite samples (NaN or infinite) were left out");
    let check = |s: &pb::JobStatus| {
        assert_eq!(s.checks.len(), 1, "{:?}", s.checks);
        assert_eq!(s.checks[0].code, "nonfinite");
        assert!(s.checks[0].message.starts_with(&want), "{:?}", s.checks);
    };
    check(&s);
    let coord = coord.restarted(&data, lease).await;
    let mut client = coord.client().await;
    let s = job_status(&mut client, &job).await;
    check(&s);
    assert_eq!(
        s.nonfinite_samples, dropped,
        "the count survives the restart"
    );
    coord.stop().await;
}
