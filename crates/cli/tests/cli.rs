//! Drives the real `tessera` binary, as a user would.

mod common;

use std::path::Path;

use common::repo;
use std::process::{Command, Output};

use tessera_render::output::{read_exr_metadata, read_exr_rgb};

fn tessera(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(args)
        .output()
        .expect("run tessera")
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write scene");
    p.display().to_string()
}

/// Fails with stderr and asserts the message is a one-line error, not a panic.
fn assert_clean_failure(out: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should fail: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    assert!(!stderr.contains("RUST_BACKTRACE"), "panic: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "missing {n:?} in: {stderr}");
    }
}

#[test]
fn renders_the_cornell_box_to_a_valid_exr() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("cb.exr");
    let png = dir.path().join("cb.png");
    let r = tessera(&[
        "render",
        &repo("scenes/cornell-box.toml"),
        "--spp",
        "4",
        "--output",
        out.to_str().expect("utf8"),
        "--preview",
        png.to_str().expect("utf8"),
        "--threads",
        "2",
        "--seed",
        "7",
    ]);
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(
        stdout.contains("Msamples/s") && stdout.contains("noise"),
        "summary line: {stdout}"
    );
    let img = read_exr_rgb(&out).expect("valid EXR");
    assert_eq!((img.width, img.height), (256, 256));
    let mean: f32 =
        img.rgb.iter().map(|p| p[0] + p[1] + p[2]).sum::<f32>() / (3.0 * img.rgb.len() as f32);
    assert!(mean > 0.05 && mean < 1.0, "mean {mean}");
    let meta = read_exr_metadata(&out).expect("metadata");
    assert!(meta.iter().any(|m| m == "seed=7"), "{meta:?}");
    assert!(
        meta.iter()
            .any(|m| m.starts_with("scene_sha256=") && m.len() == 13 + 64),
        "{meta:?}"
    );
    assert!(std::fs::read(&png).expect("png").starts_with(b"\x89PNG"));
}

#[test]
fn same_flags_same_bytes_whatever_the_threads() {
    let dir = tempfile::tempdir().expect("tmp");
    let a = dir.path().join("a.exr");
    let b = dir.path().join("b.exr");
    let scene = repo("scenes/spheres.toml");
    for (out, threads) in [(&a, "1"), (&b, "2")] {
        let r = tessera(&[
            "render",
            &scene,
            "--spp",
            "2",
            "--output",
            out.to_str().expect("utf8"),
            "--threads",
            threads,
            "--variance",
            "--sample-count",
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    assert_eq!(std::fs::read(&a).expect("a"), std::fs::read(&b).expect("b"));
}

#[test]
fn bad_scenes_give_positioned_errors() {
    let dir = tempfile::tempdir().expect("tmp");
    let good = std::fs::read_to_string(repo("scenes/cornell-box.toml")).expect("scene");
    let out = dir.path().join("o.exr");
    let out = out.to_str().expect("utf8");
    let cases = [
        ("syntax.toml", good.replace("fov = 39.3077", "fov = 39.3077 ]"), vec!["syntax.toml:10:", "syntax error"]),
        ("unknown.toml", good.replace("up = [0.0", "upp = [0.0"), vec!["unknown.toml:9:1:", "camera.upp", "unknown field `upp`"]),
        ("missing.toml", good.replace("material = \"green\"", "material = \"gren\""), vec!["missing.toml:51:12:", "objects[3].material", "`gren` is not defined"]),
        (
            "nan.toml",
            good.replace("shape = \"box\"\nmaterial = \"white\"\ntransform.matrix = [[0.28491", "shape = \"sphere\"\nradius = nan\nmaterial = \"white\"\ntransform.matrix = [[0.28491"),
            vec!["nan.toml:66:10:", "objects[6].radius", "finite number greater than 0"],
        ),
    ];
    for (name, text, needles) in cases {
        assert_ne!(text, good, "{name}: the edit did not apply");
        let path = write(dir.path(), name, &text);
        let r = tessera(&["render", &path, "--spp", "1", "--output", out]);
        assert_clean_failure(&r, &needles);
        assert_eq!(
            String::from_utf8_lossy(&r.stderr).trim().lines().count(),
            1,
            "one line: {}",
            String::from_utf8_lossy(&r.stderr)
        );
    }
    assert!(!Path::new(out).exists(), "no output for a bad scene");
}

/// A render of a scene file that does not exist: a plain failure, before any output.
const MISSING_SCENE: [&str; 6] = [
    "render",
    "no-such-scene.toml",
    "--spp",
    "1",
    "--output",
    "x.exr",
];

/// A failure with nowhere to report it (stderr's reader gone) is still the plain failure,
/// exit code 1, not a panic's 101.
#[test]
fn a_closed_stderr_does_not_turn_an_error_into_a_panic() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(MISSING_SCENE)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    drop(child.stderr.take());
    let status = child.wait().expect("wait");
    assert_eq!(status.code(), Some(1), "{status:?}");
}

#[test]
fn bad_flags_and_paths_are_refused() {
    let scene = repo("scenes/cornell-box.toml");
    assert_clean_failure(
        &tessera(&["render", &scene, "--spp", "0", "--output", "x.exr"]),
        &["--spp"],
    );
    assert_clean_failure(
        &tessera(&["render", &scene, "--spp", "many", "--output", "x.exr"]),
        &["--spp"],
    );
    assert_clean_failure(
        &tessera(&["render", &scene, "--output", "x.exr"]),
        &["--spp"],
    );
    assert_clean_failure(
        &tessera(&[
            "render",
            &scene,
            "--spp",
            "1",
            "--output",
            "x.exr",
            "--threads",
            "0",
        ]),
        &["--threads"],
    );
    assert_clean_failure(
        &tessera(&[
            "render",
            &scene,
            "--spp",
            "9",
            "--max-spp",
            "8",
            "--output",
            "x.exr",
        ]),
        &["above the limit of 8"],
    );
    assert_clean_failure(
        &tessera(&[
            "render",
            &scene,
            "--spp",
            "1",
            "--output",
            "/nonexistent-dir/x.exr",
        ]),
        &["does not exist"],
    );
    assert_clean_failure(
        &tessera(&MISSING_SCENE),
        &["no-such-scene.toml", "cannot read"],
    );
    assert_clean_failure(
        &tessera(&[
            "render",
            &scene,
            "--spp",
            "1",
            "--output",
            "x.exr",
            "--exposure",
            "NaN",
        ]),
        &["--exposure"],
    );
}

#[test]
fn outputs_are_checked_before_rendering() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = |n: &str| dir.path().join(n).display().to_string();
    // A 4096² scene at many spp would take minutes: every refusal below must come before it
    // renders anything, or the test would time out.
    let big = write(
        dir.path(),
        "big.toml",
        &std::fs::read_to_string(repo("scenes/cornell-box.toml"))
            .expect("scene")
            .replace("width = 256", "width = 4096")
            .replace("height = 256", "height = 4096"),
    );
    let render = |extra: &[&str]| {
        let mut args = vec!["render", big.as_str(), "--spp", "4096"];
        args.extend_from_slice(extra);
        tessera(&args)
    };
    // A file is named for what it is.
    assert_clean_failure(
        &render(&["--output", &d("x.png")]),
        &["--output", "must end in .exr"],
    );
    assert_clean_failure(
        &render(&["--output", &d("x.exr"), "--preview", &d("x.jpg")]),
        &["--preview", "must end in .png"],
    );
    // An unwritable preview (here: a directory in the way) fails at once, not after the render.
    std::fs::create_dir(dir.path().join("taken.png")).expect("mkdir");
    assert_clean_failure(
        &render(&["--output", &d("x.exr"), "--preview", &d("taken.png")]),
        &["taken.png", "is a directory"],
    );
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).expect("mkdir");
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).expect("chmod");
        // root writes anywhere: the check only means something for other users.
        if std::fs::write(ro.join("probe"), b"").is_err() {
            assert_clean_failure(
                &render(&["--output", &d("x.exr"), "--preview", &d("ro/p.png")]),
                &["p.png", "cannot write"],
            );
        }
    }
    assert!(!dir.path().join("x.exr").exists());
    // The client commands check their outputs the same way.
    assert_clean_failure(
        &tessera(&["fetch", "job-000001", "--output", &d("x.png")]),
        &["must end in .exr"],
    );
}

#[test]
fn a_token_file_others_can_read_is_warned_about() {
    let dir = tempfile::tempdir().expect("tmp");
    let token = write(dir.path(), "token", "0123456789abcdef0123456789abcdef\n");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let status_stderr = |mode: u32| {
            std::fs::set_permissions(&token, std::fs::Permissions::from_mode(mode)).expect("chmod");
            let out = tessera(&[
                "status",
                "--coordinator",
                "http://127.0.0.1:1",
                "--token-file",
                &token,
            ]);
            String::from_utf8_lossy(&out.stderr).into_owned()
        };
        let stderr = status_stderr(0o644);
        assert!(
            stderr.contains("can be read by others (mode 644)"),
            "{stderr}"
        );
        let stderr = status_stderr(0o600);
        assert!(!stderr.contains("read by others"), "{stderr}");
    }
}

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
            l.rsplit(',')
                .next()
                .expect("relmse")
                .parse()
                .expect("number")
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

/// `--tracer` picks how the samples are traced, never what they are: every tracer writes the
/// same EXR bytes for the Cornell box, the scene the many-path tracer applies to.
#[test]
fn every_tracer_writes_the_same_exr() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut files = Vec::new();
    for tracer in ["auto", "scalar", "lanes4", "lanes8", "lanes16"] {
        let out = dir.path().join(format!("{tracer}.exr"));
        let r = tessera(&[
            "render",
            &repo("scenes/cornell-box.toml"),
            "--spp",
            "3",
            "--batch",
            "2",
            "--tracer",
            tracer,
            "--output",
            out.to_str().expect("utf8"),
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        files.push((tracer, std::fs::read(&out).expect("exr")));
    }
    for (tracer, bytes) in &files[1..] {
        assert!(bytes == &files[0].1, "--tracer {tracer} differs from auto");
    }
    let bad = tessera(&[
        "render",
        &repo("scenes/cornell-box.toml"),
        "--spp",
        "1",
        "--tracer",
        "lanes5",
        "--output",
        "x.exr",
    ]);
    assert_clean_failure(&bad, &["--tracer"]);
}
