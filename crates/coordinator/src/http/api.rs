//! The HTTP JSON API (docs/farm.md, "The HTTP API for pipelines"): what the `tessera` client
//! commands do over gRPC, as JSON on the dashboard's port, behind the same token (a bearer
//! header; the dashboard's session cookie too) and TLS. Each route that acts calls the gRPC
//! service's own handler, so the two APIs check the same things and cannot disagree; the
//! OpenAPI document at `/api/openapi.json` is generated from the annotations here and in
//! [`super::intake`] ([`super::openapi`]).
//!
//! Errors are JSON: `{"code": "not_found", "error": "unknown job job-000009"}`. The `code` is
//! stable (the gRPC status's name in snake case; `unauthenticated`, `forbidden` and
//! `payload_too_large` from the HTTP layer); the `error` is for people and may change.
//!
//! Bodies are bounded like everything else here: the dashboard's 4 KiB for most routes, the
//! coordinator's scene limit for a submission, and the asset store's own checks for an upload,
//! which arrives a mebibyte at a time.

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::{Deserialize, Serialize};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_server::Jobs;
use tessera_proto::view::{JobView, LogPage, WorkerView};
use tonic::Request as RpcRequest;
use utoipa::ToSchema;

use super::App;
use crate::auth::Caller;
use crate::service::job_id;

/// An error, as every route answers one.
#[derive(Serialize, ToSchema)]
pub(super) struct ApiError {
    /// Stable: `not_found`, `invalid_argument`, `failed_precondition`, `permission_denied`,
    /// `resource_exhausted`, `unauthenticated`, `forbidden`, `payload_too_large`, `internal`, …
    code: &'static str,
    /// For people; may change.
    error: String,
}

/// An error answer with HTTP status `status` and stable code `code`.
pub(super) fn error(
    status: StatusCode,
    code: &'static str,
    message: impl Into<String>,
) -> Response {
    (
        status,
        Json(ApiError {
            code,
            error: message.into(),
        }),
    )
        .into_response()
}

/// A gRPC refusal as an HTTP answer with the same message and a stable code.
pub(super) fn refused(s: tonic::Status) -> Response {
    use tonic::Code;
    let (status, code) = match s.code() {
        Code::NotFound => (StatusCode::NOT_FOUND, "not_found"),
        Code::InvalidArgument => (StatusCode::BAD_REQUEST, "invalid_argument"),
        Code::FailedPrecondition => (StatusCode::CONFLICT, "failed_precondition"),
        Code::AlreadyExists => (StatusCode::CONFLICT, "already_exists"),
        Code::PermissionDenied => (StatusCode::FORBIDDEN, "permission_denied"),
        Code::Unauthenticated => (StatusCode::UNAUTHORIZED, "unauthenticated"),
        Code::ResourceExhausted => (StatusCode::TOO_MANY_REQUESTS, "resource_exhausted"),
        Code::Unavailable => (StatusCode::SERVICE_UNAVAILABLE, "unavailable"),
        _ => (StatusCode::INTERNAL_SERVER_ERROR, "internal"),
    };
    error(status, code, s.message())
}

/// A gRPC request of `msg` from `caller`, as the token check found it.
pub(super) fn as_caller<T>(msg: T, caller: Option<Extension<Caller>>) -> RpcRequest<T> {
    let mut req = RpcRequest::new(msg);
    if let Some(Extension(c)) = caller {
        req.extensions_mut().insert(c);
    }
    req
}

/// Which page of jobs to list.
#[derive(Deserialize, utoipa::IntoParams)]
pub(super) struct Page {
    /// Most jobs in the answer (default 200, at most 1000).
    limit: Option<u32>,
    /// The `X-Next-Page` header of the previous answer (default: the first page).
    page: Option<String>,
}

/// A page of jobs: those still to finish first, in scheduling order (priority, then
/// submission), then the ended ones, most recently ended first. When there are more, the
/// `X-Next-Page` header gives the `page` to ask for next.
#[utoipa::path(get, path = "/api/jobs", params(Page), responses((status = 200, body = Vec<JobView>, headers(("X-Next-Page" = String, description = "the next page's `page`, when there is one")))))]
pub(super) async fn list_jobs(State(app): State<App>, Query(p): Query<Page>) -> Response {
    let (views, next) = match app
        .svc
        .job_page(p.page.as_deref().unwrap_or(""), p.limit.unwrap_or(0))
    {
        Ok(v) => v,
        Err(s) => return refused(s),
    };
    let mut r = Json(views).into_response();
    if let Some(v) = next.and_then(|n| HeaderValue::from_str(&n.to_string()).ok()) {
        r.headers_mut().insert("x-next-page", v);
    }
    r
}

/// One job (a frame range: the whole range, with each frame).
#[utoipa::path(get, path = "/api/jobs/{id}", params(("id" = String, Path, description = "job id")), responses(
    (status = 200, body = JobView), (status = 404, body = ApiError),
))]
pub(super) async fn job(State(app): State<App>, Path(id): Path<String>) -> Response {
    match job_id(&id).and_then(|id| app.svc.job_view(id)) {
        Ok(v) => Json(v).into_response(),
        Err(s) => refused(s),
    }
}

/// Cancels a job (every frame of a range still active), answering the job as it now stands,
/// as pause and resume do: its `state` is `cancelled`, or the final state it already had.
#[utoipa::path(post, path = "/api/jobs/{id}/cancel", params(("id" = String, Path)), responses(
    (status = 200, body = JobView), (status = 403, body = ApiError, description = "another user's job"), (status = 404, body = ApiError),
))]
pub(super) async fn cancel(
    State(app): State<App>,
    Path(id): Path<String>,
    caller: Option<Extension<Caller>>,
) -> Response {
    let req = as_caller(pb::CancelJobRequest { job_id: id.clone() }, caller);
    match app.svc.cancel_job(req).await {
        Ok(_) => match job_id(&id).and_then(|id| app.svc.job_view(id)) {
            Ok(v) => Json(v).into_response(),
            Err(s) => refused(s),
        },
        Err(s) => refused(s),
    }
}

async fn update(
    app: &App,
    id: String,
    paused: Option<bool>,
    priority: Option<i32>,
    caller: Option<Extension<Caller>>,
) -> Response {
    let req = as_caller(
        pb::UpdateJobRequest {
            job_id: id.clone(),
            paused,
            priority,
        },
        caller,
    );
    match app.svc.update_job(req).await {
        Ok(_) => match job_id(&id).and_then(|id| app.svc.job_view(id)) {
            Ok(v) => Json(v).into_response(),
            Err(s) => refused(s),
        },
        Err(s) => refused(s),
    }
}

/// Pauses a queued or running job: its leased units finish, nothing new is leased.
#[utoipa::path(post, path = "/api/jobs/{id}/pause", params(("id" = String, Path)), responses(
    (status = 200, body = JobView), (status = 403, body = ApiError), (status = 404, body = ApiError), (status = 409, body = ApiError, description = "it has ended"),
))]
pub(super) async fn pause(
    State(app): State<App>,
    Path(id): Path<String>,
    caller: Option<Extension<Caller>>,
) -> Response {
    update(&app, id, Some(true), None, caller).await
}

/// Resumes a paused job.
#[utoipa::path(post, path = "/api/jobs/{id}/resume", params(("id" = String, Path)), responses(
    (status = 200, body = JobView), (status = 403, body = ApiError), (status = 404, body = ApiError), (status = 409, body = ApiError),
))]
pub(super) async fn resume(
    State(app): State<App>,
    Path(id): Path<String>,
    caller: Option<Extension<Caller>>,
) -> Response {
    update(&app, id, Some(false), None, caller).await
}

/// A new priority.
#[derive(Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct PriorityBody {
    /// Higher runs first.
    priority: i32,
}

/// Sets a queued or running job's priority.
#[utoipa::path(post, path = "/api/jobs/{id}/priority", params(("id" = String, Path)), request_body = PriorityBody, responses(
    (status = 200, body = JobView), (status = 400, body = ApiError), (status = 403, body = ApiError), (status = 404, body = ApiError), (status = 409, body = ApiError),
))]
pub(super) async fn priority(
    State(app): State<App>,
    Path(id): Path<String>,
    caller: Option<Extension<Caller>>,
    body: axum::body::Bytes,
) -> Response {
    match serde_json::from_slice::<PriorityBody>(&body) {
        Ok(b) => update(&app, id, None, Some(b.priority), caller).await,
        Err(e) => error(
            StatusCode::BAD_REQUEST,
            "invalid_argument",
            format!("body: {e}"),
        ),
    }
}

/// The frame a route is about, for a frame-range job.
#[derive(Deserialize, utoipa::IntoParams)]
pub(super) struct FrameQuery {
    /// The frame, for a frame-range job.
    frame: Option<u32>,
}

/// The jobs a retry put back.
#[derive(Serialize, ToSchema)]
pub(super) struct Retried {
    /// Their ids: the failed frames, and the jobs that waited for them.
    retried: Vec<String>,
}

/// Puts a job's failed frames back in the queue (`tessera retry`), with the jobs that failed
/// waiting for them.
#[utoipa::path(post, path = "/api/jobs/{id}/retry", params(("id" = String, Path), FrameQuery), responses(
    (status = 200, body = Retried), (status = 403, body = ApiError), (status = 404, body = ApiError),
    (status = 409, body = ApiError, description = "no failed frame, or past the retry window"),
))]
pub(super) async fn retry(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(q): Query<FrameQuery>,
    caller: Option<Extension<Caller>>,
) -> Response {
    let req = as_caller(
        pb::RetryJobRequest {
            job_id: id,
            frame: q.frame,
        },
        caller,
    );
    match app.svc.retry_job(req).await {
        Ok(r) => Json(Retried {
            retried: r.into_inner().job_ids,
        })
        .into_response(),
        Err(s) => refused(s),
    }
}

/// What to read of a job's log.
#[derive(Deserialize, utoipa::IntoParams)]
pub(super) struct LogsQuery {
    /// Only this frame's lines, for a frame-range job.
    frame: Option<u32>,
    /// Only lines after this sequence number (to follow).
    #[serde(default)]
    after: u64,
}

/// The warnings and errors workers reported about a job's units (`tessera logs`).
#[utoipa::path(get, path = "/api/jobs/{id}/logs", params(("id" = String, Path), LogsQuery), responses(
    (status = 200, body = LogPage), (status = 404, body = ApiError),
))]
pub(super) async fn logs(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(q): Query<LogsQuery>,
) -> Response {
    match app.svc.log_page(&id, q.frame, q.after).await {
        Ok(page) => Json(page).into_response(),
        Err(s) => refused(s),
    }
}

/// A done job's EXR (a frame range's: one frame's, with `frame`).
#[utoipa::path(get, path = "/api/jobs/{id}/output.exr", params(("id" = String, Path), FrameQuery), responses(
    (status = 200, content_type = "image/x-exr", description = "The EXR, byte for byte the file the coordinator wrote"),
    (status = 404, body = ApiError), (status = 409, body = ApiError, description = "not done"),
))]
pub(super) async fn output_exr(
    State(app): State<App>,
    Path(id): Path<String>,
    Query(q): Query<FrameQuery>,
) -> Response {
    let read = match job_id(&id) {
        Ok(id) => app.svc.read_output(id, q.frame).await,
        Err(s) => Err(s),
    };
    let (name, data) = match read {
        Ok(r) => r,
        Err(s) => return refused(s),
    };
    // Output names are checked at submission (no quotes, separators or control characters).
    let disposition = format!("attachment; filename=\"{}\"", name.replace('"', ""));
    let mut r = ([(header::CONTENT_TYPE, "image/x-exr")], Body::from(data)).into_response();
    if let Ok(v) = HeaderValue::from_str(&disposition) {
        r.headers_mut().insert(header::CONTENT_DISPOSITION, v);
    }
    r
}

/// Every worker the coordinator has seen.
#[utoipa::path(get, path = "/api/workers", responses((status = 200, body = Vec<WorkerView>)))]
pub(super) async fn list_workers(State(app): State<App>) -> Response {
    Json(app.svc.worker_views()).into_response()
}

/// The workers a drain reached.
#[derive(Serialize, ToSchema)]
pub(super) struct Drained {
    /// Their public ids.
    drained: Vec<String>,
}

/// Drains one worker, by public id: it finishes its units, hands back the rest, and exits.
#[utoipa::path(post, path = "/api/workers/{id}/drain", params(("id" = String, Path, description = "public worker id, e.g. w1-3")), responses(
    (status = 200, body = Drained), (status = 400, body = ApiError), (status = 403, body = ApiError, description = "not an admin"), (status = 404, body = ApiError),
))]
pub(super) async fn drain(
    State(app): State<App>,
    Path(id): Path<String>,
    caller: Option<Extension<Caller>>,
) -> Response {
    let req = match by_worker_id(id) {
        Ok(worker) => as_caller(pb::DrainWorkerRequest { worker }, caller),
        Err(status) => return refused(status),
    };
    match app.svc.drain_worker(req).await {
        Ok(r) => Json(Drained {
            drained: r.into_inner().drained,
        })
        .into_response(),
        Err(s) => refused(s),
    }
}

/// A worker route's id, by public id only: a name could reach several, which a button on one
/// row must not.
fn by_worker_id(id: String) -> Result<String, tonic::Status> {
    if id.parse::<tessera_proto::ids::WorkerId>().is_err() {
        return Err(tonic::Status::invalid_argument(format!(
            "{:?} is not a worker id",
            crate::error::truncate(&id)
        )));
    }
    Ok(id)
}

/// The workers a release reached.
#[derive(Serialize, ToSchema)]
pub(super) struct Released {
    /// Their public ids.
    released: Vec<String>,
}

/// Lifts one worker's quarantine, by public id: its invalid results and any audit conviction
/// are forgotten and it may lease again.
#[utoipa::path(post, path = "/api/workers/{id}/release", params(("id" = String, Path, description = "public worker id, e.g. w1-3")), responses(
    (status = 200, body = Released), (status = 400, body = ApiError), (status = 403, body = ApiError, description = "not an admin"), (status = 404, body = ApiError, description = "no quarantined worker has that id"),
))]
pub(super) async fn release(
    State(app): State<App>,
    Path(id): Path<String>,
    caller: Option<Extension<Caller>>,
) -> Response {
    let req = match by_worker_id(id) {
        Ok(worker) => as_caller(pb::ReleaseWorkerRequest { worker }, caller),
        Err(status) => return refused(status),
    };
    match app.svc.release_worker(req).await {
        Ok(r) => Json(Released {
            released: r.into_inner().released,
        })
        .into_response(),
        Err(s) => refused(s),
    }
}
