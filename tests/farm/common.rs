//! Fixtures shared by the farm tests: an in-process coordinator on a port it binds itself (port
//! 0), in-process workers, clients, and bounded waits.
#![allow(dead_code)] // each behaviour's file uses its own subset

pub use std::net::SocketAddr;
pub use std::path::{Path, PathBuf};
pub use std::time::Duration;

pub use tessera_coordinator::store::{JobRecord, Op, Store};
pub use tessera_coordinator::{Config, Spawned};
pub use tessera_proto::client::{endpoint, Bearer, ClientOptions, ClientTls};
pub use tessera_proto::v1 as pb;
pub use tessera_proto::v1::jobs_client::JobsClient;
pub use tessera_proto::v1::workers_client::WorkersClient;
pub use tessera_proto::Secret;
use tessera_render::guide::SdTree;
use tessera_render::guiding::{epoch_of, epochs, guide_bounds, render_tile_guided, structure};
pub use tessera_render::output::{render_metadata, write_exr, ExrChannels};
pub use tessera_render::scene::{Format, Limits, Scene};
pub use tessera_render::{render_frame, RenderSettings, IMAGE_REVISION};
pub use tessera_render::{render_tile, PixelRect};
pub use tonic::service::interceptor::InterceptedService;
pub use tonic::transport::Channel;

/// A `Jobs` client with a (possibly empty) token attached.
pub type Client = JobsClient<InterceptedService<Channel, Bearer>>;

/// Connects a `Jobs` client to `url` with `options`.
pub async fn client_with(url: &str, options: &ClientOptions) -> Client {
    let channel = endpoint(url, options)
        .expect("endpoint")
        .connect()
        .await
        .expect("connect");
    JobsClient::with_interceptor(channel, Bearer::new(options))
}

/// The Cornell box shrunk to `size`² so a farm run takes a second or two.
pub fn scene_text(size: u32) -> String {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.toml"),
    )
    .expect("read cornell-box.toml");
    text.replace("width = 256", &format!("width = {size}"))
        .replace("height = 256", &format!("height = {size}"))
}

/// A coordinator on a port it bound itself, with its output directory.
pub struct Coordinator {
    /// The address the server bound (port 0 resolved).
    pub addr: SocketAddr,
    /// The dashboard's address, when it serves one.
    pub http: Option<SocketAddr>,
    /// Its output directory.
    pub out: PathBuf,
    server: Spawned,
}

impl Coordinator {
    pub async fn start(data: &Path, lease: Duration) -> Self {
        Self::start_with(data, lease, |_| {}).await
    }

    pub async fn start_with(data: &Path, lease: Duration, edit: impl FnOnce(&mut Config)) -> Self {
        let config = Self::config(data, lease, edit);
        let out = config.output_dir();
        let server = Spawned::start(config, "127.0.0.1:0").await.expect("bind");
        Self {
            addr: server.addr,
            http: None,
            out,
            server,
        }
    }

    /// A coordinator serving its dashboard too, on another port it bound itself.
    pub async fn start_with_dashboard(
        data: &Path,
        lease: Duration,
        edit: impl FnOnce(&mut Config),
    ) -> Self {
        let config = Self::config(data, lease, edit);
        let out = config.output_dir();
        let server = Spawned::start_with_dashboard(config, "127.0.0.1:0", "127.0.0.1:0")
            .await
            .expect("bind");
        Self {
            addr: server.addr,
            http: server.http_addr,
            out,
            server,
        }
    }

    /// A coordinator on `data` again, at the address an earlier one (now stopped) had bound
    /// itself, as a coordinator restarted by its supervisor would be: workers keep their URL.
    pub async fn restart_at(addr: SocketAddr, data: &Path, lease: Duration) -> Self {
        // The old server's socket may take a moment to be released.
        let listener = wait_for("the old coordinator's port to be free", async || {
            tokio::net::TcpListener::bind(addr).await.ok()
        })
        .await;
        let config = Self::config(data, lease, |_| {});
        let out = config.output_dir();
        Self {
            addr,
            http: None,
            out,
            server: Spawned::on(config, listener).expect("serve on the old address"),
        }
    }

    /// Stops this coordinator and starts another on its address and data directory.
    pub async fn restarted(self, data: &Path, lease: Duration) -> Self {
        let addr = self.addr;
        self.stop().await;
        Self::restart_at(addr, data, lease).await
    }

    fn config(data: &Path, lease: Duration, edit: impl FnOnce(&mut Config)) -> Config {
        let mut config = Config::new(data);
        config.lease_timeout = lease;
        edit(&mut config);
        config
    }

    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    pub async fn client(&self) -> Client {
        client_with(&self.url(), &ClientOptions::default()).await
    }

    pub async fn stop(self) {
        self.server.stop().await.expect("coordinator");
    }
}

/// A worker task; dropping the handle (abort) kills it without any goodbye.
pub fn worker(url: &str, name: &str) -> tokio::task::JoinHandle<()> {
    worker_with(url, name, ClientOptions::default())
}

pub fn worker_with(url: &str, name: &str, client: ClientOptions) -> tokio::task::JoinHandle<()> {
    worker_of(url, name, 1, client)
}

/// An in-process worker of `threads` render threads.
pub fn worker_of(
    url: &str,
    name: &str,
    threads: usize,
    client: ClientOptions,
) -> tokio::task::JoinHandle<()> {
    let mut config = tessera_worker::Config::new(url);
    config.threads = Some(threads);
    config.name = name.into();
    config.client = client;
    tokio::spawn(async move {
        tessera_worker::run(config, std::future::pending())
            .await
            .expect("worker");
    })
}

/// The request the tests submit: the scene at `spp` in batches of `batch`, seed 7, 16-pixel
/// tiles.
pub fn submit_request(text: &str, spp: u32, batch: u32) -> pb::SubmitJobRequest {
    submit_request_with(text, &job_settings(spp, batch))
}

/// [`submit_request`] with these settings (a frame, AOVs, …).
pub fn submit_request_with(text: &str, settings: &RenderSettings) -> pb::SubmitJobRequest {
    pb::SubmitJobRequest {
        scene_text: text.into(),
        scene_format: pb::SceneFormat::Toml as i32,
        scene_name: "cornell.toml".into(),
        settings: Some(pb::RenderSettings::from(settings)),
        tile_size: 16,
        ..Default::default()
    }
}

/// Submits `text` and returns the job id.
pub async fn submit(
    client: &mut Client,
    text: &str,
    spp: u32,
    batch: u32,
    priority: i32,
) -> String {
    submit_job(
        client,
        pb::SubmitJobRequest {
            priority,
            ..submit_request(text, spp, batch)
        },
    )
    .await
}

/// Submits `request`, which must be admitted, and returns the job id.
pub async fn submit_job(client: &mut Client, request: pb::SubmitJobRequest) -> String {
    client
        .submit_job(request)
        .await
        .expect("submit")
        .into_inner()
        .job_id
}

/// The first page of the job listing, as `tessera status` starts reading it.
pub async fn list_jobs(client: &mut Client) -> Vec<pb::JobStatus> {
    client
        .list_jobs(pb::ListJobsRequest::default())
        .await
        .expect("list")
        .into_inner()
        .jobs
}

/// The request that hands in `result` for unit `u` leased by `worker_id`.
pub fn result_for(
    worker_id: &str,
    u: &pb::WorkUnit,
    result: pb::TileResult,
) -> pb::SubmitResultRequest {
    pb::SubmitResultRequest {
        worker_id: worker_id.to_string(),
        lease_id: u.lease_id.clone(),
        job_id: u.job_id.clone(),
        tile_index: u.tile_index,
        batch_index: u.batch_index,
        result: Some(result),
    }
}

/// The workers the coordinator lists.
pub async fn list_workers(client: &mut Client) -> Vec<pb::WorkerInfo> {
    client
        .list_workers(pb::ListWorkersRequest {})
        .await
        .expect("workers")
        .into_inner()
        .workers
}

/// A job's current status.
pub async fn job_status(client: &mut Client, job: &str) -> pb::JobStatus {
    client
        .get_job(pb::GetJobRequest { job_id: job.into() })
        .await
        .expect("status")
        .into_inner()
}

pub use tessera_testkit::{wait_for, PATIENCE};

/// Follows WatchJob to the end and returns the final status.
pub async fn wait(client: &mut Client, job: &str) -> pb::JobStatus {
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
    tokio::time::timeout(PATIENCE, fut)
        .await
        .expect("the job did not finish in time");
    last.expect("at least one status")
}

pub async fn fetch(client: &mut Client, job: &str) -> Vec<u8> {
    let mut stream = client
        .fetch_result(pb::FetchResultRequest {
            job_id: job.into(),
            frame: None,
        })
        .await
        .expect("fetch")
        .into_inner();
    let mut out = Vec::new();
    while let Some(c) = stream.message().await.expect("chunk") {
        out.extend_from_slice(&c.data);
    }
    out
}

/// An honest guided unit: rendered with `guide` (none in epoch 0), recording into its epoch's
/// structure where the epoch trains.
pub fn honest_guided(
    scene: &Scene,
    settings: &RenderSettings,
    u: &pb::WorkUnit,
    guide: Option<&SdTree>,
) -> pb::TileResult {
    let k = epoch_of(settings.spp, u.sample_start).expect("a sample of the job");
    let train =
        (k + 1 < epochs(settings.spp).len()).then(|| structure(guide_bounds(scene), k, guide));
    let rect = PixelRect::from(u.rect.expect("rect"));
    let range = u.sample_start..u.sample_end;
    let (sums, trained) = render_tile_guided(scene, settings, rect, range, guide, train.as_ref());
    pb::TileResult {
        guide_train: trained.map(|t| t.encode()).unwrap_or_default(),
        ..pb::TileResult::from(&sums)
    }
}

/// A content-addressed asset's bytes, by hash, as worker `worker_id` asks for them.
pub async fn fetch_asset(
    client: &mut WorkersClient<Channel>,
    worker_id: &str,
    hash: &str,
) -> Result<Vec<u8>, tonic::Status> {
    let mut stream = client
        .fetch_asset(pb::FetchAssetRequest {
            sha256: hash.to_string(),
            offset: 0,
            worker_id: worker_id.to_string(),
        })
        .await?
        .into_inner();
    let mut bytes = Vec::new();
    while let Some(c) = stream.message().await? {
        bytes.extend_from_slice(&c.data);
    }
    Ok(bytes)
}

/// The bytes `tessera render` writes for the same job.
pub fn local_exr(text: &str, spp: u32, batch: u32, dir: &Path) -> Vec<u8> {
    local_exr_with(text, &job_settings(spp, batch), ExrChannels::default(), dir)
}

/// The bytes `tessera render` writes for `settings` (at its frame) and `channels`.
pub fn local_exr_with(
    text: &str,
    settings: &RenderSettings,
    channels: ExrChannels,
    dir: &Path,
) -> Vec<u8> {
    local_exr_files(
        text,
        settings,
        channels,
        dir,
        &tessera_render::scene::assets::NoAssets,
    )
}

/// [`local_exr_with`] for a scene that reads `files` (meshes, textures).
pub fn local_exr_files(
    text: &str,
    settings: &RenderSettings,
    channels: ExrChannels,
    dir: &Path,
    files: &dyn tessera_render::scene::assets::Assets,
) -> Vec<u8> {
    let frame = settings.frame.unwrap_or(tessera_render::scene::FIRST_FRAME);
    let scene = Scene::text(text, Format::Toml, "cornell.toml", &Limits::default())
        .at(frame)
        .assets(files)
        .load()
        .expect("scene");
    let sums = if settings.guiding {
        tessera_render::guiding::render_frame_guided(&scene, settings, &|_| {}).sums
    } else {
        render_frame(&scene, settings, &|_| {})
    };
    let image = sums.finalize();
    let path = dir.join("local.exr");
    write_exr(
        &path,
        &image,
        channels,
        &render_metadata(&scene.hash, settings),
    )
    .expect("write");
    std::fs::read(path).expect("read")
}

/// The render settings `submit` gives a job of `spp` samples in batches of `batch`.
pub fn job_settings(spp: u32, batch: u32) -> RenderSettings {
    RenderSettings {
        seed: 7,
        spp,
        batch,
        ..RenderSettings::default()
    }
}

/// A `Workers` client for driving the protocol by hand.
pub fn workers_client(url: &str) -> WorkersClient<Channel> {
    WorkersClient::new(
        endpoint(url, &ClientOptions::default())
            .expect("endpoint")
            .connect_lazy(),
    )
}

/// Registers a hand-driven worker named `name` rendering image revision `revision`; returns
/// its id.
pub async fn register_as(
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
            ..Default::default()
        })
        .await?;
    Ok(r.into_inner().worker_id)
}

/// Leases up to `max` units for worker `id` without waiting for work.
pub async fn lease_now(
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
pub fn honest_result(scene: &Scene, settings: &RenderSettings, u: &pb::WorkUnit) -> pb::TileResult {
    let rect = PixelRect::from(u.rect.expect("rect"));
    pb::TileResult::from(&render_tile(
        scene,
        settings,
        rect,
        u.sample_start..u.sample_end,
    ))
}

/// With one worker and one client using `options`, renders `text` at 4 spp and checks the
/// bits against a local render.
pub async fn render_one_job(url: &str, options: &ClientOptions, text: &str, dir: &Path) {
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

/// A submission with an output name.
pub async fn submit_named(
    client: &mut Client,
    text: &str,
    name: &str,
) -> Result<String, tonic::Status> {
    client
        .submit_job(pb::SubmitJobRequest {
            output_name: name.into(),
            ..submit_request(text, 2, 2)
        })
        .await
        .map(|r| r.into_inner().job_id)
}

/// An HTTP reply, whole.
#[derive(Debug)]
pub struct Reply {
    pub status: u16,
    pub headers: hyper::HeaderMap,
    pub body: Vec<u8>,
}

impl Reply {
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).and_then(|v| v.to_str().ok())
    }
}

/// A GET of `path` from `addr`, with no headers.
pub async fn get(addr: SocketAddr, path: &str) -> Reply {
    http(addr, "GET", path, &[], "").await
}

/// One HTTP/1.1 request to `addr` on a connection of its own.
pub async fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> Reply {
    use http_body_util::BodyExt;
    let tcp = tokio::net::TcpStream::connect(addr).await.expect("connect");
    let (mut send, conn) = hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(tcp))
        .await
        .expect("handshake");
    tokio::spawn(conn);
    let mut req = hyper::Request::builder().method(method).uri(path);
    // The address as its Host, unless the caller names another.
    if !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("host")) {
        req = req.header("host", addr.to_string());
    }
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let req = req
        .body(http_body_util::Full::new(hyper::body::Bytes::from(
            body.to_string(),
        )))
        .expect("request");
    let r = send.send_request(req).await.expect("send");
    let status = r.status().as_u16();
    let headers = r.headers().clone();
    let body = r
        .into_body()
        .collect()
        .await
        .expect("body")
        .to_bytes()
        .to_vec();
    Reply {
        status,
        headers,
        body,
    }
}

/// A test CA and a certificate it signed for `localhost`: (CA, certificate PEM, key PEM).
pub fn test_ca_and_cert() -> (rcgen::Certificate, String, String) {
    let ca_key = rcgen::KeyPair::generate().expect("key");
    let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).expect("params");
    ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    let ca = ca_params.self_signed(&ca_key).expect("ca");
    let issuer = rcgen::Issuer::new(ca_params, ca_key);
    let key = rcgen::KeyPair::generate().expect("key");
    let params = rcgen::CertificateParams::new(vec!["localhost".to_string()]).expect("params");
    let cert = params.signed_by(&key, &issuer).expect("cert");
    (ca, cert.pem(), key.serialize_pem())
}

/// A coordinator with its dashboard and default settings (lease 30 s) under `dir/data`, and
/// the dashboard's address.
pub async fn dashboard_farm(dir: &Path) -> (Coordinator, SocketAddr) {
    let coord =
        Coordinator::start_with_dashboard(&dir.join("data"), Duration::from_secs(30), |_| {}).await;
    let addr = coord.http.expect("dashboard");
    (coord, addr)
}
