//! Concurrent submissions parse a few scenes at a time.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_submissions_parse_a_few_scenes_at_a_time() {
    use tessera_proto::v1::jobs_server::Jobs;
    let dir = tempfile::tempdir().expect("tempdir");
    let farm = tessera_coordinator::InProcess::open(Config::new(dir.path())).expect("open");
    // Large enough that a parse (and its BVH) takes a while, so unbounded parses would overlap.
    let mut text = scene_text(16);
    for i in 0..20_000 {
        let (x, y) = ((i % 141) as f32 * 0.01 - 0.7, (i / 141) as f32 * 0.01 - 0.7);
        text.push_str(&format!(
            "[[objects]]\nshape = \"sphere\"\ncenter = [{x}, {y}, -0.5]\nradius = 0.004\nmaterial = \"white\"\n"
        ));
    }
    let tasks: Vec<_> = (0..8)
        .map(|i| {
            let svc = farm.service().clone();
            let text = text.clone();
            tokio::spawn(async move {
                svc.submit_job(tonic::Request::new(pb::SubmitJobRequest {
                    scene_text: text,
                    scene_format: pb::SceneFormat::Toml as i32,
                    scene_name: format!("big-{i}.toml"),
                    settings: Some(pb::RenderSettings {
                        spp: 1,
                        ..Default::default()
                    }),
                    ..Default::default()
                }))
                .await
            })
        })
        .collect();
    for t in tasks {
        t.await.expect("task").expect("submitted");
    }
    let peak = farm.peak_parses();
    assert!(
        (1..=tessera_coordinator::MAX_CONCURRENT_PARSES).contains(&peak),
        "{peak} scenes parsed at once"
    );
    farm.close().await;
}
