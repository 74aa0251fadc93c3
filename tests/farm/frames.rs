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
        let job = submit_job(&mut client, submit_request_with(&text, &settings)).await;
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

/// `scenes/cornell-animated.toml` at `size`², with the large box flattened to nothing at frame
/// 24 (its keys pass through a zero scale), so that frame 24 alone cannot be built.
fn animated_with_a_bad_frame(size: u32) -> String {
    let mut text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-animated.toml"),
    )
    .expect("read cornell-animated.toml")
    .replace("width = 256", &format!("width = {size}"))
    .replace("height = 256", &format!("height = {size}"));
    text.push_str(
        "\n[[animation.objects]]\nobject = 6\nkeys = [{ frame = 1 }, { frame = 24, scale = [1, 0, 1] }, { frame = 48 }]\n",
    );
    text
}

async fn fetch_frame(client: &mut Client, job: &str, frame: u32) -> Result<Vec<u8>, tonic::Status> {
    let mut stream = client
        .fetch_result(pb::FetchResultRequest {
            job_id: job.into(),
            frame: Some(frame),
        })
        .await?
        .into_inner();
    let mut out = Vec::new();
    while let Some(c) = stream.message().await? {
        out.extend_from_slice(&c.data);
    }
    Ok(out)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_frame_range_gives_each_frame_the_local_bits_across_a_restart_and_a_bad_frame_fails_alone(
) {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start(&data, Duration::from_secs(30)).await;
    let addr = coord.addr;
    let text = animated_with_a_bad_frame(32);
    let (spp, batch, tile) = (1024, 4, 16);
    let mut client = coord.client().await;
    let submitted = client
        .submit_job(pb::SubmitJobRequest {
            tile_size: tile,
            output_name: "shot.exr".into(),
            frames: Some(pb::FrameRange {
                first: 1,
                last: 48,
                step: 23,
            }),
            ..submit_request(&text, spp, batch)
        })
        .await
        .expect("submit")
        .into_inner();
    assert_eq!(submitted.frames, 3);
    // 4 tiles × 256 batches per frame.
    assert_eq!(submitted.units, 3 * 4 * 256);
    let job = submitted.job_id;
    let workers: Vec<_> = (0..2)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    // Stopped part-way through the range: each frame's sums and the range itself must come
    // back from the store.
    wait_for("100 units merged", async || {
        (job_status(&mut client, &job).await.units_done >= 100).then_some(())
    })
    .await;
    coord.stop().await;
    let coord = Coordinator::restart_at(addr, &data, Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let back = job_status(&mut client, &job).await;
    let active = [pb::JobState::Queued as i32, pb::JobState::Running as i32];
    assert!(
        back.frames.len() == 3 && back.frames.iter().any(|f| active.contains(&f.state)),
        "the stop came after the range was done, or the range was not restored: {back:?}"
    );
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Failed as i32, "{status:?}");
    assert!(
        status.error.starts_with("1 of 3 frames failed; frame 24 ("),
        "{}",
        status.error
    );
    assert!(status.error.contains("degenerate"), "{}", status.error);
    assert_eq!(status.output_name, "shot.####.exr");
    let frames: Vec<_> = status
        .frames
        .iter()
        .map(|f| (f.frame, f.state, f.output_name.as_str()))
        .collect();
    let (done, failed) = (pb::JobState::Done as i32, pb::JobState::Failed as i32);
    assert_eq!(
        frames,
        [
            (1, done, "shot.0001.exr"),
            (24, failed, "shot.0024.exr"),
            (47, done, "shot.0047.exr")
        ]
    );
    // The frames that could be built are the local renders of those frames, bit for bit.
    for frame in [1, 47] {
        let farm = fetch_frame(&mut client, &job, frame).await.expect("fetch");
        let settings = RenderSettings {
            frame: Some(frame),
            ..job_settings(spp, batch)
        };
        let local = local_exr_with(&text, &settings, ExrChannels::default(), dir.path());
        assert!(
            farm == local,
            "frame {frame}: farm EXR differs from the local render"
        );
        // The frame's own job id gives the same file.
        let own = &status
            .frames
            .iter()
            .find(|f| f.frame == frame)
            .expect("frame")
            .job_id;
        assert!(fetch(&mut client, own).await == farm);
    }
    let e = fetch_frame(&mut client, &job, 24)
        .await
        .expect_err("failed frame");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e}");
    let e = fetch_frame(&mut client, &job, 2)
        .await
        .expect_err("not in the range");
    assert_eq!(e.code(), tonic::Code::NotFound, "{e}");
    assert!(e.message().contains("frames 1-48:23"), "{e}");
    let e = client
        .fetch_result(pb::FetchResultRequest {
            job_id: job.clone(),
            frame: None,
        })
        .await
        .expect_err("a range has no one EXR");
    assert!(e.message().contains("range of 3 frames"), "{e}");
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_frame_range_is_listed_and_cancelled_as_one_job() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let text = animated_with_a_bad_frame(16);
    let mut client = coord.client().await;
    let range = |first, last| pb::SubmitJobRequest {
        frames: Some(pb::FrameRange {
            first,
            last,
            step: 1,
        }),
        ..submit_request(&text, 4, 4)
    };
    let job = submit_job(&mut client, range(1, 5)).await;
    let other = submit(&mut client, &text, 4, 4, 0).await;
    let listed: Vec<_> = list_jobs(&mut client)
        .await
        .into_iter()
        .map(|s| (s.job_id, s.frames.len()))
        .collect();
    assert_eq!(listed, [(job.clone(), 5), (other.clone(), 0)]);
    let one = job_status(&mut client, &job).await;
    assert_eq!(one.state, pb::JobState::Queued as i32);
    let third = one.frames[2].job_id.clone();
    assert_eq!(job_status(&mut client, &third).await.range_job_id, job);
    let cancelled = client
        .cancel_job(pb::CancelJobRequest {
            job_id: job.clone(),
        })
        .await
        .expect("cancel")
        .into_inner();
    assert_eq!(cancelled.state, pb::JobState::Cancelled as i32);
    let after = job_status(&mut client, &job).await;
    assert_eq!(after.state, pb::JobState::Cancelled as i32);
    assert!(after
        .frames
        .iter()
        .all(|f| f.state == pb::JobState::Cancelled as i32));
    assert_eq!(
        job_status(&mut client, &other).await.state,
        pb::JobState::Queued as i32,
        "another job is not part of the range"
    );
    // A range and one frame together, and ranges that are not ranges, are refused by name.
    let mut both = range(1, 2);
    both.settings = Some(pb::RenderSettings {
        frame: Some(3),
        ..both.settings.expect("settings")
    });
    let e = client.submit_job(both).await.expect_err("both");
    assert!(e.message().contains("not both"), "{e}");
    let e = client.submit_job(range(5, 1)).await.expect_err("backwards");
    assert!(e.message().contains("frames 5-1"), "{e}");
    let mut zero = range(1, 2);
    zero.frames = Some(pb::FrameRange {
        first: 1,
        last: 2,
        step: 0,
    });
    let e = client.submit_job(zero).await.expect_err("zero step");
    assert!(e.message().contains("step"), "{e}");
    let e = client
        .submit_job(range(0, 20_000))
        .await
        .expect_err("too many");
    assert!(e.message().contains("20001 frames"), "{e}");
    coord.stop().await;
}
