//! # tessera-testkit
//!
//! What the workspace's tests share. Every poll loop of a test waits through [`wait_for`] (in
//! async tests) or [`wait_for_blocking`] (in tests that drive the binaries), so that no test
//! can hang a run, and each names what it waited for when it gives up.

use std::time::{Duration, Instant};

/// How long a test waits for a condition before it fails: far above what a healthy farm needs
/// on the slowest machine the tests run on (CI's two cores, under a parallel test run), so
/// that a failure means a bug and not a slow machine.
pub const PATIENCE: Duration = Duration::from_secs(180);

/// Asks `check` every few milliseconds until it answers `Some`, and returns that; fails the
/// test, naming `what`, once [`PATIENCE`] has passed.
pub async fn wait_for<T>(what: &str, mut check: impl AsyncFnMut() -> Option<T>) -> T {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        if let Some(v) = check().await {
            return v;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "gave up after {PATIENCE:?} waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// [`wait_for`] for a test without an async runtime: polls `check` every 50 ms (it usually
/// asks another process something).
pub fn wait_for_blocking<T>(what: &str, mut check: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = check() {
            return v;
        }
        assert!(
            start.elapsed() < PATIENCE,
            "gave up after {PATIENCE:?} waiting for {what}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wait_returns_what_the_check_found_once_it_finds_it() {
        let mut n = 0;
        let got = wait_for_blocking("the third call", || {
            n += 1;
            (n == 3).then_some(n)
        });
        assert_eq!(got, 3);
    }

    #[tokio::test]
    async fn an_async_wait_returns_what_the_check_found() {
        let mut n = 0;
        let got = wait_for("the second call", async || {
            n += 1;
            (n == 2).then_some("found")
        })
        .await;
        assert_eq!(got, "found");
    }
}

/// Installs Open Image Denoise where the project's binaries find it (`target/oidn/lib`), by
/// the script a user runs (`scripts/install-oidn.sh`), once per test process; the script
/// itself returns at once when it is installed and locks against concurrent installs. Panics,
/// with the script's output, if it fails (it needs PyPI the first time).
pub fn install_oidn() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let out = std::process::Command::new(root.join("scripts/install-oidn.sh"))
            .current_dir(&root)
            .output()
            .expect("running scripts/install-oidn.sh");
        assert!(
            out.status.success(),
            "scripts/install-oidn.sh failed: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    });
}

/// relMSE of an RGB image against a reference: each channel's squared error over
/// (reference² + 0.01), averaged (the 0.01 keeps black pixels from dividing by zero).
pub fn rel_mse(image: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let mut sum = 0.0;
    for (p, t) in image.iter().zip(reference) {
        for c in 0..3 {
            let d = f64::from(p[c] - t[c]);
            sum += d * d / (f64::from(t[c]).powi(2) + 1e-2);
        }
    }
    sum / (3 * image.len()).max(1) as f64
}
