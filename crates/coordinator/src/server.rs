//! The server: TLS, the bearer-token check on every call, connection limits, the lease
//! ticker, and the two services over the shared state. [`serve`] runs it on a listener the
//! caller binds (port 0 in tests) until a shutdown future completes.

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use tessera_proto::v1::jobs_server::JobsServer;
use tessera_proto::v1::workers_server::WorkersServer;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Certificate, Identity, ServerTlsConfig};

use crate::auth::{bearer, Api, Tokens};
use crate::config::{Config, MAX_STREAMS_PER_CONNECTION};
use crate::conn;
use crate::error::CoordinatorError;
use crate::output::finish_job;
use crate::service::Service;
use crate::shared::{writer, Shared};

/// requests have drained and queued state writes are durable.
pub async fn serve(
    config: Config,
    listeners: impl Into<Listeners>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), CoordinatorError> {
    serve_when_ready(config, listeners, shutdown, || {}).await
}

/// Where the coordinator listens: the gRPC API, and optionally the dashboard and metrics
/// (HTTP). A bare listener converts into one with no dashboard.
#[derive(Debug)]
pub struct Listeners {
    /// The gRPC API (`tessera.v1.Jobs`, `tessera.v1.Workers`).
    pub grpc: tokio::net::TcpListener,
    /// The dashboard and `/metrics`; none unless asked for (`--http`).
    pub http: Option<tokio::net::TcpListener>,
}

impl From<tokio::net::TcpListener> for Listeners {
    fn from(grpc: tokio::net::TcpListener) -> Self {
        Self { grpc, http: None }
    }
}

/// [`serve`], calling `ready` once the TLS identity is loaded and the store is open and
/// restored: the moment to tell a person or a script that the coordinator is up. Any error
/// before that (a bad key, a damaged store) comes back instead, and `ready` is not called.
pub async fn serve_when_ready(
    config: Config,
    listeners: impl Into<Listeners>,
    shutdown: impl Future<Output = ()> + Send + 'static,
    ready: impl FnOnce(),
) -> Result<(), CoordinatorError> {
    let Listeners {
        grpc: listener,
        http,
    } = listeners.into();
    let max_msg = config.max_message_bytes;
    let lease_timeout = config.lease_timeout;
    let retention = config.asset_retention;
    let mut builder = grpc_server(&config)?;
    // Loaded before the store opens, so that a bad identity stops the coordinator before it
    // says it is up, as the gRPC side's does.
    let dashboard = http
        .map(|l| crate::http::Dashboard::new(l, config.tls.as_ref()))
        .transpose()?;
    if config.denoise {
        // Loaded before the coordinator says it is up: a farm set to denoise without the
        // library stops here, not at its first finished frame.
        tessera_denoise::library_version()?;
    }
    let (max_connections, idle) = (config.max_connections, config.idle_connection);
    let (shared, rx, to_finish) = Shared::open(config)?;
    let writer = tokio::spawn(writer(
        Arc::downgrade(&shared),
        rx,
        shared.config.checkpoint_interval,
    ));
    for id in to_finish {
        tokio::spawn(finish_job(shared.clone(), id));
    }
    // Lapsed leases are noticed here as well as on each lease call, so that a long-polling
    // worker wakes up for a unit whose holder died.
    let ticker = every(
        &shared,
        (lease_timeout / 8).clamp(Duration::from_millis(50), Duration::from_secs(1)),
        |shared| async move { tick(&shared) },
    );
    // Asset files no active job uses are deleted once their retention has passed, checked a
    // few times per retention period and at least once a minute.
    let collector = every(
        &shared,
        (retention / 4).clamp(Duration::from_secs(1), Duration::from_secs(60)),
        |shared| async move { collect(shared).await },
    );
    let svc = Service::new(shared.clone());
    let tokens = shared.config.auth();
    let (incoming, gate) = conn::Limited::new(listener, max_connections, idle, tokens.is_none());
    let auth = AuthCheck {
        tokens,
        gate,
        api: Api::Jobs,
    };
    // One shutdown for both servers: the caller's, or the gRPC server's failure.
    let (stop_tx, stop) = tokio::sync::watch::channel(false);
    let stop_tx = Arc::new(stop_tx);
    {
        let stop_tx = stop_tx.clone();
        tokio::spawn(async move {
            shutdown.await;
            let _ = stop_tx.send(true);
        });
    }
    let dashboard = dashboard.map(|d| tokio::spawn(d.serve(svc.clone(), stop.clone())));
    let mut grpc_stop = stop.clone();
    let shutdown = async move {
        let _ = grpc_stop.wait_for(|s| *s).await;
    };
    ready();
    let result = builder
        .add_service(InterceptedService::new(
            JobsServer::new(svc.clone())
                .max_decoding_message_size(max_msg)
                .max_encoding_message_size(max_msg),
            auth.clone(),
        ))
        .add_service(InterceptedService::new(
            WorkersServer::new(svc)
                .max_decoding_message_size(max_msg)
                .max_encoding_message_size(max_msg),
            AuthCheck {
                api: Api::Workers,
                ..auth
            },
        ))
        .serve_with_incoming_shutdown(incoming, shutdown)
        .await;
    let _ = stop_tx.send(true);
    let dashboard = match dashboard {
        Some(task) => task
            .await
            .map_err(|e| CoordinatorError::Task(e.to_string())),
        None => Ok(()),
    };
    ticker.abort();
    collector.abort();
    if let Err(e) = shared.flush().await {
        tracing::error!("the last checkpoint before stopping failed: {e}");
    }
    drop(shared);
    // The writer ends when the last sender (inside Shared) is gone; give stragglers (watch
    // streams finishing their last message) a moment, then stop waiting.
    let _ = tokio::time::timeout(Duration::from_secs(5), writer).await;
    result?;
    dashboard
}

/// The gRPC server's builder: keepalives, a bound on streams per connection, TLS.
fn grpc_server(config: &Config) -> Result<tonic::transport::Server, CoordinatorError> {
    let mut builder = tonic::transport::Server::builder()
        // A connection that sends nothing is closed rather than kept for ever, and one
        // connection cannot open unbounded streams.
        .http2_keepalive_interval(Some(Duration::from_secs(30)))
        .http2_keepalive_timeout(Some(Duration::from_secs(20)))
        .max_concurrent_streams(Some(MAX_STREAMS_PER_CONNECTION));
    if let Some(tls) = &config.tls {
        let mut cfg = ServerTlsConfig::new()
            .identity(Identity::from_pem(&tls.cert_pem, tls.key_pem.expose()));
        if let Some(ca) = &tls.client_ca_pem {
            cfg = cfg.client_ca_root(Certificate::from_pem(ca));
        }
        builder = builder.tls_config(cfg)?;
    }
    Ok(builder)
}

/// One pass of the collector: failed jobs past their retry window let their scenes go, ended
/// jobs' logs leave memory and past their retention the store, ended jobs past theirs are
/// forgotten, and the files no job names any more are deleted.
async fn collect(shared: Arc<Shared>) {
    // Failed jobs' scenes go first, so that the files only those scenes named are collected
    // with the rest.
    let ops = shared.scheduler().sweep_failed(crate::shared::now_ms());
    if !ops.is_empty() {
        if let Err(e) = crate::shared::durable(shared.queue_write(ops)).await {
            tracing::warn!("dropping the scenes of failed jobs past their retry window: {e}");
        }
    }
    // Ended jobs' logs leave memory once the store has their last lines, and the store keeps
    // them for their retention only.
    if crate::shared::durable(shared.queue_write(Vec::new()))
        .await
        .is_ok()
    {
        let ops = shared.scheduler().sweep_logs(crate::shared::now_ms());
        if !ops.is_empty() {
            if let Err(e) = crate::shared::durable(shared.queue_write(ops)).await {
                tracing::warn!("dropping logs past their retention: {e}");
            }
        }
        // Ended jobs' records go after theirs, the oldest first.
        let ops = shared.scheduler().sweep_jobs(crate::shared::now_ms());
        if !ops.is_empty() {
            shared.bump_changed();
            if let Err(e) = crate::shared::durable(shared.queue_write(ops)).await {
                tracing::warn!("dropping ended jobs past their retention: {e}");
            }
        }
    }
    let r = tokio::task::spawn_blocking(move || shared.collect_assets()).await;
    if let Ok(Err(e)) = r {
        tracing::warn!("asset collection: {e}");
    }
}

/// A coordinator serving in this process on a port it bound itself, until stopped: what tests
/// (and anything else embedding a farm, as quickwit's sandbox does a cluster) start on port 0.
pub struct Spawned {
    /// The address it bound (port 0 resolved).
    pub addr: std::net::SocketAddr,
    /// The dashboard's address, when it serves one.
    pub http_addr: Option<std::net::SocketAddr>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), CoordinatorError>>,
}

impl Spawned {
    /// Binds `listen` (`127.0.0.1:0` for a free port) and serves `config` there. Must be
    /// called inside a tokio runtime.
    pub async fn start(config: Config, listen: &str) -> std::io::Result<Self> {
        Self::on(config, tokio::net::TcpListener::bind(listen).await?)
    }

    /// Serves `config` on a listener the caller bound (the address of a coordinator that
    /// stopped, to restart it where its workers look for it).
    pub fn on(config: Config, listener: tokio::net::TcpListener) -> std::io::Result<Self> {
        Self::serving(config, listener.into())
    }

    /// Binds `listen` for the gRPC API and `http` for the dashboard (`127.0.0.1:0` for free
    /// ports) and serves `config` there.
    pub async fn start_with_dashboard(
        config: Config,
        listen: &str,
        http: &str,
    ) -> std::io::Result<Self> {
        Self::serving(
            config,
            Listeners {
                grpc: tokio::net::TcpListener::bind(listen).await?,
                http: Some(tokio::net::TcpListener::bind(http).await?),
            },
        )
    }

    fn serving(config: Config, listeners: Listeners) -> std::io::Result<Self> {
        let addr = listeners.grpc.local_addr()?;
        let http_addr = listeners
            .http
            .as_ref()
            .map(|l| l.local_addr())
            .transpose()?;
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(serve(config, listeners, async {
            let _ = rx.await;
        }));
        Ok(Self {
            addr,
            http_addr,
            stop: Some(tx),
            task,
        })
    }

    /// The URL clients use: `http://ADDR`.
    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// Stops it and waits until queued state writes are durable; returns how serving ended.
    pub async fn stop(mut self) -> Result<(), CoordinatorError> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        match (&mut self.task).await {
            Ok(r) => r,
            Err(e) => Err(CoordinatorError::Task(e.to_string())),
        }
    }
}

/// Runs `task` every `period` (the first time at once) until the shared state is gone; the
/// task holds no reference to it between runs, so it never keeps the state alive.
fn every<F, Fut>(shared: &Arc<Shared>, period: Duration, task: F) -> tokio::task::JoinHandle<()>
where
    F: Fn(Arc<Shared>) -> Fut + Send + 'static,
    Fut: std::future::Future<Output = ()> + Send,
{
    let shared = Arc::downgrade(shared);
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(period);
        loop {
            tick.tick().await;
            let Some(shared) = shared.upgrade() else {
                return;
            };
            task(shared).await;
        }
    })
}

/// Both services over a store, with no network, transport or auth in between: what
/// [`serve`] runs, for driving sequences of calls in-process (the `rpc_surface` fuzz target).
/// Made inside a tokio runtime, which runs its state writer.
#[doc(hidden)]
pub struct InProcess {
    service: Service,
    writer: tokio::task::JoinHandle<()>,
    dashboard: axum::Router,
}

impl InProcess {
    /// Opens the store under `config.data_dir` and restores its jobs, as [`serve`] does.
    pub fn open(config: Config) -> Result<Self, CoordinatorError> {
        let (shared, rx, to_finish) = Shared::open(config)?;
        let writer = tokio::spawn(writer(
            Arc::downgrade(&shared),
            rx,
            shared.config.checkpoint_interval,
        ));
        for id in to_finish {
            tokio::spawn(finish_job(shared.clone(), id));
        }
        let service = Service::new(shared);
        let dashboard = crate::http::routes_for(&service);
        Ok(Self {
            service,
            writer,
            dashboard,
        })
    }

    /// The `Jobs` and `Workers` services.
    pub fn service(&self) -> &Service {
        &self.service
    }

    /// One HTTP request to the dashboard and `/metrics` (the routes and checks `--http`
    /// serves, without the network or the connection gate): (status, headers, body).
    pub async fn http(
        &self,
        method: &str,
        path: &str,
        headers: &[(String, String)],
        body: Vec<u8>,
    ) -> (u16, Vec<(String, String)>, Vec<u8>) {
        crate::http::one_request(&self.dashboard, method, path, headers, body).await
    }

    /// The most scene parses that have run at once.
    pub fn peak_parses(&self) -> usize {
        self.service.peak_parses()
    }

    /// Lapses overdue leases, as the server's ticker does.
    pub fn expire(&self) {
        tick(&self.service.shared);
    }

    /// The asset store.
    pub fn assets(&self) -> &crate::assets::AssetStore {
        &self.service.shared.assets
    }

    /// Runs the asset collection the server runs periodically: `None` when a submission held
    /// it off.
    pub fn collect_assets(&self) -> Result<Option<crate::assets::Collected>, CoordinatorError> {
        self.service.shared.collect_assets()
    }

    /// Stops, once every queued write is durable and the store is closed.
    pub async fn close(self) {
        let _ = self.service.shared.flush().await;
        // The dashboard's routes hold the service too: the writer ends once both are gone.
        drop(self.dashboard);
        drop(self.service);
        let _ = self.writer.await;
    }
}

/// What the server's ticker does: lapses overdue leases (waking workers for their units, and
/// committing a frame that a unit lapsing too often failed), and starts the referee's pending
/// renders.
fn tick(shared: &Arc<Shared>) {
    let (any, ops) = {
        let mut core = shared.scheduler();
        let any = core.expire(std::time::Instant::now());
        (any, core.take_deferred())
    };
    if any {
        shared.bump_work();
    }
    if !ops.is_empty() {
        // Not awaited: nothing answers a caller from here, and the next commit has it.
        drop(shared.queue_write(ops));
        shared.bump_changed();
    }
    crate::referee::spawn_pending(shared);
}

/// Checks the bearer token of every call ([`crate::auth`]) and tells the service who called
/// (a [`Caller`](crate::auth::Caller) extension). A call that passes proves its connection to
/// the gate (`conn.rs`), which closes connections that never do.
#[derive(Clone)]
struct AuthCheck {
    tokens: Option<Tokens>,
    gate: Arc<conn::Gate>,
    /// The service this check guards: a token serves one ([`crate::auth::Role`]).
    api: Api,
}

impl tonic::service::Interceptor for AuthCheck {
    fn call(
        &mut self,
        mut request: tonic::Request<()>,
    ) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(tokens) = &self.tokens {
            let presented = request
                .metadata()
                .get("authorization")
                .and_then(|v| v.to_str().ok())
                .and_then(bearer);
            let Some(t) = presented else {
                return Err(tonic::Status::unauthenticated(
                    "this coordinator requires a token (--token-file or TESSERA_TOKEN)",
                ));
            };
            let caller = tokens
                .caller(t)
                .ok_or_else(|| tonic::Status::unauthenticated("wrong token"))?;
            caller
                .may_call(self.api)
                .map_err(tonic::Status::permission_denied)?;
            request.extensions_mut().insert(caller);
        }
        self.gate.prove(request.remote_addr());
        Ok(request)
    }
}
