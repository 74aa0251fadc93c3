//! Running a farm the way studios do, with the real binaries: worker tags against jobs'
//! requirements (`tessera worker --tag`, `submit --require / --min-memory`), and draining
//! (`tessera workers --drain`, SIGTERM) without losing merged work or changing the bits; logs,
//! progressive ranges, and named tokens reread on SIGHUP.

use std::process::Command;

use tessera_testkit::wait_for_blocking;

mod common;

use common::{coordinator, one_line_failure, repo, tessera_at, worker, worker_with, BIN};

/// Runs a client command that must succeed; returns its stdout.
fn ok(args: &[&str], url: &str) -> String {
    let out = tessera_at(args, url);
    assert!(
        out.status.success(),
        "tessera {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).to_string()
}

fn wait_for(what: &str, mut f: impl FnMut() -> bool) {
    wait_for_blocking(what, || f().then_some(()));
}

/// The row of `tessera workers` for the worker named `name`, split into columns.
fn worker_row(url: &str, name: &str) -> Vec<String> {
    let table = ok(&["workers"], url);
    table
        .lines()
        .map(|l| l.split_whitespace().map(String::from).collect::<Vec<_>>())
        .find(|cols| cols.get(1).map(String::as_str) == Some(name))
        .unwrap_or_else(|| panic!("{name} not in {table}"))
}

/// "12/576 units (3 leased)" of `tessera status JOB`: (done, total, leased).
fn progress(job: &str, url: &str) -> (u64, u64, u64) {
    let text = ok(&["status", job], url);
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("progress"))
        .unwrap_or_else(|| panic!("no progress in {text}"));
    let mut words = line.split_whitespace().skip(1);
    let (done, total) = words
        .next()
        .and_then(|w| w.split_once('/'))
        .expect("done/total");
    let leased = words.nth(1).expect("leased").trim_start_matches('(');
    (
        done.parse().expect("done"),
        total.parse().expect("total"),
        leased.parse().expect("leased"),
    )
}

fn job_of(submit_stdout: &str) -> String {
    submit_stdout
        .split_whitespace()
        .find(|w| w.starts_with("job-"))
        .unwrap_or_else(|| panic!("no job id in {submit_stdout}"))
        .trim_end_matches(|c: char| !c.is_ascii_digit())
        .to_string()
}

#[test]
fn a_job_that_requires_a_tag_waits_saying_so_and_runs_only_on_workers_that_have_it() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _plain = worker(&url, "plain");
    wait_for("plain to register", || {
        ok(&["workers"], &url).contains("plain")
    });
    let scene = repo("scenes/spheres.toml");
    let job = job_of(&ok(
        &[
            "submit",
            &scene,
            "--spp",
            "4",
            "--require",
            "big-mem",
            "--require",
            "pool",
            "--min-memory",
            "1G",
        ],
        &url,
    ));
    wait_for("the waiting reason", || {
        ok(&["status", &job], &url).contains("  waiting    no worker has tag big-mem")
    });
    let detail = ok(&["status", &job], &url);
    assert!(
        detail.contains("  requires   big-mem, pool, 1 GiB of memory"),
        "{detail}"
    );
    let list = ok(&["status"], &url);
    assert!(
        list.lines()
            .any(|l| l.starts_with(&job) && l.contains("[waiting: no worker has tag big-mem]")),
        "{list}"
    );
    // Tagged, but with too little memory: the reason moves on to memory.
    let _small = worker_with(
        &url,
        "small",
        &["--tag", "big-mem", "--tag", "pool=fast", "--memory", "512M"],
        &dir.path().join("small.log"),
    );
    wait_for("the memory reason", || {
        ok(&["status", &job], &url).contains(
            "no worker with big-mem, pool has 1 GiB of memory (the most any has is 0.5 GiB)",
        )
    });
    let _strong = worker_with(
        &url,
        "strong",
        &["--tag", "big-mem", "--tag", "pool=fast", "--memory", "2G"],
        &dir.path().join("strong.log"),
    );
    wait_for("the job to finish", || {
        ok(&["status", &job], &url).contains("  state      done")
    });
    let strong = worker_row(&url, "strong");
    assert_eq!(strong[10], "2GiB", "MEMORY column: {strong:?}");
    assert_eq!(strong[11], "big-mem,pool=fast", "TAGS column: {strong:?}");
    assert_ne!(strong[5], "0", "strong rendered the job: {strong:?}");
    for other in ["plain", "small"] {
        let row = worker_row(&url, other);
        assert_eq!(
            row[5], "0",
            "{other} rendered units it does not fit: {row:?}"
        );
    }
    let json: serde_json::Value =
        serde_json::from_str(&ok(&["status", &job, "--json"], &url)).expect("JSON");
    assert_eq!(json["require"], serde_json::json!(["big-mem", "pool"]));
    assert_eq!(json["min_memory_bytes"], 1u64 << 30);

    // Malformed tags and sizes are refused before anything starts, in one line.
    let bad = Command::new(BIN)
        .args(["worker", "--coordinator", &url, "--tag", "big mem"])
        .output()
        .expect("worker");
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && stderr.contains("' ' in its name"),
        "{stderr}"
    );
    for (args, needle) in [
        (
            ["--require", "pool="],
            "'--require <TAG>': tag \"pool=\" has an empty value",
        ),
        (
            ["--min-memory", "16X"],
            "'--min-memory <SIZE>': \"16X\": unknown unit 'X'",
        ),
    ] {
        let out = tessera_at(&[&["submit", scene.as_str()][..], &args].concat(), &url);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains(needle), "{stderr}");
    }
}

#[test]
fn a_drained_and_a_terminated_worker_finish_their_units_and_lose_nothing() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let log1 = dir.path().join("d1.log");
    let mut d1 = worker_with(&url, "d1", &[], &log1);
    let mut d2 = worker_with(&url, "d2", &[], &dir.path().join("d2.log"));
    // Many small units, so that both workers are mid-job when they are told to go.
    let scene = repo("scenes/cornell-box.toml");
    let settings = [
        "--spp",
        "16",
        "--batch",
        "4",
        "--seed",
        "5",
        "--tile-size",
        "32",
    ];
    let mut submit = vec!["submit", scene.as_str()];
    submit.extend(settings);
    let job = job_of(&ok(&submit, &url));
    wait_for("both workers to merge a unit", || {
        worker_row(&url, "d1")[5] != "0" && worker_row(&url, "d2")[5] != "0"
    });

    // Drained by name: it finishes what it holds and exits cleanly.
    let said = ok(&["workers", "--drain", "d1"], &url);
    assert!(said.starts_with("draining w"), "{said}");
    let mut status = None;
    wait_for("d1 to leave", || {
        status = d1.0.try_wait().expect("wait");
        status.is_some()
    });
    assert!(status.is_some_and(|s| s.success()), "d1 exit {status:?}");
    let logged = std::fs::read_to_string(&log1).expect("log");
    assert!(logged.contains("drained by the coordinator"), "{logged}");
    assert_eq!(worker_row(&url, "d1")[3], "gone");
    let (done_then, total, _) = progress(&job, &url);
    assert!(
        done_then < total,
        "the job must still have work: {done_then}/{total}"
    );

    // SIGTERM on the other: the same, as Kubernetes stops a pod.
    let pid = d2.0.id().to_string();
    assert!(Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .expect("kill")
        .success());
    let mut status = None;
    wait_for("d2 to leave", || {
        status = d2.0.try_wait().expect("wait");
        status.is_some()
    });
    assert!(status.is_some_and(|s| s.success()), "d2 exit {status:?}");
    // Nothing is left leased to the workers that left (no lease waits out its timeout), and
    // nothing merged is lost.
    let (done, _, leased) = progress(&job, &url);
    assert_eq!(leased, 0, "units left leased to workers that left");
    assert!(done >= done_then);
    // A drain of nobody is refused in one line.
    one_line_failure(&tessera_at(&["workers", "--drain", "d9"], &url), "d9");

    let _d3 = worker(&url, "d3");
    let farm = dir.path().join("farm.exr");
    ok(
        &[
            "fetch",
            &job,
            "--wait",
            "--output",
            farm.to_str().expect("utf8"),
        ],
        &url,
    );
    let local = dir.path().join("local.exr");
    let mut render = vec![
        "render",
        scene.as_str(),
        "--output",
        local.to_str().expect("utf8"),
    ];
    render.extend(settings);
    ok(&render, &url);
    assert!(
        std::fs::read(&farm).expect("farm") == std::fs::read(&local).expect("local"),
        "the EXR after a drain and a SIGTERM differs from tessera render's"
    );
}

#[test]
fn a_workers_warning_about_a_unit_is_in_tessera_logs() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    // A worker that may spend one byte on textures cannot render a textured scene: it says so
    // about the unit, and hands it back with the reason.
    let _w = worker_with(
        &url,
        "tiny",
        &["--texture-decode-bytes", "1"],
        &dir.path().join("tiny.log"),
    );
    let job = job_of(&ok(
        &["submit", &repo("scenes/textured.toml"), "--spp", "2"],
        &url,
    ));
    wait_for("the job to end", || {
        ok(&["status", &job], &url).contains("  state      failed")
    });
    // --follow returns once the job has ended, with every line.
    let text = ok(&["logs", &job, "--follow"], &url);
    let first = text
        .lines()
        .next()
        .unwrap_or_else(|| panic!("no lines: {text}"));
    assert!(
        first.contains(&format!(" {job} tile "))
            && first.contains("(tiny): error: this worker cannot render it"),
        "{text}"
    );
    one_line_failure(
        &tessera_at(&["logs", "job-000999"], &url),
        "unknown job job-000999",
    );
}

#[test]
fn a_progressive_range_gives_the_same_frames_as_one_leased_frame_by_frame() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _a = worker(&url, "a");
    let _b = worker(&url, "b");
    let scene = repo("scenes/cornell-animated.toml");
    let job = [
        scene.as_str(),
        "--frames",
        "1-3",
        "--spp",
        "8",
        "--batch",
        "2",
        "--tile-size",
        "64",
    ];
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let output_name = format!("{name}.exr");
        let mut args = vec!["submit", "--wait", "--name", &output_name, "--output"];
        let out_arg = out.to_str().expect("utf8").to_string();
        args.push(&out_arg);
        args.extend(job);
        args.extend(extra);
        let said = ok(&args, &url);
        (out, said)
    };
    let (progressive, said) = run("progressive", &["--progressive"]);
    let id = job_of(&said);
    assert!(
        ok(&["status", &id], &url).contains("  order      progressive"),
        "status does not say progressive"
    );
    let (plain, _) = run("plain", &[]);
    for frame in 1..=3 {
        let name = |run: &str| format!("{run}.{frame:04}.exr");
        assert!(
            std::fs::read(progressive.join(name("progressive"))).expect("progressive")
                == std::fs::read(plain.join(name("plain"))).expect("plain"),
            "frame {frame}: progressive leasing changed the bits"
        );
    }
    // Progressive is for frame ranges, and not for adaptive jobs.
    for bad in [
        vec!["submit", scene.as_str(), "--progressive"],
        vec![
            "submit",
            scene.as_str(),
            "--frames",
            "1-2",
            "--progressive",
            "--noise-target",
            "0.1",
        ],
    ] {
        let out = tessera_at(&bad, &url);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && stderr.contains("--progressive"),
            "{stderr}"
        );
    }
}

/// Runs `tessera ARGS --token-file TOKEN` against `url`.
fn as_user(args: &[&str], url: &str, token: &std::path::Path) -> std::process::Output {
    Command::new(BIN)
        .args(args)
        .arg("--token-file")
        .arg(token)
        .env("TESSERA_COORDINATOR", url)
        .output()
        .expect("run tessera")
}

#[test]
fn named_tokens_record_who_submitted_and_sighup_rereads_the_file() {
    const ALICE: &str = "alice-token-0123456789abcdef";
    const BOB: &str = "bob-token-0123456789abcdef";
    let dir = tempfile::tempdir().expect("tmp");
    let tokens = common::private_file(dir.path(), "tokens", &format!("alice {ALICE}\nbob {BOB}\n"));
    let alice = common::private_file(dir.path(), "alice.token", ALICE);
    let bob = common::private_file(dir.path(), "bob.token", BOB);
    let log = dir.path().join("coordinator.log");
    let (coord, addr) = common::start_coordinator(
        "127.0.0.1:0",
        &dir.path().join("data"),
        &["--tokens-file", tokens.to_str().expect("utf8")],
        std::process::Stdio::from(std::fs::File::create(&log).expect("log")),
    );
    let url = format!("http://{addr}");
    let out = as_user(
        &["submit", &repo("scenes/cornell-box.toml"), "--spp", "1"],
        &url,
        &alice,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let job = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let status = as_user(&["status", &job], &url, &bob);
    assert!(
        String::from_utf8_lossy(&status.stdout).contains("submitter  alice"),
        "{status:?}"
    );
    one_line_failure(
        &as_user(&["cancel", &job], &url, &bob),
        "only alice or an admin may cancel it",
    );

    // Bob's token withdrawn: after SIGHUP his calls are refused, Alice's still pass.
    let pid = coord.0.id().to_string();
    let hup = || {
        let ok = Command::new("kill")
            .args(["-HUP", &pid])
            .status()
            .expect("kill");
        assert!(ok.success());
    };
    std::fs::write(&tokens, format!("alice {ALICE}\n")).expect("rewrite");
    hup();
    wait_for("bob's token to be withdrawn", || {
        let out = as_user(&["status", &job], &url, &bob);
        !out.status.success() && String::from_utf8_lossy(&out.stderr).contains("wrong token")
    });
    // A file that does not parse keeps the tokens there were, and the log says why.
    std::fs::write(&tokens, "alice short\n").expect("rewrite");
    hup();
    wait_for("the bad file to be refused", || {
        std::fs::read_to_string(&log)
            .is_ok_and(|l| l.contains("alice's token") && l.contains("keeping the tokens"))
    });
    let out = as_user(&["cancel", &job], &url, &alice);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let log = std::fs::read_to_string(&log).expect("log");
    assert!(
        !log.contains(ALICE) && !log.contains(BOB),
        "a token in the log: {log}"
    );
    drop(coord);
}

/// Named tokens have roles: a user's token serves the job API only, so a worker started with
/// it is refused and cannot lease anybody's units; a `worker` token serves the worker API
/// only, so it cannot submit; with one of each the farm renders. (A user once registered a
/// worker with her own token, leased another user's units, and her forged results were
/// merged.)
#[test]
fn a_user_token_cannot_work_and_a_worker_token_cannot_submit() {
    const ALICE: &str = "alice-token-0123456789abcdef";
    const FARM: &str = "farm-token-0123456789abcdef";
    let dir = tempfile::tempdir().expect("tmp");
    let tokens = common::private_file(
        dir.path(),
        "tokens",
        &format!("alice {ALICE}\nfarm {FARM} worker\n"),
    );
    let alice = common::private_file(dir.path(), "alice.token", ALICE);
    let farm = common::private_file(dir.path(), "farm.token", FARM);
    let (_coord, addr) = common::start_coordinator(
        "127.0.0.1:0",
        &dir.path().join("data"),
        &["--tokens-file", tokens.to_str().expect("utf8")],
        std::process::Stdio::null(),
    );
    let url = format!("http://{addr}");
    one_line_failure(
        &as_user(
            &["submit", &repo("scenes/cornell-box.toml"), "--spp", "1"],
            &url,
            &farm,
        ),
        "worker API only",
    );
    let log = dir.path().join("thief.log");
    let _thief = common::worker_with(
        &url,
        "thief",
        &["--token-file", alice.to_str().expect("utf8")],
        &log,
    );
    wait_for("the user's token to be refused to a worker", || {
        std::fs::read_to_string(&log).is_ok_and(|l| l.contains("job API only"))
    });
    let listed = as_user(&["workers"], &url, &alice);
    assert!(
        !String::from_utf8_lossy(&listed.stdout).contains("thief"),
        "{listed:?}"
    );
    let _honest = common::worker_with(
        &url,
        "honest",
        &["--token-file", farm.to_str().expect("utf8")],
        &dir.path().join("honest.log"),
    );
    let out_exr = dir.path().join("out.exr");
    let out = as_user(
        &[
            "submit",
            &repo("scenes/cornell-box.toml"),
            "--spp",
            "2",
            "--wait",
            "--output",
            out_exr.to_str().expect("utf8"),
        ],
        &url,
        &alice,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A client pointed at the dashboard's port says that it is the HTTP port and where gRPC
/// listens, not tonic's "invalid compression flag: 110".
#[test]
fn a_client_at_the_dashboard_port_is_told_it_is_the_http_port() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, _grpc, dash) = common::coordinator_with_dashboard(&dir.path().join("data"), &[]);
    let out = tessera_at(&["status"], &dash);
    one_line_failure(&out, "answers HTTP, not gRPC");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("listening on"),
        "{out:?}"
    );
}

/// `--resolution WxH` sets the film's size for any scene: a glTF file (whose own 1280×720 is
/// above `--max-resolution 512`) and a TOML scene, on `render` and on the farm with the same
/// bits; a bad value is refused naming the flag.
#[test]
fn resolution_sets_the_film_of_any_scene_on_render_and_the_farm() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _w = worker(&url, "res");
    for (scene, size) in [
        ("scenes/gltf/sample.glb", "64x36"),
        ("scenes/cornell-box.toml", "40x24"),
    ] {
        let local = dir.path().join("local.exr");
        let farm = dir.path().join("farm.exr");
        let scene = repo(scene);
        let args = |out: &std::path::Path| {
            vec![
                scene.clone(),
                "--spp".into(),
                "2".into(),
                "--resolution".into(),
                size.into(),
                "--output".into(),
                out.to_str().expect("utf8").to_string(),
            ]
        };
        let mut render: Vec<String> = vec!["render".into()];
        render.extend(args(&local));
        render.extend(["--max-resolution".into(), "512".into()]);
        let render: Vec<&str> = render.iter().map(String::as_str).collect();
        let r = tessera_at(&render, &url);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let img = tessera_render::output::read_exr_rgb(&local).expect("exr");
        let (w, h) = size.split_once('x').expect("size");
        assert_eq!(
            (img.width.to_string(), img.height.to_string()),
            (w.into(), h.into())
        );
        let mut submit: Vec<String> = vec!["submit".into()];
        submit.extend(args(&farm));
        submit.push("--wait".into());
        let submit: Vec<&str> = submit.iter().map(String::as_str).collect();
        let r = tessera_at(&submit, &url);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        assert_eq!(
            std::fs::read(&local).expect("local"),
            std::fs::read(&farm).expect("farm"),
            "{scene} at {size}: the farm's EXR differs from tessera render's"
        );
    }
    for bad in ["64", "0x10", "64x", "axb"] {
        let out = dir.path().join("x.exr");
        let r = tessera_at(
            &[
                "render",
                &repo("scenes/cornell-box.toml"),
                "--spp",
                "1",
                "--resolution",
                bad,
                "--output",
                out.to_str().expect("utf8"),
            ],
            &url,
        );
        assert!(!r.status.success());
        assert!(
            String::from_utf8_lossy(&r.stderr).contains("--resolution"),
            "{bad}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
    }
}

/// `tessera workers` lines its rows up under its header (the id once ignored its column's
/// width, pushing every later column right).
#[test]
fn the_workers_table_lines_up_under_its_header() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _w = worker(&url, "align");
    wait_for("the worker to register", || {
        String::from_utf8_lossy(&tessera_at(&["workers"], &url).stdout).contains("align")
    });
    let out = String::from_utf8_lossy(&tessera_at(&["workers"], &url).stdout).to_string();
    let mut lines = out.lines();
    let header = lines.next().expect("header");
    let row = lines.find(|l| l.contains("align")).expect("row");
    // NAME and STATE are left-aligned, CORES right-aligned.
    for (column, value, at) in [
        ("NAME", "align", 0),
        ("STATE", "alive", 0),
        ("CORES", "1", 4),
    ] {
        let start = header.find(column).expect("column") + at;
        assert_eq!(
            row.get(start..start + value.len()),
            Some(value),
            "{column} in:\n{header}\n{row}"
        );
    }
}

/// PNGs of farm results: `submit --wait --preview`, `fetch --preview` and `tessera preview` of
/// an EXR write the bytes `render --preview` writes; a fetched EXR has the permissions a
/// rendered one has (it was 0600).
#[test]
fn farm_results_get_the_preview_render_writes() {
    let dir = tempfile::tempdir().expect("tmp");
    let (_coord, url) = coordinator(&dir.path().join("data"));
    let _w = worker(&url, "png");
    let d = |n: &str| dir.path().join(n).to_str().expect("utf8").to_string();
    let scene = repo("scenes/cornell-box.toml");
    let ok = |args: &[&str]| {
        let r = tessera_at(args, &url);
        assert!(
            r.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
        String::from_utf8_lossy(&r.stdout).to_string()
    };
    ok(&[
        "render",
        &scene,
        "--spp",
        "2",
        "--output",
        &d("local.exr"),
        "--preview",
        &d("local.png"),
        "--exposure",
        "1",
    ]);
    let said = ok(&[
        "submit",
        &scene,
        "--spp",
        "2",
        "--wait",
        "--output",
        &d("farm.exr"),
        "--preview",
        &d("farm.png"),
        "--exposure",
        "1",
    ]);
    let job = said.split_whitespace().next().expect("job id").to_string();
    ok(&[
        "fetch",
        &job,
        "--output",
        &d("fetched.exr"),
        "--preview",
        &d("fetched.png"),
        "--exposure",
        "1",
    ]);
    ok(&[
        "preview",
        &d("local.exr"),
        "--output",
        &d("again.png"),
        "--exposure",
        "1",
    ]);
    let local = std::fs::read(d("local.png")).expect("png");
    for png in ["farm.png", "fetched.png", "again.png"] {
        assert!(
            std::fs::read(d(png)).expect("png") == local,
            "{png} differs from render's"
        );
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = |n: &str| std::fs::metadata(d(n)).expect("meta").permissions().mode() & 0o777;
        assert_eq!(mode("fetched.exr"), mode("local.exr"));
        assert_eq!(mode("farm.exr"), mode("local.exr"));
    }
    // Refused before anything is submitted: --preview without --wait.
    let r = tessera_at(
        &["submit", &scene, "--spp", "1", "--preview", &d("x.png")],
        &url,
    );
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("--preview needs --wait"));
}

/// A second coordinator on a data directory another one holds says so, naming the store and
/// what to do; a worker pointed where nothing listens names the address and what to check.
#[test]
fn a_second_coordinator_and_an_unreachable_worker_say_what_to_check() {
    let dir = tempfile::tempdir().expect("tmp");
    let data = dir.path().join("data");
    let (_coord, _url) = coordinator(&data);
    let second = Command::new(BIN)
        .args(["coordinator", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(&data)
        .output()
        .expect("second coordinator");
    assert!(!second.status.success());
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(
        err.contains("coordinator.redb") && err.contains("another coordinator holds it"),
        "{err}"
    );
    let log = dir.path().join("worker.log");
    let _w = worker_with("http://127.0.0.1:1", "lost", &[], &log);
    wait_for("the worker to say why it cannot connect", || {
        std::fs::read_to_string(&log).is_ok_and(|l| {
            l.contains("cannot reach the coordinator at http://127.0.0.1:1")
                && l.contains("nothing listens there")
        })
    });
}
