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

/// A `tessera worker` process with one render thread.
pub fn worker(url: &str, name: &str) -> Proc {
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
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start worker"),
    )
}

/// Runs a client command against the coordinator at `url`.
pub fn tessera_at(args: &[&str], url: &str) -> Output {
    Command::new(BIN)
        .args(args)
        .env("TESSERA_COORDINATOR", url)
        .output()
        .expect("run tessera")
}
