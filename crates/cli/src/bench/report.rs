//! The report: the machine it ran on (measured clock, vector extensions) and the markdown
//! tables of speed and equal-time error against each peer.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use super::peer::Row;
use super::stats::{by_spp, reference_noises, series, summary, Series};
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

/// A cache size as sysfs writes it ("48K", "2048K", "1M") in KiB or MiB.
fn cache_size(sysfs: &str) -> Option<String> {
    let s = sysfs.trim();
    let (digits, unit) = s.split_at(s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len()));
    let n: u64 = digits.parse().ok()?;
    let kib = match unit {
        "K" => n,
        "M" => n.checked_mul(1024)?,
        "G" => n.checked_mul(1024 * 1024)?,
        "" => n / 1024,
        _ => return None,
    };
    Some(if kib >= 1024 && kib % 1024 == 0 {
        format!("{} MiB", kib / 1024)
    } else {
        format!("{kib} KiB")
    })
}

/// How many CPUs a sysfs CPU list ("0", "0-1", "0-3,8-11") names.
fn cpu_count(list: &str) -> Option<u32> {
    list.trim().split(',').try_fold(0u32, |n, part| {
        let k = match part.split_once('-') {
            Some((a, b)) => b
                .parse::<u32>()
                .ok()?
                .checked_sub(a.parse().ok()?)?
                .checked_add(1)?,
            None => {
                part.parse::<u32>().ok()?;
                1
            }
        };
        n.checked_add(k)
    })
}

/// The first CPU's data and unified caches, from sysfs (Linux): a large mesh's queries wait
/// on memory, so how much of it the caches hold moves tessera's speed, and its ratio to a
/// peer's, from one machine to the next (docs/renderer.md). None where sysfs has no caches.
fn caches() -> Option<String> {
    let dir = std::fs::read_dir("/sys/devices/system/cpu/cpu0/cache").ok()?;
    let read = |p: &Path, f: &str| std::fs::read_to_string(p.join(f)).ok();
    let mut found: Vec<(u32, String)> = dir
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("index"))
        })
        .filter_map(|p| {
            let level: u32 = read(&p, "level")?.trim().parse().ok()?;
            let kind = read(&p, "type")?;
            let kind = match kind.trim() {
                "Data" => "d",
                "Unified" => "",
                _ => return None,
            };
            let size = cache_size(&read(&p, "size")?)?;
            let shared = read(&p, "shared_cpu_list")
                .and_then(|l| cpu_count(&l))
                .filter(|&n| n > 1)
                .map(|n| format!(" (shared by {n})"))
                .unwrap_or_default();
            Some((level, format!("L{level}{kind} {size}{shared}")))
        })
        .collect();
    found.sort();
    (!found.is_empty()).then(|| {
        found
            .into_iter()
            .map(|(_, s)| s)
            .collect::<Vec<_>>()
            .join(", ")
    })
}

/// The kernel's transparent huge pages setting (the bracketed word of sysfs's list): tessera
/// asks for huge pages for a large mesh's arrays, which the kernel grants under `always` and
/// `madvise` but not `never`.
fn huge_pages() -> Option<String> {
    let s = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled").ok()?;
    let start = s.find('[')? + 1;
    let end = start + s[start..].find(']')?;
    Some(s[start..end].to_string())
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
    let caches = caches()
        .map(|c| format!("; caches of CPU 0: {c}"))
        .unwrap_or_default();
    let huge = huge_pages()
        .map(|h| format!("; transparent huge pages: {h}"))
        .unwrap_or_default();
    format!(
        "{cpu}, {cores} cores available{mem}; vector extensions: {}{caches}{huge}; clock \
         {clock_ghz:.2} GHz (timed on a chain of dependent rotate-and-xor operations, one cycle \
         each, before rendering)",
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
    summary_section(&mut md, &all);
    by_spp_section(&mut md, &all);
    let flips = flip_means(rows);
    flip_section(&mut md, &flips);
    denoise_goal_section(&mut md, &all, &flips);
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

/// The summary: each scene and renderer's throughput, relMSE·s and efficiency, and the ratios
/// to tessera's.
fn summary_section(md: &mut String, all: &Series) {
    let _ = writeln!(md, "\n## Summary\n");
    let _ = writeln!(
        md,
        "| scene | renderer | Msamples/s | relMSE·s | efficiency | throughput vs tessera | equal-time relMSE vs tessera |\n|---|---|---:|---:|---:|---:|---:|"
    );
    for ((scene, renderer), points) in all {
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
}

/// The equal-time ratios at each spp, with the references' estimated noise taken off.
fn by_spp_section(md: &mut String, all: &Series) {
    let noises = reference_noises(all);
    let table = by_spp(all, &noises);
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
    fn cache_sizes_and_cpu_lists_read_as_sysfs_writes_them() {
        assert_eq!(cache_size("48K\n").as_deref(), Some("48 KiB"));
        assert_eq!(cache_size("2048K").as_deref(), Some("2 MiB"));
        assert_eq!(cache_size("307200K").as_deref(), Some("300 MiB"));
        assert_eq!(cache_size("1536K").as_deref(), Some("1536 KiB"));
        assert_eq!(cache_size("32M").as_deref(), Some("32 MiB"));
        assert_eq!(cache_size("K"), None);
        assert_eq!(cache_size("12Q"), None);
        assert_eq!(cpu_count("0\n"), Some(1));
        assert_eq!(cpu_count("0-1"), Some(2));
        assert_eq!(cpu_count("0-3,8-11"), Some(8));
        assert_eq!(cpu_count("3-1"), None);
        assert_eq!(cpu_count("x"), None);
        assert_eq!(cpu_count("0-4294967295"), None);
    }

    /// Where sysfs lists the caches (Linux), the machine line names each level's.
    #[test]
    fn the_machine_line_names_the_caches_where_sysfs_has_them() {
        let line = machine(1.0);
        let l2 = std::fs::read_dir("/sys/devices/system/cpu/cpu0/cache").is_ok_and(|d| {
            d.filter_map(Result::ok).any(|e| {
                std::fs::read_to_string(e.path().join("level")).is_ok_and(|l| l.trim() == "2")
            })
        });
        assert_eq!(
            line.contains(", L2 ") || line.contains(": L2 "),
            l2,
            "{line}"
        );
        assert!(
            line.contains("vector extensions: ") && line.ends_with("rendering)"),
            "{line}"
        );
    }

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

/// Mean FLIP over seeds per (scene, renderer) and spp.
type FlipMeans = BTreeMap<(String, String), BTreeMap<u32, f64>>;

/// [`FlipMeans`] of the rows that carry a FLIP.
fn flip_means(rows: &[Row]) -> FlipMeans {
    let mut acc: BTreeMap<(String, String), BTreeMap<u32, (f64, usize)>> = BTreeMap::new();
    for r in rows {
        if let Some(f) = r.flip {
            let e = acc
                .entry((r.scene.clone(), r.renderer.clone()))
                .or_default()
                .entry(r.spp)
                .or_default();
            *e = (e.0 + f, e.1 + 1);
        }
    }
    acc.into_iter()
        .map(|(k, by)| {
            (
                k,
                by.into_iter()
                    .map(|(spp, (s, n))| (spp, s / n as f64))
                    .collect(),
            )
        })
        .collect()
}

/// The perceptual error beside relMSE: mean FLIP by spp, where the renderer measured it.
fn flip_section(md: &mut String, means: &FlipMeans) {
    let spps: BTreeSet<u32> = means.values().flat_map(|m| m.keys().copied()).collect();
    if spps.is_empty() {
        return;
    }
    let _ = writeln!(md, "\n## Perceptual error (FLIP) by spp\n");
    let _ = writeln!(
        md,
        "Mean FLIP (NVIDIA's LDR FLIP, 0 = identical, 67 pixels per degree) of each image against \
         the reference, both tone-mapped as `--preview` maps them (ACES, sRGB): what a viewer \
         sees of the error, where relMSE weighs every pixel's. Renderers without the column \
         measured none.\n"
    );
    let head: Vec<String> = spps.iter().map(|s| format!("{s} spp")).collect();
    let _ = writeln!(
        md,
        "| scene | renderer | {} |\n|---|---|{}",
        head.join(" | "),
        "---:|".repeat(spps.len())
    );
    for ((scene, renderer), by) in means {
        let cells: Vec<String> = spps
            .iter()
            .map(|s| by.get(s).map_or("".into(), |f| format!("{f:.4}")))
            .collect();
        let _ = writeln!(md, "| {scene} | {renderer} | {} |", cells.join(" | "));
    }
    let _ = writeln!(md);
}

/// #82's goal, where the run has the points: the denoised image at 16 spp against the raw one
/// at 512, which the ladder of powers of 4 does not render; error falling as 1/spp puts it at
/// the geometric mean of 256 and 1024 spp.
fn denoise_goal_section(md: &mut String, all: &Series, flips: &FlipMeans) {
    let mut lines = Vec::new();
    for ((scene, renderer), points) in all {
        if renderer != super::denoised::RENDERER {
            continue;
        }
        let raw_key = (scene.clone(), "tessera".to_string());
        let (Some(d16), Some(raw)) = (points.get(&16), all.get(&raw_key)) else {
            continue;
        };
        let (Some(r256), Some(r1024)) = (raw.get(&256), raw.get(&1024)) else {
            continue;
        };
        let raw512 = (r256.1 * r1024.1).sqrt();
        let flip =
            |key: &(String, String), spp: u32| flips.get(key).and_then(|m| m.get(&spp)).copied();
        let d_key = (scene.clone(), renderer.clone());
        let flip_cells = match (flip(&d_key, 16), flip(&raw_key, 256), flip(&raw_key, 1024)) {
            (Some(d), Some(a), Some(b)) => format!("{d:.4} | {:.4}", (a * b).sqrt()),
            _ => "— | —".into(),
        };
        let met = if d16.1 < raw512 { "yes" } else { "no" };
        lines.push(format!(
            "| {scene} | {:.3e} | {raw512:.3e} | {met} | {flip_cells} |",
            d16.1
        ));
    }
    if lines.is_empty() {
        return;
    }
    let _ = writeln!(md, "\n## Denoised at 16 spp against raw at 512 spp\n");
    let _ = writeln!(
        md,
        "The raw render at 512 spp is the geometric mean of its 256 and 1024 spp points (error \
         falling as 1/spp), for relMSE and FLIP alike.\n"
    );
    let _ = writeln!(
        md,
        "| scene | relMSE denoised 16 | relMSE raw 512 | lower | FLIP denoised 16 | FLIP raw 512 |\n|---|---:|---:|---|---:|---:|"
    );
    for l in lines {
        let _ = writeln!(md, "{l}");
    }
    let _ = writeln!(md);
}
