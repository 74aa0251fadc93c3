//! `tessera render --denoise` through the real binary and the real Open Image Denoise, which
//! the tests install as a user does (`scripts/install-oidn.sh`, into `target/oidn/lib`, where
//! the built binary finds it).

mod common;

use std::path::Path;

use common::{assert_clean_failure, repo, tessera};
use tessera_render::output::{read_exr_channel, read_exr_metadata};

fn render(out: &Path, extra: &[&str]) {
    let scene = repo("scenes/cornell-box.toml");
    let mut args = vec![
        "render",
        &scene,
        "--resolution",
        "64x64",
        "--output",
        out.to_str().expect("utf8"),
    ];
    args.extend(extra);
    let r = tessera(&args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

fn rgb(path: &Path, layer: &str) -> Vec<[f32; 3]> {
    let c = |n: &str| read_exr_channel(path, &format!("{layer}{n}")).expect(n);
    let (r, g, b) = (c("R"), c("G"), c("B"));
    (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect()
}

#[test]
fn the_denoised_layer_is_added_and_the_beauty_keeps_its_bits() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tmp");
    let (plain, denoised) = (dir.path().join("plain.exr"), dir.path().join("d.exr"));
    render(&plain, &["--spp", "8"]);
    render(&denoised, &["--spp", "8", "--denoise"]);
    for c in ["R", "G", "B"] {
        let (a, b) = (
            read_exr_channel(&plain, c).expect("plain"),
            read_exr_channel(&denoised, c).expect("denoised file"),
        );
        assert!(
            a.iter()
                .map(|v| v.to_bits())
                .eq(b.iter().map(|v| v.to_bits())),
            "the beauty's channel {c} changed"
        );
    }
    for c in [
        "denoised.R",
        "denoised.G",
        "denoised.B",
        "denoised.albedo.R",
        "denoised.albedo.G",
        "denoised.albedo.B",
        "denoised.normal.X",
        "denoised.normal.Y",
        "denoised.normal.Z",
        "albedo.R",
        "normal.X",
    ] {
        let v = read_exr_channel(&denoised, c).unwrap_or_else(|e| panic!("{c}: {e}"));
        assert_eq!(v.len(), 64 * 64, "{c}");
        assert!(
            v.iter().all(|x| x.is_finite()),
            "{c} has a non-finite value"
        );
    }
    assert!(read_exr_channel(&plain, "denoised.R").is_err());
    let meta = read_exr_metadata(&denoised).expect("metadata");
    assert!(
        meta.iter().any(|m| m == "denoise=oidn 2.5.1 high hdr"),
        "{meta:?}"
    );
    // Without --denoise nothing of it is there.
    let plain_meta = read_exr_metadata(&plain).expect("metadata");
    assert!(!plain_meta.iter().any(|m| m.starts_with("denoise=")));
}

#[test]
fn a_denoised_frame_is_closer_to_the_converged_one_than_the_raw_frame() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tmp");
    let (reference, noisy) = (dir.path().join("ref.exr"), dir.path().join("noisy.exr"));
    render(&reference, &["--spp", "1024"]);
    render(&noisy, &["--spp", "16", "--denoise", "--seed", "7"]);
    let truth = rgb(&reference, "");
    let (raw, den) = (
        tessera_testkit::rel_mse(&rgb(&noisy, ""), &truth),
        tessera_testkit::rel_mse(&rgb(&noisy, "denoised."), &truth),
    );
    // A guard against a filter that stops helping (wrong inputs, a swapped image), not a
    // measure of how well it does (docs/renderer.md has that).
    assert!(
        den < raw / 2.0,
        "relMSE against 1024 spp: raw {raw}, denoised {den}"
    );
}

#[test]
fn denoised_files_are_the_same_bytes_on_any_number_of_threads_on_one_machine() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tmp");
    let (one, two) = (dir.path().join("1.exr"), dir.path().join("2.exr"));
    render(&one, &["--spp", "4", "--denoise", "--threads", "1"]);
    render(&two, &["--spp", "4", "--denoise", "--threads", "2"]);
    assert!(
        std::fs::read(&one).expect("1") == std::fs::read(&two).expect("2"),
        "the files differ"
    );
}

/// Runs the copied binary. Its copy was written through a file handle that a child which
/// another test thread forked at that moment holds until that child execs; exec meanwhile
/// fails with ETXTBSY ("Text file busy", seen in CI), so that one error is waited out.
fn output_of_copy(cmd: &mut std::process::Command) -> std::process::Output {
    for _ in 0..200 {
        match cmd.output() {
            Err(e) if e.kind() == std::io::ErrorKind::ExecutableFileBusy => {
                std::thread::sleep(std::time::Duration::from_millis(25));
            }
            r => return r.expect("run"),
        }
    }
    panic!("the copied binary stayed busy for 5 s");
}

#[test]
fn without_the_library_denoise_fails_at_once_saying_how_to_install_it() {
    // The binary copied where no oidn/lib is beside it or above it: as on a machine where
    // the script was never run.
    let dir = tempfile::tempdir().expect("tmp");
    let bin = dir.path().join("bin").join("tessera");
    std::fs::create_dir_all(bin.parent().expect("parent")).expect("mkdir");
    std::fs::copy(env!("CARGO_BIN_EXE_tessera"), &bin).expect("copy");
    let out = dir.path().join("out.exr");
    let r = output_of_copy(
        std::process::Command::new(&bin)
            .args([
                "render",
                &repo("scenes/cornell-box.toml"),
                "--spp",
                "1024",
                "--denoise",
                "--output",
                out.to_str().expect("utf8"),
            ])
            .env_remove("TESSERA_OIDN_DIR"),
    );
    assert_clean_failure(
        &r,
        &[
            "--denoise",
            "libOpenImageDenoise.so.2",
            "scripts/install-oidn.sh",
        ],
    );
    assert!(!out.exists(), "nothing is rendered or written");
    // A worker asked to denoise does not start without it either (nor register: the URL
    // leads nowhere, and the library is checked first).
    let r = output_of_copy(
        std::process::Command::new(&bin)
            .args(["worker", "--coordinator", "http://127.0.0.1:9", "--denoise"])
            .env_remove("TESSERA_OIDN_DIR"),
    );
    assert_clean_failure(&r, &["libOpenImageDenoise.so.2", "scripts/install-oidn.sh"]);
    // The same binary renders without --denoise.
    let r = output_of_copy(std::process::Command::new(&bin).args([
        "render",
        &repo("scenes/cornell-box.toml"),
        "--spp",
        "1",
        "--resolution",
        "16x16",
        "--output",
        out.to_str().expect("utf8"),
    ]));
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

#[test]
fn denoise_options_need_denoise() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("o.exr");
    let scene = repo("scenes/cornell-box.toml");
    for flags in [&["--denoise-quality", "fast"][..], &["--denoise-ldr"][..]] {
        let mut args = vec!["render", &scene, "--output", out.to_str().expect("utf8")];
        args.extend(flags);
        assert_clean_failure(&tessera(&args), &["--denoise"]);
    }
    let mut args = vec!["render", &scene, "--output", out.to_str().expect("utf8")];
    args.extend(["--denoise", "--denoise-quality", "best"]);
    assert_clean_failure(&tessera(&args), &["best"]);
}

/// Runs `tessera` against the coordinator at `url`.
/// The flags of the farm tests' denoised job, which `tessera render` is given too.
const FARM_FLAGS: [&str; 9] = [
    "--spp",
    "8",
    "--batch",
    "4",
    "--resolution",
    "64x48",
    "--denoise",
    "--denoise-quality",
    "balanced",
];

fn at(args: &[&str], url: &str) -> std::process::Output {
    common::tessera_at(args, url)
}

#[test]
fn the_farm_denoises_once_after_the_last_merge_and_matches_render_denoise() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url, dashboard) = common::coordinator_with_dashboard(
        &dir.path().join("data"),
        &["--lease-timeout", "5", "--denoise"],
    );
    let _a = common::worker(&url, "a");
    let _b = common::worker(&url, "b");
    let scene = repo("scenes/cornell-box.toml");
    let farm =
        common::assert_farm_file_is_render_file(dir.path(), &url, &scene, &FARM_FLAGS, "denoised");
    let meta = read_exr_metadata(&farm).expect("metadata");
    assert!(
        meta.iter().any(|m| m == "denoise=oidn 2.5.1 balanced hdr"),
        "{meta:?}"
    );
    // The dashboard shows the finished job's denoised image, and says why a job without one
    // has none.
    let job = meta
        .iter()
        .find_map(|m| m.strip_prefix("job="))
        .map(str::to_string);
    let listed = at(&["status", "--json"], &url);
    let text = String::from_utf8_lossy(&listed.stdout);
    let id = job.unwrap_or_else(|| {
        let at = text.find("job-").expect("a job id");
        text[at..at + 10].to_string()
    });
    let (status, body) = http_get(
        &dashboard,
        &format!("/api/jobs/{id}/preview.png?view=denoised"),
    );
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    assert!(body.starts_with(b"\x89PNG"), "not a PNG");
    let (plain, _) = http_get(
        &dashboard,
        &format!("/api/jobs/{id}/preview.png?view=color"),
    );
    assert_eq!(plain, 200);
    // A bad quality is named, and refused before anything is stored.
    let out = at(
        &[
            "submit",
            scene.as_str(),
            "--spp",
            "1",
            "--denoise",
            "--denoise-quality",
            "best",
        ],
        &url,
    );
    assert_clean_failure(&out, &["best"]);
}

/// A coordinator that does not denoise lends the finished frame to a worker started with
/// `--denoise` (the real library, in its own process): the same bytes as `tessera render
/// --denoise`; until such a worker joins, the job says what it waits for.
#[test]
fn a_worker_that_denoises_finishes_the_frame_for_a_coordinator_that_does_not() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url, dashboard) =
        common::coordinator_with_dashboard(&dir.path().join("data"), &["--lease-timeout", "5"]);
    let _renders = common::worker(&url, "renders");
    let scene = repo("scenes/cornell-box.toml");
    let submitted = at(
        &[
            "submit",
            &scene,
            "--spp",
            "4",
            "--resolution",
            "32x24",
            "--denoise",
        ],
        &url,
    );
    assert!(
        submitted.status.success(),
        "{}",
        String::from_utf8_lossy(&submitted.stderr)
    );
    let status = || String::from_utf8_lossy(&at(&["status", "--json"], &url).stdout).to_string();
    assert!(
        eventually(|| status().contains("waiting for a worker that denoises")),
        "the job never said it waits for a denoising worker: {}",
        status()
    );
    // While it waits, the dashboard shows the rendered frame, and a denoised preview made
    // on the coordinator (which finds the library here).
    let text = status();
    let at_job = text.find("job-").expect("a job id");
    let id = &text[at_job..at_job + 10];
    for view in ["color", "denoised"] {
        let (code, body) = http_get(
            &dashboard,
            &format!("/api/jobs/{id}/preview.png?view={view}"),
        );
        assert_eq!(code, 200, "{view}: {}", String::from_utf8_lossy(&body));
        let mut png = png::Decoder::new(std::io::Cursor::new(body))
            .read_info()
            .expect("a PNG");
        let mut px = vec![0; png.output_buffer_size()];
        png.next_frame(&mut px).expect("pixels");
        let lit = px.iter().filter(|&&v| v > 0).count();
        assert!(lit > px.len() / 2, "the {view} preview is mostly black");
    }
    let log = dir.path().join("denoiser.log");
    let _denoises = common::worker_with(&url, "denoises", &["--denoise"], &log);
    assert!(
        eventually(|| {
            let w = at(&["workers"], &url);
            String::from_utf8_lossy(&w.stdout).contains("denoise")
        }),
        "tessera workers does not show the denoise tag"
    );
    // The waiting job finishes, and a second one matches render --denoise byte for byte.
    let farm = common::assert_farm_file_is_render_file(
        dir.path(),
        &url,
        &scene,
        &FARM_FLAGS,
        "worker-denoised",
    );
    let meta = read_exr_metadata(&farm).expect("metadata");
    assert!(
        meta.iter().any(|m| m == "denoise=oidn 2.5.1 balanced hdr"),
        "{meta:?}"
    );
    assert!(
        eventually(|| !status().contains("\"running\"")),
        "{}",
        status()
    );
    let log = std::fs::read_to_string(&log).expect("log");
    assert_eq!(log.matches("denoised job-").count(), 2, "{log}");
}

/// Whether `check` holds within a minute, polled.
fn eventually(mut check: impl FnMut() -> bool) -> bool {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while std::time::Instant::now() < deadline {
        if check() {
            return true;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    false
}

/// A scene with `[render] denoise` is denoised without the flag: as `render` asked with it,
/// the same bytes.
#[test]
fn a_scene_that_asks_to_be_denoised_is_denoised_without_the_flag() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tmp");
    let text = std::fs::read_to_string(repo("scenes/cornell-box.toml")).expect("scene");
    let text = format!("{text}\n[render]\ndenoise = {{ quality = \"fast\" }}\n");
    let scene = common::write(dir.path(), "asks.toml", &text);
    let (by_scene, by_flag) = (dir.path().join("scene.exr"), dir.path().join("flag.exr"));
    for (out, extra) in [
        (&by_scene, &[][..]),
        (&by_flag, &["--denoise", "--denoise-quality", "fast"][..]),
    ] {
        let mut args = vec!["render", &scene, "--spp", "2", "--resolution", "32x32"];
        args.extend(extra);
        args.extend(["--output", out.to_str().expect("utf8")]);
        let r = tessera(&args);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    assert!(read_exr_channel(&by_scene, "denoised.R").is_ok());
    assert!(std::fs::read(&by_scene).expect("a") == std::fs::read(&by_flag).expect("b"));
}

/// A GET of `path` from the HTTP server at `base` (`http://host:port`): status and body.
fn http_get(base: &str, path: &str) -> (u16, Vec<u8>) {
    use std::io::{Read, Write};
    let host = base.trim_start_matches("http://");
    let mut conn = std::net::TcpStream::connect(host).expect("connect");
    write!(
        conn,
        "GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
    )
    .expect("request");
    let mut raw = Vec::new();
    conn.read_to_end(&mut raw).expect("response");
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("headers end");
    let head = String::from_utf8_lossy(&raw[..split]).to_string();
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .expect("status");
    (status, raw[split + 4..].to_vec())
}
