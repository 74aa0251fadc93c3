//! The worker's pipeline against a real coordinator in this process (port 0): how many units
//! it holds, what it renders, and what it hands back when told to stop.

use std::time::Duration;
use tessera_testkit::wait_for;

use tessera_coordinator::{Config, Spawned};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_client::JobsClient;
use tessera_render::output::{render_metadata, write_exr, ExrChannels};
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{render_frame, RenderSettings};
use tessera_worker::MAX_HELD_UNITS;
use tonic::transport::Channel;

/// The Cornell box at `size`², so that a job takes a second or so.
fn scene_text(size: u32) -> String {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cornell-box.toml"),
    )
    .expect("read cornell-box.toml");
    text.replace("width = 256", &format!("width = {size}"))
        .replace("height = 256", &format!("height = {size}"))
}

/// A coordinator on a port it binds itself, whose data lives in `dir`.
async fn coordinator(dir: &std::path::Path, edit: impl FnOnce(&mut Config)) -> Spawned {
    let mut config = Config::new(dir.join("data"));
    edit(&mut config);
    Spawned::start(config, "127.0.0.1:0").await.expect("bind")
}

async fn client(url: &str) -> JobsClient<Channel> {
    JobsClient::connect(url.to_string()).await.expect("connect")
}

/// Submits `text` at `spp` samples in batches of `batch`, in 16-pixel tiles.
async fn submit(client: &mut JobsClient<Channel>, text: &str, spp: u32, batch: u32) -> String {
    let settings = RenderSettings {
        spp,
        batch,
        ..RenderSettings::default()
    };
    client
        .submit_job(pb::SubmitJobRequest {
            scene_text: text.into(),
            settings: Some(pb::RenderSettings::from(&settings)),
            tile_size: 16,
            ..Default::default()
        })
        .await
        .expect("submit")
        .into_inner()
        .job_id
}

async fn status(client: &mut JobsClient<Channel>, job: &str) -> pb::JobStatus {
    client
        .get_job(pb::GetJobRequest { job_id: job.into() })
        .await
        .expect("status")
        .into_inner()
}

async fn workers(client: &mut JobsClient<Channel>) -> Vec<pb::WorkerInfo> {
    client
        .list_workers(pb::ListWorkersRequest {})
        .await
        .expect("workers")
        .into_inner()
        .workers
}

/// The job's EXR as the coordinator wrote it, and the same job rendered locally.
fn exr_pair(
    out: &std::path::Path,
    job: &str,
    text: &str,
    spp: u32,
    batch: u32,
) -> (Vec<u8>, Vec<u8>) {
    let farm = std::fs::read(out.join(format!("{job}.exr"))).expect("farm EXR");
    let scene = Scene::text(text, Format::Toml, "box.toml", &Limits::default())
        .load()
        .expect("scene");
    let settings = RenderSettings {
        spp,
        batch,
        ..RenderSettings::default()
    };
    let image = render_frame(&scene, &settings, &|_| {}).finalize();
    let path = out.join("local.exr");
    write_exr(
        &path,
        &image,
        ExrChannels::default(),
        &render_metadata(&scene.hash, &settings),
    )
    .expect("write");
    (farm, std::fs::read(path).expect("local EXR"))
}

fn worker_config(url: &str, name: &str) -> tessera_worker::Config {
    let mut config = tessera_worker::Config::new(url);
    config.threads = Some(1);
    config.name = name.into();
    config
}

/// Tiny units (a 16² tile, one sample) render far faster than results are committed: a worker
/// that did not count results waiting to be sent would lease without bound. It holds at most
/// [`MAX_HELD_UNITS`], and what it renders is the local renderer's bits.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_holds_at_most_its_pipeline_and_renders_the_local_bits() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The coordinator's own cap must not hide the worker's behaviour.
    let coord = coordinator(dir.path(), |c| c.max_leases_per_worker = 100_000).await;
    let out = Config::new(dir.path().join("data")).output_dir();
    let text = scene_text(64);
    let mut jobs = client(&coord.url()).await;
    let job = submit(&mut jobs, &text, 64, 1).await;
    let w = tokio::spawn(tessera_worker::run(
        worker_config(&coord.url(), "stock"),
        std::future::pending(),
    ));
    let mut most = 0;
    wait_for("the job to finish", async || {
        let held = workers(&mut jobs).await.iter().map(|w| w.leases).max();
        most = most.max(held.unwrap_or(0));
        (status(&mut jobs, &job).await.state == pb::JobState::Done as i32).then_some(())
    })
    .await;
    assert!(most >= 1, "the sampling never saw a lease");
    assert!(
        most as usize <= MAX_HELD_UNITS,
        "a worker held {most} leases at once, more than its {MAX_HELD_UNITS}"
    );
    w.abort();
    let (farm, local) = exr_pair(&out, &job, &text, 64, 1);
    assert!(
        farm == local,
        "the worker's EXR differs from the local render"
    );
    coord.stop().await.expect("coordinator");
}

/// A worker told to stop finishes or hands back every unit it holds, says goodbye, and returns:
/// its units go back to the queue at once (the lease time here is a minute), and another
/// worker finishes the job with the same bits.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_stopped_worker_hands_back_every_lease_at_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = coordinator(dir.path(), |c| c.lease_timeout = Duration::from_secs(60)).await;
    let out = Config::new(dir.path().join("data")).output_dir();
    let text = scene_text(64);
    let mut jobs = client(&coord.url()).await;
    let job = submit(&mut jobs, &text, 32, 2).await;
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let first = tokio::spawn(tessera_worker::run(
        worker_config(&coord.url(), "leaving"),
        async {
            let _ = stopped.await;
        },
    ));
    wait_for(
        "the first worker to merge units and hold leases",
        async || {
            let s = status(&mut jobs, &job).await;
            (s.units_done >= 4 && s.units_leased > 0 && s.units_done < s.units_total).then_some(())
        },
    )
    .await;
    let _ = stop.send(());
    first.await.expect("joined").expect("a clean stop");
    let s = status(&mut jobs, &job).await;
    assert_eq!(
        s.units_leased, 0,
        "units still leased after the worker stopped: {s:?}"
    );
    let listed = workers(&mut jobs).await;
    assert!(
        listed.iter().all(|w| w.leases == 0 && !w.alive),
        "the worker left without its goodbye: {listed:?}"
    );
    assert!(
        s.units_done < s.units_total,
        "the job finished before the worker stopped"
    );
    let second = tokio::spawn(tessera_worker::run(
        worker_config(&coord.url(), "staying"),
        std::future::pending(),
    ));
    wait_for("the second worker to finish the job", async || {
        (status(&mut jobs, &job).await.state == pb::JobState::Done as i32).then_some(())
    })
    .await;
    second.abort();
    let (farm, local) = exr_pair(&out, &job, &text, 32, 2);
    assert!(farm == local, "the EXR differs from the local render");
    coord.stop().await.expect("coordinator");
}
