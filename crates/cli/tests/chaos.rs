//! Chaos: a coordinator and 4 workers as separate processes on loopback. Workers are killed
//! with SIGKILL at random and restarted; the coordinator is killed with SIGKILL once, mid-job,
//! and restarted on the same data directory and port. The job must finish with an EXR
//! bit-identical to `tessera render`, and no lease may be left behind.
//!
//! A farm's day is in the mix too: two of the workers carry a tag that a second job requires,
//! a third job is paused from the start and resumed only after the coordinator's restart (which
//! must keep it paused), and one of the random events drains a worker instead of killing it
//! (it must exit 0, and comes back as a supervisor would start it again). Every job's EXR must
//! be `tessera render`'s.

mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};

use common::{repo, start_coordinator, tessera_at, Proc, BIN};

fn tessera(args: &[&str], url: &str) -> Output {
    tessera_at(args, url)
}

use std::time::{Duration, Instant};

/// A coordinator listening on `listen`, logging to `log`; returns it and the address it bound.
fn coordinator(data: &Path, listen: &str, log: &Path) -> (Proc, String) {
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(log)
        .expect("log");
    start_coordinator(
        listen,
        data,
        &["--lease-timeout", "2", "--checkpoint-interval", "1"],
        Stdio::from(log),
    )
}

/// (units done, units total, units leased) from `tessera status JOB`, if the coordinator
/// answers.
fn progress(job: &str, url: &str) -> Option<(u64, u64, u64)> {
    let out = tessera(&["status", job], url);
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("progress"))?;
    // "  progress   12/576 units (3 leased), ..."
    let mut words = line.split_whitespace().skip(1);
    let (done, total) = words.next()?.split_once('/')?;
    let leased = words.nth(1)?.trim_start_matches('(');
    Some((
        done.parse().ok()?,
        total.parse().ok()?,
        leased.parse().ok()?,
    ))
}

/// Waits up to `limit` for `p` to exit by itself; its exit status.
fn wait_exit(p: &mut Proc, limit: Duration) -> std::process::ExitStatus {
    let end = Instant::now() + limit;
    loop {
        if let Some(s) = p.0.try_wait().expect("try_wait") {
            return s;
        }
        assert!(
            Instant::now() < end,
            "the process did not exit in {limit:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A small deterministic generator, so a failing run can be replayed from its seed.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[test]
fn sigkilled_workers_and_coordinator_do_not_change_a_bit() {
    let dir = tempfile::tempdir().expect("tmp");
    let data = dir.path().join("data");
    let log = dir.path().join("coordinator.log");
    let scene = dir.path().join("box.toml");
    // Big enough that the job outlasts the kill's conditions below on a fast machine: at 80²
    // a 2-core Zen 4 merged the whole job within the first three seconds of progress.
    std::fs::write(
        &scene,
        std::fs::read_to_string(repo("scenes/cornell-box.toml"))
            .expect("scene")
            .replace("width = 256", "width = 160")
            .replace("height = 256", "height = 160"),
    )
    .expect("write scene");
    let scene = scene.to_str().expect("utf8").to_string();
    let settings = ["--spp", "2048", "--batch", "4", "--seed", "11"];

    // The server picks its port; after its SIGKILL it comes back on the same one, as a
    // supervised coordinator would, so that workers and clients keep their URL.
    let (mut coord, addr) = coordinator(&data, "127.0.0.1:0", &log);
    let url = format!("http://{addr}");
    // w0 and w1 are in pool a, which the second job requires.
    let start_worker = |i: usize| -> Proc {
        let extra: &[&str] = if i < 2 { &["--tag", "pool=a"] } else { &[] };
        let log = dir.path().join(format!("w{i}.log"));
        common::worker_with(&url, &format!("w{i}"), extra, &log)
    };
    let mut workers: Vec<Proc> = (0..4).map(start_worker).collect();
    let started = Instant::now();
    let job = loop {
        let mut args = vec!["submit", scene.as_str(), "--tile-size", "16"];
        args.extend(settings);
        let out = tessera(&args, &url);
        if out.status.success() {
            break String::from_utf8_lossy(&out.stdout).trim().to_string();
        }
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "coordinator never came up"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    // The second job only pool a may render; the third waits paused until after the restart.
    let small = ["--spp", "64", "--batch", "4"];
    let submit_small = |extra: &[&str]| -> String {
        let mut args = vec!["submit", scene.as_str()];
        args.extend(small);
        args.extend(extra);
        let out = tessera(&args, &url);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    };
    let pooled = submit_small(&["--seed", "3", "--require", "pool=a"]);
    let paused = submit_small(&["--seed", "5"]);
    let out = tessera(&["pause", &paused], &url);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A client following the job across the coordinator's death, as `--wait` users do.
    let farm_exr = dir.path().join("farm.exr");
    let follower = Command::new(BIN)
        .args(["fetch", &job, "--wait", "-o"])
        .arg(&farm_exr)
        .env("TESSERA_COORDINATOR", &url)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("fetch --wait");

    let seed = 0x5eed_u64;
    let mut rng = Rng(seed);
    let mut events = Vec::new();
    let mut coordinator_killed = false;
    let mut drained = None;
    let deadline = Instant::now() + Duration::from_secs(240);
    let (mut last_done, mut total) = (0, u64::MAX);
    // When each progress was seen: what was merged a checkpoint interval (and a commit's
    // time) before the coordinator's SIGKILL must survive it.
    let mut seen: Vec<(Instant, u64)> = Vec::new();
    while last_done < total {
        assert!(
            Instant::now() < deadline,
            "job not done after 240 s (seed {seed:#x}); events: {events:?}"
        );
        std::thread::sleep(Duration::from_millis(200 + rng.next() % 400));
        if let Some((done, t, _)) = progress(&job, &url) {
            (last_done, total) = (done, t);
            seen.push((Instant::now(), done));
        }
        if last_done >= total {
            break;
        }
        // Killed once 40% is merged and a checkpoint (every second) has had time to land, so
        // that what must survive is more than nothing.
        let first_seen = seen.first().map(|(at, _)| *at);
        if !coordinator_killed
            && total != u64::MAX
            && last_done * 10 >= total * 4
            && first_seen.is_some_and(|t| t.elapsed() >= Duration::from_secs(3))
        {
            let killed = Instant::now();
            coord.kill9();
            let checkpointed = seen
                .iter()
                .filter(|(at, _)| killed.duration_since(*at) >= Duration::from_secs(2))
                .map(|(_, done)| *done)
                .max()
                .unwrap_or(0);
            events.push(format!("coordinator SIGKILL at {last_done}/{total} units"));
            std::thread::sleep(Duration::from_millis(300));
            coord = coordinator(&data, &addr, &log).0;
            coordinator_killed = true;
            // What was acknowledged before the last checkpoint survived: progress resumes from
            // the store, less at most the units merged in the last checkpoint interval (1 s)
            // and the commit's time (docs/reliability.md's bound).
            let resumed = loop {
                if let Some((done, _, _)) = progress(&job, &url) {
                    break done;
                }
                assert!(
                    Instant::now() < deadline,
                    "the coordinator did not come back"
                );
                std::thread::sleep(Duration::from_millis(50));
            };
            events.push(format!(
                "coordinator restarted with {resumed}/{total} units ({checkpointed} merged 2 s \
                 before the kill)"
            ));
            // The pause survived the restart; now the third job may go.
            let status =
                String::from_utf8_lossy(&tessera(&["status", &paused], &url).stdout).to_string();
            assert!(status.contains("paused"), "the pause was lost: {status}");
            let out = tessera(&["resume", &paused], &url);
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            events.push(format!("{paused} resumed"));
            assert!(
                checkpointed > 0,
                "nothing was merged 2 s before the kill: the check below would be empty"
            );
            assert!(
                resumed >= checkpointed,
                "restart lost checkpointed work: {checkpointed} units merged 2 s before the kill \
                 ({last_done} at it), {resumed} after"
            );
            continue;
        }
        let i = (rng.next() % workers.len() as u64) as usize;
        if drained.is_none() && events.len() >= 6 {
            // Drained instead: it finishes what it holds and exits 0 by itself.
            let name = format!("w{i}");
            let out = tessera(&["workers", "--drain", &name], &url);
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            let exit = wait_exit(&mut workers[i], Duration::from_secs(60));
            assert!(exit.success(), "the drained worker w{i} exited with {exit}");
            events.push(format!("worker w{i} drained at {last_done}/{total} units"));
            drained = Some(i);
        } else {
            workers[i].kill9();
            events.push(format!("worker w{i} SIGKILL at {last_done}/{total} units"));
        }
        if !rng.next().is_multiple_of(4) {
            std::thread::sleep(Duration::from_millis(rng.next() % 300));
        }
        workers[i] = start_worker(i);
    }
    assert!(
        coordinator_killed,
        "the job finished before the coordinator could be killed"
    );
    assert!(
        drained.is_some(),
        "no worker was drained (events: {events:?})"
    );
    let follower = follower.wait_with_output().expect("fetch --wait");
    assert!(
        follower.status.success(),
        "fetch --wait across the restart failed: {}",
        String::from_utf8_lossy(&follower.stderr)
    );

    // Each job's EXR must be `tessera render`'s with the same settings.
    let same_as_render = |farm: &Path, settings: &[&str], job: &str| {
        let local = dir.path().join(format!("{job}-local.exr"));
        let mut args = vec!["render", scene.as_str(), "--output"];
        args.push(local.to_str().expect("utf8"));
        args.extend(settings);
        let out = tessera(&args, &url);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            std::fs::read(farm).expect("farm") == std::fs::read(&local).expect("local"),
            "{job}'s EXR after the chaos differs from tessera render's (events: {events:?})"
        );
    };
    same_as_render(&farm_exr, &settings, &job);
    // The pooled and the paused jobs: done, with tessera render's bits too.
    for (small_job, seed) in [(&pooled, "3"), (&paused, "5")] {
        let farm = dir.path().join(format!("{small_job}.exr"));
        let out = tessera(
            &[
                "fetch",
                small_job,
                "--wait",
                "-o",
                farm.to_str().expect("utf8"),
            ],
            &url,
        );
        assert!(
            out.status.success(),
            "{small_job}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let mut settings = vec!["--seed", seed];
        settings.extend(small);
        same_as_render(&farm, &settings, small_job);
    }
    // Its requirement survived the restart with it.
    let status = String::from_utf8_lossy(&tessera(&["status", &pooled], &url).stdout).to_string();
    assert!(status.contains("requires   pool=a"), "{status}");

    // No lease left behind, on the job or on any worker.
    let (done, total, leased) = progress(&job, &url).expect("status");
    assert_eq!((done, leased), (total, 0));
    let out = tessera(&["workers"], &url);
    let table = String::from_utf8_lossy(&out.stdout);
    for line in table.lines().skip(1) {
        let leases: u64 = line
            .split_whitespace()
            .nth(4)
            .and_then(|w| w.parse().ok())
            .unwrap_or_else(|| panic!("unparsable workers line {line:?}"));
        assert_eq!(leases, 0, "{table}");
    }
    let kills = events.len();
    eprintln!(
        "chaos (seed {seed:#x}): {kills} kills in {:.1} s: {events:#?}",
        started.elapsed().as_secs_f64()
    );
    drop(workers);
    drop(coord);
}
