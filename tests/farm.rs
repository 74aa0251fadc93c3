//! End-to-end farm tests: a coordinator and workers in-process on loopback (port 0), driven
//! through the real gRPC API. The farm's EXR must be bit-identical to the local renderer's.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tessera_coordinator::store::{JobRecord, Op, Store};
use tessera_coordinator::{serve, Config};
use tessera_proto::client::{endpoint, Bearer, ClientOptions, ClientTls};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_client::JobsClient;
use tessera_proto::v1::workers_client::WorkersClient;
use tessera_proto::Secret;
use tessera_render::output::{render_metadata, write_exr, ExrChannels};
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{render_frame, RenderSettings, IMAGE_REVISION};
use tessera_render::{render_tile, PixelRect};
use tokio::sync::oneshot;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;

/// A `Jobs` client with a (possibly empty) token attached.
type Client = JobsClient<InterceptedService<Channel, Bearer>>;

/// Connects a `Jobs` client to `url` with `options`.
async fn client_with(url: &str, options: &ClientOptions) -> Client {
    let channel = endpoint(url, options)
        .expect("endpoint")
        .connect()
        .await
        .expect("connect");
    JobsClient::with_interceptor(channel, Bearer::new(options))
}

/// The Cornell box shrunk to `size`² so a farm run takes a second or two.
fn scene_text(size: u32) -> String {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.toml"),
    )
    .expect("read cornell-box.toml");
    text.replace("width = 256", &format!("width = {size}"))
        .replace("height = 256", &format!("height = {size}"))
}

/// A coordinator on an ephemeral port, stopped when dropped.
struct Coordinator {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<()>,
    out: PathBuf,
}

impl Coordinator {
    async fn start(data: &Path, lease: Duration) -> Self {
        Self::start_with(data, lease, |_| {}).await
    }

    async fn start_with(data: &Path, lease: Duration, edit: impl FnOnce(&mut Config)) -> Self {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .expect("bind");
        let addr = listener.local_addr().expect("addr");
        let mut config = Config::new(data);
        config.lease_timeout = lease;
        edit(&mut config);
        let out = config.output_dir();
        let (tx, rx) = oneshot::channel::<()>();
        let task = tokio::spawn(async move {
            serve(config, listener, async {
                let _ = rx.await;
            })
            .await
            .expect("coordinator");
        });
        Self {
            addr,
            stop: Some(tx),
            task,
            out,
        }
    }

    fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    async fn client(&self) -> Client {
        client_with(&self.url(), &ClientOptions::default()).await
    }

    async fn stop(mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        let _ = (&mut self.task).await;
    }
}

/// A worker task; dropping the handle (abort) kills it without any goodbye.
fn worker(url: &str, name: &str) -> tokio::task::JoinHandle<()> {
    worker_with(url, name, ClientOptions::default())
}

fn worker_with(url: &str, name: &str, client: ClientOptions) -> tokio::task::JoinHandle<()> {
    let mut config = tessera_worker::Config::new(url);
    config.threads = Some(1);
    config.name = name.into();
    config.client = client;
    tokio::spawn(async move {
        tessera_worker::run(config, std::future::pending())
            .await
            .expect("worker");
    })
}

async fn submit(client: &mut Client, text: &str, spp: u32, batch: u32, priority: i32) -> String {
    client
        .submit_job(pb::SubmitJobRequest {
            scene_text: text.into(),
            scene_format: pb::SceneFormat::Toml as i32,
            scene_name: "cornell.toml".into(),
            settings: Some(pb::RenderSettings {
                spp,
                seed: 7,
                batch,
                strategy: pb::Strategy::Mis as i32,
            }),
            tile_size: 16,
            output_name: String::new(),
            priority,
            channels: None,
        })
        .await
        .expect("submit")
        .into_inner()
        .job_id
}

/// A job's current status.
async fn job_status(client: &mut Client, job: &str) -> pb::JobStatus {
    client
        .get_job(pb::GetJobRequest { job_id: job.into() })
        .await
        .expect("status")
        .into_inner()
}

/// Follows WatchJob to the end and returns the final status.
async fn wait(client: &mut Client, job: &str) -> pb::JobStatus {
    let mut stream = client
        .watch_job(pb::WatchJobRequest {
            job_id: job.into(),
            interval_ms: 200,
        })
        .await
        .expect("watch")
        .into_inner();
    let mut last = None;
    let fut = async {
        while let Some(s) = stream.message().await.expect("stream") {
            last = Some(s);
        }
    };
    tokio::time::timeout(Duration::from_secs(120), fut)
        .await
        .expect("job did not finish within 120 s");
    last.expect("at least one status")
}

async fn fetch(client: &mut Client, job: &str) -> Vec<u8> {
    let mut stream = client
        .fetch_result(pb::FetchResultRequest { job_id: job.into() })
        .await
        .expect("fetch")
        .into_inner();
    let mut out = Vec::new();
    while let Some(c) = stream.message().await.expect("chunk") {
        out.extend_from_slice(&c.data);
    }
    out
}

/// The bytes `tessera render` writes for the same job.
fn local_exr(text: &str, spp: u32, batch: u32, dir: &Path) -> Vec<u8> {
    let scene =
        Scene::from_str(text, Format::Toml, "cornell.toml", &Limits::default()).expect("scene");
    let settings = job_settings(spp, batch);
    let image = render_frame(&scene, &settings, &|_| {}).finalize();
    let path = dir.join("local.exr");
    write_exr(
        &path,
        &image,
        ExrChannels::default(),
        &render_metadata(&scene.hash, &settings),
    )
    .expect("write");
    std::fs::read(path).expect("read")
}

/// The render settings `submit` gives a job of `spp` samples in batches of `batch`.
fn job_settings(spp: u32, batch: u32) -> RenderSettings {
    RenderSettings {
        seed: 7,
        spp,
        batch,
        ..RenderSettings::default()
    }
}

/// A `Workers` client for driving the protocol by hand.
fn workers_client(url: &str) -> WorkersClient<Channel> {
    WorkersClient::new(
        endpoint(url, &ClientOptions::default())
            .expect("endpoint")
            .connect_lazy(),
    )
}

/// Registers a hand-driven worker named `name` rendering image revision `revision`; returns
/// its id.
async fn register_as(
    workers: &mut WorkersClient<Channel>,
    name: &str,
    version: &str,
    revision: u32,
) -> Result<String, tonic::Status> {
    let r = workers
        .register(pb::RegisterRequest {
            name: name.into(),
            cores: 1,
            version: version.into(),
            image_revision: revision,
        })
        .await?;
    Ok(r.into_inner().worker_id)
}

/// Leases up to `max` units for worker `id` without waiting for work.
async fn lease_now(
    workers: &mut WorkersClient<Channel>,
    id: &str,
    max: u32,
) -> Result<Vec<pb::WorkUnit>, tonic::Status> {
    let r = workers
        .lease(pb::LeaseRequest {
            worker_id: id.into(),
            max_units: max,
            wait_ms: 0,
        })
        .await?;
    Ok(r.into_inner().units)
}

/// The result an honest worker sends for `u`.
fn honest_result(scene: &Scene, settings: &RenderSettings, u: &pb::WorkUnit) -> pb::TileResult {
    let rect = PixelRect::from(u.rect.expect("rect"));
    pb::TileResult::from(&render_tile(
        scene,
        settings,
        rect,
        u.sample_start..u.sample_end,
    ))
}

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

    let listed = client
        .list_workers(pb::ListWorkersRequest {})
        .await
        .expect("workers")
        .into_inner()
        .workers;
    assert_eq!(listed.len(), 3);
    assert_eq!(listed.iter().map(|w| w.units_done).sum::<u64>(), 27);
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_killed_mid_job_does_not_break_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_millis(800)).await;
    let text = scene_text(48);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 64, 4, 0).await;
    let doomed = worker(&coord.url(), "doomed");
    // Let it merge some units and hold some leases, then kill it without a goodbye.
    loop {
        let s = job_status(&mut client, &job).await;
        if s.units_done >= 10 {
            assert!(
                s.units_done < s.units_total,
                "the job finished too fast to test"
            );
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    doomed.abort();
    let _ = doomed.await;
    let held = job_status(&mut client, &job).await;
    let survivor = worker(&coord.url(), "survivor");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert!(
        held.units_leased > 0,
        "the killed worker held no lease, so nothing was tested"
    );
    let farm = fetch(&mut client, &job).await;
    assert!(farm == local_exr(&text, 64, 4, dir.path()));
    survivor.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn priorities_order_jobs_and_cancel_frees_units() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let text = scene_text(32);
    let mut client = coord.client().await;
    // Submitted before any worker exists, so the scheduler alone decides the order.
    let low = submit(&mut client, &text, 32, 4, 0).await;
    let doomed = submit(&mut client, &text, 4096, 4, 5).await;
    let high = submit(&mut client, &text, 32, 4, 10).await;
    let jobs = client
        .list_jobs(pb::ListJobsRequest {})
        .await
        .expect("list")
        .into_inner()
        .jobs;
    let order: Vec<&str> = jobs.iter().map(|j| j.job_id.as_str()).collect();
    assert_eq!(order, [high.as_str(), doomed.as_str(), low.as_str()]);
    assert!(jobs.iter().all(|j| j.state == pb::JobState::Queued as i32));

    let workers: Vec<_> = (0..2)
        .map(|i| worker(&coord.url(), &format!("w{i}")))
        .collect();
    let high_status = wait(&mut client, &high).await;
    assert_eq!(high_status.state, pb::JobState::Done as i32);
    // The big job runs next; cancel it while it holds leases.
    loop {
        let s = job_status(&mut client, &doomed).await;
        if s.units_done > 0 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let cancelled = client
        .cancel_job(pb::CancelJobRequest {
            job_id: doomed.clone(),
        })
        .await
        .expect("cancel")
        .into_inner();
    assert_eq!(cancelled.state, pb::JobState::Cancelled as i32);
    let low_status = wait(&mut client, &low).await;
    assert_eq!(low_status.state, pb::JobState::Done as i32);
    assert!(high_status.finished_unix_ms <= low_status.finished_unix_ms);
    let d = job_status(&mut client, &doomed).await;
    assert_eq!(d.state, pb::JobState::Cancelled as i32);
    assert_eq!(d.units_leased, 0, "cancel left leases behind");
    assert!(d.units_done < d.units_total);
    let err = client
        .fetch_result(pb::FetchResultRequest {
            job_id: doomed.clone(),
        })
        .await
        .expect_err("a cancelled job has no result");
    assert_eq!(err.code(), tonic::Code::FailedPrecondition);
    assert!(!coord.out.join(format!("{doomed}.exr")).exists());
    assert!(fetch(&mut client, &low).await == local_exr(&text, 32, 4, dir.path()));
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_submissions_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let bad_scene = scene_text(32).replace("fov = 39.3077", "fov = 390");
    let mut req = pb::SubmitJobRequest {
        scene_text: bad_scene,
        scene_format: pb::SceneFormat::Toml as i32,
        scene_name: "box.toml".into(),
        settings: Some(pb::RenderSettings {
            spp: 4,
            ..Default::default()
        }),
        ..Default::default()
    };
    let err = client.submit_job(req.clone()).await.expect_err("bad fov");
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    assert!(
        err.message().starts_with("box.toml:10:7: camera.fov"),
        "{}",
        err.message()
    );
    req.scene_text = scene_text(32);
    req.output_name = "../escape.exr".into();
    let err = client.submit_job(req.clone()).await.expect_err("bad name");
    assert!(err.message().contains("output name"), "{}", err.message());
    req.output_name = String::new();
    req.settings = Some(pb::RenderSettings::default());
    let err = client.submit_job(req.clone()).await.expect_err("spp 0");
    assert!(err.message().contains("spp 0"), "{}", err.message());
    let err = client
        .get_job(pb::GetJobRequest {
            job_id: "job-999999".into(),
        })
        .await
        .expect_err("unknown job");
    assert_eq!(err.code(), tonic::Code::NotFound);
    assert!(client
        .list_jobs(pb::ListJobsRequest {})
        .await
        .expect("list")
        .into_inner()
        .jobs
        .is_empty());
    coord.stop().await;

    // Limits: units per job, active jobs, scene bytes.
    let coord = Coordinator::start_with(&dir.path().join("limits"), Duration::from_secs(30), |c| {
        c.max_units_per_job = 100;
        c.max_active_jobs = 1;
        c.limits.max_bytes = 4096;
    })
    .await;
    let mut client = coord.client().await;
    let small = "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 40\n[film]\nwidth = 8\nheight = 8\n";
    let mut req = pb::SubmitJobRequest {
        scene_text: small.into(),
        settings: Some(pb::RenderSettings {
            spp: 1024,
            batch: 1,
            ..Default::default()
        }),
        ..Default::default()
    };
    let err = client
        .submit_job(req.clone())
        .await
        .expect_err("too many units");
    assert_eq!(err.code(), tonic::Code::ResourceExhausted);
    assert!(
        err.message().contains("1024 work units"),
        "{}",
        err.message()
    );
    req.settings = Some(pb::RenderSettings {
        spp: 4,
        ..Default::default()
    });
    client.submit_job(req.clone()).await.expect("first job");
    let err = client
        .submit_job(req.clone())
        .await
        .expect_err("second job");
    assert_eq!(err.code(), tonic::Code::ResourceExhausted);
    req.scene_text = format!("{small}# {}\n", "x".repeat(5000));
    let err = client.submit_job(req).await.expect_err("big scene");
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    assert!(
        err.message().contains("above the limit of 4096"),
        "{}",
        err.message()
    );
    coord.stop().await;
}

/// With one worker and one client using `options`, renders `text` at 4 spp and checks the
/// bits against a local render.
async fn render_one_job(url: &str, options: &ClientOptions, text: &str, dir: &Path) {
    let w = worker_with(url, "one", options.clone());
    let mut client = client_with(url, options).await;
    let job = submit(&mut client, text, 4, 2, 0).await;
    assert_eq!(
        wait(&mut client, &job).await.state,
        pb::JobState::Done as i32
    );
    assert!(fetch(&mut client, &job).await == local_exr(text, 4, 2, dir));
    w.abort();
}

/// A coordinator that requires a token refuses calls without it or with a wrong one, on both
/// services, and works with the right one.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_token_is_required_on_every_service() {
    let dir = tempfile::tempdir().expect("tempdir");
    let token = Secret::new("farm-token-0123456789abcdef");
    let t = token.clone();
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.token = Some(t)
    })
    .await;
    let url = coord.url();
    let good = ClientOptions {
        token: Some(token.clone()),
        tls: None,
    };
    let wrong = ClientOptions {
        token: Some(Secret::new("farm-token-0123456789abcdeX")),
        tls: None,
    };
    let text = scene_text(16);
    for options in [ClientOptions::default(), wrong.clone()] {
        let mut client = client_with(&url, &options).await;
        let req = pb::SubmitJobRequest {
            scene_text: text.clone(),
            settings: Some(pb::RenderSettings {
                spp: 1,
                ..Default::default()
            }),
            ..Default::default()
        };
        let e = client
            .submit_job(req)
            .await
            .expect_err("submit without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated, "{e:?}");
        let e = client
            .fetch_result(pb::FetchResultRequest {
                job_id: "job-000001".into(),
            })
            .await
            .expect_err("fetch without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = client
            .list_jobs(pb::ListJobsRequest {})
            .await
            .expect_err("list without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let channel = endpoint(&url, &options).expect("ep").connect_lazy();
        let mut workers = WorkersClient::with_interceptor(channel, Bearer::new(&options));
        let e = workers
            .lease(pb::LeaseRequest {
                worker_id: "w1-1".into(),
                max_units: 1,
                wait_ms: 0,
            })
            .await
            .expect_err("lease without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
        let e = workers
            .register(pb::RegisterRequest::default())
            .await
            .expect_err("register without the token");
        assert_eq!(e.code(), tonic::Code::Unauthenticated);
    }
    // A worker with the wrong token stops with an error instead of retrying forever.
    let mut config = tessera_worker::Config::new(url.clone());
    config.client = wrong;
    let err = tessera_worker::run(config, std::future::pending())
        .await
        .expect_err("refused");
    assert!(err.to_string().contains("wrong token"), "{err}");

    render_one_job(&url, &good, &text, dir.path()).await;
    coord.stop().await;
}

/// A job runs end to end over TLS (server certificate from a test CA), with a token too.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_job_completes_over_tls() {
    let ca_key = rcgen::KeyPair::generate().expect("key");
    let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).expect("params");
    ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    let ca = ca_params.self_signed(&ca_key).expect("ca");
    let issuer = rcgen::Issuer::new(ca_params, ca_key);
    let key = rcgen::KeyPair::generate().expect("key");
    let params = rcgen::CertificateParams::new(vec!["localhost".to_string()]).expect("params");
    let cert = params.signed_by(&key, &issuer).expect("cert");

    let dir = tempfile::tempdir().expect("tempdir");
    let token = Secret::new("tls-token-0123456789abcdef");
    let (t, cert_pem, key_pem) = (token.clone(), cert.pem(), key.serialize_pem());
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.token = Some(t);
        c.tls = Some(tessera_coordinator::ServerTls {
            cert_pem: cert_pem.into_bytes(),
            key_pem: Secret::new(key_pem),
            client_ca_pem: None,
        });
    })
    .await;
    let url = format!("https://localhost:{}", coord.addr.port());
    let options = ClientOptions {
        token: Some(token),
        tls: Some(ClientTls {
            ca_pem: Some(ca.pem().into_bytes()),
            identity: None,
            domain: None,
        }),
    };
    // Plain HTTP to a TLS port fails rather than leaking anything.
    let plain = format!("http://127.0.0.1:{}", coord.addr.port());
    let channel = endpoint(&plain, &ClientOptions::default())
        .expect("ep")
        .connect_lazy();
    let mut raw = JobsClient::new(channel);
    assert!(raw.list_jobs(pb::ListJobsRequest {}).await.is_err());

    render_one_job(&url, &options, &scene_text(16), dir.path()).await;
    coord.stop().await;
}

/// A forged worker sends NaN sums, wrong dimensions, a lease issued for another unit, a lease
/// from before a restart, and a duplicate. Each is refused or deduplicated, the worker is
/// quarantined, and the image is still bit-identical.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn forged_results_are_refused_and_leave_the_image_unaffected() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let url = coord.url();
    let text = scene_text(32);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 8, 4, 0).await;
    let scene = Scene::from_str(&text, Format::Toml, "c", &Limits::default()).expect("scene");
    let settings = job_settings(8, 4);

    let mut forger = workers_client(&url);
    let id = register_as(&mut forger, "forger", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut forger, &id, 2).await.expect("lease");
    assert_eq!(units.len(), 2);
    let honest = |u: &pb::WorkUnit| honest_result(&scene, &settings, u);
    let send = |lease: &str, u: &pb::WorkUnit, result: pb::TileResult| pb::SubmitResultRequest {
        worker_id: id.clone(),
        lease_id: lease.into(),
        job_id: u.job_id.clone(),
        tile_index: u.tile_index,
        batch_index: u.batch_index,
        result: Some(result),
    };
    let (a, b) = (&units[0], &units[1]);
    let mut nan = honest(a);
    nan.sum[5] = f64::NAN;
    let mut short = honest(a);
    short.sum.truncate(9);
    let mut wrong_rect = honest(a);
    wrong_rect.rect = b.rect;
    let cases = [
        (
            "NaN sums",
            send(&a.lease_id, a, nan),
            tonic::Code::InvalidArgument,
        ),
        (
            "wrong dimensions",
            send(&a.lease_id, a, short),
            tonic::Code::InvalidArgument,
        ),
        (
            "another tile's rect",
            send(&a.lease_id, a, wrong_rect),
            tonic::Code::InvalidArgument,
        ),
        (
            "lease of another unit",
            send(&b.lease_id, a, honest(a)),
            tonic::Code::FailedPrecondition,
        ),
        (
            "stale lease",
            send("L0-1", a, honest(a)),
            tonic::Code::FailedPrecondition,
        ),
    ];
    for (what, req, code) in cases {
        let e = forger.submit_result(req).await.expect_err(what);
        assert_eq!(e.code(), code, "{what}: {e:?}");
    }
    // The honest result is merged once; its copy is a duplicate.
    let ok = forger
        .submit_result(send(&b.lease_id, b, honest(b)))
        .await
        .expect("honest")
        .into_inner();
    assert_eq!(ok.outcome, pb::ResultOutcome::Merged as i32);
    let dup = forger
        .submit_result(send(&b.lease_id, b, honest(b)))
        .await
        .expect("duplicate")
        .into_inner();
    assert_eq!(dup.outcome, pb::ResultOutcome::Duplicate as i32);
    // Three invalid results so far (a foreign or stale lease is not counted: it happens
    // honestly after restarts); two more reach the quarantine limit (5).
    for _ in 0..2 {
        let mut nan = honest(a);
        nan.sum_sq[0] = f64::INFINITY;
        let _ = forger.submit_result(send(&a.lease_id, a, nan)).await;
    }
    let e = lease_now(&mut forger, &id, 1)
        .await
        .expect_err("quarantined");
    assert_eq!(e.code(), tonic::Code::PermissionDenied);
    let listed = client
        .list_workers(pb::ListWorkersRequest {})
        .await
        .expect("workers")
        .into_inner()
        .workers;
    let f = listed.iter().find(|w| w.name == "forger").expect("listed");
    assert!(f.quarantined);
    assert_eq!(f.bad_results, 5);

    let w = worker(&url, "honest");
    let status = wait(&mut client, &job).await;
    assert_eq!(status.state, pb::JobState::Done as i32);
    assert!(fetch(&mut client, &job).await == local_exr(&text, 8, 4, dir.path()));
    w.abort();
    coord.stop().await;
}

/// Results of two renderer revisions never meet in one job: a worker of another image revision
/// is refused at registration (and stops, since retrying cannot help), and a job that a
/// coordinator of another revision had started is failed with the reason after an upgrade,
/// while one it had not started is simply rendered by the new revision.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn renderer_revisions_are_never_mixed() {
    let data = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(data.path(), Duration::from_secs(30)).await;
    let url = coord.url();
    let mut workers = workers_client(&url);
    let e = register_as(&mut workers, "old-build", "0.0.9", IMAGE_REVISION + 1)
        .await
        .expect_err("another revision");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    let why = e.message();
    assert!(
        why.contains("old-build")
            && why.contains(&format!("image revision {}", IMAGE_REVISION + 1))
            && why.contains(&format!("revision {IMAGE_REVISION}")),
        "{why}"
    );

    // One job gets a merged unit, the other none; then the store is made to say that another
    // revision accepted both, as after an upgrade.
    let text = scene_text(16);
    let mut client = coord.client().await;
    let started = submit(&mut client, &text, 8, 4, 1).await;
    let untouched = submit(&mut client, &text, 8, 4, 0).await;
    let id = register_as(&mut workers, "one-unit", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let unit = lease_now(&mut workers, &id, 1)
        .await
        .expect("lease")
        .remove(0);
    assert_eq!(unit.job_id, started, "the higher priority first");
    let scene = Scene::from_str(&text, Format::Toml, "c", &Limits::default()).expect("scene");
    let settings = job_settings(8, 4);
    let outcome = workers
        .submit_result(pb::SubmitResultRequest {
            worker_id: id,
            lease_id: unit.lease_id.clone(),
            job_id: unit.job_id.clone(),
            tile_index: unit.tile_index,
            batch_index: unit.batch_index,
            result: Some(honest_result(&scene, &settings, &unit)),
        })
        .await
        .expect("submit")
        .into_inner()
        .outcome;
    assert_eq!(outcome, pb::ResultOutcome::Merged as i32);
    coord.stop().await;
    {
        let store = Store::open(data.path()).expect("store");
        let ops: Vec<Op> = store
            .load()
            .expect("load")
            .into_iter()
            .map(|j| {
                assert_eq!(j.record.image_revision, IMAGE_REVISION);
                Op::PutJob(JobRecord {
                    image_revision: IMAGE_REVISION + 1,
                    ..j.record
                })
            })
            .collect();
        assert_eq!(ops.len(), 2);
        store.apply(&ops).expect("rewrite");
    }

    let coord = Coordinator::start(data.path(), Duration::from_secs(30)).await;
    let url = coord.url();
    let mut client = coord.client().await;
    let s = job_status(&mut client, &started).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(
        s.error
            .contains(&format!("image revision {}", IMAGE_REVISION + 1))
            && s.error.contains("resubmit"),
        "{}",
        s.error
    );
    let w = worker(&url, "new-build");
    let s = wait(&mut client, &untouched).await;
    assert_eq!(s.state, pb::JobState::Done as i32, "{}", s.error);
    let dir = tempfile::tempdir().expect("tempdir");
    assert_eq!(
        fetch(&mut client, &untouched).await,
        local_exr(&text, 8, 4, dir.path()),
        "the job the old revision never touched renders as a fresh one"
    );
    w.abort();
    coord.stop().await;
}

/// A submission with an output name.
async fn submit_named(
    client: &mut Client,
    text: &str,
    name: &str,
) -> Result<String, tonic::Status> {
    client
        .submit_job(pb::SubmitJobRequest {
            scene_text: text.into(),
            scene_format: pb::SceneFormat::Toml as i32,
            scene_name: "cornell.toml".into(),
            settings: Some(pb::RenderSettings {
                spp: 2,
                seed: 7,
                batch: 2,
                strategy: pb::Strategy::Mis as i32,
            }),
            tile_size: 16,
            output_name: name.into(),
            priority: 0,
            channels: None,
        })
        .await
        .map(|r| r.into_inner().job_id)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_stock_worker_holds_no_more_than_its_pipeline() {
    // Tiny units (a 16² tile, one sample) render far faster than results are committed: a
    // worker that did not count results waiting to be sent would lease without bound.
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        // The coordinator's own cap must not hide the worker's behaviour.
        c.max_leases_per_worker = 100_000;
    })
    .await;
    let text = scene_text(64);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 64, 1, 0).await;
    let w = worker(&coord.url(), "stock");
    let mut most = 0;
    loop {
        let listed = client
            .list_workers(pb::ListWorkersRequest {})
            .await
            .expect("workers")
            .into_inner()
            .workers;
        most = most.max(listed.iter().map(|w| w.leases).max().unwrap_or(0));
        let s = job_status(&mut client, &job).await;
        if s.state == pb::JobState::Done as i32 {
            break;
        }
        assert!(
            s.state == pb::JobState::Running as i32 || s.state == pb::JobState::Queued as i32,
            "{s:?}"
        );
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    assert!(most >= 1, "the sampling never saw a lease");
    assert!(most <= 3, "a stock worker held {most} leases at once");
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn ids_and_leases_are_bound_to_the_worker_that_got_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let url = coord.url();
    let text = scene_text(16);
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 4, 2, 0).await;
    let mut workers = workers_client(&url);
    let honest = register_as(&mut workers, "honest", "0", IMAGE_REVISION)
        .await
        .expect("register");
    let thief = register_as(&mut workers, "thief", "0", IMAGE_REVISION)
        .await
        .expect("register");
    // What anyone can see of the honest worker: its public id, without the secret.
    let listed = client
        .list_workers(pb::ListWorkersRequest {})
        .await
        .expect("workers")
        .into_inner()
        .workers;
    let public = listed
        .iter()
        .find(|w| w.name == "honest")
        .expect("listed")
        .worker_id
        .clone();
    assert!(honest.starts_with(&format!("{public}.")) && honest.len() > public.len() + 16);
    assert!(
        listed.iter().all(|w| !w.worker_id.contains('.')),
        "secrets listed"
    );
    let unit = lease_now(&mut workers, &honest, 1)
        .await
        .expect("lease")
        .remove(0);
    let scene = Scene::from_str(&text, Format::Toml, "c", &Limits::default()).expect("scene");
    let result = honest_result(&scene, &job_settings(4, 2), &unit);
    let send = |who: &str, r: pb::TileResult| pb::SubmitResultRequest {
        worker_id: who.into(),
        lease_id: unit.lease_id.clone(),
        job_id: unit.job_id.clone(),
        tile_index: unit.tile_index,
        batch_index: unit.batch_index,
        result: Some(r),
    };
    // The thief quotes the honest worker's lease under its own id: refused.
    let e = workers
        .submit_result(send(&thief, result.clone()))
        .await
        .expect_err("another worker's lease");
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    // The thief quotes the honest worker's public id (with or without a made-up secret):
    // unknown. Five empty results that way would once have quarantined the honest worker.
    for forged in [
        public.clone(),
        format!("{public}.00000000000000000000000000000000"),
    ] {
        for _ in 0..5 {
            let e = workers
                .submit_result(send(&forged, pb::TileResult::default()))
                .await
                .expect_err("forged id");
            assert_eq!(e.code(), tonic::Code::NotFound, "{e:?}");
        }
        let e = workers
            .heartbeat(pb::HeartbeatRequest {
                worker_id: forged.clone(),
                lease_ids: vec![unit.lease_id.clone()],
            })
            .await
            .expect_err("forged id");
        assert_eq!(e.code(), tonic::Code::NotFound);
    }
    let listed = client
        .list_workers(pb::ListWorkersRequest {})
        .await
        .expect("workers")
        .into_inner()
        .workers;
    let h = listed.iter().find(|w| w.name == "honest").expect("listed");
    assert_eq!((h.bad_results, h.quarantined), (0, false));
    // The honest worker's result still merges.
    let outcome = workers
        .submit_result(send(&honest, result))
        .await
        .expect("merged")
        .into_inner()
        .outcome;
    assert_eq!(outcome, pb::ResultOutcome::Merged as i32);
    assert_eq!(job_status(&mut client, &job).await.units_done, 1);
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_unit_the_workers_cannot_render_fails_the_job_once_with_the_reason() {
    // The coordinator accepts wider images than the worker (its default limit is 16384).
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.limits.max_resolution = 20_000;
    })
    .await;
    let text = scene_text(16)
        .replace("width = 16", "width = 20000")
        .replace("height = 16", "height = 1");
    let mut client = coord.client().await;
    let job = submit(&mut client, &text, 1, 1, 0).await;
    let w = worker(&coord.url(), "small");
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(s.error.contains("cannot render"), "{}", s.error);
    assert!(
        s.error.contains("20000 is above the limit of 16384"),
        "{}",
        s.error
    );
    assert!(s.error.contains("small"), "{}", s.error);
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn output_names_are_never_taken_twice_nor_files_overwritten() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start(&dir.path().join("data"), Duration::from_secs(30)).await;
    let text = scene_text(16);
    let mut client = coord.client().await;
    // A later job's default name cannot be taken in advance.
    let e = submit_named(&mut client, &text, "job-000004.exr")
        .await
        .expect_err("a default name");
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{e:?}");
    let w = worker(&coord.url(), "w");
    let first = submit_named(&mut client, &text, "shot.exr")
        .await
        .expect("named");
    assert_eq!(
        wait(&mut client, &first).await.state,
        pb::JobState::Done as i32
    );
    let before = fetch(&mut client, &first).await;
    // The name stays with the finished job: fetch keeps returning its image.
    let e = submit_named(&mut client, &scene_text(24), "shot.exr")
        .await
        .expect_err("a finished job's name");
    assert_eq!(e.code(), tonic::Code::AlreadyExists, "{e:?}");
    assert_eq!(fetch(&mut client, &first).await, before);
    // A file someone put in the output directory is theirs.
    std::fs::write(coord.out.join("mine.exr"), b"not ours").expect("write");
    let e = submit_named(&mut client, &text, "mine.exr")
        .await
        .expect_err("a file in the way");
    assert_eq!(e.code(), tonic::Code::AlreadyExists, "{e:?}");
    // Default names squatted by files are passed over, not waited for. (Refused submissions
    // take no id: the next one would be the second.)
    for n in [2, 3] {
        std::fs::write(coord.out.join(format!("job-{n:06}.exr")), b"squat").expect("write");
    }
    let job = submit(&mut client, &text, 2, 2, 0).await;
    assert_eq!(job, "job-000004");
    assert_eq!(
        wait(&mut client, &job).await.state,
        pb::JobState::Done as i32
    );
    // A job whose name is taken while it renders fails rather than overwrite the file.
    w.abort();
    let job = submit(&mut client, &text, 2, 2, 0).await;
    let next = format!("{job}.exr");
    std::fs::write(coord.out.join(&next), b"also not ours").expect("write");
    let w = worker(&coord.url(), "w2");
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Failed as i32);
    assert!(s.error.contains("exists"), "{}", s.error);
    assert_eq!(
        std::fs::read(coord.out.join(&next)).expect("kept"),
        b"also not ours"
    );
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_ended_jobs_scene_leaves_the_store() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start(&data, Duration::from_secs(30)).await;
    let mut client = coord.client().await;
    let mut workers = workers_client(&coord.url());
    let text = scene_text(16);
    let shared_a = submit(&mut client, &text, 4, 2, 0).await;
    let shared_b = submit(&mut client, &text, 4, 2, 0).await;
    let hash = job_status(&mut client, &shared_a).await.scene_hash;
    let scene = |hash: String| pb::GetSceneRequest { scene_hash: hash };
    client
        .cancel_job(pb::CancelJobRequest { job_id: shared_a })
        .await
        .expect("cancel");
    // Still needed by the other job.
    workers.get_scene(scene(hash.clone())).await.expect("kept");
    client
        .cancel_job(pb::CancelJobRequest { job_id: shared_b })
        .await
        .expect("cancel");
    let e = workers
        .get_scene(scene(hash.clone()))
        .await
        .expect_err("gone");
    assert_eq!(e.code(), tonic::Code::NotFound);
    coord.stop().await;
    let store = Store::open(&data).expect("store");
    assert!(store.scene_hashes().expect("hashes").is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn silent_connections_are_closed_and_do_not_starve_clients() {
    use tokio::io::AsyncReadExt;
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = Coordinator::start_with(&dir.path().join("data"), Duration::from_secs(30), |c| {
        c.max_connections = 4;
        c.idle_connection = Duration::from_millis(500);
    })
    .await;
    // Every connection slot taken by a peer that sends nothing.
    let mut silent = Vec::new();
    for _ in 0..4 {
        silent.push(
            tokio::net::TcpStream::connect(coord.addr)
                .await
                .expect("connect"),
        );
    }
    // A real client still gets its answer, once the silent ones are cut off.
    let mut client = coord.client().await;
    let listed = tokio::time::timeout(
        Duration::from_secs(20),
        client.list_jobs(pb::ListJobsRequest {}),
    )
    .await
    .expect("answered in time")
    .expect("list");
    assert!(listed.into_inner().jobs.is_empty());
    for mut s in silent {
        let mut buf = [0u8; 64];
        // The server's HTTP/2 preface may come first; then the connection is closed.
        let closed = tokio::time::timeout(Duration::from_secs(10), async {
            loop {
                match s.read(&mut buf).await {
                    Ok(0) | Err(_) => return,
                    Ok(_) => {}
                }
            }
        })
        .await;
        assert!(closed.is_ok(), "a silent connection was kept open");
    }
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_worker_registers_once_after_a_coordinator_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let coord = Coordinator::start(&data, Duration::from_secs(30)).await;
    let addr = coord.addr;
    let text = scene_text(64);
    let mut client = coord.client().await;
    // Many tiny units, so results are in flight when the coordinator goes: the fetcher and
    // the submitter both learn at once that their worker id is unknown.
    let job = submit(&mut client, &text, 256, 1, 0).await;
    let w = worker(&coord.url(), "once");
    while job_status(&mut client, &job).await.units_done < 20 {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    coord.stop().await;
    // The same address, as a restarted coordinator would have.
    let listener = loop {
        match tokio::net::TcpListener::bind(addr).await {
            Ok(l) => break l,
            Err(_) => tokio::time::sleep(Duration::from_millis(20)).await,
        }
    };
    let mut config = Config::new(&data);
    config.lease_timeout = Duration::from_secs(30);
    let (tx, rx) = oneshot::channel::<()>();
    let task = tokio::spawn(async move {
        serve(config, listener, async {
            let _ = rx.await;
        })
        .await
        .expect("coordinator");
    });
    let mut client = client_with(&format!("http://{addr}"), &ClientOptions::default()).await;
    let s = wait(&mut client, &job).await;
    assert_eq!(s.state, pb::JobState::Done as i32);
    let listed = client
        .list_workers(pb::ListWorkersRequest {})
        .await
        .expect("workers")
        .into_inner()
        .workers;
    assert_eq!(listed.len(), 1, "ghost registrations: {listed:?}");
    w.abort();
    let _ = tx.send(());
    let _ = task.await;
}

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
