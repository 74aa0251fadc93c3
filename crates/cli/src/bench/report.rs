//! The report: the machine it ran on (measured clock, vector extensions) and the markdown
//! tables of speed and equal-time error against each peer.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use super::peer::Row;
use super::stats::{by_spp, reference_noises, series, summary};
use super::BenchArgs;

/// The core clock, timed on a chain of dependent rotate-and-xor operations, which take one
/// cycle each on current x86-64 and AArch64 cores. The best of three runs, so a moment's
/// contention does not lower it. Shared machines change clock from one sitting to the next,
/// and with it every absolute figure of a report; the ratios, measured in one run, do not.
pub(super) fn measured_clock_ghz() -> f64 {
    // Not inlined, so the chain's length stays opaque to the optimiser.
    #[inline(never)]
    pub(super) fn chain(n: u64, mut x: u64) -> u64 {
        for _ in 0..n {
            x = x.rotate_left(1) ^ 0x9e37_79b9_7f4a_7c15;
        }
        x
    }
    const STEPS: u64 = 100_000_000;
    (0..3)
        .map(|_| {
            let start = Instant::now();
            std::hint::black_box(chain(std::hint::black_box(STEPS), 1));
            2.0 * STEPS as f64 / start.elapsed().as_secs_f64().max(1e-9) / 1e9
        })
        .fold(0.0, f64::max)
}

/// The vector extensions this CPU has. tessera is built for baseline x86-64 so that every worker
/// rounds alike, but a peer that compiles its kernels on the host (Mitsuba's `llvm_ad_rgb`) uses
/// the widest it finds, so this explains much of a peer's speed from one sitting to the next.
pub(super) fn simd_extensions() -> String {
    #[cfg(target_arch = "x86_64")]
    let found: Vec<&str> = [
        ("SSE4.1", std::arch::is_x86_feature_detected!("sse4.1")),
        ("AVX", std::arch::is_x86_feature_detected!("avx")),
        ("AVX2", std::arch::is_x86_feature_detected!("avx2")),
        ("FMA", std::arch::is_x86_feature_detected!("fma")),
        ("AVX-512F", std::arch::is_x86_feature_detected!("avx512f")),
    ]
    .into_iter()
    .filter_map(|(name, has)| has.then_some(name))
    .collect();
    #[cfg(target_arch = "aarch64")]
    let found = vec!["NEON"];
    #[cfg(not(any(target_arch = "x86_64", target_arch = "aarch64")))]
    let found: Vec<&str> = Vec::new();
    if found.is_empty() {
        "none detected".into()
    } else {
        found.join(", ")
    }
}

pub(super) fn machine(clock_ghz: f64) -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let mem = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemTotal"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map(|kb| format!(", {:.0} GiB", kb / 1024.0 / 1024.0))
        .unwrap_or_default();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!(
        "{cpu}, {cores} cores available{mem}; vector extensions: {}; clock {clock_ghz:.2} GHz \
         (timed on a chain of dependent rotate-and-xor operations, one cycle each, before \
         rendering)",
        simd_extensions()
    )
}

pub(super) fn report(
    rows: &[Row],
    references: &[(String, String)],
    args: &BenchArgs,
    threads: usize,
    clock_ghz: f64,
    svg: &Path,
    csv: &Path,
) -> String {
    let all = series(rows);
    let mut md = String::new();
    let _ = writeln!(md, "# Speed against error\n");
    let _ = writeln!(
        md,
        "Made by `{}` (tessera on {threads} threads).\n",
        command()
    );
    let _ = writeln!(md, "Machine: {}.\n", machine(clock_ghz));
    let peers = match (&args.peer_command, args.peers.is_empty()) {
        (Some(_), true) => {
            "Peers were measured interleaved with tessera: each peer point right after tessera's \
             point of the same scene, spp and seed, so that both face the same minute of the \
             machine. "
        }
        (Some(_), false) => {
            "Peers were measured interleaved with tessera (each peer point right after tessera's \
             point of the same scene, spp and seed), or read from CSV files measured in the same \
             run. "
        }
        (None, false) => "Peers' rows come from their own CSV files, measured in the same run. ",
        (None, true) => "",
    };
    let _ = writeln!(
        md,
        "Each scene is rendered at 4, 16, … {} spp with {} seeds; a row is the mean over seeds. \
         relMSE = mean over pixels and channels of (I − R)²/(R² + 0.01); efficiency = 1/(relMSE·s). \
         relMSE·s is the geometric mean over spp ≥ 64, where error falls as 1/time. \
         {peers}Data: [`{}`]({}), plot: [`{}`]({}).\n",
        args.max_spp,
        args.seeds,
        csv.display(),
        csv.file_name().map_or_else(String::new, |f| f.to_string_lossy().into()),
        svg.display(),
        svg.file_name().map_or_else(String::new, |f| f.to_string_lossy().into()),
    );
    let _ = writeln!(md, "References:\n");
    for (name, source) in references {
        let _ = writeln!(md, "- {name}: {source}");
    }
    let _ = writeln!(md, "\n## Summary\n");
    let _ = writeln!(
        md,
        "| scene | renderer | Msamples/s | relMSE·s | efficiency | throughput vs tessera | equal-time relMSE vs tessera |\n|---|---|---:|---:|---:|---:|---:|"
    );
    for ((scene, renderer), points) in &all {
        let (et, ms) = summary(points);
        let (ratio_t, ratio_e) = match all.get(&(scene.clone(), "tessera".to_string())) {
            Some(t) if renderer != "tessera" => {
                let (t_et, t_ms) = summary(t);
                (format!("{:.2}×", t_ms / ms), format!("{:.3}×", t_et / et))
            }
            _ => ("".into(), "".into()),
        };
        let _ = writeln!(
            md,
            "| {scene} | {renderer} | {ms:.2} | {et:.4} | {:.0} | {ratio_t} | {ratio_e} |",
            1.0 / et
        );
    }
    let _ = writeln!(
        md,
        "\n\"throughput vs tessera\" is tessera's Msamples/s over the peer's; \"equal-time relMSE vs \
         tessera\" is tessera's relMSE·s over the peer's: the error tessera reaches in the time the \
         peer needs for its own (below 1 is better for tessera).\n"
    );
    let noises = reference_noises(&all);
    let table = by_spp(&all, &noises);
    if !table.is_empty() {
        let _ = writeln!(md, "## Equal-time relMSE by spp\n");
        let _ = writeln!(
            md,
            "tessera's relMSE·s over the peer's at each spp. The summary's one number hides how \
             the ratio moves with spp. At high spp part of every error is the reference's own \
             noise, the same amount ρ for every renderer of a scene, so it weighs most on the \
             renderer with the smaller error. The last column takes an estimate of ρ off both: \
             ρ = (4·e(4N) − e(N))/3 from each renderer's top octave (exact where error falls as \
             1/spp; quasi-Monte Carlo makes it an underestimate), averaged over the scene's \
             renderers. It is an estimate, for reading the measured column, not a replacement \
             for it.\n"
        );
        let _ = writeln!(
            md,
            "| scene | peer | spp | measured | reference noise removed |\n|---|---|---:|---:|---:|"
        );
        for (scene, peer, spp, raw, corrected) in table {
            let corrected = corrected.map_or_else(|| "".into(), |c| format!("{c:.3}×"));
            let _ = writeln!(md, "| {scene} | {peer} | {spp} | {raw:.3}× | {corrected} |");
        }
        let _ = writeln!(md);
        for (scene, rho) in &noises {
            if let Some(rho) = rho {
                let _ = writeln!(md, "- {scene}: estimated reference noise ρ = {rho:.2e}");
            }
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md, "## All points\n");
    let _ = writeln!(
        md,
        "| scene | renderer | spp | seconds | Msamples/s | relMSE | efficiency |\n|---|---|---:|---:|---:|---:|---:|"
    );
    for ((scene, renderer), points) in &all {
        for (spp, (s, e, m)) in points {
            let _ = writeln!(
                md,
                "| {scene} | {renderer} | {spp} | {s:.3} | {m:.2} | {e:.3e} | {:.1} |",
                1.0 / (e * s)
            );
        }
    }
    md
}

/// The command line this process was run with, each argument quoted as a shell would need it
/// (a --peer-command is one argument with spaces), so that it can be run again as it stands.
pub(super) fn command() -> String {
    std::env::args()
        .map(|a| shell_quote(&a))
        .collect::<Vec<_>>()
        .join(" ")
}

/// `arg` as one shell word: as it is when that is safe, else in single quotes.
pub(super) fn shell_quote(arg: &str) -> String {
    let plain = !arg.is_empty()
        && arg
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if plain {
        arg.to_string()
    } else {
        format!("'{}'", arg.replace('\'', "'\\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shell_quote_keeps_plain_words_and_quotes_the_rest() {
        assert_eq!(shell_quote("--max-spp=4096"), "--max-spp=4096");
        assert_eq!(
            shell_quote("python peer.py --serve"),
            "'python peer.py --serve'"
        );
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
        assert_eq!(shell_quote(""), "''");
    }
}
