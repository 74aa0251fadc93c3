//! The dashboard and metrics over HTTP (`tessera coordinator --http ADDR`): a few pages with
//! no build step, the JSON they read, a progressive preview of each job, the finished EXR, and
//! Prometheus metrics at `/metrics` (docs/farm.md, "Dashboard and metrics").
//!
//! It answers from the same state as the gRPC API: the scheduler's views, serialised as JSON
//! (the gRPC API sends the same views as protobuf, and `tessera status --json` turns them back
//! into this JSON), and the same handlers where one acts (cancel, the EXR), so the two never
//! disagree. With a token configured,
//! every request but the login form's must carry it: as `Authorization: Bearer`, or as the
//! session cookie the login sets. With TLS configured it serves TLS only, with the same
//! identity and client CA as the gRPC API.

mod api;
mod intake;
mod openapi;
mod preview;
mod sessions;

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::extract::{Path, Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Form, Router};
use tessera_proto::ids::JobId;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio_rustls::rustls;
use tokio_stream::StreamExt as _;
use tracing::debug;

use crate::auth::{bearer, token_hash, Caller, Tokens};
use crate::config::ServerTls;
use crate::error::CoordinatorError;
use crate::service::Service;
use crate::store::FILE_NAME;
use api::refused;

use preview::{NoPreview, Previews, View};

/// Most HTTP connections open at once; more wait to be accepted.
const MAX_CONNECTIONS: usize = 256;

/// A client has this long to finish its TLS handshake and send a request's headers.
const HANDSHAKE: Duration = Duration::from_secs(10);

/// The session cookie's name.
const COOKIE: &str = "tessera_session";

/// The dashboard's state: the service it answers through, its previews, and what a request
/// must present.
#[derive(Clone)]
struct App {
    svc: Service,
    previews: Arc<Previews>,
    auth: Arc<Auth>,
    uploads: Arc<Uploads>,
}

/// HTTP uploads under way, by who sends them (a user, or an address without named tokens).
#[derive(Default)]
struct Uploads(std::sync::Mutex<std::collections::HashMap<String, usize>>);

/// One upload's place among its sender's, given back when it ends however it ends.
struct UploadSlot(Arc<Uploads>, String);

impl Uploads {
    /// A place for one more of `who`'s uploads, if it has fewer than `max` under way.
    fn take(self: &Arc<Self>, who: &str, max: usize) -> Option<UploadSlot> {
        let mut m = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let n = m.entry(who.to_string()).or_default();
        if *n >= max {
            return None;
        }
        *n += 1;
        Some(UploadSlot(self.clone(), who.to_string()))
    }
}

impl Drop for UploadSlot {
    fn drop(&mut self) {
        let mut m = (self.0).0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = m.get_mut(&self.1) {
            *n -= 1;
            if *n == 0 {
                m.remove(&self.1);
            }
        }
    }
}

/// What a request must present when tokens are configured: a token (as a bearer header,
/// compared in constant time) or an open login session (as the cookie).
struct Auth {
    tokens: Option<Tokens>,
    secure: bool,
    sessions: sessions::Sessions,
}

impl Auth {
    fn new(tokens: Option<Tokens>, secure: bool) -> Self {
        Self {
            tokens,
            secure,
            sessions: sessions::Sessions::default(),
        }
    }

    /// The session cookie values a request carries.
    fn cookies(headers: &HeaderMap) -> impl Iterator<Item = &str> {
        headers
            .get_all(header::COOKIE)
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(';'))
            .filter_map(|kv| kv.trim().strip_prefix(COOKIE)?.strip_prefix('='))
    }

    /// Who sends a request with these headers: `None` if it must not pass; with no tokens
    /// configured, anyone passes, as nobody in particular.
    fn caller(&self, headers: &HeaderMap) -> Option<Option<Caller>> {
        let Some(tokens) = &self.tokens else {
            return Some(None);
        };
        let presented = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(bearer);
        if let Some(c) = presented.and_then(|t| tokens.caller(t)) {
            return Some(Some(c));
        }
        let now = std::time::Instant::now();
        Self::cookies(headers)
            .find_map(|v| tokens.caller_of_hash(&self.sessions.token_of(v, now)?))
            .map(Some)
    }
}

/// The dashboard's routes over `svc`, as `serve` builds them for a plain-HTTP port.
pub(crate) fn routes_for(svc: &Service) -> Router {
    router(App {
        auth: Arc::new(Auth::new(svc.shared.config.auth(), false)),
        previews: Arc::default(),
        uploads: Arc::default(),
        svc: svc.clone(),
    })
}

/// One request through `routes` (every check but the connection gate), with no network:
/// (status, headers, body). What the `http_surface` fuzz target drives.
pub(crate) async fn one_request(
    routes: &Router,
    method: &str,
    path: &str,
    headers: &[(String, String)],
    body: Vec<u8>,
) -> (u16, Vec<(String, String)>, Vec<u8>) {
    use tower::ServiceExt as _;
    let mut req = axum::http::Request::builder().method(method).uri(path);
    for (k, v) in headers {
        req = req.header(k.as_str(), v.as_str());
    }
    let Ok(req) = req.body(Body::from(body)) else {
        // Not a request at all (a method or header no client could send).
        return (400, Vec::new(), Vec::new());
    };
    let Ok(resp) = routes.clone().oneshot(req).await;
    let status = resp.status().as_u16();
    let headers = resp
        .headers()
        .iter()
        .map(|(k, v)| {
            (
                k.to_string(),
                String::from_utf8_lossy(v.as_bytes()).into_owned(),
            )
        })
        .collect();
    let body = axum::body::to_bytes(resp.into_body(), 64 << 20)
        .await
        .map(|b| b.to_vec())
        .unwrap_or_default();
    (status, headers, body)
}

/// The routes, behind the token check.
fn router(app: App) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/jobs/{id}", get(page))
        .route("/workers", get(page))
        .route("/static/app.js", get(app_js))
        .route("/static/style.css", get(style_css))
        .route("/api/openapi.json", get(openapi::openapi))
        .route("/api/jobs", get(api::list_jobs).post(intake::submit))
        .route("/api/jobs/{id}", get(api::job))
        .route("/api/jobs/{id}/cancel", post(api::cancel))
        .route("/api/jobs/{id}/pause", post(api::pause))
        .route("/api/jobs/{id}/resume", post(api::resume))
        .route("/api/jobs/{id}/priority", post(api::priority))
        .route("/api/jobs/{id}/retry", post(api::retry))
        .route("/api/jobs/{id}/logs", get(api::logs))
        .route("/api/jobs/{id}/preview.png", get(preview_png))
        .route("/api/jobs/{id}/output.exr", get(api::output_exr))
        .route("/api/workers", get(api::list_workers))
        .route("/api/workers/{id}/drain", post(api::drain))
        .route("/api/workers/{id}/release", post(api::release))
        .route(
            "/api/assets/{sha256}",
            get(intake::asset_status).put(intake::upload_asset),
        )
        .route("/metrics", get(metrics))
        .route("/login", post(login))
        .route("/logout", post(logout))
        .fallback(not_found)
        .layer(axum::middleware::from_fn_with_state(app.clone(), check))
        .with_state(app)
}

/// Lets a request through if it carries a token (or is the login form's), else answers 401:
/// the login page to a browser, JSON to an API client, a line of text to anything else.
async fn check(State(app): State<App>, req: Request, next: Next) -> Response {
    let api = req.uri().path().starts_with("/api/");
    // Without a token anyone who reaches the port may act, so the Host must be one this
    // dashboard is served as: a page on evil.example whose name an attacker points at the
    // farm (DNS rebinding) sends `Host: evil.example`. Prometheus's scrape of /metrics names
    // the coordinator's service, and reads nothing a user owns.
    if app.auth.tokens.is_none() && req.uri().path() != "/metrics" {
        if let Some(host) = foreign_host(&req, &app.svc.shared.config.http_hosts) {
            let message = format!(
                "this dashboard is not served as {host:?}: reach it by an IP address, \
                 localhost, or a name given to `tessera coordinator --http-host` (without a \
                 token, other names are refused against DNS rebinding)"
            );
            if api {
                return api::error(StatusCode::FORBIDDEN, "forbidden", message);
            }
            return (StatusCode::FORBIDDEN, format!("{message}\n")).into_response();
        }
    }
    let changes = !matches!(*req.method(), Method::GET | Method::HEAD);
    if changes && cross_site(req.headers()) {
        let message = "a request from another site may not change anything here";
        if api {
            return api::error(StatusCode::FORBIDDEN, "forbidden", message);
        }
        return (StatusCode::FORBIDDEN, format!("{message}\n")).into_response();
    }
    let open = req.method() == Method::POST && req.uri().path() == "/login";
    let mut req = req;
    if let Some(caller) = app.auth.caller(req.headers()) {
        if let Some(trust) = req.extensions().get::<Arc<crate::conn::Trust>>() {
            trust.prove();
        }
        if let Some(c) = caller {
            // The dashboard and its HTTP API are the job API: a worker's token is refused.
            if let Err(message) = c.may_call(crate::auth::Api::Jobs) {
                if api {
                    return api::error(StatusCode::FORBIDDEN, "forbidden", &message);
                }
                return (StatusCode::FORBIDDEN, format!("{message}\n")).into_response();
            }
            req.extensions_mut().insert(c);
        }
    } else if !open {
        let browser = req
            .headers()
            .get(header::ACCEPT)
            .and_then(|v| v.to_str().ok())
            .is_some_and(|a| a.contains("text/html"));
        if api && !browser {
            // Said apart, as gRPC says them: a person who sent a token needs to hear that it
            // is the wrong one, not that one is needed.
            let message = if req.headers().contains_key(header::AUTHORIZATION) {
                "wrong token: the coordinator knows no such token"
            } else {
                "this coordinator requires a token: send Authorization: Bearer TOKEN"
            };
            let mut r = api::error(StatusCode::UNAUTHORIZED, "unauthenticated", message);
            r.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"tessera\""),
            );
            return r;
        }
        return unauthorized(browser, req.uri().path(), None);
    }
    // A submission and an upload bound their own bodies (the scene limit; the asset store's
    // chunks), and only a caller with a token gets this far.
    let path = req.uri().path();
    let streams = (*req.method() == Method::POST && path == "/api/jobs")
        || (*req.method() == Method::PUT && path.starts_with("/api/assets/"));
    if streams {
        return next.run(req).await;
    }
    match whole_body(req).await {
        Ok(req) => next.run(req).await,
        Err(r) => r,
    }
}

/// The host `req` names (its `Host` header, or an HTTP/2 request's authority), if it is not
/// one the dashboard is served as: an IP address, `localhost` (or a name under it), or one of
/// `allowed` (lower case). A request that names none passes: browsers always send one.
fn foreign_host(req: &Request, allowed: &[String]) -> Option<String> {
    let host = req
        .headers()
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string)
        .or_else(|| req.uri().authority().map(|a| a.as_str().to_string()))?;
    // Without the port; an IPv6 literal keeps its brackets.
    let name = match host.rsplit_once(':') {
        Some((h, port))
            if !h.is_empty() && port.bytes().all(|b| b.is_ascii_digit()) && !h.ends_with(':') =>
        {
            h
        }
        _ => host.as_str(),
    }
    .trim_end_matches('.')
    .to_ascii_lowercase();
    let ip = name
        .strip_prefix('[')
        .and_then(|n| n.strip_suffix(']'))
        .unwrap_or(&name)
        .parse::<std::net::IpAddr>()
        .is_ok();
    let local = name == "localhost" || name.ends_with(".localhost");
    if ip || local || allowed.contains(&name) {
        return None;
    }
    Some(crate::error::truncate(&host))
}

/// Whether a browser says the request comes from another site: its `Sec-Fetch-Site`, or else
/// an `Origin` whose host is not the one asked. A page elsewhere could otherwise make a
/// visitor's browser cancel jobs (with no token configured, nothing else stops it; with one,
/// the cookie's `SameSite=Strict` does too). Clients that are not browsers send neither, and
/// pass.
fn cross_site(headers: &HeaderMap) -> bool {
    let get = |name: &str| headers.get(name).and_then(|v| v.to_str().ok());
    if let Some(site) = get("sec-fetch-site") {
        return !matches!(site, "same-origin" | "none");
    }
    match (get("origin"), get("host")) {
        (Some(origin), Some(host)) => {
            let origin_host = origin
                .split_once("://")
                .map_or(origin, |(_, rest)| rest)
                .trim_end_matches('/');
            !origin_host.eq_ignore_ascii_case(host)
        }
        // An opaque origin ("null", from a sandboxed frame or a file) is another site too.
        (Some(_), None) => true,
        (None, _) => false,
    }
}

/// Most bytes of a request body: the login form's token and path are the largest anyone sends
/// (but for a submission and an upload, [`api`]).
const MAX_BODY: usize = 4096;

/// A submission's body, or the next piece of an upload, must arrive within this.
const BODY_TIME: Duration = Duration::from_secs(60);

/// Reads a request's whole body, at most [`MAX_BODY`] bytes within [`HANDSHAKE`], before any
/// handler sees it: a body sent a byte at a time holds nothing for longer than that, and a
/// large one is refused at once (413) without being read.
async fn whole_body(req: Request) -> Result<Request, Response> {
    let (parts, body) = req.into_parts();
    let declared = parts
        .headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let too_large = || {
        (
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("a request body may be at most {MAX_BODY} bytes\n"),
        )
            .into_response()
    };
    if declared.is_some_and(|n| n > MAX_BODY as u64) {
        return Err(too_large());
    }
    match tokio::time::timeout(HANDSHAKE, axum::body::to_bytes(body, MAX_BODY)).await {
        Ok(Ok(bytes)) => Ok(Request::from_parts(parts, Body::from(bytes))),
        Ok(Err(_)) => Err(too_large()),
        Err(_) => Err((
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "the request's body did not arrive within {} s\n",
                HANDSHAKE.as_secs()
            ),
        )
            .into_response()),
    }
}

fn unauthorized(browser: bool, next: &str, message: Option<&str>) -> Response {
    let mut r = if browser {
        (
            StatusCode::UNAUTHORIZED,
            [(header::CONTENT_TYPE, "text/html; charset=utf-8")],
            login_page(next, message),
        )
            .into_response()
    } else {
        (
            StatusCode::UNAUTHORIZED,
            "this dashboard requires the farm's token: send Authorization: Bearer TOKEN, or \
             log in from a browser\n",
        )
            .into_response()
    };
    r.headers_mut().insert(
        header::WWW_AUTHENTICATE,
        HeaderValue::from_static("Bearer realm=\"tessera\""),
    );
    r
}

/// Where to go after logging in: a path of this site only, never another site's address.
fn local_path(next: &str) -> &str {
    let ok = next.starts_with('/')
        && !next.starts_with("//")
        && !next.contains('\\')
        && next.bytes().all(|b| b.is_ascii_graphic());
    if ok {
        next
    } else {
        "/"
    }
}

fn escape_html(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&#39;")
}

fn login_page(next: &str, message: Option<&str>) -> String {
    include_str!("assets/login.html")
        .replace("{next}", &escape_html(local_path(next)))
        .replace(
            "{message}",
            &message
                .map(|m| format!("<p class=\"error\">{}</p>", escape_html(m)))
                .unwrap_or_default(),
        )
}

#[derive(serde::Deserialize)]
struct LoginForm {
    token: String,
    #[serde(default)]
    next: String,
}

async fn login(State(app): State<App>, Form(form): Form<LoginForm>) -> Response {
    let Some(tokens) = &app.auth.tokens else {
        return redirect(local_path(&form.next), None);
    };
    if tokens.caller(&form.token).is_none() {
        // Slows guessing down; a real token is far too long to guess anyway.
        tokio::time::sleep(Duration::from_millis(250)).await;
        return unauthorized(true, &form.next, Some("wrong token"));
    }
    let now = std::time::Instant::now();
    let Some(session) = app.auth.sessions.open(token_hash(&form.token), now) else {
        return unauthorized(true, &form.next, Some("no random source for a session"));
    };
    let secure = if app.auth.secure { "; Secure" } else { "" };
    let age = sessions::SESSION_TIME.as_secs();
    let cookie =
        format!("{COOKIE}={session}; Path=/; HttpOnly; SameSite=Strict; Max-Age={age}{secure}");
    redirect(local_path(&form.next), Some(cookie))
}

/// Ends the request's session (its cookie no longer works, wherever it was copied to) and
/// clears the cookie.
async fn logout(State(app): State<App>, headers: HeaderMap) -> Response {
    for value in Auth::cookies(&headers) {
        app.auth.sessions.close(value);
    }
    redirect(
        "/",
        Some(format!(
            "{COOKIE}=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0"
        )),
    )
}

fn redirect(to: &str, cookie: Option<String>) -> Response {
    let mut r = (StatusCode::SEE_OTHER, [(header::LOCATION, to.to_string())]).into_response();
    if let Some(c) = cookie.and_then(|c| HeaderValue::from_str(&c).ok()) {
        r.headers_mut().insert(header::SET_COOKIE, c);
    }
    r
}

async fn not_found() -> Response {
    (StatusCode::NOT_FOUND, "no such page\n").into_response()
}

async fn page(State(app): State<App>) -> Response {
    // Logging out means something only where logging in does.
    let logout = if app.auth.tokens.is_some() {
        "  <form method=\"post\" action=\"/logout\"><button class=\"link\">Log out</button></form>\n"
    } else {
        ""
    };
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        include_str!("assets/index.html").replace("{logout}", logout),
    )
        .into_response()
}

async fn app_js() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/javascript; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        include_str!("assets/app.js"),
    )
        .into_response()
}

async fn style_css() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/css; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        include_str!("assets/style.css"),
    )
        .into_response()
}

/// How to draw a preview.
#[derive(serde::Deserialize, utoipa::IntoParams)]
struct PreviewQuery {
    /// Exposure in stops (0 by default).
    #[serde(default)]
    exposure: f32,
    /// `color` (the default), `noise` (each tile's relative noise) or `denoised` (a finished
    /// job's denoised layer).
    #[serde(default)]
    view: Option<String>,
}

/// A running or done job's image so far, tone-mapped, at most 1600 pixels on its longer side.
#[utoipa::path(get, path = "/api/jobs/{id}/preview.png", params(("id" = String, Path), PreviewQuery), responses(
    (status = 200, content_type = "image/png", description = "The preview"),
    (status = 404, body = api::ApiError), (status = 409, body = api::ApiError, description = "a frame range, or a job whose sums are gone"),
))]
async fn preview_png(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(q): Query<PreviewQuery>,
) -> Response {
    let id: JobId = match id.parse() {
        Ok(id) => id,
        Err(e) => return refused(tonic::Status::invalid_argument(format!("{e}"))),
    };
    let view = match q.view.as_deref() {
        None | Some("color") => View::Color,
        Some("noise") => View::Noise,
        Some("denoised") => View::Denoised,
        Some(v) => {
            return refused(tonic::Status::invalid_argument(format!(
                "view {:?}: expected color, noise or denoised",
                crate::error::truncate(v)
            )))
        }
    };
    let exposure = if q.exposure.is_finite() {
        q.exposure
    } else {
        0.0
    };
    match app.previews.png(&app.svc.shared, id, exposure, view).await {
        Ok(png) => (
            [
                (header::CONTENT_TYPE, "image/png"),
                (header::CACHE_CONTROL, "no-store"),
            ],
            Body::from(png.as_ref().clone()),
        )
            .into_response(),
        Err(NoPreview::Unknown) => refused(tonic::Status::not_found(format!("unknown job {id}"))),
        Err(NoPreview::Range) => refused(tonic::Status::failed_precondition(format!(
            "{id} is a frame range: open one of its frames for a preview"
        ))),
        Err(NoPreview::Gone(m)) => refused(tonic::Status::failed_precondition(m)),
        Err(NoPreview::Failed(m)) => refused(tonic::Status::internal(m)),
    }
}

async fn metrics(State(app): State<App>) -> Response {
    let shared = &app.svc.shared;
    let mut g = shared.scheduler().gauges(Instant::now());
    g.store_file_bytes = tokio::fs::metadata(shared.config.data_dir.join(FILE_NAME))
        .await
        .ok()
        .map(|m| m.len());
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        shared.metrics.render(&g),
    )
        .into_response()
}

/// The TLS configuration of the dashboard: the gRPC API's identity, and its client CA if it
/// has one (a farm that asks its clients for certificates asks browsers too).
fn tls_config(tls: &ServerTls) -> Result<Arc<rustls::ServerConfig>, CoordinatorError> {
    use rustls_pki_types::pem::PemObject;
    use rustls_pki_types::{CertificateDer, PrivateKeyDer};
    let bad =
        |what: &str, e: &dyn std::fmt::Display| CoordinatorError::Http(format!("TLS {what}: {e}"));
    let certs = CertificateDer::pem_slice_iter(&tls.cert_pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| bad("certificate", &e))?;
    let key = PrivateKeyDer::from_pem_slice(tls.key_pem.expose().as_bytes())
        .map_err(|e| bad("key", &e))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ServerConfig::builder_with_provider(provider.clone())
        .with_safe_default_protocol_versions()
        .map_err(|e| bad("versions", &e))?;
    let builder = match &tls.client_ca_pem {
        Some(ca) => {
            let mut roots = rustls::RootCertStore::empty();
            for c in CertificateDer::pem_slice_iter(ca) {
                roots
                    .add(c.map_err(|e| bad("client CA", &e))?)
                    .map_err(|e| bad("client CA", &e))?;
            }
            let verifier = rustls::server::WebPkiClientVerifier::builder_with_provider(
                Arc::new(roots),
                provider,
            )
            .build()
            .map_err(|e| bad("client CA", &e))?;
            builder.with_client_cert_verifier(verifier)
        }
        None => builder.with_no_client_auth(),
    };
    let mut cfg = builder
        .with_single_cert(certs, key)
        .map_err(|e| bad("identity", &e))?;
    cfg.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
    Ok(Arc::new(cfg))
}

/// The dashboard, ready to serve: its TLS identity (if any) is loaded, so that a bad one stops
/// the coordinator before it says it is up.
pub(crate) struct Dashboard {
    listener: TcpListener,
    tls: Option<Arc<rustls::ServerConfig>>,
}

impl Dashboard {
    /// Prepares a dashboard on `listener`, with the coordinator's TLS identity if it has one.
    pub(crate) fn new(
        listener: TcpListener,
        tls: Option<&ServerTls>,
    ) -> Result<Self, CoordinatorError> {
        let tls = tls.map(tls_config).transpose()?;
        Ok(Self { listener, tls })
    }

    /// Serves `svc` until `stop` turns true, then lets requests in flight finish (for at most a
    /// few seconds).
    pub(crate) async fn serve(self, svc: Service, stop: watch::Receiver<bool>) {
        serve(svc, self.listener, self.tls, stop).await;
    }
}

async fn serve(
    svc: Service,
    listener: TcpListener,
    tls: Option<Arc<rustls::ServerConfig>>,
    mut stop: watch::Receiver<bool>,
) {
    let config = &svc.shared.config;
    let app = App {
        auth: Arc::new(Auth::new(config.auth(), tls.is_some())),
        previews: Arc::default(),
        uploads: Arc::default(),
        svc: svc.clone(),
    };
    let routes = router(app);
    let acceptor = tls.map(tokio_rustls::TlsAcceptor::from);
    // The gRPC port's accept loop and gate (`conn.rs`): at most MAX_CONNECTIONS open, one
    // whose peer sends nothing for `Config::idle_connection` (60 s) is closed, and so is one
    // that has made no request with the token within `conn::PROVE_WITHIN`; connections without
    // it never hold more than half the slots, so a peer without the token (a slow login body,
    // idle keep-alives) cannot shut the dashboard out.
    let (mut incoming, _gate) = crate::conn::Limited::new(
        listener,
        MAX_CONNECTIONS,
        config.idle_connection,
        config.token.is_none() && config.tokens.is_none(),
    );
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    loop {
        let conn = tokio::select! {
            c = incoming.next() => match c {
                Some(Ok(c)) => c,
                Some(Err(_)) => continue,
                None => break,
            },
            _ = stopped(&mut stop) => break,
        };
        let peer = tonic::transport::server::Connected::connect_info(&conn)
            .remote_addr()
            .map(|a| a.to_string())
            .unwrap_or_default();
        // The check marks the connection proven when a request on it carries the token.
        let routes = routes.clone().layer(axum::Extension(conn.trust()));
        let acceptor = acceptor.clone();
        let watcher = graceful.watcher();
        tokio::spawn(async move {
            let io: Box<dyn Io> = match acceptor {
                Some(a) => match tokio::time::timeout(HANDSHAKE, a.accept(conn)).await {
                    Ok(Ok(s)) => Box::new(s),
                    Ok(Err(e)) => return debug!("dashboard: TLS handshake from {peer}: {e}"),
                    Err(_) => return debug!("dashboard: TLS handshake from {peer} timed out"),
                },
                None => Box::new(conn),
            };
            if let Err(e) = watcher.watch(serve_connection(io, routes)).await {
                debug!("dashboard: connection from {peer}: {e}");
            }
        });
    }
    let _ = tokio::time::timeout(Duration::from_secs(5), graceful.shutdown()).await;
}

/// Returns once `stop` is true (or its sender is gone).
async fn stopped(stop: &mut watch::Receiver<bool>) {
    let _ = stop.wait_for(|s| *s).await;
}

/// A connection's byte stream, plain or TLS.
trait Io: tokio::io::AsyncRead + tokio::io::AsyncWrite + Send + Unpin {}
impl<T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Send + Unpin> Io for T {}

/// An accepted connection served over HTTP/1.1 or HTTP/2.
fn serve_connection(
    io: Box<dyn Io>,
    routes: Router,
) -> impl hyper_util::server::graceful::GracefulConnection<
    Error = Box<dyn std::error::Error + Send + Sync>,
> {
    let mut builder =
        hyper_util::server::conn::auto::Builder::new(hyper_util::rt::TokioExecutor::new());
    builder
        .http1()
        .timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(HANDSHAKE);
    let svc = hyper_util::service::TowerToHyperService::new(routes);
    builder
        .serve_connection_with_upgrades(hyper_util::rt::TokioIo::new(io), svc)
        .into_owned()
}
