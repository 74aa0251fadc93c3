//! A job for one frame of an animated scene gives `tessera render --frame N`'s bits.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_frame_job_gives_the_local_render_of_that_frame() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-animated.toml"),
    )
    .expect("read cornell-animated.toml")
    .replace("width = 256", "width = 32")
    .replace("height = 256", "height = 32");
    let w = worker(&coord.url(), "w");
    let mut client = coord.client().await;
    let mut exrs = Vec::new();
    for frame in [30, 48] {
        let settings = RenderSettings {
            frame: Some(frame),
            ..job_settings(8, 4)
        };
        let job = client
            .submit_job(pb::SubmitJobRequest {
                settings: Some(pb::RenderSettings::from(&settings)),
                ..submit_request(&text, 8, 4)
            })
            .await
            .expect("submit")
            .into_inner()
            .job_id;
        let status = wait(&mut client, &job).await;
        assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
        assert_eq!(status.settings.and_then(|s| s.frame), Some(frame));
        let farm = fetch(&mut client, &job).await;
        let local = local_exr_with(&text, &settings, ExrChannels::default(), dir.path());
        assert!(
            farm == local,
            "frame {frame}: farm EXR differs from the local render"
        );
        exrs.push(farm);
    }
    assert!(exrs[0] != exrs[1], "frames 30 and 48 must differ");
    w.abort();
    coord.stop().await;
}
