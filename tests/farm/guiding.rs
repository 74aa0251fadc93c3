//! A guided job (issue #60): epochs released one after another, each unit's training tree
//! merged into the next guide, which workers fetch by hash. The farm gives `tessera render
//! --guiding`'s bits on workers of different thread counts, across a coordinator restart
//! between epochs; forged training trees are refused and never reach the guide.

use crate::common::*;
use tessera_render::guide::SdTree;
use tessera_render::guiding::{guide_bounds, structure};

/// Guided settings: 32 spp in batches of 4 (epochs [0,1) [1,3) [3,7) [7,15) [15,32), cut into
/// 12 batches), seed 7.
fn guided() -> RenderSettings {
    RenderSettings {
        guiding: true,
        ..job_settings(32, 4)
    }
}

/// Waits for `job` to finish and checks its EXR against `render --guiding`'s.
async fn assert_local_bits(
    client: &mut Client,
    job: &str,
    text: &str,
    settings: &RenderSettings,
    dir: &Path,
) {
    let status = wait(client, job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    let farm = fetch(client, job).await;
    let local = local_exr_with(text, settings, ExrChannels::default(), dir);
    assert!(
        farm == local,
        "farm EXR differs from the local guided render"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_guided_job_gives_the_local_bits_across_a_restart_between_epochs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start(&data, Duration::from_secs(30)).await;
    let addr = coord.addr;
    let text = scene_text(64);
    let settings = guided();
    // This scene's guide does not pay, so guiding turns off from epoch 3: the bits compared
    // cover guided epochs and the unguided ones workers render after.
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let frame = tessera_render::guiding::render_frame_guided(&scene, &settings, &|_| {});
    let guided_epochs: Vec<bool> = frame.epochs.iter().map(|e| e.guided).collect();
    assert_eq!(guided_epochs, [false, true, true, false, false]);
    let mut client = coord.client().await;
    let job = submit_job(&mut client, submit_request_with(&text, &settings)).await;
    let status = job_status(&mut client, &job).await;
    // 16 tiles × 12 batches.
    assert_eq!(status.units_total, 16 * 12);
    assert!(status.settings.as_ref().is_some_and(|s| s.guiding));
    let workers = vec![
        worker_of(&coord.url(), "one-thread", 1, ClientOptions::default()),
        worker_of(&coord.url(), "two-threads", 2, ClientOptions::default()),
    ];
    // Through epoch 2 (batches 0..4 of every tile: three guides trained and stored) and into
    // epoch 3, whose training tree as merged so far the restart must resume from.
    wait_for("epochs 0-2 merged and some of epoch 3", async || {
        (job_status(&mut client, &job).await.units_done >= 16 * 4 + 4).then_some(())
    })
    .await;
    coord.stop().await;
    let coord = Coordinator::restart_at(addr, &data, Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    assert_local_bits(&mut client, &job, &text, &settings, dir.path()).await;
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}

/// A hand-driven worker sends epoch-0 results without a training tree, with one of another
/// structure, with one counting more vertices than the unit has paths for, and with bytes that
/// are no tree: each is refused. Its honest results are merged, no unit of epoch 1 is
/// leased before epoch 0 is all in, epoch 1's units name the guide, which FetchAsset serves,
/// and the image is the local one.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn forged_training_trees_are_refused_and_epochs_wait_for_their_guide() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let url = coord.url();
    let text = scene_text(32);
    let settings = guided();
    let mut client = coord.client().await;
    let job = submit_job(&mut client, submit_request_with(&text, &settings)).await;
    let scene = Scene::text(&text, Format::Toml, "c", &Limits::default())
        .load()
        .expect("scene");
    let bounds = guide_bounds(&scene);

    let mut hand = workers_client(&url);
    let id = register_as(&mut hand, "hand", "0", IMAGE_REVISION)
        .await
        .expect("register");
    // Epoch 0 is one batch of 4 tiles: all of it, and nothing of epoch 1.
    let units = lease_now(&mut hand, &id, 8).await.expect("lease");
    assert_eq!(units.len(), 4, "epoch 1 was leased before its guide");
    assert!(units
        .iter()
        .all(|u| u.sample_end == 1 && u.guide_sha256.is_empty()));
    let honest = |u: &pb::WorkUnit| honest_guided(&scene, &settings, u, None);
    let send = |u: &pb::WorkUnit, result: pb::TileResult| pb::SubmitResultRequest {
        worker_id: id.clone(),
        lease_id: u.lease_id.clone(),
        job_id: u.job_id.clone(),
        tile_index: u.tile_index,
        batch_index: u.batch_index,
        result: Some(result),
    };
    let a = &units[0];
    let mut none = honest(a);
    none.guide_train.clear();
    let mut other = structure(bounds, 0, None);
    other.record(glam::Vec3A::ZERO, glam::Vec3A::Z, 1.0);
    other.freeze();
    let mut shaped = honest(a);
    shaped.guide_train = other.refined(0, 0.01).encode();
    let mut many = structure(bounds, 0, None);
    for _ in 0..=16 * 16 * 16 {
        many.record(glam::Vec3A::ZERO, glam::Vec3A::Z, 1.0);
    }
    let mut counted = honest(a);
    counted.guide_train = many.encode();
    let mut garbage = honest(a);
    garbage.guide_train = vec![7; 40];
    let cases = [
        ("no training tree", none, "no training tree"),
        ("another structure", shaped, "structure"),
        ("too many vertices", counted, "vertices"),
        ("bytes that are no tree", garbage, "guide_train"),
    ];
    for (what, result, says) in cases {
        let e = hand.submit_result(send(a, result)).await.expect_err(what);
        assert_eq!(e.code(), tonic::Code::InvalidArgument, "{what}: {e:?}");
        assert!(e.message().contains(says), "{what}: {}", e.message());
    }
    for u in &units {
        let ok = hand
            .submit_result(send(u, honest(u)))
            .await
            .expect("honest");
        assert_eq!(ok.into_inner().outcome, pb::ResultOutcome::Merged as i32);
    }
    // Epoch 1 is released, naming the guide epoch 0 trained; the coordinator serves it.
    let next = lease_now(&mut hand, &id, 1).await.expect("lease");
    let hash = next
        .first()
        .map(|u| u.guide_sha256.clone())
        .unwrap_or_default();
    assert_eq!(hash.len(), 64, "{next:?}");
    let bytes = fetch_asset(&mut hand, &id, &hash).await.expect("fetch");
    assert_eq!(tessera_render::scene::assets::sha256_hex(&bytes), hash);
    SdTree::decode(&bytes).expect("a guide");
    // The hand-driven worker leaves; a real one finishes the job to the local bits.
    hand.release_leases(pb::ReleaseLeasesRequest {
        worker_id: id.clone(),
        lease_ids: next.iter().map(|u| u.lease_id.clone()).collect(),
        goodbye: true,
        cannot_render: String::new(),
    })
    .await
    .expect("release");
    let w = worker(&url, "w");
    assert_local_bits(&mut client, &job, &text, &settings, dir.path()).await;
    w.abort();
    coord.stop().await;
}
