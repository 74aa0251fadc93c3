//! A job that asks to be denoised, on a coordinator that does not denoise: its finished frame
//! is lent to a worker that registered as one that denoises, over a `Denoise` stream. Driven
//! by hand here (the filter is a stand-in: these tests check the protocol, what the worker is
//! sent and what is done with its output, not Open Image Denoise, whose farm test runs the
//! real binaries with the real library in crates/cli/tests/denoise.rs).

use tessera_render::output::{read_exr_channel, read_exr_metadata};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::Code;

use crate::common::*;

const SIZE: u32 = 24;

/// A job of the Cornell box at 24² and 2 spp that asks to be denoised at `fast`.
fn denoised_request() -> pb::SubmitJobRequest {
    let mut req = submit_request(&scene_text(SIZE), 2, 2);
    req.channels = Some(pb::OutputChannels {
        denoise: Some(pb::DenoiseOptions {
            quality: "fast".into(),
            ldr: false,
        }),
        ..Default::default()
    });
    req
}

/// A hand-driven worker that registered as one that denoises (it loaded no library: the
/// coordinator cannot tell, and need not).
async fn denoiser(url: &str) -> (WorkersClient<Channel>, String) {
    let mut w = workers_client(url);
    let id = w
        .register(pb::RegisterRequest {
            name: "denoiser".into(),
            cores: 1,
            version: "test".into(),
            image_revision: IMAGE_REVISION,
            denoise_version: 20501,
            ..Default::default()
        })
        .await
        .expect("register")
        .into_inner()
        .worker_id;
    (w, id)
}

/// An open Denoise stream: what the worker sends, and what it is sent.
struct Stream {
    up: mpsc::Sender<pb::DenoiseUp>,
    down: tonic::Streaming<pb::DenoiseDown>,
}

fn up(m: pb::denoise_up::Msg) -> pb::DenoiseUp {
    pb::DenoiseUp { msg: Some(m) }
}

async fn open(
    w: &mut WorkersClient<Channel>,
    id: &str,
    wait_ms: u32,
) -> Result<Stream, tonic::Status> {
    let (tx, rx) = mpsc::channel(16);
    let hello = pb::DenoiseHello {
        worker_id: id.into(),
        wait_ms,
    };
    tx.send(up(pb::denoise_up::Msg::Hello(hello)))
        .await
        .expect("hello");
    let down = w.denoise(ReceiverStream::new(rx)).await?.into_inner();
    Ok(Stream { up: tx, down })
}

/// Opens a stream and takes the frame it is lent: the unit and its input planes.
async fn claim(w: &mut WorkersClient<Channel>, id: &str) -> (Stream, pb::DenoiseUnit, Vec<f32>) {
    let mut s = open(w, id, 10_000).await.expect("open");
    let first = s
        .down
        .message()
        .await
        .expect("unit")
        .expect("a frame was lent");
    let Some(pb::denoise_down::Msg::Unit(unit)) = first.msg else {
        panic!("the stream began with {first:?}");
    };
    let want = (unit.width * unit.height * 9) as usize;
    let mut input = Vec::new();
    while input.len() < want {
        match s
            .down
            .message()
            .await
            .expect("input")
            .expect("more input")
            .msg
        {
            Some(pb::denoise_down::Msg::Input(b)) => input.extend(
                b.chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            ),
            other => panic!("expected input, got {other:?}"),
        }
    }
    assert_eq!(input.len(), want);
    (s, unit, input)
}

async fn send(s: &Stream, values: &[f32]) {
    let bytes: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
    for c in bytes.chunks(100_000) {
        s.up.send(up(pb::denoise_up::Msg::Output(c.to_vec())))
            .await
            .expect("send");
    }
}

async fn end(mut s: Stream) -> Result<Option<pb::DenoiseDown>, tonic::Status> {
    s.down.message().await
}

/// A coordinator that does not denoise, a worker that renders, and a job that asks to be
/// denoised.
struct Farm {
    dir: tempfile::TempDir,
    data: PathBuf,
    c: Coordinator,
    client: Client,
    _renders: tokio::task::JoinHandle<()>,
    job: String,
}

impl Farm {
    async fn with_a_job() -> Self {
        let dir = tempfile::tempdir().expect("tmp");
        let data = dir.path().join("data");
        let c = Coordinator::start(&data, Duration::from_secs(5)).await;
        let mut client = c.client().await;
        let _renders = worker(&c.url(), "renders");
        let job = submit_job(&mut client, denoised_request()).await;
        Self {
            dir,
            data,
            c,
            client,
            _renders,
            job,
        }
    }
}

async fn waiting(client: &mut Client, job: &str) -> String {
    job_status(client, job).await.waiting
}

async fn wait_until_waiting(client: &mut Client, job: &str, words: &str) {
    wait_for(&format!("{job} to say {words:?}"), async || {
        waiting(client, job).await.contains(words).then_some(())
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frame_waits_for_a_denoising_worker_whose_output_is_checked_then_written() {
    let Farm {
        dir,
        data,
        c,
        mut client,
        _renders,
        job,
    } = Farm::with_a_job().await;
    // Rendered, the frame waits, and says for what.
    wait_until_waiting(
        &mut client,
        &job,
        "waiting for a worker that denoises (none is connected",
    )
    .await;
    assert_eq!(
        job_status(&mut client, &job).await.state,
        pb::JobState::Running as i32
    );

    // A worker that did not register as a denoiser is refused, as is an id nobody was given.
    let mut plain = workers_client(&c.url());
    let plain_id = register_as(&mut plain, "plain", "test", IMAGE_REVISION)
        .await
        .expect("reg");
    let e = open(&mut plain, &plain_id, 0).await.err().expect("refused");
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("--denoise"), "{}", e.message());
    let forged = format!(
        "{}.{}",
        plain_id.split('.').next().expect("id"),
        "00".repeat(16)
    );
    let e = open(&mut plain, &forged, 0).await.err().expect("refused");
    assert_ne!(e.code(), Code::Ok);

    // What a denoiser is sent is the finished frame's beauty, albedo and normal, the bits
    // `tessera render` gives them.
    let (mut w, id) = denoiser(&c.url()).await;
    wait_until_waiting(
        &mut client,
        &job,
        "waiting for a denoising worker to take it",
    )
    .await;
    let (s, unit, input) = claim(&mut w, &id).await;
    assert_eq!(
        (unit.width, unit.height, unit.job_id.as_str()),
        (SIZE, SIZE, job.as_str())
    );
    let options = unit.options.clone().expect("options");
    assert_eq!((options.quality.as_str(), options.ldr), ("fast", false));
    let mut settings = job_settings(2, 2);
    settings.aovs.albedo = true;
    settings.aovs.normal = true;
    let scene = Scene::text(
        &scene_text(SIZE),
        Format::Toml,
        "c.toml",
        &Limits::default(),
    )
    .load()
    .expect("scene");
    let image = render_frame(&scene, &settings, &|_| {}).finalize();
    let aov = image.aov.as_ref().expect("aovs");
    let n = (SIZE * SIZE) as usize;
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&input[..3 * n]), bits(image.rgb.as_flattened()));
    assert_eq!(bits(&input[3 * n..6 * n]), bits(aov.albedo.as_flattened()));
    assert_eq!(bits(&input[6 * n..]), bits(aov.normal.as_flattened()));
    assert!(waiting(&mut client, &job)
        .await
        .contains("being denoised by worker \"denoiser\""));

    // Output past the frame's size is refused, and the frame waits again.
    send(&s, &vec![0.5; 9 * n + 1]).await;
    let e = end(s).await.expect_err("refused");
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().contains("more output than"), "{}", e.message());
    // A non-finite value is refused, naming the plane and the pixel.
    let (s, _, _) = claim(&mut w, &id).await;
    let mut nan = vec![0.25f32; 9 * n];
    nan[3 * n + 3 * 7 + 1] = f32::NAN;
    send(&s, &nan).await;
    let e = end(s).await.expect_err("refused");
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(
        e.message().contains("albedo is not finite at pixel 7"),
        "{}",
        e.message()
    );
    // A worker that goes away mid-filter gives the frame back at once.
    let (s, _, _) = claim(&mut w, &id).await;
    drop(s);
    wait_until_waiting(
        &mut client,
        &job,
        "waiting for a denoising worker to take it",
    )
    .await;
    // A filter that fails says so; the frame waits again.
    let (s, _, _) = claim(&mut w, &id).await;
    s.up.send(up(pb::denoise_up::Msg::Failed("out of memory".into())))
        .await
        .expect("failed");
    assert!(end(s).await.expect("closed").is_none());
    wait_until_waiting(
        &mut client,
        &job,
        "the filter failed 1 times; the last: out of memory",
    )
    .await;

    // Good output is written as the denoised layer, beside the beauty `tessera render` gives.
    let (s, _, input) = claim(&mut w, &id).await;
    let output: Vec<f32> = input.iter().map(|x| x * 0.5).collect();
    send(&s, &output).await;
    let outcome = end(s).await.expect("outcome").expect("an outcome");
    assert!(
        matches!(
            outcome.msg,
            Some(pb::denoise_down::Msg::Outcome(pb::DenoiseOutcome {
                written: true
            }))
        ),
        "{outcome:?}"
    );
    let done = wait(&mut client, &job).await;
    assert_eq!(done.state, pb::JobState::Done as i32, "{}", done.error);
    let farm = dir.path().join("farm.exr");
    std::fs::write(&farm, fetch(&mut client, &job).await).expect("write");
    let denoised = read_exr_channel(&farm, "denoised.G").expect("denoised layer");
    let sent: Vec<f32> = (0..n).map(|p| output[3 * p + 1]).collect();
    assert_eq!(bits(&denoised), bits(&sent));
    let local = dir.path().join("local.exr");
    std::fs::write(&local, local_exr(&scene_text(SIZE), 2, 2, dir.path())).expect("local");
    for ch in ["R", "G", "B"] {
        assert_eq!(
            bits(&read_exr_channel(&farm, ch).expect("farm")),
            bits(&read_exr_channel(&local, ch).expect("local")),
            "beauty {ch}"
        );
    }
    let meta = read_exr_metadata(&farm).expect("meta");
    assert!(
        meta.iter().any(|m| m == "denoise=oidn 2.5.1 fast hdr"),
        "{meta:?}"
    );
    // Nothing of the frame is kept once it is written.
    let kept = std::fs::read_dir(data.join("denoise")).map_or(0, |d| d.count());
    assert_eq!(kept, 0);
    c.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_waiting_frame_survives_a_restart_and_can_be_cancelled() {
    let dir = tempfile::tempdir().expect("tmp");
    let data = dir.path().join("data");
    let lease = Duration::from_secs(5);
    let c = Coordinator::start(&data, lease).await;
    let mut client = c.client().await;
    let renders = worker(&c.url(), "renders");
    let kept = submit_job(&mut client, denoised_request()).await;
    let dropped = submit_job(&mut client, denoised_request()).await;
    for job in [&kept, &dropped] {
        wait_until_waiting(&mut client, job, "waiting for a worker that denoises").await;
    }
    renders.abort();
    // After a restart both frames wait again, gathered from the store.
    let c = c.restarted(&data, lease).await;
    let mut client = c.client().await;
    for job in [&kept, &dropped] {
        wait_until_waiting(&mut client, job, "waiting for a worker that denoises").await;
    }
    // One is cancelled while it waits: what was kept of it goes.
    let r = client
        .cancel_job(pb::CancelJobRequest {
            job_id: dropped.clone(),
        })
        .await
        .expect("cancel")
        .into_inner();
    assert_eq!(r.state, pb::JobState::Cancelled as i32);
    let names = || -> Vec<String> {
        std::fs::read_dir(data.join("denoise"))
            .map(|d| {
                d.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default()
    };
    assert_eq!(names(), vec![format!("{kept}.frame")]);
    // The other is lent, and written.
    let (mut w, id) = denoiser(&c.url()).await;
    let (s, unit, input) = claim(&mut w, &id).await;
    assert_eq!(unit.job_id, kept);
    send(&s, &input).await;
    assert!(end(s).await.expect("outcome").is_some());
    assert_eq!(
        wait(&mut client, &kept).await.state,
        pb::JobState::Done as i32
    );
    assert!(names().is_empty(), "{:?}", names());
    // Nothing is left to lend: the stream ends empty when its wait is over.
    let mut s = open(&mut w, &id, 100).await.expect("open");
    assert!(s.down.message().await.expect("end").is_none());
    c.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frame_the_filter_fails_on_three_times_fails_its_job_saying_why() {
    let Farm {
        dir: _dir,
        data,
        c,
        mut client,
        _renders,
        job,
    } = Farm::with_a_job().await;
    wait_until_waiting(&mut client, &job, "waiting for a worker that denoises").await;
    let (mut w, id) = denoiser(&c.url()).await;
    for k in 1..=3 {
        let (s, _, _) = claim(&mut w, &id).await;
        s.up.send(up(pb::denoise_up::Msg::Failed(format!("boom {k}"))))
            .await
            .expect("failed");
        assert!(end(s).await.expect("closed").is_none());
    }
    let done = wait(&mut client, &job).await;
    assert_eq!(done.state, pb::JobState::Failed as i32);
    assert!(
        done.error
            .contains("denoising failed 3 times; the last worker said: boom 3"),
        "{}",
        done.error
    );
    let kept = std::fs::read_dir(data.join("denoise")).map_or(0, |d| d.count());
    assert_eq!(kept, 0);
    c.stop().await;
}

/// A worker gets one stream at a time, and a frame it lost goes to another denoiser first: one
/// worker that takes frames and drops them cannot keep a frame from the others.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_stream_a_worker_and_a_lost_frame_goes_to_another_denoiser_first() {
    let Farm {
        dir: _dir,
        c,
        mut client,
        _renders,
        job,
        ..
    } = Farm::with_a_job().await;
    wait_until_waiting(&mut client, &job, "waiting for a worker that denoises").await;
    let (mut w, id) = denoiser(&c.url()).await;
    // The frame waits, so the first stream claims it at once.
    let held = open(&mut w, &id, 10_000).await.expect("open");
    let e = open(&mut w, &id, 0)
        .await
        .err()
        .expect("a second stream is refused");
    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    // Dropped: the frame is lost by `w` (its stream is closed before the frame waits again).
    drop(held);
    wait_until_waiting(
        &mut client,
        &job,
        "waiting for a denoising worker to take it",
    )
    .await;
    let (mut other, other_id) = denoiser(&c.url()).await;
    // While another denoiser may take it, `w` is offered nothing.
    let mut s = open(&mut w, &id, 300).await.expect("open");
    assert!(
        s.down.message().await.expect("end").is_none(),
        "lent again to the worker that lost it"
    );
    let (s, unit, input) = claim(&mut other, &other_id).await;
    assert_eq!(unit.job_id, job);
    send(&s, &input).await;
    assert!(end(s).await.expect("outcome").is_some());
    assert_eq!(
        wait(&mut client, &job).await.state,
        pb::JobState::Done as i32
    );
    c.stop().await;
}
