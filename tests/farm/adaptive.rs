//! A job with a noise target: the tiles' decisions, made by the coordinator from merged sums,
//! give the local renderer's bits, across a coordinator restart in the middle of the job.

use crate::common::*;
use tessera_render::Adaptive;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_adaptive_job_gives_the_local_bits_across_a_coordinator_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start(&data, Duration::from_secs(30)).await;
    let addr = coord.addr;
    let text = scene_text(64);
    let (spp, batch, tile) = (512, 8, 16);
    let settings = RenderSettings {
        adaptive: Some(Adaptive::new(0.025, tile).expect("target")),
        ..job_settings(spp, batch)
    };
    let mut client = coord.client().await;
    let job = client
        .submit_job(pb::SubmitJobRequest {
            tile_size: tile,
            channels: Some(pb::OutputChannels {
                variance: false,
                sample_count: true,
                denoise: None,
            }),
            ..submit_request_with(&text, &settings)
        })
        .await
        .expect("submit")
        .into_inner()
        .job_id;
    let workers: Vec<_> = (0..2)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    // Past every tile's first batches (16 tiles × 8), so that decisions were made and stored
    // before the stop, and the restarted coordinator must make them again from its store.
    wait_for("150 units merged", async || {
        (job_status(&mut client, &job).await.units_done >= 150).then_some(())
    })
    .await;
    coord.stop().await;
    let coord = Coordinator::restart_at(addr, &data, Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert_eq!(status.units_done, status.units_total);
    let pixels = 64 * 64;
    assert!(
        status.samples_done < pixels * spp as u64 && status.samples_done > pixels * 64,
        "{} samples: no tile stopped early, or some stopped before the minimum",
        status.samples_done
    );
    let farm = fetch(&mut client, &job).await;
    let channels = ExrChannels {
        variance: false,
        samples: true,
        ..ExrChannels::default()
    };
    let local = local_exr_with(&text, &settings, channels, dir.path());
    assert!(
        farm == local,
        "farm EXR differs from the local adaptive render"
    );
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}
