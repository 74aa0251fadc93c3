//! The farm as a user runs it: a `tessera coordinator` process, two `tessera worker`
//! processes and `tessera submit --wait`, on loopback. The fetched EXR must be the same bytes
//! as `tessera render` writes.

use std::io::{BufRead, BufReader};
use tessera_testkit::wait_for_blocking;
mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};

use common::{
    coordinator, one_line_failure, repo, start_coordinator, tessera_at, worker, Proc, BIN,
};

fn tessera(args: &[&str], url: &str) -> Output {
    tessera_at(args, url)
}

use std::time::Duration;

/// The job id a successful `tessera submit` printed.
fn submitted(out: &Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    text.split_whitespace()
        .find(|w| w.starts_with("job-"))
        .unwrap_or_else(|| panic!("no job id in {text}"))
        .trim_end_matches(|c: char| !c.is_ascii_digit())
        .to_string()
}

/// Waits until `f` holds, polling ([`wait_for_blocking`]).
fn wait_for(what: &str, mut f: impl FnMut() -> bool) {
    wait_for_blocking(what, || f().then_some(()));
}

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[test]
fn coordinator_two_workers_and_submit_wait_match_a_local_render() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _a = worker(&url, "a");
    let mut b = worker(&url, "b");
    let scene = repo("scenes/spheres.toml");
    // The job's settings, given alike to `submit` and to `render`.
    let job = [scene.as_str(), "--spp", "8", "--batch", "4", "--seed", "3"];
    let with = |cmd: &str, extra: &[&str]| -> Vec<String> {
        std::iter::once(cmd)
            .chain(job)
            .chain(extra.iter().copied())
            .map(String::from)
            .collect()
    };
    let run = |args: Vec<String>| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        tessera(&args, &url)
    };
    let farm = dir.path().join("farm.exr");
    let out = run(with(
        "submit",
        &["--wait", "--output", farm.to_str().expect("utf8")],
    ));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("job-000001 done"), "{stdout}");

    let local = dir.path().join("local.exr");
    let out = run(with("render", &["--output", local.to_str().expect("utf8")]));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        std::fs::read(&farm).expect("farm") == std::fs::read(&local).expect("local"),
        "the farm's EXR differs from tessera render's"
    );

    // Both workers took part and are listed.
    let out = tessera(&["workers"], &url);
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    for name in [" a ", " b "] {
        assert!(table.contains(name), "{table}");
    }

    // A reader that has gone (`tessera status JOB | grep -q …` once grep has its line) is not a
    // failure: every command that prints ends quietly and successfully, with no panic. The read
    // end closes before the command has even connected, so its first write meets the closed pipe.
    for args in [&["status", "job-000001"][..], &["status"], &["workers"]] {
        let mut child = Command::new(BIN)
            .args(args)
            .env("TESSERA_COORDINATOR", &url)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn");
        drop(child.stdout.take());
        let out = child.wait_with_output().expect("wait");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && stderr.is_empty(),
            "tessera {args:?} into a closed pipe: {:?}, {stderr}",
            out.status
        );
    }

    // Without --wait, submit prints the job id alone; fetch --wait then gets the same bytes.
    let out = run(with("submit", &[]));
    assert!(out.status.success());
    assert_eq!(String::from_utf8_lossy(&out.stdout), "job-000002\n");
    let again = dir.path().join("again.exr");
    // A link left where an older fetch put its partial file is not followed.
    let victim = dir.path().join("victim");
    std::fs::write(&victim, b"precious").expect("write");
    #[cfg(unix)]
    std::os::unix::fs::symlink(&victim, dir.path().join(".again.exr.part")).expect("symlink");
    let out = tessera(
        &[
            "fetch",
            "job-000002",
            "--wait",
            "-o",
            again.to_str().expect("utf8"),
        ],
        &url,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(std::fs::read(&again).expect("again") == std::fs::read(&local).expect("local"));
    assert_eq!(std::fs::read(&victim).expect("victim"), b"precious");

    // SIGTERM: the worker says goodbye and exits cleanly.
    let pid = b.0.id().to_string();
    let killed = Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .expect("kill");
    assert!(killed.success());
    let mut status = None;
    wait_for("the worker to exit", || {
        status = b.0.try_wait().expect("wait");
        status.is_some()
    });
    assert!(
        status.is_some_and(|s| s.success()),
        "worker exit {status:?}"
    );
    let out = tessera(&["workers"], &url);
    let table = String::from_utf8_lossy(&out.stdout);
    let line_b = table.lines().find(|l| l.contains(" b ")).expect("b listed");
    assert!(line_b.contains("gone"), "{table}");

    // Errors are one line and a non-zero exit.
    one_line_failure(
        &tessera(&["status", "job-000042"], &url),
        "unknown job job-000042",
    );
    one_line_failure(&tessera(&["cancel", "job-000001"], &url), "already ended");
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        std::fs::read_to_string(&scene)
            .expect("scene")
            .replace("[film]", "[film]\nwidht = 3"),
    )
    .expect("write");
    let out = tessera(&["submit", bad.to_str().expect("utf8"), "--spp", "1"], &url);
    one_line_failure(&out, "widht");
    one_line_failure(
        &tessera(&["status"], "http://127.0.0.1:1"),
        "cannot reach the coordinator at http://127.0.0.1:1",
    );
}

/// A farm as docker compose starts it: settings passed on as empty variables when the host
/// has none (`TESSERA_WORKER_THREADS=`, `TESSERA_TOKEN=`) mean "not set", and `submit --wait`
/// with no worker connected says so and keeps waiting until one joins.
#[test]
fn empty_settings_mean_unset_and_a_job_without_workers_says_so() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let out = dir.path().join("waited.exr");
    let mut submit = Command::new(BIN)
        .args([
            "submit",
            &repo("scenes/spheres.toml"),
            "--spp",
            "4",
            "--wait",
        ])
        .args(["--coordinator", &url, "--output"])
        .arg(&out)
        .env("TESSERA_TOKEN", "")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("submit");
    let stderr = submit.stderr.take().expect("stderr");
    let lines = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let sink = lines.clone();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let mut all = sink.lock().expect("lock");
            all.push_str(&line);
            all.push('\n');
        }
    });
    let _submit = Proc(submit);
    let said = || lines.lock().expect("lock").clone();
    wait_for("the no-worker warning", || {
        said().contains("no worker is connected")
    });
    assert!(
        said().contains(&format!("tessera worker --coordinator {url}")),
        "{}",
        said()
    );

    // A worker started the way compose starts it, with blank settings, logging to a file
    // (as `docker logs` does).
    let log = dir.path().join("worker.log");
    let _w = Proc(
        Command::new(BIN)
            .args(["worker", "--name", "blank"])
            .env("TESSERA_COORDINATOR", &url)
            .env("TESSERA_WORKER_THREADS", "")
            .env("TESSERA_TOKEN", " ")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).expect("log"))
            .spawn()
            .expect("worker"),
    );
    let mut submit = _submit;
    let mut status = None;
    wait_for("submit --wait to finish", || {
        status = submit.0.try_wait().expect("wait");
        status.is_some()
    });
    reader.join().expect("reader");
    assert!(
        status.is_some_and(|s| s.success()),
        "{status:?}: {}",
        said()
    );
    assert!(out.exists());
    let table = String::from_utf8_lossy(&tessera(&["workers"], &url).stdout).to_string();
    assert!(table.contains("blank"), "{table}");
    // A log that is not a terminal gets no colour codes.
    let logged = std::fs::read_to_string(&log).expect("log");
    assert!(logged.contains("registered"), "{logged}");
    assert!(
        !logged.contains('\u{1b}'),
        "ANSI codes in a log file: {logged:?}"
    );

    // A blank coordinator URL falls back to the default instead of failing to parse.
    let out = Command::new(BIN)
        .args(["status", "job-000001"])
        .env("TESSERA_COORDINATOR", "")
        .output()
        .expect("status");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() || stderr.contains("http://127.0.0.1:7878"),
        "{stderr}"
    );
}

/// A coordinator never starts on a damaged store: it says which file and why, in one line,
/// and never says it is listening.
#[test]
fn a_damaged_store_is_refused_at_start() {
    let dir = tempfile::tempdir().expect("tmp");
    let data = dir.path().join("data");
    std::fs::create_dir(&data).expect("mkdir");
    std::fs::write(data.join("coordinator.redb"), b"").expect("truncate");
    let out = Command::new(BIN)
        .args(["coordinator", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(&data)
        .output()
        .expect("coordinator");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!stdout.contains("listening"), "{stdout}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(errors.len(), 1, "{stderr}");
    assert!(
        errors[0].contains("coordinator.redb") && errors[0].contains("empty"),
        "{stderr}"
    );
    assert!(!out.status.success());
    assert!(!stderr.contains("panicked"), "{stderr}");

    // A file that is not a redb database: redb's message once (it was printed twice,
    // "X: X", as the error and again as its source).
    std::fs::write(data.join("coordinator.redb"), [7u8; 8192]).expect("garbage");
    let out = Command::new(BIN)
        .args(["coordinator", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(&data)
        .output()
        .expect("coordinator");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    let line = stderr
        .lines()
        .find(|l| l.starts_with("error:"))
        .expect("an error");
    assert!(line.contains("Not a redb database"), "{stderr}");
    assert_eq!(line.matches("Not a redb database").count(), 1, "{line}");

    // Nor on a bad TLS key: the error comes before any "listening on".
    let key = dir.path().join("key.pem");
    std::fs::write(&key, "not a key").expect("write");
    let out = Command::new(BIN)
        .args(["coordinator", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(dir.path().join("data2"))
        .args(["--tls-cert"])
        .arg(&key)
        .args(["--tls-key"])
        .arg(&key)
        .output()
        .expect("coordinator");
    assert!(!out.status.success());
    assert!(!String::from_utf8_lossy(&out.stdout).contains("listening"));
}

/// A frame range as a user runs it: `submit --frames … --wait --output DIR` saves every frame,
/// each the bytes `tessera render --frame N` writes; `status` shows the frames, and `fetch`
/// gets one frame or all of them.
#[test]
fn a_frame_range_is_submitted_followed_and_fetched_frame_by_frame() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _w = worker(&url, "a");
    let scene = repo("scenes/cornell-animated.toml");
    let shots = dir.path().join("shots");
    let s = |p: &Path| p.to_str().expect("utf8").to_string();
    let job = [scene.as_str(), "--spp", "4", "--batch", "4"];
    let mut submit = vec![
        "submit", "--frames", "1-48:47", "--name", "shot.exr", "--wait",
    ];
    submit.extend(job);
    let shots_arg = s(&shots);
    submit.extend(["--output", shots_arg.as_str()]);
    let out = tessera(&submit, &url);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("job-000001 frame 48 →"), "{stdout}");
    for frame in ["1", "48"] {
        let local = dir.path().join(format!("local-{frame}.exr"));
        let mut render = vec!["render", "--frame", frame, "--output"];
        let local_arg = s(&local);
        render.push(&local_arg);
        render.extend(job);
        let out = tessera(&render, &url);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let farm = shots.join(format!("shot.{frame:0>4}.exr"));
        assert!(
            std::fs::read(&farm).expect("farm frame") == std::fs::read(&local).expect("local"),
            "frame {frame}: the farm's EXR differs from tessera render --frame's"
        );
    }
    let out = tessera(&["status", "job-000001"], &url);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("frames     1-48:47, 2 frames: 2 done") && text.contains("shot.####.exr"),
        "{text}"
    );
    let one = dir.path().join("one.exr");
    let out = tessera(
        &["fetch", "job-000001", "--frame", "48", "-o", &s(&one)],
        &url,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        std::fs::read(&one).expect("one")
            == std::fs::read(shots.join("shot.0048.exr")).expect("48")
    );
    let all = dir.path().join("all");
    let out = tessera(&["fetch", "job-000001", "-o", &s(&all)], &url);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(all.join("shot.0001.exr").is_file() && all.join("shot.0048.exr").is_file());
    // Bad ranges are refused (as clap words a bad flag), naming what is wrong.
    for (args, needle) in [
        (
            &["--frames", "48-1"][..],
            "frames 48-1: the last frame is before the first",
        ),
        (&["--frames", "1-3", "--frame", "2"], "cannot be used with"),
    ] {
        let mut submit = vec!["submit", scene.as_str()];
        submit.extend(args);
        let out = tessera(&submit, &url);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && stderr.contains(needle) && !stderr.contains("panicked"),
            "{stderr}"
        );
    }
    let out = tessera(&["fetch", "job-000001", "-o", &s(&one)], &url);
    one_line_failure(&out, "names a directory");
}

/// `tessera coordinator --audit 1` as docs/farm.md gives it: every unit is rendered by both
/// workers and compared before it is merged; the EXR is still `tessera render`'s bytes, and
/// `tessera workers` shows the audits each passed.
#[test]
fn an_auditing_coordinator_checks_every_unit_and_keeps_the_bits() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, addr) = start_coordinator(
        "127.0.0.1:0",
        &dir.path().join("data"),
        &["--audit", "1"],
        Stdio::null(),
    );
    let url = format!("http://{addr}");
    let _a = worker(&url, "a");
    let _b = worker(&url, "b");
    let scene = repo("scenes/spheres.toml");
    let job = [scene.as_str(), "--spp", "8", "--batch", "4", "--seed", "3"];
    let farm = dir.path().join("farm.exr");
    let local = dir.path().join("local.exr");
    for (cmd, out) in [("submit", &farm), ("render", &local)] {
        let mut args = vec![cmd];
        args.extend(job);
        args.extend(["--output", out.to_str().expect("utf8")]);
        if cmd == "submit" {
            args.push("--wait");
        }
        let o = tessera(&args, &url);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert!(
        std::fs::read(&farm).expect("farm") == std::fs::read(&local).expect("local"),
        "the audited farm's EXR differs from tessera render's"
    );
    let out = tessera(&["workers"], &url);
    let table = String::from_utf8_lossy(&out.stdout);
    let audits = table
        .lines()
        .skip(1)
        .map(|l| {
            let cols: Vec<&str> = l.split_whitespace().collect();
            assert_eq!(cols.last(), Some(&"127.0.0.1"), "HOST column: {l}");
            cols[cols.len() - 5].parse::<u64>().expect("AUDITS column")
        })
        .sum::<u64>();
    assert!(
        table.contains("AUDITS") && table.contains("HOST"),
        "{table}"
    );
    // Every unit was merged once two copies agreed: each merge passed two workers' audits.
    assert!(audits >= 2, "{table}");
    assert!(!table.contains("convicted"), "{table}");
}

/// The README's coordinator command (`--data-dir farm-data`, relative, with `--http`), with and
/// without `--output-dir`: the data directory is 0700 and the store and every uploaded file
/// 0600, whatever the umask leaves ordinary files. Before, the output directory was created
/// inside the data directory first, with the umask's 0755, and the store left a directory
/// that existed as it was; the store and assets were 0644.
#[cfg(unix)]
#[test]
fn the_data_directory_and_its_files_are_private_with_the_readmes_command() {
    use std::os::unix::fs::PermissionsExt;
    let mode = |p: &Path| std::fs::metadata(p).expect("stat").permissions().mode() & 0o777;
    for output_dir in [None, Some("renders")] {
        let dir = tempfile::tempdir().expect("tmp");
        let mut cmd = Command::new(BIN);
        cmd.current_dir(dir.path()).args([
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--http",
            "127.0.0.1:0",
            "--data-dir",
            "farm-data",
        ]);
        if let Some(o) = output_dir {
            cmd.args(["--output-dir", o]);
        }
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start coordinator");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("listening line");
        let _coord = common::Proc(child);
        let url = format!(
            "http://{}",
            line.trim()
                .strip_prefix("listening on ")
                .expect("listening")
        );
        // A scene with a mesh, so that submit uploads a file into the asset store.
        let out = tessera(
            &["submit", &repo("scenes/cornell-mesh.toml"), "--spp", "1"],
            &url,
        );
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let data = dir.path().join("farm-data");
        assert_eq!(mode(&data), 0o700, "farm-data, --output-dir {output_dir:?}");
        assert_eq!(mode(&data.join("coordinator.redb")), 0o600);
        let assets: Vec<_> = std::fs::read_dir(data.join("assets"))
            .expect("assets")
            .map(|e| e.expect("entry").path())
            .filter(|p| p.is_file())
            .collect();
        assert!(!assets.is_empty(), "no asset was uploaded");
        for a in assets {
            assert_eq!(mode(&a), 0o600, "{}", a.display());
        }
    }
}

/// #55, what a user of Rust CLIs expects: `--json` on `status` and `workers`, `fetch` saving to
/// the job's name by default, a cancelled job that says it has no EXR (not "not ready") and
/// shows no made-up noise, and Ctrl-C on `submit --wait` saying the job goes on, with its id.
#[test]
fn json_default_names_cancelled_jobs_and_ctrl_c_say_what_they_mean() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let scene = repo("scenes/spheres.toml");
    // A job nobody renders (no worker yet), then cancelled.
    let out = tessera(&["submit", &scene, "--spp", "4"], &url);
    assert!(out.status.success());
    let cancelled = String::from_utf8_lossy(&out.stdout).trim().to_string();
    assert!(tessera(&["cancel", &cancelled], &url).status.success());
    let out = tessera(&["status", &cancelled], &url);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("noise      – (no sample merged)"), "{text}");
    one_line_failure(
        &tessera(&["fetch", &cancelled, "-o", "x.exr"], &url),
        "was cancelled, so it has no EXR",
    );
    let json: serde_json::Value =
        serde_json::from_slice(&tessera(&["status", &cancelled, "--json"], &url).stdout)
            .expect("status --json is JSON");
    assert_eq!(json["state"], "cancelled");
    assert_eq!(json["job_id"], cancelled.as_str());
    assert!(json["noise_relative"].is_null(), "{json}");

    let _w = worker(&url, "w");
    let out = tessera(&["submit", &scene, "--spp", "4", "--wait", "-o"], &url);
    assert!(!out.status.success(), "-o needs a value");
    let out = tessera(&["submit", &scene, "--spp", "4"], &url);
    let job = String::from_utf8_lossy(&out.stdout).trim().to_string();
    // fetch with no --output saves under the job's name, in the current directory.
    let here = tempfile::tempdir().expect("cwd");
    let out = Command::new(BIN)
        .current_dir(here.path())
        .args(["fetch", &job, "--wait"])
        .env("TESSERA_COORDINATOR", &url)
        .output()
        .expect("fetch");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(here.path().join(format!("{job}.exr")).is_file());
    let list: serde_json::Value =
        serde_json::from_slice(&tessera(&["status", "--json"], &url).stdout).expect("JSON");
    assert_eq!(list.as_array().map(Vec::len), Some(2), "{list}");
    let workers: serde_json::Value =
        serde_json::from_slice(&tessera(&["workers", "--json"], &url).stdout).expect("JSON");
    assert_eq!(workers[0]["name"], "w", "{workers}");
    assert!(workers[0]["units_done"].as_u64().is_some_and(|n| n > 0));

    // Ctrl-C while following: the job goes on, and the message names it.
    let mut child = Command::new(BIN)
        .args(["submit", &scene, "--spp", "65536", "--wait"])
        .env("TESSERA_COORDINATOR", &url)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("submit --wait");
    let stderr = child.stderr.take().expect("stderr");
    let mut lines = BufReader::new(stderr).lines();
    let first = lines.next().and_then(Result::ok).unwrap_or_default();
    assert!(first.contains("submitted"), "{first}");
    std::thread::sleep(Duration::from_millis(500));
    let pid = child.id().to_string();
    assert!(Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .expect("kill")
        .success());
    let status = child.wait().expect("wait");
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let said = rest.join("\n");
    assert!(!status.success());
    let id = first.split_whitespace().next().expect("id");
    assert!(
        said.contains(&format!("interrupted: {id} goes on rendering")),
        "{said:?}"
    );
    let s: serde_json::Value =
        serde_json::from_slice(&tessera(&["status", id, "--json"], &url).stdout).expect("JSON");
    assert!(
        matches!(s["state"].as_str(), Some("running" | "queued")),
        "{s}"
    );
}

/// #55: `submit --wait` of an adaptive job said "at 64 spp" where `render` says the average
/// and the cap, and their noise figures differed without saying why (the farm's came from
/// its running per-tile totals, `render`'s from the image). Now both say the same words and
/// the same figure, computed from the same pixels.
#[test]
fn submit_wait_and_render_report_an_adaptive_job_alike() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _w = worker(&url, "w");
    let scene = repo("scenes/spheres.toml");
    let flags = ["--spp", "64", "--noise-target", "0.05", "--tile-size", "16"];
    let farm = dir.path().join("farm.exr");
    let mut args = vec!["submit", scene.as_str()];
    args.extend(flags);
    args.extend(["--wait", "--output", farm.to_str().expect("utf8")]);
    let out = tessera(&args, &url);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let submitted = String::from_utf8_lossy(&out.stdout).to_string();
    let local = dir.path().join("local.exr");
    let mut args = vec!["render", scene.as_str()];
    args.extend(flags);
    args.extend(["--output", local.to_str().expect("utf8")]);
    let out = tessera(&args, &url);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rendered = String::from_utf8_lossy(&out.stdout).to_string();
    assert_eq!(
        std::fs::read(&farm).expect("farm"),
        std::fs::read(&local).expect("local")
    );
    let between = |s: &str, a: &str, b: &str| -> String {
        let i = s.find(a).unwrap_or_else(|| panic!("{a:?} in {s:?}"));
        let j = s[i..].find(b).unwrap_or_else(|| panic!("{b:?} in {s:?}"));
        s[i..i + j + b.len()].to_string()
    };
    let spp = |s: &str| between(s, " at ", "cap 64)");
    assert_eq!(spp(&submitted), spp(&rendered), "{submitted} / {rendered}");
    assert!(
        spp(&rendered).contains("spp on average (noise target 0.05"),
        "{rendered}"
    );
    let noise = |s: &str| between(s, "noise σ≈", "of mean)");
    assert_eq!(
        noise(&submitted),
        noise(&rendered),
        "{submitted} / {rendered}"
    );
}

/// A frame that comes out black is delivered as rendered, but `submit --wait` warns,
/// `tessera status` flags it in the list and names the check in the job's detail, and `tessera
/// render` warns alike.
#[test]
fn a_black_frame_is_delivered_and_flagged_by_submit_status_and_render() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _w = worker(&url, "w");
    // The Cornell box with its light switched off.
    let text = std::fs::read_to_string(repo("scenes/cornell-box.toml")).expect("scene");
    let dark = text
        .replace("emission = [18.387, 13.9873, 6.75357]\n", "")
        .replace("width = 256", "width = 24")
        .replace("height = 256", "height = 24");
    assert_ne!(dark, text);
    let scene = common::write(dir.path(), "dark.toml", &dark);
    let fetched = dir.path().join("fetched.exr");
    let out = tessera(
        &[
            "submit",
            &scene,
            "--spp",
            "4",
            "--wait",
            "--output",
            fetched.to_str().expect("utf-8"),
        ],
        &url,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains(": the image is entirely black: no light reached the camera"),
        "{stderr}"
    );
    let list = tessera(&["status"], &url);
    let list = String::from_utf8_lossy(&list.stdout);
    let line = list
        .lines()
        .find(|l| l.contains("[flagged: black]"))
        .unwrap_or_else(|| panic!("no flagged job in:\n{list}"));
    let job = line.split_whitespace().next().expect("job id");
    let detail = tessera(&["status", job], &url);
    let detail = String::from_utf8_lossy(&detail.stdout);
    assert!(
        detail.contains("  check      black: the image is entirely black"),
        "{detail}"
    );
    let local = dir.path().join("local.exr");
    let rendered = common::tessera(&[
        "render",
        &scene,
        "--spp",
        "4",
        "--output",
        local.to_str().expect("utf-8"),
    ]);
    let said = String::from_utf8_lossy(&rendered.stderr);
    assert!(rendered.status.success(), "{said}");
    assert!(
        said.contains("warning: the image is entirely black"),
        "{said}"
    );
    assert!(
        std::fs::read(&fetched).expect("fetched") == std::fs::read(&local).expect("local"),
        "the farm's black frame is tessera render's"
    );
}

/// `submit --after` with the real binaries: a job after another shows what it waits for, fails
/// with the reason when that one is cancelled, and one after a job the coordinator does not
/// know is refused in one line.
#[test]
fn a_job_submitted_after_a_cancelled_one_fails_saying_why() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let scene = repo("scenes/spheres.toml");
    let submit = |extra: &[&str]| {
        let mut args = vec!["submit", scene.as_str(), "--spp", "4"];
        args.extend_from_slice(extra);
        tessera(&args, &url)
    };
    // No worker: the first job stays queued.
    let first = submitted(&submit(&[]));
    let then = submitted(&submit(&["--after", &first]));
    let detail = tessera(&["status", &then], &url);
    let detail = String::from_utf8_lossy(&detail.stdout);
    assert!(
        detail.contains(&format!("  after      {first} (starts when it is done)")),
        "{detail}"
    );
    let cancelled = tessera(&["cancel", &first], &url);
    assert!(cancelled.status.success());
    let detail = tessera(&["status", &then], &url);
    let detail = String::from_utf8_lossy(&detail.stdout);
    assert!(detail.contains("  state      failed"), "{detail}");
    assert!(
        detail.contains(&format!(
            "the job it waits for (--after) ended: {first} was cancelled"
        )),
        "{detail}"
    );
    one_line_failure(&submit(&["--after", "job-000999"]), "no such job");
}

/// `tessera pause`, `resume` and `priority` with the real binaries: each says what it did,
/// `tessera status` shows it (the detail and the list), and a job that has ended is refused in
/// one line.
#[test]
fn pause_resume_and_priority_change_a_queued_job_and_status_shows_it() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let job = submitted(&tessera(
        &["submit", &repo("scenes/spheres.toml"), "--spp", "4"],
        &url,
    ));
    let run = |args: &[&str]| {
        let out = tessera(args, &url);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    assert!(run(&["pause", &job]).contains(&format!("{job} paused")));
    let detail = run(&["status", &job]);
    assert!(
        detail.contains("(paused: `tessera resume` to go on)"),
        "{detail}"
    );
    let list = run(&["status"]);
    assert!(
        list.lines()
            .any(|l| l.starts_with(&job) && l.contains(" paused ")),
        "{list}"
    );
    assert!(run(&["priority", &job, "-3"]).contains(&format!("{job} priority -3")));
    assert!(run(&["status", &job]).contains("  priority   -3"));
    assert!(run(&["resume", &job]).contains(&format!("{job} resumed")));
    assert!(!run(&["status", &job]).contains("paused"));
    run(&["cancel", &job]);
    one_line_failure(&tessera(&["pause", &job], &url), "has ended");
}

/// `tessera submit --guiding --wait` on two worker processes fetches the bytes `tessera render
/// --guiding` writes for the same flags (issue #60); with --noise-target or --frames it is
/// refused before anything is sent, naming the flags.
#[test]
fn submit_guiding_matches_render_guiding() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _a = worker(&url, "a");
    let _b = worker(&url, "b");
    let scene = repo("scenes/caustic.toml");
    let flags = ["--guiding", "--spp", "16", "--batch", "4", "--seed", "5"];
    common::assert_farm_file_is_render_file(dir.path(), &url, &scene, &flags, "guided");
    for (extra, says) in [
        (["--noise-target", "0.05"], "--noise-target"),
        (["--frames", "1-2"], "--frames"),
    ] {
        let mut args = vec!["submit", scene.as_str(), "--guiding", "--spp", "8"];
        args.extend(extra);
        let out = tessera(&args, &url);
        one_line_failure(&out, says);
        assert!(String::from_utf8_lossy(&out.stderr).contains("--guiding"));
    }
}
