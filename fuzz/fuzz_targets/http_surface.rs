//! Sequences of HTTP requests to the dashboard and `/metrics`, through the coordinator's real
//! routes and checks over its real service and store (`InProcess::http`: everything `--http`
//! serves but the network and the connection gate), as `rpc_surface` does for gRPC: every
//! route with ids, query strings, headers and bodies taken from the input (valid, invalid,
//! overlong, not UTF-8), the login form, logout, cancel (with the token or without, from the
//! same site or another), previews of a job while a fake worker's honest results come in, and
//! raw method/path pairs.
//!
//! Checks: no request panics or answers 500; with a token configured, a request that does not
//! carry it gets nothing but the login's answers (401, or 403/408/413 from the checks before
//! it), and never cancels the job; a cross-site POST never cancels it; every 200 from a JSON
//! endpoint is JSON, and from a preview a PNG. Inputs of odd length run with a token.
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use tessera_coordinator::{Config, InProcess};
use tessera_proto::v1 as pb;
use tessera_proto::v1::jobs_server::Jobs;
use tessera_proto::v1::workers_server::Workers;
use tessera_proto::Secret;
use tessera_render::scene::{Format, Limits, Scene};
use tessera_render::{render_tile, PixelRect, RenderSettings, IMAGE_REVISION};
use tonic::Request;

const TOKEN: &str = "fuzz-token-0123456789abcdef";

fn scene_text() -> &'static str {
    static TEXT: OnceLock<String> = OnceLock::new();
    TEXT.get_or_init(|| {
        include_str!("../../scenes/cornell-box.toml")
            .replace("width = 256", "width = 8")
            .replace("height = 256", "height = 6")
    })
}

fn scene() -> &'static Scene {
    static SCENE: OnceLock<Scene> = OnceLock::new();
    SCENE.get_or_init(|| {
        Scene::text(scene_text(), Format::Toml, "c.toml", &Limits::default())
            .load()
            .expect("scene")
    })
}

fn settings() -> RenderSettings {
    RenderSettings {
        seed: 3,
        spp: 6,
        batch: 2,
        ..RenderSettings::default()
    }
}

/// Up to `n` bytes of the input as text (lossy: the routes must take anything).
fn take(bytes: &mut impl Iterator<Item = u8>, n: u8) -> String {
    let raw: Vec<u8> = bytes.take(n as usize).collect();
    String::from_utf8_lossy(&raw).into_owned()
}

fn percent(s: &str) -> String {
    s.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"-._~=&".contains(&b) {
                char::from(b).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

fuzz_target!(|data: &[u8]| {
    let Ok(rt) = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    else {
        return;
    };
    let dir = tempfile::tempdir_in("/dev/shm")
        .or_else(|_| tempfile::tempdir())
        .expect("tmp");
    let mut config = Config::new(dir.path());
    let guarded = data.len() % 2 == 1;
    if guarded {
        config.token = Some(Secret::new(TOKEN));
    }
    rt.block_on(async {
        let farm = InProcess::open(config).expect("a fresh store opens");
        let svc = farm.service();
        let job = svc
            .submit_job(Request::new(pb::SubmitJobRequest {
                scene_text: scene_text().into(),
                scene_format: pb::SceneFormat::Toml as i32,
                scene_name: "c.toml".into(),
                settings: Some(pb::RenderSettings::from(&settings())),
                tile_size: 4,
                ..Default::default()
            }))
            .await
            .expect("the job")
            .into_inner()
            .job_id;
        let worker = svc
            .register(Request::new(pb::RegisterRequest {
                name: "w".into(),
                cores: 1,
                version: "0".into(),
                image_revision: IMAGE_REVISION,
                ..Default::default()
            }))
            .await
            .expect("register")
            .into_inner()
            .worker_id;
        let mut bytes = data.iter().copied();
        let mut legit_cancel = false;
        while let (Some(op), Some(arg)) = (bytes.next(), bytes.next()) {
            // Who is asking: with the token (bearer or the login's cookie), a wrong one, or
            // nothing; from this site, another, or no browser at all.
            let mut headers: Vec<(String, String)> = Vec::new();
            let authed = match arg % 4 {
                0 => {
                    headers.push(("authorization".into(), format!("Bearer {TOKEN}")));
                    true
                }
                1 => {
                    headers.push(("authorization".into(), "Bearer nope".into()));
                    false
                }
                2 => {
                    headers.push(("cookie".into(), "tessera_session=0000".into()));
                    false
                }
                _ => false,
            };
            let cross = match (arg >> 2) % 4 {
                0 => {
                    headers.push(("origin".into(), "http://evil.example".into()));
                    true
                }
                1 => {
                    headers.push(("sec-fetch-site".into(), "cross-site".into()));
                    true
                }
                2 => {
                    headers.push(("sec-fetch-site".into(), "same-origin".into()));
                    false
                }
                _ => false,
            };
            let n = arg >> 4;
            let (method, path, body) = match op % 13 {
                0 => ("GET", "/api/jobs".to_string(), Vec::new()),
                1 => (
                    "GET",
                    format!("/api/jobs/{}", percent(&take(&mut bytes, n))),
                    Vec::new(),
                ),
                2 => ("GET", format!("/api/jobs/{job}"), Vec::new()),
                3 => (
                    "GET",
                    format!(
                        "/api/jobs/{job}/preview.png?{}",
                        percent(&take(&mut bytes, n))
                    ),
                    Vec::new(),
                ),
                4 => ("POST", format!("/api/jobs/{job}/cancel"), Vec::new()),
                5 => {
                    let body = take(&mut bytes, n);
                    ("POST", "/login".to_string(), body.into_bytes())
                }
                6 => {
                    // A fake worker's honest result, so previews have sums to show.
                    let r = svc
                        .lease(Request::new(pb::LeaseRequest {
                            worker_id: worker.clone(),
                            max_units: 1,
                            wait_ms: 0,
                        }))
                        .await;
                    for u in r.map(|r| r.into_inner().units).unwrap_or_default() {
                        let rect = PixelRect::from(u.rect.unwrap_or_default());
                        let sums =
                            render_tile(scene(), &settings(), rect, u.sample_start..u.sample_end);
                        let _ = svc
                            .submit_result(Request::new(pb::SubmitResultRequest {
                                worker_id: worker.clone(),
                                lease_id: u.lease_id,
                                job_id: u.job_id,
                                tile_index: u.tile_index,
                                batch_index: u.batch_index,
                                result: Some(pb::TileResult::from(&sums)),
                            }))
                            .await;
                    }
                    continue;
                }
                7 => (
                    "GET",
                    [
                        "/metrics",
                        "/workers",
                        "/api/workers",
                        "/",
                        "/static/app.js",
                    ][n as usize % 5]
                        .to_string(),
                    Vec::new(),
                ),
                8 => ("POST", "/logout".to_string(), Vec::new()),
                // The pipelines' API: a submission, an upload and job control with whatever
                // bodies and queries the bytes make.
                9 => {
                    let body = take(&mut bytes, n);
                    ("POST", "/api/jobs".to_string(), body.into_bytes())
                }
                10 => {
                    let body = take(&mut bytes, n);
                    let total = u64::from(arg) * 3;
                    let hash =
                        ["0".repeat(64), "zz".into(), percent(&body)][n as usize % 3].clone();
                    let path = format!("/api/assets/{hash}?offset={}&total={total}", arg % 7);
                    ("PUT", path, body.into_bytes())
                }
                11 => {
                    let verb = ["pause", "resume", "priority", "retry"][n as usize % 4];
                    let body = take(&mut bytes, n);
                    ("POST", format!("/api/jobs/{job}/{verb}"), body.into_bytes())
                }
                12 => ("GET", "/api/openapi.json".to_string(), Vec::new()),
                _ => {
                    let raw = take(&mut bytes, n);
                    let method = if arg % 2 == 0 { "GET" } else { "POST" };
                    (method, format!("/{}", percent(&raw)), raw.into_bytes())
                }
            };
            if method == "POST" && !path.starts_with("/login") && !path.starts_with("/api/") {
                headers.push((
                    "content-type".into(),
                    "application/x-www-form-urlencoded".into(),
                ));
            }
            let (status, resp_headers, resp) = farm.http(method, &path, &headers, body).await;
            assert_ne!(
                status,
                500,
                "{method} {path} {headers:?}: {}",
                String::from_utf8_lossy(&resp)
            );
            let may = !guarded || authed;
            if guarded && !authed && !(method == "POST" && path == "/login") {
                assert!(
                    matches!(status, 401 | 403 | 408 | 413),
                    "{method} {path} without the token answered {status}"
                );
            }
            if status == 200 && may {
                let content = resp_headers
                    .iter()
                    .find(|(k, _)| k == "content-type")
                    .map(|(_, v)| v.as_str())
                    .unwrap_or("");
                if content.starts_with("application/json") {
                    assert!(
                        serde_json::from_slice::<serde_json::Value>(&resp).is_ok(),
                        "{path}: not JSON"
                    );
                }
                if path.contains("/preview.png") {
                    assert!(resp.starts_with(b"\x89PNG"), "{path}: not a PNG");
                }
            }
            if op % 13 == 4 && may && !cross && status < 400 {
                legit_cancel = true;
            }
            let state = svc
                .get_job(Request::new(pb::GetJobRequest {
                    job_id: job.clone(),
                }))
                .await
                .expect("the job")
                .into_inner()
                .state;
            if state == pb::JobState::Cancelled as i32 {
                assert!(
                    legit_cancel,
                    "{method} {path} {headers:?} cancelled the job"
                );
            }
        }
        farm.close().await;
    });
});
