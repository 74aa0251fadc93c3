//! Several workers give the bits of one local render.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn three_workers_render_the_same_bits_as_a_local_render() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let workers: Vec<_> = (0..3)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    let text = scene_text(48);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 24, 8, 0).await;
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert_eq!(status.units_done, status.units_total);
    assert_eq!(status.units_total, 9 * 3);
    let farm = fetch(&mut client, &job).await;
    assert_eq!(
        std::fs::read(coord.out.join(format!("{job}.exr"))).expect("output file"),
        farm
    );
    let local = local_exr(&text, 24, 8, dir.path());
    assert!(farm == local, "farm EXR differs from the local render");

    let listed = list_workers(&mut client).await;
    assert_eq!(listed.len(), 3);
    assert_eq!(listed.iter().map(|w| w.units_done).sum::<u64>(), 27);
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}

/// A frame whose tiles do not line up with the EXR's 16-row blocks (tiles of 12 in a 45² frame:
/// bands of 12 rows and a last one of 9, while the encoder asks for rows 16 at a time) and
/// whose variance and sample channels are written too: the farm's EXR, written a band at a
/// time from its strips, is the bytes of `tessera render`'s.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_frame_written_in_bands_across_the_exr_blocks_is_the_local_render() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let workers: Vec<_> = (0..2)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    let text = scene_text(45);
    let mut client = coord.client().await;
    let job = submit_job(
        &mut client,
        pb::SubmitJobRequest {
            tile_size: 12,
            channels: Some(pb::OutputChannels {
                variance: true,
                sample_count: true,
                denoise: None,
            }),
            ..submit_request(&text, 8, 4)
        },
    )
    .await;
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert_eq!(status.units_total, 16 * 2);
    let farm = fetch(&mut client, &job).await;
    let channels = ExrChannels {
        variance: true,
        samples: true,
        ..ExrChannels::default()
    };
    let local = local_exr_with(&text, &job_settings(8, 4), channels, dir.path());
    assert!(farm == local, "farm EXR differs from the local render");
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}

/// AOVs on the farm: each unit's result carries their sums, the coordinator merges them in
/// batch order and writes their channels, and the EXR is `tessera render --aov`'s bytes.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn aovs_rendered_by_the_farm_are_the_local_renders_bytes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let workers: Vec<_> = (0..2)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    let text = scene_text(40);
    let all = tessera_render::Aovs::ALL;
    let settings = RenderSettings {
        aovs: all,
        ..job_settings(8, 4)
    };
    let mut client = coord.client().await;
    let job = submit_job(&mut client, submit_request_with(&text, &settings)).await;
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    let farm = fetch(&mut client, &job).await;
    let channels = ExrChannels {
        aovs: all,
        ..ExrChannels::default()
    };
    let local = local_exr_with(&text, &settings, channels, dir.path());
    assert!(
        farm == local,
        "farm EXR with AOVs differs from the local render"
    );
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}
