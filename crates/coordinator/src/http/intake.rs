//! The two routes of the HTTP API that take more than a few bytes ([`super::api`]): a job's
//! submission (its scene, up to the coordinator's scene limit) and the upload of a file a
//! scene names (any size the asset store allows, stored a mebibyte at a time). The token check
//! lets them read their own bodies, each with its own bound and a time limit on every piece.

use std::collections::BTreeMap;

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::{Deserialize, Serialize};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_server::Jobs;
use tokio_stream::StreamExt as _;
use tonic::Request as RpcRequest;
use utoipa::ToSchema;

use super::api::{as_caller, error, refused, ApiError};
use super::App;
use crate::auth::Caller;

/// A job to submit: what `tessera submit` sends.
#[derive(Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct SubmitBody {
    /// The scene file's text; with `format: "gltf"`, the glTF file's name among `files`.
    scene: String,
    /// `toml` (the default), `json`, or `gltf`: then `scene` names the glTF file (.gltf or
    /// .glb) among `files`, rendered as `tessera submit` renders one.
    #[serde(default)]
    format: Option<String>,
    /// A name for the scene in error messages (its file name).
    #[serde(default)]
    scene_name: String,
    /// Samples per pixel.
    spp: u32,
    /// Seed (0 by default).
    #[serde(default)]
    seed: u64,
    /// Samples per work unit (0: the coordinator's choice).
    #[serde(default)]
    batch: u32,
    /// An adaptive job's noise target (0: every pixel takes `spp` samples).
    #[serde(default)]
    noise_target: f64,
    /// AOVs for denoising, e.g. `albedo,normal,depth`.
    #[serde(default)]
    aovs: String,
    /// One frame of the scene's animation.
    #[serde(default)]
    frame: Option<u32>,
    /// A frame range, `A-B` or `A-B:STEP`: one job, one EXR per frame.
    #[serde(default)]
    frames: Option<String>,
    /// With `frames`: every frame's first samples before any frame's next.
    #[serde(default)]
    progressive: bool,
    /// Tile edge in pixels (0: the coordinator's default).
    #[serde(default)]
    tile_size: u32,
    /// The EXR's file name (`NAME.exr`); the job id's by default.
    #[serde(default)]
    name: String,
    /// Higher runs first.
    #[serde(default)]
    priority: i32,
    /// Write per-pixel variance channels.
    #[serde(default)]
    variance: bool,
    /// Write the sample-count channel.
    #[serde(default)]
    sample_count: bool,
    /// Add a denoised layer: `{"quality": "fast"|"balanced"|"high", "ldr": false}` (both
    /// optional); made by a coordinator started with `--denoise`, else by a worker started
    /// with `--denoise` (the job waits for one).
    #[serde(default)]
    denoise: Option<DenoiseRequest>,
    /// The files the scene names, each uploaded first (`PUT /api/assets/{sha256}`): name as in
    /// the scene → SHA-256.
    #[serde(default)]
    files: BTreeMap<String, String>,
    /// A job this one starts after.
    #[serde(default)]
    after: String,
    /// Tags a worker must have (`pool=fast`, `cpu:avx2`).
    #[serde(default)]
    require: Vec<String>,
    /// Memory a worker must report, in bytes.
    #[serde(default)]
    min_memory_bytes: u64,
    /// Path guiding (not with a noise target or frames).
    #[serde(default)]
    guiding: bool,
    /// The film's size, `[width, height]`, in place of the scene file's own.
    #[serde(default)]
    resolution: Option<[u32; 2]>,
    /// With `format: "gltf"`: the glTF camera to render from, by name or index (`--camera`).
    #[serde(default)]
    camera: Option<String>,
    /// With `format: "gltf"`: an HDR map among `files` to light it by (`--environment`).
    #[serde(default)]
    environment: Option<String>,
}

impl SubmitBody {
    /// A glTF submission (`format: "gltf"`, `scene` the glTF file's name among `files`) as the
    /// scene text `tessera submit` sends for it ([`gltf_scene_text`]), read from the uploaded
    /// file's JSON (a .glb's JSON chunk alone); other submissions as they are.
    async fn with_gltf_text(mut self, app: &App) -> Result<Self, tonic::Status> {
        if self.format.as_deref() != Some("gltf") {
            if self.camera.is_some() || self.environment.is_some() {
                return Err(tonic::Status::invalid_argument(
                    "camera and environment are for glTF scenes (format \"gltf\")",
                ));
            }
            return Ok(self);
        }
        let name = self.scene.clone();
        tessera_render::scene::assets::check_file_name(&name)
            .map_err(|e| tonic::Status::invalid_argument(format!("scene: {e}")))?;
        if !tessera_render::scene::is_gltf(std::path::Path::new(&name)) {
            return Err(tonic::Status::invalid_argument(format!(
                "scene: with format \"gltf\", name the glTF file (.gltf or .glb) among `files`, \
                 not `{}`",
                crate::error::truncate(&name)
            )));
        }
        let sha = self.files.get(&name).cloned().ok_or_else(|| {
            tonic::Status::invalid_argument(format!(
                "scene: `{}` is not among `files` (upload it and name it there)",
                crate::error::truncate(&name)
            ))
        })?;
        let assets = app.svc.shared.assets.clone();
        let max = app.svc.shared.config.limits.max_bytes as u64;
        let json = tokio::task::spawn_blocking(move || gltf_json(&assets, &sha, max))
            .await
            .map_err(|e| tonic::Status::internal(e.to_string()))??;
        let options = tessera_render::scene::GltfOptions {
            camera: self.camera.take(),
            environment: self.environment.take(),
        };
        self.scene = tessera_render::scene::gltf_scene_text(&name, &json, &options);
        self.format = None;
        if self.scene_name.is_empty() {
            self.scene_name = name;
        }
        Ok(self)
    }
}

/// The JSON of the uploaded glTF file `sha`: a .glb's JSON chunk (read alone, however large
/// its binary chunk), or a .gltf file's whole text; at most `max` bytes of it.
fn gltf_json(
    assets: &crate::assets::AssetStore,
    sha: &str,
    max: u64,
) -> Result<Vec<u8>, tonic::Status> {
    let held = |e: crate::assets::AssetError| tonic::Status::failed_precondition(e.to_string());
    let head = assets.read_from(sha, 0, 20).map_err(held)?;
    let (at, len) = if head.len() == 20 && head.starts_with(b"glTF") && &head[16..20] == b"JSON" {
        (
            20,
            u64::from(u32::from_le_bytes([head[12], head[13], head[14], head[15]])),
        )
    } else {
        (0, max + 1)
    };
    let json = assets.read_from(sha, at, len.min(max + 1)).map_err(held)?;
    if json.len() as u64 > max {
        return Err(tonic::Status::resource_exhausted(format!(
            "the glTF file's JSON is above the coordinator's scene limit of {max} bytes"
        )));
    }
    Ok(json)
}

impl SubmitBody {
    /// The gRPC submission this body asks for.
    fn into_request(self) -> Result<pb::SubmitJobRequest, String> {
        let scene_format = match self.format.as_deref() {
            None | Some("toml") => pb::SceneFormat::Toml,
            Some("json") => pb::SceneFormat::Json,
            Some(f) => {
                return Err(format!(
                    "format {:?}: expected toml, json or gltf",
                    crate::error::truncate(f)
                ))
            }
        };
        let frames = match &self.frames {
            None => None,
            Some(f) => {
                let r: tessera_render::scene::FrameRange =
                    f.parse().map_err(|e| format!("frames: {e}"))?;
                Some(pb::FrameRange {
                    first: r.first,
                    last: r.last,
                    step: r.step,
                })
            }
        };
        Ok(pb::SubmitJobRequest {
            scene_text: self.scene,
            scene_format: scene_format as i32,
            scene_name: self.scene_name,
            settings: Some(pb::RenderSettings {
                spp: self.spp,
                seed: self.seed,
                batch: self.batch,
                strategy: 0,
                noise_target: self.noise_target,
                frame: self.frame,
                aovs: self.aovs,
                guiding: self.guiding,
                resolution: self
                    .resolution
                    .map(|[width, height]| pb::Resolution { width, height }),
            }),
            tile_size: self.tile_size,
            output_name: self.name,
            priority: self.priority,
            channels: Some(pb::OutputChannels {
                variance: self.variance,
                sample_count: self.sample_count,
                denoise: self.denoise.map(|d| pb::DenoiseOptions {
                    quality: d.quality,
                    ldr: d.ldr,
                }),
            }),
            frames,
            assets: self
                .files
                .into_iter()
                .map(|(name, sha256)| pb::AssetRef { name, sha256 })
                .collect(),
            after: self.after,
            require: self.require,
            min_memory_bytes: self.min_memory_bytes,
            progressive: self.progressive,
        })
    }
}

/// A submitted job.
#[derive(Serialize, ToSchema)]
pub(super) struct Submitted {
    /// Its id.
    job_id: String,
    /// Its scene's content hash.
    scene_sha256: String,
    /// Work units in all.
    units: u64,
    /// Frames (1 without a range).
    frames: u32,
}

/// Submits a job; the scene is checked as `tessera submit`'s is, and refused with its
/// `file:line:column` message.
#[utoipa::path(post, path = "/api/jobs", request_body = SubmitBody, responses(
    (status = 201, body = Submitted),
    (status = 400, body = ApiError, description = "a bad scene or setting (`invalid_argument`)"),
    (status = 409, body = ApiError, description = "a file not uploaded, or an `after` job that failed (`failed_precondition`)"),
    (status = 413, body = ApiError, description = "a scene above the coordinator's limit"),
    (status = 429, body = ApiError, description = "over a limit (`resource_exhausted`)"),
))]
pub(super) async fn submit(
    State(app): State<App>,
    caller: Option<Extension<Caller>>,
    headers: axum::http::HeaderMap,
    body: Body,
) -> Response {
    let limit = app.svc.shared.config.limits.max_bytes + (64 << 10);
    let too_large = || {
        error(
            StatusCode::PAYLOAD_TOO_LARGE,
            "payload_too_large",
            format!(
                "a submission may be at most {limit} bytes (the coordinator's --max-scene-bytes \
                 and 64 KiB more)"
            ),
        )
    };
    // Refused before a byte is read when the client says how much it sends.
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit as u64) {
        return too_large();
    }
    let bytes =
        match tokio::time::timeout(super::BODY_TIME, axum::body::to_bytes(body, limit)).await {
            Ok(Ok(b)) => b,
            Ok(Err(_)) => return too_large(),
            Err(_) => {
                return error(
                    StatusCode::REQUEST_TIMEOUT,
                    "timeout",
                    "the submission did not arrive in time",
                )
            }
        };
    let body: SubmitBody = match serde_json::from_slice(&bytes) {
        Ok(b) => b,
        Err(e) => {
            return error(
                StatusCode::BAD_REQUEST,
                "invalid_argument",
                format!("body: {e}"),
            )
        }
    };
    let body = match body.with_gltf_text(&app).await {
        Ok(b) => b,
        Err(s) => return refused(s),
    };
    let req = match body.into_request() {
        Ok(r) => r,
        Err(e) => return error(StatusCode::BAD_REQUEST, "invalid_argument", e),
    };
    match app.svc.submit_job(as_caller(req, caller)).await {
        Ok(r) => {
            let r = r.into_inner();
            let out = Submitted {
                job_id: r.job_id,
                scene_sha256: r.scene_hash,
                units: r.units,
                frames: r.frames,
            };
            (StatusCode::CREATED, Json(out)).into_response()
        }
        Err(s) => refused(s),
    }
}

/// How much of a file the coordinator holds.
#[derive(Serialize, ToSchema)]
pub(super) struct Held {
    /// Bytes held: the whole file once complete, else where an upload resumes.
    received: u64,
    /// The whole file is held and its hash checked.
    complete: bool,
}

/// How much of the file of this SHA-256 the coordinator holds.
#[utoipa::path(get, path = "/api/assets/{sha256}", params(("sha256" = String, Path, description = "64 lower-case hex digits")), responses(
    (status = 200, body = Held), (status = 400, body = ApiError),
))]
pub(super) async fn asset_status(State(app): State<App>, Path(sha): Path<String>) -> Response {
    let req = RpcRequest::new(pb::GetAssetStatusRequest { sha256: sha });
    match app.svc.get_asset_status(req).await {
        Ok(r) => {
            let r = r.into_inner();
            Json(Held {
                received: r.received,
                complete: r.complete,
            })
            .into_response()
        }
        Err(s) => refused(s),
    }
}

/// Where an upload's bytes go.
#[derive(Deserialize, utoipa::IntoParams)]
pub(super) struct UploadQuery {
    /// Where the body starts in the file: 0, or the `received` an interrupted upload reached.
    #[serde(default)]
    offset: u64,
    /// The whole file's size in bytes.
    total: u64,
}

/// Uploads a file a scene names (or the rest of one), addressed by its SHA-256; the hash is
/// checked when the last byte arrives, and a mismatch throws the upload away.
#[utoipa::path(put, path = "/api/assets/{sha256}", params(("sha256" = String, Path), UploadQuery),
    request_body(content = Vec<u8>, content_type = "application/octet-stream"),
    responses(
        (status = 200, body = Held), (status = 400, body = ApiError, description = "a wrong offset or hash, or bytes past the size"),
        (status = 429, body = ApiError, description = "above the store's limits"),
))]
pub(super) async fn upload_asset(
    State(app): State<App>,
    Path(sha): Path<String>,
    Query(q): Query<UploadQuery>,
    caller: Option<Extension<Caller>>,
    trust: Option<Extension<std::sync::Arc<crate::conn::Trust>>>,
    body: Body,
) -> Response {
    let config = &app.svc.shared.config;
    // One user's uploads at once are bounded: trickling many could hold every connection.
    let who = match (&caller, &trust) {
        (Some(c), _) if !c.user.is_empty() => format!("user {}", c.user),
        (_, Some(t)) => format!("address {}", t.peer()),
        _ => "anyone".to_string(),
    };
    let Some(_slot) = app.uploads.take(&who, config.max_uploads_per_user) else {
        return error(
            StatusCode::TOO_MANY_REQUESTS,
            "resource_exhausted",
            format!(
                "{who} has {} uploads under way, the most at once; finish one first",
                config.max_uploads_per_user
            ),
        );
    };
    let started = tokio::time::Instant::now();
    let mut received: u64 = 0;
    let mut stream = body.into_data_stream();
    let mut offset = q.offset;
    let mut pending: Vec<u8> = Vec::new();
    let mut held = None;
    loop {
        let next = tokio::time::timeout(super::BODY_TIME, stream.next()).await;
        let frame = match next {
            Ok(Some(Ok(f))) => Some(f),
            Ok(None) => None,
            Ok(Some(Err(e))) => {
                return error(
                    StatusCode::BAD_REQUEST,
                    "invalid_argument",
                    format!("body: {e}"),
                )
            }
            Err(_) => return error(StatusCode::REQUEST_TIMEOUT, "timeout", "the upload stalled"),
        };
        let end = frame.is_none();
        if let Some(f) = frame {
            received += f.len() as u64;
            pending.extend_from_slice(&f);
        }
        // A minimum rate, once past the grace: the bytes so far are kept below, for a resume.
        let elapsed = started.elapsed();
        if !end
            && elapsed > config.upload_grace
            && (received as f64) < config.upload_min_rate as f64 * elapsed.as_secs_f64()
        {
            return error(
                StatusCode::REQUEST_TIMEOUT,
                "timeout",
                format!(
                    "the upload arrives slower than {} bytes a second; resume it from where it \
                     stands (GET /api/assets/{sha})",
                    config.upload_min_rate
                ),
            );
        }
        // A mebibyte at a time, as the gRPC upload's chunks; the last piece whatever is left.
        while pending.len() >= crate::assets::CHUNK_BYTES || (end && !pending.is_empty()) {
            let n = pending.len().min(crate::assets::CHUNK_BYTES);
            let chunk: Vec<u8> = pending.drain(..n).collect();
            let (assets, hash, at) = (app.svc.shared.assets.clone(), sha.clone(), offset);
            let total = q.total;
            let r =
                tokio::task::spawn_blocking(move || assets.append(&hash, at, total, &chunk)).await;
            match r {
                Ok(Ok(h)) => {
                    offset += n as u64;
                    held = Some(h);
                    if h.complete {
                        break;
                    }
                }
                Ok(Err(e)) => return refused(crate::service::asset_status(e)),
                Err(e) => {
                    return error(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string())
                }
            }
        }
        if end || held.is_some_and(|h| h.complete) {
            break;
        }
    }
    let held = match held {
        Some(h) => h,
        // An empty body changes nothing: it asks where the upload stands.
        None => match app.svc.shared.assets.status(&sha) {
            Ok(h) => h,
            Err(e) => return refused(crate::service::asset_status(e)),
        },
    };
    Json(Held {
        received: held.received,
        complete: held.complete,
    })
    .into_response()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_submission_converts_to_the_grpc_request_and_bad_fields_are_named() {
        let body: SubmitBody = serde_json::from_str(
            r#"{"scene": "x", "spp": 16, "frames": "1-9:2", "files": {"m.obj": "ab"}, "format": "json"}"#,
        )
        .expect("body");
        let req = body.into_request().expect("request");
        assert_eq!(req.settings.expect("settings").spp, 16);
        assert_eq!(
            req.frames.map(|f| (f.first, f.last, f.step)),
            Some((1, 9, 2))
        );
        assert_eq!(req.scene_format, pb::SceneFormat::Json as i32);
        assert_eq!(req.assets[0].name, "m.obj");
        let bad: SubmitBody =
            serde_json::from_str(r#"{"scene": "x", "spp": 1, "frames": "9-1"}"#).expect("body");
        assert!(bad
            .into_request()
            .expect_err("range")
            .starts_with("frames: "));
        let bad: SubmitBody =
            serde_json::from_str(r#"{"scene": "x", "spp": 1, "format": "yaml"}"#).expect("body");
        assert!(bad.into_request().expect_err("format").contains("yaml"));
        let e = serde_json::from_str::<SubmitBody>(r#"{"scene": "x", "spp": 1, "sp": 2}"#)
            .err()
            .expect("unknown field");
        assert!(e.to_string().contains("unknown field `sp`"), "{e}");
    }
}

/// A submission's `denoise` object.
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct DenoiseRequest {
    /// `fast`, `balanced` or `high` (empty: `high`).
    #[serde(default)]
    quality: String,
    /// Filter the beauty as LDR.
    #[serde(default)]
    ldr: bool,
}
