//! Helpers shared by the tests that drive the real `tessera` binary.
#![allow(dead_code)] // each test file uses its own subset

use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};

/// The binary under test.
pub const BIN: &str = env!("CARGO_BIN_EXE_tessera");

/// A path in the repository, as a string for command lines.
pub fn repo(path: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(path)
        .display()
        .to_string()
}

/// A child process killed (SIGKILL) when dropped, so a failing test leaves nothing running.
pub struct Proc(pub Child);

impl Proc {
    /// SIGKILL: no goodbye, no flush, leases left to lapse.
    pub fn kill9(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill9();
    }
}

/// Starts `tessera coordinator --listen LISTEN --data-dir DATA` with `extra` arguments and its
/// stderr to `stderr`, and returns it with the address it bound, read from its "listening on"
/// line: with port 0 the server picks the port itself, so no test ever binds a port, drops it
/// and hopes it is still free.
pub fn start_coordinator(
    listen: &str,
    data: &std::path::Path,
    extra: &[&str],
    stderr: Stdio,
) -> (Proc, String) {
    use std::io::{BufRead, BufReader};
    let mut child = Command::new(BIN)
        .args(["coordinator", "--listen", listen, "--data-dir"])
        .arg(data)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(stderr)
        .spawn()
        .expect("start coordinator");
    let stdout = child.stdout.take().expect("stdout");
    let mut line = String::new();
    BufReader::new(stdout)
        .read_line(&mut line)
        .expect("read the listening line");
    let addr = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    (Proc(child), addr)
}

/// A `tessera worker` process with one render thread.
pub fn worker(url: &str, name: &str) -> Proc {
    worker_with_stderr(url, name, &[], Stdio::null())
}

/// A `tessera worker` with one render thread, `extra` flags, and its log in the file `log`.
pub fn worker_with(url: &str, name: &str, extra: &[&str], log: &std::path::Path) -> Proc {
    worker_with_stderr(
        url,
        name,
        extra,
        Stdio::from(std::fs::File::create(log).expect("log")),
    )
}

fn worker_with_stderr(url: &str, name: &str, extra: &[&str], stderr: Stdio) -> Proc {
    Proc(
        Command::new(BIN)
            .args([
                "worker",
                "--coordinator",
                url,
                "--threads",
                "1",
                "--name",
                name,
            ])
            .args(extra)
            .stdout(Stdio::null())
            .stderr(stderr)
            .spawn()
            .expect("start worker"),
    )
}

/// A coordinator on port 0 with 5-second leases, and its URL.
pub fn coordinator(data: &std::path::Path) -> (Proc, String) {
    let (proc, addr) = start_coordinator(
        "127.0.0.1:0",
        data,
        &["--lease-timeout", "5"],
        Stdio::null(),
    );
    (proc, format!("http://{addr}"))
}

/// Asserts that a command failed with one line on stderr that contains `needle`, and no
/// panic.
pub fn one_line_failure(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should fail: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "not one line: {stderr}");
    assert!(stderr.contains(needle), "missing {needle:?} in: {stderr}");
}

/// Runs a client command against the coordinator at `url`.
pub fn tessera_at(args: &[&str], url: &str) -> Output {
    Command::new(BIN)
        .args(args)
        .env("TESSERA_COORDINATOR", url)
        .output()
        .expect("run tessera")
}

/// Runs `tessera` with `args` and nothing else set.
pub fn tessera(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().expect("run tessera")
}

/// Writes `text` to `dir/name` and returns the path.
pub fn write(dir: &std::path::Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write scene");
    p.display().to_string()
}

/// Fails with stderr and asserts the message is a one-line error, not a panic.
pub fn assert_clean_failure(out: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should fail: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    assert!(!stderr.contains("RUST_BACKTRACE"), "panic: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "missing {n:?} in: {stderr}");
    }
}

/// Starts `tessera coordinator` on port 0 with its dashboard on port 0 and `extra` arguments;
/// returns it with its gRPC URL and its dashboard's URL, read from the lines it prints once
/// it is up (where it listens, then where its dashboard is).
pub fn coordinator_with_dashboard(
    data: &std::path::Path,
    extra: &[&str],
) -> (Proc, String, String) {
    let mut child = Command::new(BIN)
        .args([
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--http",
            "127.0.0.1:0",
        ])
        .args(extra)
        .arg("--data-dir")
        .arg(data)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start coordinator");
    use std::io::{BufRead, BufReader};
    let mut out = BufReader::new(child.stdout.take().expect("stdout"));
    let coordinator = Proc(child);
    let mut line = String::new();
    out.read_line(&mut line).expect("listening line");
    let grpc = format!(
        "http://{}",
        line.trim().strip_prefix("listening on ").expect(&line)
    );
    line.clear();
    out.read_line(&mut line).expect("dashboard line");
    let dash = line
        .trim()
        .strip_prefix("dashboard on ")
        .unwrap_or_else(|| panic!("unexpected line {line:?}"))
        .trim_end_matches('/')
        .to_string();
    (coordinator, grpc, dash)
}

/// Writes `text` to the private file `dir/name` (a token file others can read earns a warning
/// line on stderr) and returns its path.
pub fn private_file(dir: &std::path::Path, name: &str, text: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write");
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    p
}

/// Submits `scene` with `flags` to the farm at `url` and waits for its EXR, renders it with
/// `tessera render` and the same flags, and asserts the two files are the same bytes
/// (`what` names the job in the failure); returns the farm's file.
pub fn assert_farm_file_is_render_file(
    dir: &std::path::Path,
    url: &str,
    scene: &str,
    flags: &[&str],
    what: &str,
) -> PathBuf {
    let run = |args: Vec<&str>| {
        let out = tessera_at(&args, url);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let (farm, local) = (dir.join("farm.exr"), dir.join("local.exr"));
    let mut args = vec!["submit", scene];
    args.extend(flags);
    args.extend(["--wait", "--output", farm.to_str().expect("utf8")]);
    run(args);
    let mut args = vec!["render", scene];
    args.extend(flags);
    args.extend(["--output", local.to_str().expect("utf8")]);
    run(args);
    assert!(
        std::fs::read(&farm).expect("farm") == std::fs::read(&local).expect("local"),
        "the farm's {what} EXR differs from render's"
    );
    farm
}
