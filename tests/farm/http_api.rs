//! The HTTP JSON API (docs/farm.md, "The HTTP API for pipelines"): every route its OpenAPI
//! document lists is served, a job goes from upload to EXR over HTTP alone with
//! `tessera render`'s bits, and hostile bodies get JSON errors with stable codes.

use std::collections::BTreeMap;

use tessera_render::scene::assets::{sha256_hex, MemAssets};

use crate::common::*;

fn json(r: &Reply) -> serde_json::Value {
    serde_json::from_slice(&r.body).unwrap_or_else(|e| panic!("not JSON ({e}): {}", r.text()))
}

/// Asserts an error answer: its HTTP status and its stable code.
fn refused(r: &Reply, status: u16, code: &str) -> String {
    assert_eq!(r.status, status, "{}", r.text());
    let v = json(r);
    assert_eq!(v["code"], code, "{v}");
    v["error"].as_str().expect("a message").to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn every_documented_route_is_served_and_a_job_goes_from_upload_to_exr() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let doc = json(&get(addr, "/api/openapi.json").await);
    assert_eq!(doc["info"]["title"], "tessera coordinator");
    // Every documented route answers as a route (its own JSON error for a made-up id), never
    // the fallback's "no such page".
    let paths = doc["paths"].as_object().expect("paths");
    assert!(paths.len() >= 14, "{paths:?}");
    let sha = "0".repeat(64);
    for (path, item) in paths {
        for method in ["get", "post", "put"] {
            if item.get(method).is_none() {
                continue;
            }
            let p = path
                .replace("{id}", "job-000099")
                .replace("{sha256}", &sha)
                .replace("/api/workers/job-000099", "/api/workers/w1-99");
            let r = http(addr, &method.to_uppercase(), &p, &[], "").await;
            assert!(
                !r.text().contains("no such page"),
                "{method} {path} is documented but not served"
            );
        }
    }

    // A mesh scene, its file uploaded in two pieces (the second resuming where the first
    // stopped), submitted, rendered and downloaded over HTTP alone.
    let mesh = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    let mesh_sha = sha256_hex(mesh.as_bytes());
    let at = |offset: usize| {
        format!(
            "/api/assets/{mesh_sha}?offset={offset}&total={}",
            mesh.len()
        )
    };
    let r = http(addr, "PUT", &at(0), &[], &mesh[..10]).await;
    assert_eq!(json(&r)["received"], 10, "{}", r.text());
    let msg = refused(
        &http(addr, "PUT", &at(3), &[], &mesh[3..]).await,
        400,
        "invalid_argument",
    );
    assert!(msg.contains("resume from there"), "{msg}");
    let r = http(addr, "PUT", &at(10), &[], &mesh[10..]).await;
    assert_eq!(json(&r)["complete"], true, "{}", r.text());
    let text = format!(
        "{}\n[[objects]]\nshape = \"mesh\"\nfile = \"tri.obj\"\nmaterial = \"white\"\n",
        scene_text(16)
    );
    let body = serde_json::json!({
        "scene": text, "scene_name": "tri.toml", "spp": 4, "batch": 2, "seed": 7,
        "files": { "tri.obj": mesh_sha },
    })
    .to_string();
    let r = http(
        addr,
        "POST",
        "/api/jobs",
        &[("content-type", "application/json")],
        &body,
    )
    .await;
    assert_eq!(r.status, 201, "{}", r.text());
    let job = json(&r)["job_id"].as_str().expect("id").to_string();
    let w = worker(&coord.url(), "http");
    let mut client = coord.client().await;
    assert_eq!(
        wait(&mut client, &job).await.state,
        pb::JobState::Done as i32
    );
    let exr = http(addr, "GET", &format!("/api/jobs/{job}/output.exr"), &[], "").await;
    assert_eq!(exr.status, 200);
    assert_eq!(
        exr.body,
        fetch(&mut client, &job).await,
        "the same file as FetchResult"
    );
    let files = MemAssets(BTreeMap::from([(
        "tri.obj".to_string(),
        mesh.as_bytes().to_vec(),
    )]));
    let local = local_exr_files(
        &text,
        &job_settings(4, 2),
        ExrChannels::default(),
        dir.path(),
        &files,
    );
    assert!(exr.body == local, "the EXR differs from tessera render's");
    // Control over HTTP: a finished job cannot be paused, and says so.
    let r = http(addr, "POST", &format!("/api/jobs/{job}/pause"), &[], "").await;
    refused(&r, 409, "failed_precondition");
    w.abort();
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn hostile_bodies_get_json_errors_with_stable_codes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.limits.max_bytes = 1 << 20
        })
        .await;
    let addr = coord.http.expect("dashboard");
    let post = |body: String| async move { http(addr, "POST", "/api/jobs", &[], &body).await };
    refused(&post("{not json".into()).await, 400, "invalid_argument");
    let m = refused(
        &post(r#"{"scene": "", "spp": 4, "colour": 1}"#.into()).await,
        400,
        "invalid_argument",
    );
    assert!(m.contains("unknown field `colour`"), "{m}");
    let m = refused(
        &post(r#"{"scene": "", "spp": "many"}"#.into()).await,
        400,
        "invalid_argument",
    );
    assert!(m.contains("spp") || m.contains("invalid type"), "{m}");
    // A scene error names the place, as `tessera submit`'s does.
    let bad = scene_text(16).replace("fov = ", "fov = 400 #");
    let body = serde_json::json!({ "scene": bad, "scene_name": "bad.toml", "spp": 4 }).to_string();
    let m = refused(&post(body).await, 400, "invalid_argument");
    assert!(m.contains("bad.toml:") && m.contains("fov"), "{m}");
    // A submission over the scene limit is refused before its body is read: only the head is
    // sent, declaring 3 MB, and the answer comes anyway.
    {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut tcp = tokio::net::TcpStream::connect(addr).await.expect("connect");
        let head = format!(
            "POST /api/jobs HTTP/1.1\r\nhost: {addr}\r\ncontent-type: application/json\r\n\
             content-length: 3000000\r\n\r\n"
        );
        tcp.write_all(head.as_bytes()).await.expect("head");
        let mut answer = vec![0u8; 4096];
        let n = tokio::time::timeout(Duration::from_secs(10), tcp.read(&mut answer))
            .await
            .expect("an answer before the body")
            .expect("read");
        let answer = String::from_utf8_lossy(&answer[..n]);
        assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
        assert!(
            answer.contains("\"code\":\"payload_too_large\""),
            "{answer}"
        );
    }
    // A file the scene names but nobody uploaded.
    let text = format!(
        "{}\n[[objects]]\nshape = \"mesh\"\nfile = \"m.obj\"\nmaterial = \"white\"\n",
        scene_text(16)
    );
    let body = serde_json::json!({ "scene": text, "spp": 4, "files": {"m.obj": "ab".repeat(32)} })
        .to_string();
    refused(&post(body).await, 409, "failed_precondition");
    // Uploads: a malformed hash, bytes past the declared size, content that is not the hash's.
    let r = http(addr, "PUT", "/api/assets/xyz?total=3", &[], "abc").await;
    refused(&r, 400, "invalid_argument");
    let sha = "ab".repeat(32);
    let r = http(
        addr,
        "PUT",
        &format!("/api/assets/{sha}?total=2"),
        &[],
        "abc",
    )
    .await;
    refused(&r, 400, "invalid_argument");
    let r = http(
        addr,
        "PUT",
        &format!("/api/assets/{sha}?total=3"),
        &[],
        "abc",
    )
    .await;
    let m = refused(&r, 400, "invalid_argument");
    assert!(m.contains("hash") || m.contains("SHA-256"), "{m}");
    // A priority that is not a number; a job id that is not one.
    let r = http(
        addr,
        "POST",
        "/api/jobs/job-000001/priority",
        &[],
        r#"{"priority": "high"}"#,
    )
    .await;
    refused(&r, 400, "invalid_argument");
    refused(
        &http(addr, "GET", "/api/jobs/yesterday", &[], "").await,
        400,
        "invalid_argument",
    );
    refused(
        &http(addr, "POST", "/api/jobs/job-000042/retry", &[], "").await,
        404,
        "not_found",
    );
    // Another site's page may not submit or upload through a visitor's browser.
    let r = http(
        addr,
        "PUT",
        &format!("/api/assets/{sha}?total=3"),
        &[("origin", "https://evil.example")],
        "abc",
    )
    .await;
    refused(&r, 403, "forbidden");
    coord.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn with_a_token_the_api_answers_401_in_json_and_a_bearer_passes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let token = Secret::new("api-token-0123456789abcdef");
    let t = token.clone();
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.token = Some(t)
        })
        .await;
    let addr = coord.http.expect("dashboard");
    let r = http(addr, "POST", "/api/jobs", &[], r#"{"scene": "", "spp": 1}"#).await;
    let missing = refused(&r, 401, "unauthenticated");
    assert!(missing.contains("requires a token"), "{missing}");
    assert!(r.header("www-authenticate").is_some());
    // A wrong token is told apart from none (the Blender add-on shows this text).
    let r = http(
        addr,
        "GET",
        "/api/jobs",
        &[("authorization", "Bearer not-the-token")],
        "",
    )
    .await;
    let wrong = refused(&r, 401, "unauthenticated");
    assert!(wrong.starts_with("wrong token"), "{wrong}");
    let bearer = format!("Bearer {}", token.expose());
    let r = http(
        addr,
        "GET",
        "/api/jobs",
        &[("authorization", bearer.as_str())],
        "",
    )
    .await;
    assert_eq!(r.status, 200, "{}", r.text());
    coord.stop().await;
}

/// Listings come a page at a time, over gRPC and HTTP alike: with more jobs than a page holds,
/// the answer says where the next page starts, the pages together are the list once, and a
/// token no listing gave is refused. (With every job in one answer, a long `--after` chain
/// once took `ListJobs` past the gRPC limit, for every user.)
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn job_listings_come_a_page_at_a_time() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let mut client = coord.client().await;
    let text = scene_text(16);
    let mut ids = Vec::new();
    for p in 0..5 {
        ids.push(submit(&mut client, &text, 4, 2, p).await);
    }
    ids.reverse(); // priority order
    let mut paged = Vec::new();
    let mut page_token = String::new();
    loop {
        let page = client
            .list_jobs(pb::ListJobsRequest {
                page_size: 2,
                page_token,
            })
            .await
            .expect("list")
            .into_inner();
        assert!(page.jobs.len() <= 2);
        paged.extend(page.jobs.into_iter().map(|j| j.job_id));
        if page.next_page_token.is_empty() {
            break;
        }
        page_token = page.next_page_token;
    }
    assert_eq!(paged, ids);
    let bad = client
        .list_jobs(pb::ListJobsRequest {
            page_size: 2,
            page_token: "x".into(),
        })
        .await
        .expect_err("refused");
    assert_eq!(bad.code(), tonic::Code::InvalidArgument);
    // HTTP: ?limit and ?page, the next page in X-Next-Page.
    let first = get(addr, "/api/jobs?limit=3").await;
    let next = first.header("x-next-page").expect("more").to_string();
    let second = get(addr, &format!("/api/jobs?limit=3&page={next}")).await;
    assert_eq!(second.header("x-next-page"), None);
    let listed: Vec<String> = [json(&first), json(&second)]
        .iter()
        .flat_map(|v| v.as_array().expect("array").clone())
        .map(|j| j["job_id"].as_str().expect("id").to_string())
        .collect();
    assert_eq!(listed, ids);
    refused(
        &get(addr, "/api/jobs?page=nope").await,
        400,
        "invalid_argument",
    );
}

/// A glTF submission names its file among `files`: one that is not there, not uploaded, not a
/// glTF file, or outside the scene's folder is refused with what is wrong; `camera` is for
/// glTF scenes only.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn gltf_submissions_are_refused_naming_what_is_wrong() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_coord, addr) = dashboard_farm(dir.path()).await;
    let post = |body: serde_json::Value| async move {
        http(
            addr,
            "POST",
            "/api/jobs",
            &[("content-type", "application/json")],
            &body.to_string(),
        )
        .await
    };
    let sha = "ab".repeat(32);
    for (body, status, code, says) in [
        (
            serde_json::json!({"format": "gltf", "scene": "m.glb", "spp": 1}),
            400,
            "invalid_argument",
            "not among `files`",
        ),
        (
            serde_json::json!({"format": "gltf", "scene": "m.glb", "spp": 1, "files": {"m.glb": sha}}),
            409,
            "failed_precondition",
            "not uploaded",
        ),
        (
            serde_json::json!({"format": "gltf", "scene": "m.toml", "spp": 1, "files": {"m.toml": sha}}),
            400,
            "invalid_argument",
            "name the glTF file",
        ),
        (
            serde_json::json!({"format": "gltf", "scene": "../m.glb", "spp": 1, "files": {"../m.glb": sha}}),
            400,
            "invalid_argument",
            "climbs out",
        ),
        (
            serde_json::json!({"scene": scene_text(8), "spp": 1, "camera": "main"}),
            400,
            "invalid_argument",
            "for glTF scenes",
        ),
    ] {
        let msg = refused(&post(body.clone()).await, status, code);
        assert!(msg.contains(says), "{body}: {msg}");
    }
}

/// An upload that trickles is cut off once past its grace (the bytes so far kept for a
/// resume), and one sender may have only so many uploads under way at once: 260 trickling
/// uploads once held the dashboard's every connection, and one byte every 40 s lived 240 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn trickling_uploads_are_cut_off_and_bounded_per_sender() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let dir = tempfile::tempdir().expect("tempdir");
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.upload_grace = Duration::from_secs(1);
            c.upload_min_rate = 1000;
            c.max_uploads_per_user = 2;
        })
        .await;
    let addr = coord.http.expect("dashboard");
    let sha = "cd".repeat(32);
    // A PUT whose headers announce 100,000 bytes, its body sent `first` bytes at once.
    let open = |first: usize| {
        let sha = sha.clone();
        async move {
            let mut tcp = tokio::net::TcpStream::connect(addr).await.expect("connect");
            let head = format!(
                "PUT /api/assets/{sha}?offset=0&total=100000 HTTP/1.1\r\nhost: {addr}\r\n\
                 content-length: 100000\r\n\r\n"
            );
            tcp.write_all(head.as_bytes()).await.expect("head");
            tcp.write_all(&vec![b'x'; first]).await.expect("body");
            tcp
        }
    };
    let status_of = |reply: &[u8]| {
        String::from_utf8_lossy(reply)
            .lines()
            .next()
            .unwrap_or("")
            .to_string()
    };
    // Two trickles hold this sender's places; a third upload is refused at once.
    let mut a = open(1).await;
    let _b = open(1).await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut c = open(1).await;
    let mut reply = vec![0u8; 4096];
    let n = tokio::time::timeout(Duration::from_secs(5), c.read(&mut reply))
        .await
        .expect("an answer")
        .expect("read");
    assert!(
        status_of(&reply[..n]).contains("429"),
        "{}",
        String::from_utf8_lossy(&reply[..n])
    );
    // The trickle: a byte every 300 ms is under 1000 bytes a second; past the 1 s grace, the
    // next byte gets 408.
    let started = std::time::Instant::now();
    let n = loop {
        let _ = a.write_all(b"x").await;
        if let Ok(Ok(n)) =
            tokio::time::timeout(Duration::from_millis(300), a.read(&mut reply)).await
        {
            break n;
        }
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "the trickle was never cut off"
        );
    };
    let text = String::from_utf8_lossy(&reply[..n]).to_string();
    assert!(
        status_of(&reply[..n]).contains("408") && text.contains("slower than 1000 bytes"),
        "{text}"
    );
}
