//! The farm across network namespaces this test makes itself: the coordinator in one, each
//! worker in its own, joined by veth pairs, as on separate machines. A worker's link is cut for
//! longer than a lease and then restored, and the job still gives `tessera render`'s bytes.
//! Where netem is available (`sch_netem`), the workers' links then get 50 ms ± 10 ms of delay
//! and 1% loss for a second job, which must give the same bytes too.
//!
//! Needs root and `ip` (iproute2); without them it says so and passes, as it cannot run.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{repo, Proc, BIN};

/// The namespaces and links made, removed when dropped (removing a namespace removes the veth
/// ends in it, and so their peers).
struct Net {
    coord: String,
    workers: Vec<String>,
}

impl Drop for Net {
    fn drop(&mut self) {
        for ns in std::iter::once(&self.coord).chain(&self.workers) {
            let _ = Command::new("ip").args(["netns", "del", ns]).status();
        }
    }
}

/// Whether `program ARGS` ran and succeeded.
fn succeeds(program: &str, args: &[&str]) -> bool {
    Command::new(program)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn ip(args: &[&str]) -> bool {
    succeeds("ip", args)
}

fn must(args: &[&str]) {
    assert!(ip(args), "ip {}", args.join(" "));
}

/// The coordinator's namespace and one per worker; worker `i` reaches the coordinator at
/// 10.213.i.1 over its own veth pair. `None` where namespaces cannot be made here.
fn make_net(workers: usize) -> Option<Net> {
    let tag = std::process::id() % 100_000;
    let coord = format!("tessera-{tag}-c");
    if !ip(&["netns", "add", &coord]) {
        return None;
    }
    let mut net = Net {
        coord,
        workers: Vec::new(),
    };
    must(&["-n", &net.coord, "link", "set", "lo", "up"]);
    for i in 1..=workers {
        let ns = format!("tessera-{tag}-w{i}");
        must(&["netns", "add", &ns]);
        net.workers.push(ns.clone());
        let (a, b) = (format!("tc{tag}x{i}"), format!("tw{tag}x{i}"));
        must(&["link", "add", &a, "type", "veth", "peer", "name", &b]);
        must(&["link", "set", &a, "netns", &net.coord]);
        must(&["link", "set", &b, "netns", &ns]);
        must(&[
            "-n",
            &net.coord,
            "addr",
            "add",
            &format!("10.213.{i}.1/24"),
            "dev",
            &a,
        ]);
        must(&[
            "-n",
            &ns,
            "addr",
            "add",
            &format!("10.213.{i}.2/24"),
            "dev",
            &b,
        ]);
        must(&["-n", &net.coord, "link", "set", &a, "up"]);
        must(&["-n", &ns, "link", "set", &b, "up"]);
        must(&["-n", &ns, "link", "set", "lo", "up"]);
    }
    Some(net)
}

impl Net {
    /// Worker `i`'s end of its link.
    fn worker_link(&self, i: usize) -> String {
        format!("tw{}x{i}", std::process::id() % 100_000)
    }

    /// `tessera ARGS` inside namespace `ns`.
    fn tessera(&self, ns: &str, args: &[&str]) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", ns, BIN]).args(args);
        c
    }

    fn client(&self, args: &[&str], url: &str) -> Output {
        self.tessera(&self.coord, args)
            .env("TESSERA_COORDINATOR", url)
            .output()
            .expect("run tessera")
    }
}

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The job's done units, from `tessera status`.
fn units_done(net: &Net, url: &str, job: &str) -> u64 {
    let text = ok(&net.client(&["status", job], url));
    text.lines()
        .find_map(|l| l.trim().strip_prefix("progress"))
        .and_then(|p| p.trim().split('/').next()?.parse().ok())
        .unwrap_or(0)
}

/// A worker's line of `tessera workers`.
struct WorkerRow {
    state: String,
    leases: u32,
}

fn worker_row(net: &Net, url: &str, name: &str) -> Option<WorkerRow> {
    let text = ok(&net.client(&["workers"], url));
    text.lines().find_map(|l| {
        let f: Vec<&str> = l.split_whitespace().collect();
        (f.get(1) == Some(&name)).then(|| WorkerRow {
            state: f.get(3).unwrap_or(&"").to_string(),
            leases: f.get(4).and_then(|n| n.parse().ok()).unwrap_or(0),
        })
    })
}

#[test]
fn a_farm_across_namespaces_survives_a_cut_link_and_gives_the_local_bytes() {
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout.trim_ascii() == b"0");
    let Some(net) = root.then(|| make_net(2)).flatten() else {
        eprintln!(
            "skipped: making network namespaces needs root and iproute2's `ip`, and this test \
             has neither here"
        );
        return;
    };
    let dir = tempfile::tempdir().expect("tmp");
    // Listening on every address of the coordinator's namespace, which holds only loopback
    // and the workers' links.
    let mut child = net
        .tessera(
            &net.coord,
            &[
                "coordinator",
                "--listen",
                "0.0.0.0:0",
                "--lease-timeout",
                "2",
            ],
        )
        .arg("--data-dir")
        .arg(dir.path().join("data"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("coordinator");
    let stdout = child.stdout.take().expect("stdout");
    let _coord = Proc(child);
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line).expect("line");
    let port = line.trim().rsplit(':').next().expect("port").to_string();
    let url = format!("http://127.0.0.1:{port}");
    let _workers: Vec<Proc> = (1..=2)
        .map(|i| {
            Proc(
                net.tessera(
                    &net.workers[i - 1],
                    &[
                        "worker",
                        "--coordinator",
                        &format!("http://10.213.{i}.1:{port}"),
                        "--threads",
                        "1",
                        "--name",
                        &format!("w{i}"),
                    ],
                )
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("worker"),
            )
        })
        .collect();
    let scene = repo("scenes/cornell-box.toml");
    let job_flags = [
        scene.as_str(),
        "--spp",
        "256",
        "--batch",
        "16",
        "--tile-size",
        "64",
    ];
    let local = dir.path().join("local.exr");
    let mut render = vec!["render", "--output", local.to_str().expect("utf8")];
    render.extend(job_flags);
    ok(&Command::new(BIN).args(&render).output().expect("render"));

    let mut submit = vec!["submit"];
    submit.extend(job_flags);
    let job = ok(&net.client(&submit, &url)).trim().to_string();
    // Cut worker 1's link once the job is under way, for three lease timeouts: its leases
    // lapse and worker 2 takes their units; then the link comes back.
    let start = Instant::now();
    while units_done(&net, &url, &job) == 0 {
        assert!(start.elapsed() < Duration::from_secs(60), "no unit merged");
        std::thread::sleep(Duration::from_millis(50));
    }
    while worker_row(&net, &url, "w1").is_none_or(|r| r.leases == 0) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "worker 1 never held a lease"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let link = net.worker_link(1);
    must(&["-n", &net.workers[0], "link", "set", &link, "down"]);
    let text = ok(&net.client(&["status", &job], &url));
    assert!(
        text.contains("state      running"),
        "the job ended before the cut, which then tests nothing: {text}"
    );
    std::thread::sleep(Duration::from_secs(6));
    must(&["-n", &net.workers[0], "link", "set", &link, "up"]);
    // Back on its link, worker 1 is heard from again.
    let restored = Instant::now();
    while worker_row(&net, &url, "w1").is_none_or(|r| r.state != "alive") {
        assert!(
            restored.elapsed() < Duration::from_secs(60),
            "worker 1 did not come back after its link was restored"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    // Waits for `job`, fetches its EXR into `file` and compares it with the local render.
    let same_as_local = |job: &str, file: &str, after: &str| {
        let out = dir.path().join(file);
        ok(&net.client(
            &[
                "fetch",
                job,
                "--wait",
                "--output",
                out.to_str().expect("utf8"),
            ],
            &url,
        ));
        assert!(
            std::fs::read(&out).expect("fetched") == std::fs::read(&local).expect("local"),
            "the farm's EXR {after} differs from tessera render's"
        );
    };
    same_as_local(&job, "farm.exr", "after a cut link");

    // The same over links with delay and loss, where netem exists.
    let netem = |i: usize| {
        let link = net.worker_link(i);
        let ns = &net.workers[i - 1];
        let qdisc = ["qdisc", "add", "dev", &link, "root", "netem"];
        let netem = ["delay", "50ms", "10ms", "loss", "1%"];
        let args: Vec<&str> = ["-n", ns].into_iter().chain(qdisc).chain(netem).collect();
        succeeds("tc", &args)
    };
    if !netem(1) {
        eprintln!(
            "netem is not available here (no sch_netem): the run over delayed, lossy links is \
             skipped"
        );
        return;
    }
    assert!(netem(2), "netem on worker 2's link");
    let job = ok(&net.client(&submit, &url)).trim().to_string();
    same_as_local(&job, "netem.exr", "over delayed, lossy links");
}
