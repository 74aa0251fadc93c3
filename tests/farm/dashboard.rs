//! The dashboard and metrics over HTTP (`--http`): the token on every page and endpoint, the
//! login, the preview against the merged sums and the EXR, the preview's rate limit, cancel,
//! and metrics that parse as Prometheus text and agree with the gRPC status.

use crate::common::*;

/// Every route the dashboard serves, with a method; `JOB` is replaced by a real job's id.
const ROUTES: &[(&str, &str)] = &[
    ("GET", "/"),
    ("GET", "/jobs/JOB"),
    ("GET", "/workers"),
    ("GET", "/static/app.js"),
    ("GET", "/static/style.css"),
    ("GET", "/api/jobs"),
    ("GET", "/api/jobs/JOB"),
    ("POST", "/api/jobs/JOB/cancel"),
    ("GET", "/api/jobs/JOB/logs"),
    ("GET", "/api/jobs/JOB/preview.png"),
    ("GET", "/api/jobs/JOB/preview.png?view=noise&exposure=2"),
    ("GET", "/api/jobs/JOB/output.exr"),
    ("GET", "/api/workers"),
    ("POST", "/api/workers/w1-99/drain"),
    ("GET", "/metrics"),
    ("POST", "/logout"),
    ("GET", "/no/such/page"),
    ("GET", "/api/jobs/job-999999"),
];

const TOKEN: &str = "dashboard-token-0123456789abcdef";

async fn farm_with_token(dir: &Path) -> Coordinator {
    Coordinator::start_with_dashboard(&dir.join("data"), Duration::from_secs(30), |c| {
        c.token = Some(Secret::new(TOKEN));
    })
    .await
}

fn token_options() -> ClientOptions {
    ClientOptions {
        token: Some(Secret::new(TOKEN)),
        ..ClientOptions::default()
    }
}

/// The value of the session cookie a `Set-Cookie` header sets.
fn session_cookie(reply: &Reply) -> String {
    let set = reply.header("set-cookie").expect("a Set-Cookie header");
    assert!(
        set.contains("HttpOnly") && set.contains("SameSite=Strict"),
        "{set}"
    );
    set.split(';').next().expect("cookie").to_string()
}

/// Without the token (none, a wrong bearer, a forged cookie) every page and endpoint answers
/// 401, browsers get the login page, and nothing is done (the cancel does not cancel); with
/// the token, as a bearer or as the login's cookie, each answers something else.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn every_page_and_endpoint_needs_the_token() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = farm_with_token(dir.path()).await;
    let addr = coord.http.expect("dashboard");
    let mut client = client_with(&coord.url(), &token_options()).await;
    let job = submit(&mut client, &scene_text(16), 4, 2, 0).await;
    let wrong_bearer = format!("Bearer {TOKEN}x");
    let refusals: [&[(&str, &str)]; 5] = [
        &[],
        &[("authorization", &wrong_bearer)],
        &[("authorization", TOKEN)],
        &[("cookie", "tessera_session=0000")],
        &[("cookie", "tessera_session=")],
    ];
    for (method, route) in ROUTES {
        let path = route.replace("JOB", &job);
        for headers in refusals {
            let r = http(addr, method, &path, headers, "").await;
            assert_eq!(
                r.status,
                401,
                "{method} {path} with {headers:?}: {}",
                r.text()
            );
            assert_eq!(
                r.header("www-authenticate"),
                Some("Bearer realm=\"tessera\"")
            );
        }
        let r = http(addr, method, &path, &[("accept", "text/html")], "").await;
        assert_eq!(r.status, 401);
        assert!(r.text().contains("name=\"token\""), "{path}: no login form");
    }
    assert_eq!(
        job_status(&mut client, &job).await.state,
        pb::JobState::Queued as i32,
        "a refused cancel cancelled"
    );

    // A wrong token at the login is refused; the right one sets a cookie that works, and the
    // login only ever sends the browser back to a page of this site.
    let form = "application/x-www-form-urlencoded";
    let r = http(
        addr,
        "POST",
        "/login",
        &[("content-type", form)],
        "token=nope&next=/",
    )
    .await;
    assert_eq!(r.status, 401);
    assert!(r.header("set-cookie").is_none());
    assert!(r.text().contains("wrong token"));
    let body = format!("token={TOKEN}&next=%2F%2Fevil.example%2F");
    let r = http(addr, "POST", "/login", &[("content-type", form)], &body).await;
    assert_eq!(r.status, 303);
    assert_eq!(r.header("location"), Some("/"));
    let cookie = session_cookie(&r);
    assert!(!cookie.contains(TOKEN), "the cookie is the token itself");
    let body = format!("token={TOKEN}&next=%2Fjobs%2F{job}");
    let r = http(addr, "POST", "/login", &[("content-type", form)], &body).await;
    assert_eq!(r.header("location"), Some(format!("/jobs/{job}").as_str()));

    let bearer = format!("Bearer {TOKEN}");
    for auth in [
        ("authorization", bearer.as_str()),
        ("cookie", cookie.as_str()),
    ] {
        for (method, route) in ROUTES {
            if route.contains("cancel") || route.contains("logout") {
                continue;
            }
            let path = route.replace("JOB", &job);
            let r = http(addr, method, &path, &[auth], "").await;
            let want = match *route {
                "/no/such/page" | "/api/jobs/job-999999" | "/api/workers/w1-99/drain" => 404,
                // Queued, nothing merged: the EXR is not ready; the preview is black.
                "/api/jobs/JOB/output.exr" => 409,
                _ => 200,
            };
            assert_eq!(r.status, want, "{method} {path}: {}", r.text());
        }
    }
    let r = http(
        addr,
        "POST",
        &format!("/api/jobs/{job}/cancel"),
        &[("cookie", &cookie)],
        "",
    )
    .await;
    assert_eq!(r.status, 200, "{}", r.text());
    // The answer is the job, as pause's is.
    let v: serde_json::Value = serde_json::from_slice(&r.body).expect("json");
    assert_eq!(
        (v["job_id"].as_str(), v["state"].as_str()),
        (Some(job.as_str()), Some("cancelled")),
        "{v}"
    );
    assert_eq!(
        job_status(&mut client, &job).await.state,
        pb::JobState::Cancelled as i32
    );
    let r = http(addr, "POST", "/logout", &[("cookie", &cookie)], "").await;
    assert_eq!(r.status, 303);
    assert!(r
        .header("set-cookie")
        .is_some_and(|c| c.contains("Max-Age=0")));
    // Logging out ends the session itself: the cookie, wherever it was copied, no longer works.
    let r = http(addr, "GET", "/api/jobs", &[("cookie", &cookie)], "").await;
    assert_eq!(
        r.status,
        401,
        "a logged-out session still works: {}",
        r.text()
    );
    coord.stop().await;
}

/// Decodes an 8-bit RGB PNG.
fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("frame");
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// The pixels `tessera render --preview` shows for these means at exposure 0.
fn tone_mapped(rgb: &[[f32; 3]]) -> Vec<u8> {
    tessera_render::output::tone_map(rgb, tessera_render::output::Preview { exposure: 0.0 })
}

/// While a job runs, its preview shows exactly the means merged so far (a tile merged, the
/// others black) and a noise map; once it is done, the preview is the EXR tone-mapped, the
/// download is the EXR, and that is `tessera render`'s bits.
///
/// Long because it is one scenario, its steps in the order they happen to the farm (each
/// step's state is the next one's start); split into functions, that order would be hidden.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_preview_shows_the_merged_sums_then_the_exr() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let mut client = coord.client().await;
    let text = scene_text(32);
    let (spp, batch) = (8, 4);
    let job = submit(&mut client, &text, spp, batch, 0).await;

    // One unit, merged by hand: tile 0's first batch.
    let mut workers = workers_client(&coord.url());
    let me = register_as(&mut workers, "hand", "test", IMAGE_REVISION)
        .await
        .expect("register");
    let units = lease_now(&mut workers, &me, 1).await.expect("lease");
    let u = &units[0];
    let scene = Scene::text(&text, Format::Toml, "cornell.toml", &Limits::default())
        .at(1)
        .load()
        .expect("scene");
    let settings = job_settings(spp, batch);
    let rect = PixelRect::from(u.rect.expect("rect"));
    let sums = render_tile(&scene, &settings, rect, u.sample_start..u.sample_end);
    workers
        .submit_result(pb::SubmitResultRequest {
            worker_id: me.clone(),
            lease_id: u.lease_id.clone(),
            job_id: job.clone(),
            tile_index: u.tile_index,
            batch_index: u.batch_index,
            result: Some(pb::TileResult::from(&sums)),
        })
        .await
        .expect("submit");

    let r = get(addr, &format!("/api/jobs/{job}/preview.png")).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("image/png"));
    let (w, h, px) = decode_png(&r.body);
    assert_eq!((w, h), (32, 32));
    let tile = tone_mapped(&sums.finalize().rgb);
    for y in 0..32u32 {
        for x in 0..32u32 {
            let i = 3 * (y * 32 + x) as usize;
            let got = &px[i..i + 3];
            let inside = x >= rect.x0
                && x < rect.x0 + rect.width
                && y >= rect.y0
                && y < rect.y0 + rect.height;
            if inside {
                let j = 3 * ((y - rect.y0) * rect.width + (x - rect.x0)) as usize;
                assert_eq!(got, &tile[j..j + 3], "pixel ({x}, {y}) of the merged tile");
            } else {
                assert_eq!(
                    got,
                    [0, 0, 0],
                    "pixel ({x}, {y}) of a tile with no samples yet"
                );
            }
        }
    }
    let r = get(addr, &format!("/api/jobs/{job}/preview.png?view=noise")).await;
    assert_eq!(r.status, 200, "{}", r.text());
    let (_, _, noise) = decode_png(&r.body);
    assert_ne!(noise, px, "the noise view is the image");
    let r = get(addr, &format!("/api/jobs/{job}/preview.png?view=x")).await;
    assert_eq!(r.status, 400);
    assert!(
        r.text().contains("expected color, noise or denoised"),
        "{}",
        r.text()
    );
    // Hostile or odd parameters: refused with the reason, or read as the default; no panic.
    for (query, status) in [
        ("exposure=1e39", 200),
        ("exposure=NaN", 200),
        ("exposure=-inf", 200),
        ("exposure=abc", 400),
        ("exposure=1&exposure=2", 400),
    ] {
        let path = format!("/api/jobs/{job}/preview.png?{query}");
        let r = get(addr, &path).await;
        assert_eq!(r.status, status, "{query}: {}", r.text());
    }
    let long = "9".repeat(5000);
    for path in [
        format!("/api/jobs/job-{long}/preview.png"),
        format!("/api/jobs/{job}/output.exr?frame=-1"),
        "/api/jobs/job-000001%00/preview.png".to_string(),
    ] {
        let r = get(addr, &path).await;
        assert!((400..500).contains(&r.status), "{path}: {}", r.status);
    }

    // The rest by real workers.
    let w1 = worker(&coord.url(), "w1");
    let done = wait(&mut client, &job).await;
    assert_eq!(done.state, pb::JobState::Done as i32);
    let exr = fetch(&mut client, &job).await;
    assert!(
        exr == local_exr(&text, spp, batch, dir.path()),
        "farm EXR differs"
    );
    let r = get(addr, &format!("/api/jobs/{job}/output.exr")).await;
    assert_eq!(r.status, 200);
    assert!(r.body == exr, "the download is not the EXR");
    assert!(r
        .header("content-disposition")
        .is_some_and(|d| d.contains(&done.output_name)));
    let path = dir.path().join("fetched.exr");
    std::fs::write(&path, &exr).expect("write");
    let image = tessera_render::output::read_exr_rgb(&path).expect("read EXR");
    let r = get(addr, &format!("/api/jobs/{job}/preview.png")).await;
    let (_, _, px) = decode_png(&r.body);
    assert!(
        px == tone_mapped(&image.rgb),
        "the final preview is not the EXR tone-mapped"
    );
    let r = get(addr, &format!("/api/jobs/{job}/preview.png?view=noise")).await;
    // The finished job's per-tile noise is kept for its noise view.
    assert_eq!(r.status, 200, "{}", r.text());
    let (_, _, noise) = decode_png(&r.body);
    assert!(noise != px, "the finished job's noise view is its image");
    w1.abort();
    coord.stop().await;

    // Not across a restart: the sums it came from are gone.
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let r = get(addr, &format!("/api/jobs/{job}/preview.png?view=noise")).await;
    assert_eq!(r.status, 409, "{}", r.text());
    assert!(r.text().contains("not kept"), "{}", r.text());
    let r = get(addr, &format!("/api/jobs/{job}/preview.png")).await;
    let (_, _, again) = decode_png(&r.body);
    assert!(again == px, "after a restart the preview is not the EXR's");
    coord.stop().await;
}

/// However many requests come at once or in a row, a running job's preview is computed at
/// most once per interval (and again as results come in), and every request gets an image.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn previews_are_computed_at_most_a_few_times_a_second() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let mut client = coord.client().await;
    let job = submit(&mut client, &scene_text(128), 256, 2, 0).await;
    let w = worker(&coord.url(), "busy");
    wait_for("a first merged unit", async || {
        (job_status(&mut client, &job).await.units_done > 0).then_some(())
    })
    .await;
    let start = std::time::Instant::now();
    let mut requests = 0;
    while start.elapsed() < Duration::from_millis(1500) {
        let round: Vec<_> = (0..40)
            .map(|i| {
                let path = format!("/api/jobs/{job}/preview.png?exposure={}", i % 3);
                tokio::spawn(async move { get(addr, &path).await.status })
            })
            .collect();
        for r in round {
            assert_eq!(r.await.expect("request"), 200);
            requests += 1;
        }
    }
    let elapsed = start.elapsed();
    let merged_meanwhile = job_status(&mut client, &job).await.units_done;
    let metrics = get(addr, "/metrics").await.text();
    let computed = sample(&metrics, "tessera_dashboard_previews_total", &[]);
    let most = (elapsed.as_secs_f64() / 0.25).floor() + 1.0;
    assert!(
        (2.0..=most).contains(&computed),
        "{requests} requests in {elapsed:?} ({merged_meanwhile} units merged by then) computed \
         {computed} previews; between 2 and {most} expected"
    );
    w.abort();
    coord.stop().await;
}

/// A sample's value in Prometheus text, parsed by a parser that is not ours; fails if absent.
fn sample(text: &str, name: &str, labels: &[(&str, &str)]) -> f64 {
    let lines = text.lines().map(|l| Ok(l.to_string()));
    let scrape = prometheus_parse::Scrape::parse(lines).expect("Prometheus text");
    scrape
        .samples
        .iter()
        .find(|s| s.metric == name && labels.iter().all(|(k, v)| s.labels.get(k) == Some(*v)))
        .map(|s| match s.value {
            prometheus_parse::Value::Counter(v)
            | prometheus_parse::Value::Gauge(v)
            | prometheus_parse::Value::Untyped(v) => v,
            _ => f64::NAN,
        })
        .unwrap_or_else(|| panic!("no sample {name} {labels:?} in\n{text}"))
}

/// `/metrics` parses as Prometheus text, and after a job its counters agree with what
/// `tessera status` and `tessera workers` say.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn metrics_parse_and_agree_with_the_status() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let mut client = coord.client().await;
    let workers = [worker(&coord.url(), "m1"), worker(&coord.url(), "m2")];
    let job = submit(&mut client, &scene_text(32), 8, 2, 0).await;
    let done = wait(&mut client, &job).await;
    assert_eq!(done.state, pb::JobState::Done as i32);
    let r = get(addr, "/metrics").await;
    assert_eq!(r.status, 200);
    assert!(r
        .header("content-type")
        .is_some_and(|c| c.starts_with("text/plain; version=0.0.4")));
    let text = r.text();
    let merged = sample(&text, "tessera_units_merged_total", &[]);
    assert_eq!(merged, done.units_done as f64);
    assert_eq!(merged, done.units_total as f64);
    assert_eq!(
        sample(&text, "tessera_samples_merged_total", &[]),
        done.samples_done as f64
    );
    assert!(sample(&text, "tessera_units_leased_total", &[]) >= merged);
    assert_eq!(sample(&text, "tessera_jobs", &[("state", "done")]), 1.0);
    assert_eq!(sample(&text, "tessera_jobs", &[("state", "running")]), 0.0);
    assert_eq!(sample(&text, "tessera_results_refused_total", &[]), 0.0);
    assert_eq!(sample(&text, "tessera_merge_seconds_count", &[]), merged);
    assert!(sample(&text, "tessera_store_commit_seconds_count", &[]) >= 1.0);
    assert!(sample(&text, "tessera_store_written_bytes_total", &[]) > 0.0);
    let listed = list_workers(&mut client).await;
    assert_eq!(listed.len(), 2);
    assert_eq!(
        sample(&text, "tessera_workers_active", &[]),
        listed.iter().filter(|w| w.alive).count() as f64
    );
    let mut total = 0.0;
    for w in &listed {
        let v = sample(
            &text,
            "tessera_worker_samples_merged_total",
            &[("worker", &w.worker_id), ("name", &w.name)],
        );
        assert_eq!(v, w.samples_done as f64, "{}", w.name);
        total += v;
    }
    assert_eq!(total, done.samples_done as f64);
    for w in workers {
        w.abort();
    }
    coord.stop().await;
}

/// Every query of the Grafana dashboard in deploy/ names only metrics the coordinator exports,
/// so that renaming a metric cannot leave a panel silently empty.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_grafana_dashboard_queries_only_metrics_that_exist() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let w = worker(&coord.url(), "g1");
    let mut client = coord.client().await;
    let job = submit(&mut client, &scene_text(16), 2, 2, 0).await;
    wait(&mut client, &job).await;
    let metrics = get(addr, "/metrics").await.text();
    let exported: std::collections::BTreeSet<&str> = metrics
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/monitoring/grafana/tessera-dashboard.json");
    let dashboard: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).expect("read the dashboard"))
            .expect("the dashboard is JSON");
    let mut queried = 0;
    for panel in dashboard["panels"].as_array().expect("panels") {
        for target in panel["targets"].as_array().expect("targets") {
            let expr = target["expr"].as_str().expect("expr");
            let names = expr
                .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .filter(|w| w.starts_with("tessera_"));
            for name in names {
                let base = ["_bucket", "_sum", "_count"]
                    .iter()
                    .find_map(|s| name.strip_suffix(s).filter(|b| exported.contains(b)))
                    .unwrap_or(name);
                assert!(
                    exported.contains(base),
                    "panel {:?} queries {name}, which /metrics does not export",
                    panel["title"]
                );
                queried += 1;
            }
        }
    }
    assert!(
        queried >= 10,
        "only {queried} metric references in the dashboard"
    );
    w.abort();
    coord.stop().await;
}

/// With TLS configured the dashboard serves TLS only, with the gRPC API's certificate: plain
/// HTTP gets no page, and a client that trusts the farm's CA gets the job list with the token.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_dashboard_serves_tls_when_the_farm_has_it() {
    use tokio_rustls::rustls;
    let (ca, cert_pem, key_pem) = test_ca_and_cert();
    let dir = tempfile::tempdir().expect("tempdir");
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.token = Some(Secret::new(TOKEN));
            c.tls = Some(tessera_coordinator::ServerTls {
                cert_pem: cert_pem.into_bytes(),
                key_pem: Secret::new(key_pem),
                client_ca_pem: None,
            });
        })
        .await;
    let addr = coord.http.expect("dashboard");

    // Plain HTTP: the server expects a TLS handshake, and answers none of it with a page.
    let plain = tokio::time::timeout(PATIENCE, async {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut tcp = tokio::net::TcpStream::connect(addr).await.expect("connect");
        let _ = tcp
            .write_all(b"GET /api/jobs HTTP/1.1\r\nhost: x\r\nconnection: close\r\n\r\n")
            .await;
        let mut got = Vec::new();
        let _ = tcp.read_to_end(&mut got).await;
        got
    })
    .await
    .expect("plain HTTP to the TLS port hung");
    assert!(
        !String::from_utf8_lossy(&plain).contains("HTTP/1.1 200"),
        "served in clear"
    );

    let mut roots = rustls::RootCertStore::empty();
    roots
        .add(rustls::pki_types::CertificateDer::from(ca.der().to_vec()))
        .expect("root");
    let config = rustls::ClientConfig::builder_with_provider(std::sync::Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .expect("versions")
    .with_root_certificates(roots)
    .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(std::sync::Arc::new(config));
    let tcp = tokio::net::TcpStream::connect(addr).await.expect("connect");
    let name = rustls::pki_types::ServerName::try_from("localhost").expect("name");
    let tls = connector.connect(name, tcp).await.expect("TLS handshake");
    let (mut send, conn) = hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(tls))
        .await
        .expect("handshake");
    tokio::spawn(conn);
    let req = hyper::Request::get("/api/jobs")
        .header("host", "localhost")
        .header("authorization", format!("Bearer {TOKEN}"))
        .body(http_body_util::Empty::<hyper::body::Bytes>::new())
        .expect("request");
    let r = send.send_request(req).await.expect("send");
    assert_eq!(r.status(), 200);
    coord.stop().await;
}

/// A connection to the dashboard that sends nothing, or stops halfway through choosing its
/// protocol, is closed once it has been silent for the idle time, as on the gRPC port: silent
/// connections cannot fill the dashboard's slots.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn silent_dashboard_connections_are_closed() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let dir = tempfile::tempdir().expect("tempdir");
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.idle_connection = Duration::from_millis(500);
        })
        .await;
    let addr = coord.http.expect("dashboard");
    for opening in [&b""[..], b"PRI * HTTP/2.0\r\n", b"GET / HTTP/1.1\r\nhost"] {
        let mut tcp = tokio::net::TcpStream::connect(addr).await.expect("connect");
        tcp.write_all(opening).await.expect("write");
        let mut buf = [0u8; 256];
        let closed = tokio::time::timeout(PATIENCE, async {
            loop {
                match tcp.read(&mut buf).await {
                    Ok(0) | Err(_) => return,
                    Ok(_) => {}
                }
            }
        })
        .await;
        assert!(
            closed.is_ok(),
            "a silent connection after {opening:?} stayed open"
        );
    }
    // A live one is served.
    assert_eq!(get(addr, "/api/jobs").await.status, 200);
    coord.stop().await;
}

/// The attack of #55 B: connections without the token that POST /login with a large declared
/// body and send it a byte at a time. Before, each byte reset the idle timer and 260 of them
/// held every slot, so authorised requests timed out for as long as the trickle went on. Now
/// a login body is read whole within a deadline and capped at 4 KiB (a larger declared one is
/// refused at once), and connections that have made no request with the token never hold
/// more than half the slots: an authorised request is answered at once.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn slow_logins_do_not_shut_the_dashboard_out() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let dir = tempfile::tempdir().expect("tempdir");
    let coord = farm_with_token(dir.path()).await;
    let addr = coord.http.expect("dashboard");
    // A body larger than a login's is refused before it is read.
    let r = http(
        addr,
        "POST",
        "/login",
        &[("content-type", "application/x-www-form-urlencoded")],
        &format!("token={}", "x".repeat(5000)),
    )
    .await;
    assert_eq!(r.status, 413, "{}", r.text());
    let mut tricklers = Vec::new();
    for _ in 0..300 {
        let Ok(mut tcp) = tokio::net::TcpStream::connect(addr).await else {
            continue;
        };
        tricklers.push(tokio::spawn(async move {
            let head = "POST /login HTTP/1.1\r\nhost: x\r\ncontent-type: \
                        application/x-www-form-urlencoded\r\ncontent-length: 4000\r\n\r\n";
            if tcp.write_all(head.as_bytes()).await.is_err() {
                return;
            }
            let mut buf = [0u8; 256];
            loop {
                if tcp.write_all(b"t").await.is_err() {
                    return;
                }
                // A closed connection (the server's answer, or its close) ends the trickle.
                if let Ok(Ok(0) | Err(_)) =
                    tokio::time::timeout(Duration::from_millis(100), tcp.read(&mut buf)).await
                {
                    return;
                }
            }
        }));
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    for round in 0..3 {
        let answered = tokio::time::timeout(
            Duration::from_secs(5),
            http(
                addr,
                "GET",
                "/api/jobs",
                &[("authorization", &format!("Bearer {TOKEN}"))],
                "",
            ),
        )
        .await;
        assert!(
            matches!(&answered, Ok(r) if r.status == 200),
            "round {round}: an authorised request was not answered within 5 s: {answered:?}"
        );
    }
    for t in tricklers {
        t.abort();
    }
    coord.stop().await;
}

/// #55: with no token configured, a page on another site could make a visitor's browser POST
/// the dashboard's cancel. Now a POST that a browser marks as cross-site (`Sec-Fetch-Site`, or
/// an `Origin` of another host) is refused; the dashboard's own, and non-browser clients, pass.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_cross_site_post_cannot_cancel_a_job() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let mut client = coord.client().await;
    let job = submit(&mut client, &scene_text(16), 4, 1, 0).await;
    let path = format!("/api/jobs/{job}/cancel");
    let host = addr.to_string();
    for headers in [
        vec![("origin", "http://evil.example")],
        vec![("sec-fetch-site", "cross-site")],
        vec![("sec-fetch-site", "same-site")],
        vec![("origin", "null")],
    ] {
        let r = http(addr, "POST", &path, &headers, "").await;
        assert_eq!(r.status, 403, "{headers:?}: {}", r.text());
        assert_eq!(
            job_status(&mut client, &job).await.state,
            pb::JobState::Queued as i32,
            "{headers:?}"
        );
    }
    let own = format!("http://{host}");
    let r = http(
        addr,
        "POST",
        &path,
        &[("origin", own.as_str()), ("sec-fetch-site", "same-origin")],
        "",
    )
    .await;
    assert!(r.status < 400, "{}: {}", r.status, r.text());
    assert_eq!(
        job_status(&mut client, &job).await.state,
        pb::JobState::Cancelled as i32
    );
    coord.stop().await;
}

/// #55: "Log out" showed with no token configured, where there is nothing to log out of.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn log_out_shows_only_where_logging_in_does() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (open, addr) = dashboard_farm(&dir.path().join("open")).await;
    let page = get(addr, "/").await.text();
    assert!(page.contains("id=\"main\""), "{page}");
    assert!(!page.contains("Log out"), "{page}");
    open.stop().await;
    let guarded = farm_with_token(&dir.path().join("guarded")).await;
    let addr = guarded.http.expect("dashboard");
    let page = http(
        addr,
        "GET",
        "/",
        &[("authorization", &format!("Bearer {TOKEN}"))],
        "",
    )
    .await
    .text();
    assert!(page.contains("Log out"), "{page}");
    guarded.stop().await;
}

/// The dashboard's JSON and `tessera status --json`'s are one document: the dashboard
/// serialises the scheduler's views, and the CLI turns the gRPC status back into the same view
/// (`JobView::try_from`) and serialises that. A done job's document is the same bit for bit;
/// a worker's differs only in the figures that move with time.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_dashboard_and_the_cli_read_one_document() {
    use tessera_proto::view::{JobView, WorkerView};
    let dir = tempfile::tempdir().expect("tempdir");
    let (coord, addr) = dashboard_farm(dir.path()).await;
    let mut client = coord.client().await;
    let w = worker(&coord.url(), "doc");
    let job = submit(&mut client, &scene_text(16), 4, 2, 0).await;
    wait(&mut client, &job).await;
    let status = job_status(&mut client, &job).await;
    let as_cli = serde_json::to_value(JobView::try_from(&status).expect("a view")).expect("JSON");
    let r = get(addr, &format!("/api/jobs/{job}")).await;
    assert_eq!(r.status, 200);
    let served: serde_json::Value = serde_json::from_slice(&r.body).expect("JSON");
    assert_eq!(served, as_cli);
    assert_eq!(served["state"], "done");
    assert_eq!(served["job_id"], job.as_str());
    let list: serde_json::Value =
        serde_json::from_slice(&get(addr, "/api/jobs").await.body).expect("JSON");
    assert_eq!(list, serde_json::json!([as_cli]));
    let moving = |mut v: serde_json::Value| {
        for w in v.as_array_mut().expect("a list") {
            w["last_seen_seconds_ago"] = serde_json::Value::Null;
            w["samples_per_second"] = serde_json::Value::Null;
        }
        v
    };
    let workers: Vec<WorkerView> = list_workers(&mut client)
        .await
        .iter()
        .map(|w| WorkerView::try_from(w).expect("a view"))
        .collect();
    let served: serde_json::Value =
        serde_json::from_slice(&get(addr, "/api/workers").await.body).expect("JSON");
    assert_eq!(
        moving(served),
        moving(serde_json::to_value(workers).expect("JSON"))
    );
    w.abort();
    coord.stop().await;
}

/// DNS rebinding: without a token, a request naming a host the dashboard is not served as (a
/// page on evil.example whose name now points at the farm) is refused, reading and changing
/// alike; IP addresses, localhost and `--http-host` names pass, and so does Prometheus's scrape
/// of /metrics. With a token the token decides, whatever the Host.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn without_a_token_only_the_dashboards_own_names_are_served() {
    let dir = tempfile::tempdir().expect("tempdir");
    let coord =
        Coordinator::start_with_dashboard(&dir.path().join("data"), Duration::from_secs(30), |c| {
            c.http_hosts = vec!["renderbox".into()];
        })
        .await;
    let addr = coord.http.expect("dashboard");
    let port = addr.port();
    let evil = format!("evil.example:{port}");
    for (method, path) in [
        ("GET", "/api/jobs"),
        ("GET", "/"),
        ("POST", "/api/jobs/job-000001/cancel"),
    ] {
        let r = http(addr, method, path, &[("host", &evil)], "").await;
        assert_eq!(r.status, 403, "{method} {path}: {}", r.text());
        assert!(r.text().contains("--http-host"), "{}", r.text());
    }
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
        format!("RenderBox:{port}"),
        "renderbox".to_string(),
    ] {
        let r = http(addr, "GET", "/api/jobs", &[("host", &host)], "").await;
        assert_eq!(r.status, 200, "{host}: {}", r.text());
    }
    let r = http(addr, "GET", "/metrics", &[("host", "coordinator:7880")], "").await;
    assert_eq!(r.status, 200);
    let with_token = farm_with_token(&dir.path().join("t")).await;
    let addr = with_token.http.expect("dashboard");
    let r = http(
        addr,
        "GET",
        "/api/jobs",
        &[
            ("host", "evil.example"),
            ("authorization", &format!("Bearer {TOKEN}")),
        ],
        "",
    )
    .await;
    assert_eq!(r.status, 200, "{}", r.text());
}
