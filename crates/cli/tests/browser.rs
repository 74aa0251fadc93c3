//! The dashboard in a real browser: Debian's headless Chromium, driven over the DevTools
//! protocol, against the real `tessera` binaries (a coordinator with a token and `--http`, a
//! worker, `submit`, `fetch`), as a user would run them.
//!
//! The browser logs in with the token, opens the job's page, waits until the preview shows
//! something, takes the screenshot docs/images/dashboard.png is made from, watches the
//! progress move, switches to the noise map and back, turns the exposure up and down, and at
//! the end checks that the preview it shows is the fetched EXR tone-mapped and that its
//! download link gives the EXR.
//!
//! Built only with the `browser` feature (it needs Chromium: `.ci/run` installs Debian's
//! package): `cargo test --release -p tessera-cli --features browser --test browser`.

mod common;

use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use base64::Engine as _;
use serde_json::{json, Value};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

use common::{coordinator_with_dashboard, repo, Proc, BIN};
use tessera_testkit::{wait_for_blocking as wait_for, PATIENCE};

const TOKEN: &str = "browser-test-token-0123456789abcdef";

/// The Chromium binary: Debian's package installs it as `chromium`.
fn chromium() -> PathBuf {
    let found = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .flat_map(|d| ["chromium", "chromium-browser"].map(|n| d.join(n)))
            .find(|p| p.is_file())
    });
    found.unwrap_or_else(|| {
        panic!(
            "no chromium on PATH: this test drives a real browser; install Debian's package \
             (.ci/install-chromium.sh, which .ci/run runs)"
        )
    })
}

/// A DevTools protocol session with one page, over the browser's WebSocket, with target
/// sessions flattened onto it.
struct Cdp {
    ws: WebSocket<MaybeTlsStream<TcpStream>>,
    session: String,
    next: u64,
    _browser: Proc,
}

impl Cdp {
    /// Starts headless Chromium with a fresh profile in `profile` and attaches to its page.
    fn launch(profile: &Path) -> Self {
        let mut child = Command::new(chromium())
            .args([
                "--headless=new",
                // Containers and CI runners run as root, where Chromium's sandbox cannot start.
                "--no-sandbox",
                "--disable-gpu",
                "--disable-dev-shm-usage",
                "--no-first-run",
                "--hide-scrollbars",
                "--remote-debugging-port=0",
                "--window-size=1400,860",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg("about:blank")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start chromium");
        let stderr = child.stderr.take().expect("stderr");
        let browser = Proc(child);
        let mut lines = BufReader::new(stderr).lines();
        let url = loop {
            let line = lines
                .next()
                .expect("chromium exited before its DevTools line")
                .expect("read chromium's stderr");
            if let Some(u) = line.strip_prefix("DevTools listening on ") {
                break u.trim().to_string();
            }
        };
        // Chromium blocks once its stderr pipe is full: keep reading it.
        std::thread::spawn(move || for _ in lines {});
        let (ws, _) = tungstenite::connect(url.as_str()).expect("connect to DevTools");
        if let MaybeTlsStream::Plain(s) = ws.get_ref() {
            s.set_read_timeout(Some(PATIENCE)).expect("timeout");
        }
        let mut cdp = Self {
            ws,
            session: String::new(),
            next: 0,
            _browser: browser,
        };
        let targets = cdp.call("Target.getTargets", json!({}));
        let page = targets["targetInfos"]
            .as_array()
            .and_then(|t| t.iter().find(|t| t["type"] == "page"))
            .expect("a page target")["targetId"]
            .clone();
        let attached = cdp.call(
            "Target.attachToTarget",
            json!({ "targetId": page, "flatten": true }),
        );
        cdp.session = attached["sessionId"]
            .as_str()
            .expect("session id")
            .to_string();
        cdp.call("Page.enable", json!({}));
        // A fixed viewport, whatever the window's decorations take.
        cdp.call(
            "Emulation.setDeviceMetricsOverride",
            json!({ "width": 1400, "height": 860, "deviceScaleFactor": 1, "mobile": false }),
        );
        cdp
    }

    /// Sends a command (to the page once attached) and returns its result; events that come
    /// in between are dropped.
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.next += 1;
        let id = self.next;
        let mut msg = json!({ "id": id, "method": method, "params": params });
        if !self.session.is_empty() {
            msg["sessionId"] = json!(self.session);
        }
        self.ws
            .send(Message::Text(msg.to_string().into()))
            .expect("send to DevTools");
        loop {
            let m = self.ws.read().expect("read from DevTools");
            let Message::Text(t) = m else { continue };
            let v: Value = serde_json::from_str(&t).expect("DevTools JSON");
            if v["id"] == id {
                assert!(v.get("error").is_none(), "{method}: {}", v["error"]);
                return v["result"].clone();
            }
        }
    }

    /// Evaluates `js` in the page (awaiting it if it is a promise) and returns its value.
    fn eval(&mut self, js: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({ "expression": js, "returnByValue": true, "awaitPromise": true }),
        );
        assert!(
            r.get("exceptionDetails").is_none(),
            "{js}: {}",
            r["exceptionDetails"]
        );
        r["result"]["value"].clone()
    }

    fn navigate(&mut self, url: &str) {
        self.call("Page.navigate", json!({ "url": url }));
    }

    fn screenshot(&mut self) -> Vec<u8> {
        let r = self.call("Page.captureScreenshot", json!({ "format": "png" }));
        base64::engine::general_purpose::STANDARD
            .decode(r["data"].as_str().expect("screenshot data"))
            .expect("base64")
    }
}

/// The state of the job page, read in the page: the preview's status and whether it shows
/// anything but black, and the progress the page prints.
const PAGE_STATE: &str = r#"(() => {
  const img = document.getElementById("preview");
  const text = (id) => { const e = document.getElementById(id); return e ? e.textContent : null; };
  let bright = 0, sum = 0;
  if (img && img.complete && img.naturalWidth > 0) {
    const c = document.createElement("canvas");
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    const g = c.getContext("2d");
    g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    for (let i = 0; i < d.length; i += 4) {
      const v = d[i] + d[i + 1] + d[i + 2];
      sum += v;
      if (v > 30) bright++;
    }
  }
  return {
    login: document.getElementById("token") !== null,
    units: img ? img.dataset.units || null : null,
    view: img ? img.dataset.view || null : null,
    exposure: img ? img.dataset.exposure || null : null,
    mean: img && img.naturalWidth > 0 ? sum / (3 * img.naturalWidth * img.naturalHeight) : 0,
    shown_state: img ? img.dataset.state || null : null,
    bright,
    state: text("stat-state"),
    progress: text("stat-progress"),
    units_text: text("stat-units"),
  };
})()"#;

/// Decodes an 8-bit RGB PNG.
fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("frame");
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// Bytes a `fetch` in the page gets for `url`, as the browser (with its cookie) sees them.
fn fetch_in_page(cdp: &mut Cdp, url_js: &str) -> Vec<u8> {
    let v = cdp.eval(&format!(
        "fetch({url_js}).then(r => r.arrayBuffer()).then(b => Array.from(new Uint8Array(b)))"
    ));
    v.as_array()
        .expect("bytes")
        .iter()
        .map(|b| b.as_u64().expect("byte") as u8)
        .collect()
}

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[test]
fn the_dashboard_in_chromium_follows_a_job_to_its_exr() {
    let dir = tempfile::tempdir().expect("tempdir");
    let token_file = dir.path().join("token");
    std::fs::write(&token_file, format!("{TOKEN}\n")).expect("token");
    let token_file = token_file.display().to_string();

    let (_coordinator, grpc, dash) =
        coordinator_with_dashboard(&dir.path().join("data"), &["--token-file", &token_file]);

    let _worker = Proc(
        Command::new(BIN)
            .args([
                "worker",
                "--coordinator",
                &grpc,
                "--token-file",
                &token_file,
            ])
            .args(["--threads", "1", "--name", "render-node-1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start worker"),
    );
    let tessera = |args: &[&str]| {
        let out = Command::new(BIN)
            .current_dir(repo(""))
            .args(args)
            .args(["--coordinator", &grpc, "--token-file", &token_file])
            .output()
            .expect("run tessera");
        assert!(
            out.status.success(),
            "tessera {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    };
    // Long enough on one thread (several seconds) for the page to see it run, in batches
    // small enough that the preview refines in many steps (the unit rule would cut this job
    // into 8 units).
    let job = tessera(&[
        "submit",
        "scenes/cornell-box.toml",
        "--spp",
        "384",
        "--batch",
        "16",
    ]);
    assert!(job.starts_with("job-"), "{job}");

    let profile = tempfile::tempdir().expect("profile");
    let mut cdp = Cdp::launch(profile.path());
    // Without the token the page is the login form; the token logs in and comes back here.
    cdp.navigate(&format!("{dash}/jobs/{job}"));
    wait_for("the login form", || {
        (cdp.eval(PAGE_STATE)["login"] == true).then_some(())
    });
    cdp.eval(&format!(
        "document.getElementById('token').value = {}; document.getElementById('login').click(); true",
        json!(TOKEN)
    ));
    // A quarter in, so that the screenshot shows a picture taking shape.
    let first = wait_for("a preview with something in it, a quarter in", || {
        let s = cdp.eval(PAGE_STATE);
        let units: u64 = s["units"]
            .as_str()
            .and_then(|u| u.parse().ok())
            .unwrap_or(0);
        (s["bright"].as_u64().unwrap_or(0) > 1000 && units >= 24).then_some(s)
    });
    let shot = cdp.screenshot();
    let (w, h, _) = decode_png(&shot);
    assert_eq!((w, h), (1400, 860));
    let target = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("dashboard.png");
    std::fs::write(&target, &shot).expect("write the screenshot");
    eprintln!("screenshot: {}", target.display());

    // The progress moves while the job runs (or the job ends, which moves it to 100%).
    let before = first["progress"].as_str().unwrap_or_default().to_string();
    wait_for("the progress to move", || {
        let s = cdp.eval(PAGE_STATE);
        (s["progress"].as_str() != Some(before.as_str())).then_some(())
    });

    // The noise map, then the image again.
    cdp.eval("document.getElementById('view-toggle').click(); true");
    let noise = wait_for("the noise view (or the job's end)", || {
        let s = cdp.eval(PAGE_STATE);
        let noted = cdp.eval("document.getElementById('preview-note').textContent");
        let ended = noted.as_str().is_some_and(|n| n.contains("has ended"));
        (s["view"] == "noise" || ended).then_some(s)
    });
    eprintln!("noise view: {noise}");
    cdp.eval("document.getElementById('view-toggle').click(); true");

    // Two stops up brightens the picture; then back to 0.
    let set_exposure = |cdp: &mut Cdp, ev: &str| {
        cdp.eval(&format!(
            "(() => {{ const e = document.getElementById('exposure'); e.value = '{ev}'; \
             e.dispatchEvent(new Event('input')); return true; }})()"
        ));
        wait_for(&format!("the preview at {ev} EV"), || {
            let s = cdp.eval(PAGE_STATE);
            (s["view"] == "color" && s["exposure"] == ev).then_some(s)
        })
    };
    let at0 = wait_for("the image view again", || {
        let s = cdp.eval(PAGE_STATE);
        (s["view"] == "color").then_some(s)
    });
    let at2 = set_exposure(&mut cdp, "2");
    let (m0, m2) = (
        at0["mean"].as_f64().unwrap_or(0.0),
        at2["mean"].as_f64().unwrap_or(0.0),
    );
    assert!(
        m2 > 1.2 * m0,
        "+2 EV did not brighten the preview: {m0} then {m2}"
    );
    set_exposure(&mut cdp, "0");

    let done = wait_for("the page to show the job done", || {
        let s = cdp.eval(PAGE_STATE);
        let shown = s["shown_state"] == "done" && s["view"] == "color" && s["exposure"] == "0";
        (s["state"] == "done" && shown).then_some(s)
    });
    assert_eq!(
        done["progress"].as_str().map(str::trim),
        Some("100.0%"),
        "{done}"
    );

    // What the page shows at the end is the EXR, tone-mapped as `--preview` does it.
    let exr = dir.path().join("fetched.exr");
    tessera(&["fetch", &job, "--output", &exr.display().to_string()]);
    let image = tessera_render::output::read_exr_rgb(&exr).expect("read EXR");
    let shown = fetch_in_page(&mut cdp, "document.getElementById('preview').src");
    let (w, h, px) = decode_png(&shown);
    assert_eq!((w as usize, h as usize), (image.width, image.height));
    let want = tessera_render::output::tone_map(
        &image.rgb,
        tessera_render::output::Preview { exposure: 0.0 },
    );
    assert!(px == want, "the final preview is not the EXR tone-mapped");
    let downloaded = fetch_in_page(&mut cdp, "document.getElementById('download').href");
    assert!(
        downloaded == std::fs::read(&exr).expect("EXR"),
        "the download link does not give the EXR"
    );

    // The job list and the workers page show the job and the worker.
    cdp.navigate(&format!("{dash}/"));
    let row = wait_for("the job list", || {
        let v = cdp.eval(&format!(
            "(() => {{ const r = document.querySelector('tr[data-job=\"{job}\"]'); return r ? r.textContent : null; }})()"
        ));
        v.as_str().map(str::to_string)
    });
    assert!(row.contains("done") && row.contains("100.0%"), "{row}");
    cdp.navigate(&format!("{dash}/workers"));
    let table = wait_for("the workers page", || {
        let v = cdp.eval(
            "(() => { const t = document.getElementById('workers'); return t ? t.textContent : null; })()",
        );
        v.as_str().map(str::to_string)
    });
    assert!(
        table.contains("render-node-1") && table.contains("127.0.0.1"),
        "{table}"
    );
}

/// #55, what a new user met: at 1280 px the job list needed a horizontal scroll (a long scene
/// path, the priority and the Cancel button off the edge); with no token configured the page
/// offered "Log out"; a cancelled job's page showed a broken-image icon and "Noise – (rms
/// 0.00)".
///
/// Long because it is one scenario, its steps in the order they happen to the farm (each
/// step's state is the next one's start); split into functions, that order would be hidden.
#[test]
fn the_dashboard_fits_1280_px_and_a_cancelled_job_shows_no_broken_picture() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_coordinator, grpc, dash) = coordinator_with_dashboard(&dir.path().join("data"), &[]);
    // A scene under a long path, as a studio's are, and no worker: the jobs stay queued.
    let deep = dir
        .path()
        .join("projects/feature-film/sequences/sq0420/shots/sh0420_0130/lighting/v012");
    std::fs::create_dir_all(&deep).expect("mkdir");
    let scene = deep.join("sh0420_0130_lighting_v012_cornell.toml");
    std::fs::copy(repo("scenes/spheres.toml"), &scene).expect("copy");
    let tessera = |args: &[&str]| {
        let out = Command::new(BIN)
            .args(args)
            .args(["--coordinator", &grpc])
            .output()
            .expect("run tessera");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    };
    let scene = scene.display().to_string();
    let cancelled = tessera(&["submit", &scene, "--spp", "64", "--priority", "10"]);
    tessera(&["cancel", &cancelled]);
    // Waiting for a tag no worker has, so that it stays queued with a worker connected.
    let queued = tessera(&[
        "submit",
        &scene,
        "--spp",
        "1048576",
        "--priority",
        "-3",
        "--require",
        "pool=none",
    ]);
    // A worker named and tagged as a studio's are (#79.16: the workers page clipped its Drain
    // button at 1280 px).
    let _worker = Proc(
        Command::new(BIN)
            .args(["worker", "--coordinator", &grpc, "--threads", "1"])
            .args([
                "--name",
                "render-node-0042.lighting.feature-film.studio.example",
            ])
            .args([
                "--tag",
                "pool=lighting-and-comp-farm",
                "--tag",
                "gpu-class=none",
            ])
            .args(["--tag", "site=building-7-floor-3"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start worker"),
    );

    let profile = tempfile::tempdir().expect("profile");
    let mut cdp = Cdp::launch(profile.path());
    cdp.call(
        "Emulation.setDeviceMetricsOverride",
        json!({ "width": 1280, "height": 800, "deviceScaleFactor": 1, "mobile": false }),
    );
    cdp.navigate(&format!("{dash}/"));
    let fit = wait_for("the job list", || {
        let v = cdp.eval(
            "(() => { const t = document.getElementById('jobs'); if (!t || t.rows.length < 3) return null; \
             const d = document.documentElement; const box = t.getBoundingClientRect(); \
             return { page: d.scrollWidth, view: d.clientWidth, right: box.right, \
                      logout: document.body.textContent.includes('Log out') }; })()",
        );
        (!v.is_null()).then_some(v)
    });
    let (page, view, right) = (
        fit["page"].as_f64().unwrap_or(f64::MAX),
        fit["view"].as_f64().unwrap_or(0.0),
        fit["right"].as_f64().unwrap_or(f64::MAX),
    );
    assert!(
        page <= view && right <= view,
        "the job list overflows 1280 px: {fit}"
    );
    assert_eq!(fit["logout"], false, "Log out with no token configured");

    cdp.navigate(&format!("{dash}/jobs/{cancelled}"));
    let page = wait_for("the cancelled job's page", || {
        let v = cdp.eval(
            "(() => { const n = document.getElementById('stat-noise'); const img = document.getElementById('preview'); \
             const note = document.getElementById('preview-note'); \
             if (!n || !img || !note || !note.textContent) return null; \
             return { noise: n.textContent, hidden: img.hidden, shown: img.getBoundingClientRect().width, \
                      note: note.textContent }; })()",
        );
        (!v.is_null()).then_some(v)
    });
    assert_eq!(page["noise"], "–", "{page}");
    assert_eq!(page["hidden"], true, "{page}");
    assert_eq!(page["shown"].as_f64(), Some(0.0), "{page}");
    assert!(
        page["note"]
            .as_str()
            .is_some_and(|n| n.contains("cancelled before any sample")),
        "{page}"
    );

    // The queued job's page pauses, resumes and reprioritises it (#79.16: it offered Cancel
    // alone).
    cdp.navigate(&format!("{dash}/jobs/{queued}"));
    let stat = |cdp: &mut Cdp, id: &str| {
        cdp.eval(&format!(
            "(() => {{ const e = document.getElementById('{id}'); return e ? e.textContent : null; }})()"
        ))
    };
    wait_for("the pause button", || {
        (stat(&mut cdp, "pause").as_str() == Some("Pause")).then_some(())
    });
    cdp.eval("document.getElementById('pause').click(); true");
    wait_for("the job paused", || {
        let paused = stat(&mut cdp, "stat-state").as_str() == Some("paused");
        (paused && stat(&mut cdp, "resume").as_str() == Some("Resume")).then_some(())
    });
    cdp.eval("document.getElementById('resume').click(); true");
    wait_for("the job resumed", || {
        (stat(&mut cdp, "stat-state").as_str() == Some("queued")).then_some(())
    });
    cdp.eval(
        "document.getElementById('priority-input').value = '7'; \
         document.getElementById('set-priority').click(); true",
    );
    wait_for("the new priority", || {
        (stat(&mut cdp, "stat-priority").as_str() == Some("7")).then_some(())
    });
    let listed = tessera(&["status", &queued]);
    let words: Vec<&str> = listed.split_whitespace().collect();
    assert!(words.windows(2).any(|w| w == ["priority", "7"]), "{listed}");

    // The workers page fits 1280 px, its Drain button in view.
    cdp.navigate(&format!("{dash}/workers"));
    let fit = wait_for("the workers page with its Drain button", || {
        let v = cdp.eval(
            "(() => { const b = [...document.querySelectorAll('#workers button')].find((x) => x.textContent === 'Drain'); \
             if (!b) return null; const d = document.documentElement; const r = b.getBoundingClientRect(); \
             const box = b.closest('.scroll').getBoundingClientRect(); \
             return { page: d.scrollWidth, view: d.clientWidth, right: r.right, width: r.width, box: box.right }; })()",
        );
        (!v.is_null()).then_some(v)
    });
    let (page, view, right, width) = (
        fit["page"].as_f64().unwrap_or(f64::MAX),
        fit["view"].as_f64().unwrap_or(0.0),
        fit["right"].as_f64().unwrap_or(f64::MAX),
        fit["width"].as_f64().unwrap_or(0.0),
    );
    assert!(
        page <= view && right <= view && width > 20.0,
        "the workers page clips its Drain button at 1280 px: {fit}"
    );
}

/// The dashboard's submit form, as an artist uses it: a scene that names a mesh, chosen with
/// the mesh, denoised. The coordinator names the file the scene needs, the page uploads the
/// chosen file of that name and submits again; without it, the page says which file to add.
#[test]
fn a_job_submitted_from_the_dashboard_uploads_its_files_and_is_denoised() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tempdir");
    let (_coordinator, grpc, dash) =
        coordinator_with_dashboard(&dir.path().join("data"), &["--denoise"]);
    let _worker = common::worker(&grpc, "render-node-1");
    let profile = tempfile::tempdir().expect("profile");
    let mut cdp = Cdp::launch(profile.path());
    cdp.navigate(&format!("{dash}/"));
    wait_for("the submit form", || {
        (cdp.eval("document.getElementById('submit-files') !== null") == true).then_some(())
    });
    let choose = |cdp: &mut Cdp, files: &[String]| {
        let input = cdp.call(
            "Runtime.evaluate",
            json!({ "expression": "document.getElementById('submit-files')" }),
        );
        let object = input["result"]["objectId"].clone();
        cdp.call(
            "DOM.setFileInputFiles",
            json!({ "files": files, "objectId": object }),
        );
    };
    // The browser reads files by their real paths (no `..`).
    let real = |p: &str| {
        std::fs::canonicalize(repo(p))
            .expect("a file of the repository")
            .display()
            .to_string()
    };
    let (scene, mesh) = (
        real("scenes/cornell-mesh.toml"),
        real("scenes/meshes/cube.obj"),
    );
    // Without the mesh: the page names it.
    choose(&mut cdp, std::slice::from_ref(&scene));
    cdp.eval(
        "document.getElementById('submit').open = true; \
         document.getElementById('submit-spp').value = '4'; \
         document.getElementById('submit-denoise').checked = true; \
         document.getElementById('submit-quality').value = 'fast'; \
         document.getElementById('submit-go').click(); true",
    );
    let said = wait_for("the page to say what is missing", || {
        let v = cdp.eval(
            "(() => { const n = document.getElementById('submit-note'); \
             return n && n.className === 'error' ? n.textContent : null; })()",
        );
        v.as_str().map(str::to_string)
    });
    assert!(said.contains("choose cube.obj too"), "{said}");
    // With it: uploaded, submitted, and the page goes to the job.
    choose(&mut cdp, &[scene, mesh]);
    cdp.eval("document.getElementById('submit-go').click(); true");
    let job = wait_for("the job's page", || {
        let v = cdp.eval("location.pathname");
        v.as_str()
            .and_then(|p| p.strip_prefix("/jobs/"))
            .map(str::to_string)
    });
    wait_for("the job to finish", || {
        (cdp.eval(&format!(
            "fetch('/api/jobs/{job}').then(r => r.json()).then(j => j.state)"
        )) == "done")
            .then_some(())
    });
    let exr = fetch_in_page(&mut cdp, &format!("'/api/jobs/{job}/output.exr'"));
    let path = dir.path().join("submitted.exr");
    std::fs::write(&path, exr).expect("write");
    let denoised = tessera_render::output::read_exr_channel(&path, "denoised.R").expect("layer");
    assert_eq!(denoised.len(), 256 * 256);
    let meta = tessera_render::output::read_exr_metadata(&path).expect("metadata");
    assert!(
        meta.iter().any(|m| m == "denoise=oidn 2.5.1 fast hdr"),
        "{meta:?}"
    );
}
