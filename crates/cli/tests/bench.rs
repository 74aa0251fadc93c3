//! `tessera bench` (built with the `bench` feature: `.ci/run` runs these with
//! `cargo test --release -p tessera-cli --features bench --test bench`), driven as a user would.
#![cfg(feature = "bench")]

mod common;

use std::path::Path;

use common::{assert_clean_failure, repo, tessera, write};

/// A 12×8 scene that renders in moments, named `tiny`, for the bench's tests.
fn tiny_bench_scene(dir: &Path) -> String {
    write(
        dir,
        "tiny.toml",
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 4]\ntarget = [0, 0, 0]\nfov = 40\n\
         [film]\nwidth = 12\nheight = 8\n[environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\
         [materials.m]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\
         [[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\n",
    )
}

/// Runs `tessera bench` on `scene` at 4 … `max_spp` spp, one seed, a reference of `ref_spp`
/// cached under `dir/cache`, its reports named `name` in `out`, with `extra` flags; fails on
/// a failed run.
fn bench(dir: &Path, scene: &str, (max_spp, ref_spp): (&str, &str), name: &str, extra: &str) {
    let (out, cache) = (dir.join("out"), dir.join("cache"));
    let r = tessera(&[
        "bench",
        "--scene",
        scene,
        "--max-spp",
        max_spp,
        "--seeds",
        "1",
        "--reference-spp",
        ref_spp,
        "--cache",
        cache.to_str().expect("utf8"),
        "--out",
        out.to_str().expect("utf8"),
        "--name",
        name,
        extra,
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[test]
fn bench_writes_csv_markdown_and_plot_with_peer_ratios() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene = tiny_bench_scene(dir.path());
    let peer = write(
        dir.path(),
        "peer.csv",
        "renderer,scene,spp,seed,threads,seconds,msamples_per_s,relmse\n\
         other,tiny,4,1,2,0.5,0.001,0.02\nother,tiny,16,1,2,2.0,0.001,0.005\n",
    );
    let out = dir.path().join("out");
    std::fs::create_dir(&out).expect("mkdir");
    let cache = dir.path().join("cache");
    let args = |peer: &str| {
        vec![
            "bench".to_string(),
            "--scene".into(),
            scene.clone(),
            "--max-spp".into(),
            "16".into(),
            "--seeds".into(),
            "2".into(),
            "--reference-spp".into(),
            "64".into(),
            "--cache".into(),
            cache.display().to_string(),
            "--out".into(),
            out.display().to_string(),
            "--peer".into(),
            peer.to_string(),
        ]
    };
    let a = args(&peer);
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let csv = std::fs::read_to_string(out.join("speed-vs-error.csv")).expect("csv");
    // 2 spp levels × 2 seeds of tessera, plus the peer's 2 rows.
    assert_eq!(csv.lines().count(), 1 + 4 + 2, "{csv}");
    let ours: Vec<f64> = csv
        .lines()
        .filter(|l| l.starts_with("tessera,tiny,"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 9, "{l}");
            // relMSE and FLIP, each finite and positive.
            let e: f64 = f[7].parse().expect("relmse");
            let flip: f64 = f[8].parse().expect("flip");
            assert!(flip.is_finite() && flip > 0.0 && flip < 1.0, "{l}");
            e
        })
        .collect();
    assert!(ours.iter().all(|e| e.is_finite() && *e > 0.0), "{csv}");
    let md = std::fs::read_to_string(out.join("speed-vs-error.md")).expect("md");
    assert!(
        md.contains("| tiny | other |") && md.contains("| tiny | tessera | 16 |"),
        "{md}"
    );
    // The equal-time ratio at each spp the peer and tessera both measured.
    assert!(
        md.contains("## Equal-time relMSE by spp")
            && md.contains("| tiny | other | 4 |")
            && md.contains("| tiny | other | 16 |"),
        "{md}"
    );
    assert!(
        md.contains("Machine:") && md.contains("tessera bench"),
        "{md}"
    );
    // The clock is a timing, so only its form is checked: a finite, positive figure.
    let clock: f64 = md
        .split("clock ")
        .nth(1)
        .and_then(|rest| rest.split(" GHz").next())
        .and_then(|x| x.parse().ok())
        .expect("the machine line gives the measured clock");
    assert!(clock.is_finite() && clock > 0.0, "{md}");
    let simd = md
        .split("vector extensions: ")
        .nth(1)
        .and_then(|rest| rest.split(';').next())
        .expect("the machine line gives the vector extensions");
    #[cfg(target_arch = "x86_64")]
    assert_eq!(
        simd.split(", ").any(|x| x == "AVX2"),
        std::arch::is_x86_feature_detected!("avx2"),
        "{simd}"
    );
    assert!(!simd.is_empty(), "{md}");
    let svg = std::fs::read_to_string(out.join("speed-vs-error.svg")).expect("svg");
    assert!(svg.starts_with("<svg") && svg.contains("polyline"), "{svg}");
    assert_eq!(
        std::fs::read_dir(&cache).expect("cache").count(),
        1,
        "the reference is cached"
    );
    // A reference given by file is described by what its header says of its origin.
    let cached = std::fs::read_dir(&cache)
        .expect("cache")
        .next()
        .expect("one entry")
        .expect("entry")
        .path();
    let mut a = args(&peer);
    a.extend(["--reference".into(), format!("tiny={}", cached.display())]);
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let md = std::fs::read_to_string(out.join("speed-vs-error.md")).expect("md");
    assert!(
        md.contains(&format!(
            "- tiny: `{}` (tessera render: scene_sha256=",
            cached.display()
        )) && md.contains("spp=64, seed=18446744073709551615"),
        "{md}"
    );

    let bad = write(dir.path(), "bad.csv", "other,tiny,4,1,2,NaN,1,1\n");
    let a = args(&bad);
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_clean_failure(&r, &["bad.csv:1", "seconds"]);
    let r = tessera(&[
        "bench",
        "--max-spp",
        "8",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert_clean_failure(&r, &["--max-spp", "power of 4"]);
    let mut a = args(&peer);
    a.extend(["--reference".into(), "tiny".into()]);
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_clean_failure(&r, &["--reference \"tiny\"", "NAME=FILE.exr"]);
    // A reference for no scene of the run, or two for one, is refused before anything renders,
    // rather than left unused.
    let mut a = args(&peer);
    a.extend(["--reference".into(), "tyni=ref.exr".into()]);
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_clean_failure(
        &r,
        &[
            "--reference \"tyni=ref.exr\"",
            "no scene is named \"tyni\"",
            "tiny",
        ],
    );
    let mut a = args(&peer);
    a.extend([
        "--reference".into(),
        "tiny=a.exr".into(),
        "--reference".into(),
        "tiny=b.exr".into(),
    ]);
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_clean_failure(&r, &["--reference \"tiny=b.exr\"", "twice"]);
    let mut a = args(&peer);
    let spp = a.iter().position(|x| x == "--reference-spp").expect("flag") + 1;
    a[spp] = "0".into();
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_clean_failure(&r, &["--reference-spp"]);
    let mut a = args(&peer);
    let wrong_size = format!("tiny={}", repo("tests/data/cornell-box-reference.exr"));
    a.extend(["--reference".into(), wrong_size]);
    let r = tessera(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_clean_failure(&r, &["reference for tiny is 256×256", "12×8"]);
}

/// `--peer-command` asks the peer for each point right after tessera measures it, and every
/// wrong answer (a row for another point, a malformed row, an error line, an early exit) ends
/// the run with an error that names the peer's line or the point it failed at.
#[test]
fn bench_measures_a_peer_command_point_by_point_and_rejects_its_bad_answers() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene = tiny_bench_scene(dir.path());
    let out = dir.path().join("out");
    std::fs::create_dir(&out).expect("mkdir");
    let cache = dir.path().join("cache").display().to_string();
    let run = |peer: &str| {
        tessera(&[
            "bench",
            "--scene",
            &scene,
            "--max-spp",
            "16",
            "--seeds",
            "2",
            "--reference-spp",
            "64",
            "--cache",
            &cache,
            "--out",
            out.to_str().expect("utf8"),
            "--peer-command",
            peer,
        ])
    };
    // The peer logs each request it gets, so the test sees the order of the points.
    let log = dir.path().join("asked.txt");
    let r = run(&format!(
        "while read s n k; do echo \"$s $n $k\" >> '{}'; \
         echo \"other,$s,$n,$k,2,0.5,0.001,0.02\"; echo done; done",
        log.display()
    ));
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let asked = std::fs::read_to_string(&log).expect("the peer was asked");
    assert_eq!(asked, "tiny 4 1\ntiny 4 2\ntiny 16 1\ntiny 16 2\n");
    let csv = std::fs::read_to_string(out.join("speed-vs-error.csv")).expect("csv");
    // tessera's 4 points, each followed by the peer's.
    let renderers: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| &l[..l.find(',').expect("row")])
        .collect();
    assert_eq!(renderers, ["tessera", "other"].repeat(4), "{csv}");
    let md = std::fs::read_to_string(out.join("speed-vs-error.md")).expect("md");
    assert!(
        md.contains("interleaved") && md.contains("| tiny | other |"),
        "{md}"
    );

    let r = run("while read s n k; do echo \"other,$s,999,$k,2,0.5,0.001,0.02\"; echo done; done");
    assert_clean_failure(
        &r,
        &["--peer-command output line 1", "999 spp", "`tiny 4 1`"],
    );
    let r = run("read l; echo other,tiny,4,1,2,NaN,1,1; echo done");
    assert_clean_failure(&r, &["--peer-command output line 1", "seconds"]);
    let r = run("while read l; do echo 'error: no counterpart of this scene'; done");
    assert_clean_failure(
        &r,
        &["failed at `tiny 4 1`", "no counterpart of this scene"],
    );
    let r = run("read l; exit 3");
    assert_clean_failure(
        &r,
        &["ended (exit status: 3)", "before it answered `tiny 4 1`"],
    );
    let r = run("while read s n k; do echo \"tessera,$s,$n,$k,2,0.5,0.001,0.02\"; echo done; done");
    assert_clean_failure(&r, &["may not be named tessera"]);
}

/// `bench --guiding` measures a guided render right after each unguided point and reports
/// each guided point's speed-up at equal relMSE (NAME-guiding.md).
#[test]
fn bench_guiding_measures_guided_renders_beside_unguided_ones() {
    let dir = tempfile::tempdir().expect("tmp");
    let scene = tiny_bench_scene(dir.path());
    let out = dir.path().join("out");
    std::fs::create_dir(&out).expect("mkdir");
    bench(dir.path(), &scene, ("64", "64"), "g", "--guiding");
    let csv = std::fs::read_to_string(out.join("g.csv")).expect("csv");
    // 4, 16 and 64 spp, each unguided and guided.
    for renderer in ["tessera", "tessera-guided"] {
        let rows = csv
            .lines()
            .filter(|l| l.starts_with(&format!("{renderer},tiny,")))
            .count();
        assert_eq!(rows, 3, "{renderer}: {csv}");
    }
    let md = std::fs::read_to_string(out.join("g-guiding.md")).expect("the guiding report");
    assert!(
        md.contains("| scene | spp | unguided s |")
            && md.contains("| tiny | 64 |")
            && md.contains("## Summary")
            && md.contains("--guiding"),
        "{md}"
    );
}

/// `bench --denoise` measures a denoised render right after each raw point, as a series of
/// its own, whose relMSE at 16 and 64 spp is below the raw render's (the Cornell box, cut to
/// 64²).
#[test]
fn bench_denoise_measures_denoised_renders_beside_raw_ones() {
    tessera_testkit::install_oidn();
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("out");
    std::fs::create_dir(&out).expect("mkdir");
    let text = std::fs::read_to_string(repo("scenes/cornell-box.toml")).expect("scene");
    let scene = write(
        dir.path(),
        "box.toml",
        &text
            .replace("width = 256", "width = 64")
            .replace("height = 256", "height = 64"),
    );
    bench(dir.path(), &scene, ("64", "1024"), "d", "--denoise");
    let csv = std::fs::read_to_string(out.join("d.csv")).expect("csv");
    // Column 7 is relMSE, 8 FLIP.
    let error = |renderer: &str, spp: u32, column: usize| -> f64 {
        let row = csv
            .lines()
            .find(|l| l.starts_with(&format!("{renderer},box,{spp},")))
            .unwrap_or_else(|| panic!("no {renderer} row at {spp} spp: {csv}"));
        row.split(',')
            .nth(column)
            .expect("column")
            .parse()
            .expect("a number")
    };
    for spp in [16, 64] {
        for (column, what) in [(7, "relMSE"), (8, "FLIP")] {
            let (raw, denoised) = (
                error("tessera", spp, column),
                error("tessera-denoised", spp, column),
            );
            assert!(
                denoised < raw,
                "{what} at {spp} spp: raw {raw}, denoised {denoised}"
            );
        }
    }
    let md = std::fs::read_to_string(out.join("d.md")).expect("md");
    assert!(
        md.contains("## Perceptual error (FLIP) by spp")
            && md.contains("| box | tessera-denoised |"),
        "{md}"
    );
}

#[test]
fn loadtest_runs_simulated_workers_against_a_coordinator_and_reports_what_it_measured() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("out");
    let o = tessera(&[
        "loadtest",
        "--workers",
        "3,12",
        "--seconds",
        "1",
        "--name",
        "lt",
        "--out-dir",
        out.to_str().expect("utf8"),
        "--guiding",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(out.join("lt.csv")).expect("csv");
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len(), 4, "{csv}");
    let runs = [
        ("3", "false"),
        ("3", "true"),
        ("12", "false"),
        ("12", "true"),
    ];
    for (row, (workers, guided)) in rows.iter().zip(runs) {
        assert_eq!((row[0], row[1]), (workers, guided), "{csv}");
        let merged: u64 = row[3].parse().expect("units merged");
        assert!(merged > 0, "no unit merged: {csv}");
        // Every simulated result is an honest render: none may be refused or duplicated. (A
        // guided job's barriers may give a slow unit a speculative copy, whose result is then
        // a duplicate; its training trees are checked like any, and a refused one would stop
        // the run with an error.)
        if guided == "false" {
            assert_eq!(row[4], "0", "{csv}");
        }
        for f in &row[5..] {
            let v: f64 = f.parse().expect("a number");
            assert!(v.is_finite() && v >= 0.0, "{csv}");
        }
    }
    let md = std::fs::read_to_string(out.join("lt.md")).expect("md");
    assert!(
        md.contains("Made by `tessera loadtest --workers 3,12"),
        "{md}"
    );
    assert!(md.contains("Machine: "), "{md}");
    let bad = tessera(&["loadtest", "--workers", "0"]);
    assert_clean_failure(&bad, &["--workers"]);
    // Every result is a 128² tile's sums of the job's unit rule's batch; a guided job's first
    // epochs cut its units smaller (1, 2, 4, … samples).
    let header = csv.lines().next().expect("header");
    assert!(
        header.contains("gsamples_per_s,cpu_s_per_gsample,mb_written_per_gsample"),
        "{csv}"
    );
    for row in &rows {
        let (units, samples): (u64, u64) = (row[3].parse().expect("n"), row[5].parse().expect("n"));
        if row[1] == "false" {
            assert_eq!(samples, units * 128 * 128 * 1024, "{csv}");
        } else {
            assert!(
                samples >= units * 128 * 128 && samples <= units * 128 * 128 * 1024,
                "{csv}"
            );
        }
    }
    assert!(
        md.contains("| 3 guided |") && md.contains("training epochs 0 to"),
        "{md}"
    );
}

#[test]
fn loadtest_memory_renders_large_frames_to_the_end_and_reports_the_coordinators_memory() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("out");
    let o = tessera(&[
        "loadtest",
        "--memory",
        "256",
        "--jobs",
        "2",
        "--name",
        "mem",
        "--out-dir",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(out.join("mem.md")).expect("md");
    assert!(md.contains("| 256² | 2 | 8 |"), "{md}");
    // In four batches a tile, with every open tile sent to the store between them and every
    // merged tile holding the next result back until a checkpoint: both jobs still end.
    let o = tessera(&[
        "loadtest",
        "--memory",
        "256",
        "--batch",
        "2",
        "--evict-open-over",
        "0",
        "--max-unstored-bytes",
        "1",
        "--checkpoint-interval",
        "0.05",
        "--name",
        "mem-open",
        "--out-dir",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(out.join("mem-open.md")).expect("md");
    assert!(
        md.contains("--evict-open-over 0 --max-unstored-bytes 1"),
        "{md}"
    );
    let row = md
        .lines()
        .find(|l| l.starts_with("| 256² | 2 | 2 |"))
        .unwrap_or_else(|| panic!("{md}"));
    let deferred: u64 = row
        .trim_end_matches(" |")
        .rsplit("| ")
        .next()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("{row}"));
    assert!(deferred > 0, "no result was deferred: {row}");
    let bad = tessera(&["loadtest", "--memory", "100"]);
    assert_clean_failure(&bad, &["--memory"]);
}
