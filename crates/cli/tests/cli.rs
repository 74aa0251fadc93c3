//! Drives the real `tessera` binary, as a user would.

mod common;

use std::path::Path;

use common::{assert_clean_failure, repo, tessera, tessera_at, write};
use std::process::Command;

use tessera_render::output::{read_exr_channel, read_exr_metadata, read_exr_rgb};

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

// Long because it is a table of cases, one refusal each, read top to bottom.
#[test]
fn bad_flags_and_paths_are_refused() {
    let scene = repo("scenes/cornell-box.toml");
    for bad in ["0", "4095", "many", "17179869185"] {
        assert_clean_failure(
            &tessera(&[
                "render",
                &scene,
                "--spp",
                "4",
                "--unit-samples",
                bad,
                "--output",
                "x.exr",
            ]),
            &["--unit-samples"],
        );
    }
    for bad in ["-1", "NaN", "3601"] {
        assert_clean_failure(
            &tessera(&[
                "coordinator",
                "--listen",
                "127.0.0.1:0",
                "--data-dir",
                "/nonexistent/tessera-data",
                &format!("--checkpoint-interval={bad}"),
            ]),
            &["--checkpoint-interval"],
        );
    }
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
    for bad in ["1.5", "-0.1", "NaN"] {
        let bad = format!("--audit={bad}");
        assert_clean_failure(
            &tessera(&["coordinator", "--data-dir", "/nonexistent-dir/d", &bad]),
            &["--audit must be a fraction between 0 and 1"],
        );
    }
    // Every flag of seconds, one helper for all (`Duration::from_secs_f64` panics on these).
    for (flag, range) in [
        ("--asset-retention", "0 and 1e9"),
        ("--retry-window", "0 and 1e9"),
        ("--log-retention", "0 and 1e9"),
        ("--job-retention", "0 and 1e9"),
        ("--lease-timeout", "0.1 and 86400"),
        ("--checkpoint-interval", "0 and 3600"),
    ] {
        for bad in ["-1", "NaN", "inf"] {
            let bad = format!("{flag}={bad}");
            let said = format!("{flag} must be between {range} seconds");
            assert_clean_failure(
                &tessera(&["coordinator", "--data-dir", "/nonexistent-dir/d", &bad]),
                &[&said],
            );
        }
    }
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

/// Without the `bench` feature, `tessera bench` says how to build a tessera that has it.
#[cfg(not(feature = "bench"))]
#[test]
fn bench_says_how_to_build_it_where_it_is_left_out() {
    let r = tessera(&["bench", "--max-spp", "16"]);
    assert_clean_failure(&r, &["without the benchmark harness", "--features bench"]);
    // `loadtest` too (it was "unrecognized subcommand"), and asking for help is no failure.
    let r = tessera(&["loadtest", "--workers", "10"]);
    assert_clean_failure(&r, &["without the benchmark harness", "--features bench"]);
    for cmd in ["bench", "loadtest"] {
        let r = tessera(&[cmd, "--help"]);
        assert!(r.status.success(), "tessera {cmd} --help: {:?}", r.status);
        assert!(String::from_utf8_lossy(&r.stdout).contains("--features bench"));
    }
}

/// #55: a bad coordinator URL is named once (it was "coordinator URL "x": coordinator URL
/// "x": …" from the worker), and one render thread is "1 thread".
#[test]
fn messages_say_things_once_and_in_the_right_number() {
    for cmd in [&["status"][..], &["worker"]] {
        let mut args = cmd.to_vec();
        args.extend(["--coordinator", "x:1"]);
        let r = tessera(&args);
        assert_clean_failure(&r, &["must start with http://"]);
        let stderr = String::from_utf8_lossy(&r.stderr);
        assert_eq!(stderr.matches("coordinator URL").count(), 1, "{stderr}");
    }
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("o.exr");
    let r = tessera(&[
        "render",
        &repo("scenes/spheres.toml"),
        "--spp",
        "1",
        "--threads",
        "1",
        "--output",
        out.to_str().expect("utf8"),
    ]);
    assert!(r.status.success());
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(stdout.contains(" on 1 thread:"), "{stdout}");
}

/// `--tracer` picks how the samples are traced, never what they are: every tracer writes the
/// same EXR bytes for the Cornell box, the scene the many-path tracer applies to.
#[test]
fn every_tracer_writes_the_same_exr() {
    let dir = tempfile::tempdir().expect("tmp");
    // The lanes alone; with glass and mirrors stepped lane by lane; under a sky, which only
    // --tracer lanesN takes to the lanes.
    for scene in ["cornell-box", "glass-mirror", "envmap-balls"] {
        let mut files = Vec::new();
        for tracer in ["auto", "scalar", "lanes4", "lanes8", "lanes16"] {
            let out = dir.path().join(format!("{scene}-{tracer}.exr"));
            let r = tessera(&[
                "render",
                &repo(&format!("scenes/{scene}.toml")),
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
            assert!(
                bytes == &files[0].1,
                "{scene}: --tracer {tracer} differs from auto"
            );
        }
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

#[test]
fn noise_targets_and_frames_reach_the_exr_header() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("a.exr");
    let o = out.to_str().expect("utf8");
    let r = tessera(&[
        "render",
        &repo("scenes/cornell-box.toml"),
        "--spp",
        "256",
        "--noise-target",
        "0.5",
        "--tile-size",
        "64",
        "--sample-count",
        "--output",
        o,
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert!(
        stdout.contains("spp on average (noise target 0.5, cap 256)"),
        "{stdout}"
    );
    let meta = read_exr_metadata(&out).expect("metadata");
    for m in ["noise_target=0.5", "adaptive_tile=64", "spp=256"] {
        assert!(meta.iter().any(|x| x == m), "{m}: {meta:?}");
    }
    let r = tessera(&[
        "render",
        &repo("scenes/cornell-animated.toml"),
        "--spp",
        "1",
        "--frame",
        "12",
        "--output",
        o,
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let meta = read_exr_metadata(&out).expect("metadata");
    assert!(meta.iter().any(|x| x == "frame=12"), "{meta:?}");
    let scene = repo("scenes/cornell-box.toml");
    for (value, want) in [
        ("0", "noise target 0 must be"),
        ("2", "between"),
        ("lots", "not a number"),
    ] {
        assert_clean_failure(
            &tessera(&[
                "render",
                &scene,
                "--spp",
                "4",
                "--noise-target",
                value,
                "--output",
                o,
            ]),
            &["--noise-target", want],
        );
    }
}

/// #55: for a scene whose files are bad, `submit` printed only "`X` is not among the files
/// sent with the job"; now it prints the cause, as `render` does, before connecting anywhere.
#[test]
fn submit_names_a_bad_file_as_render_does() {
    let dir = tempfile::tempdir().expect("tmp");
    let cube = std::fs::read_to_string(repo("scenes/meshes/cube.obj")).expect("cube");
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
               property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n";
    std::fs::write(dir.path().join("truncated.ply"), ply).expect("ply");
    std::fs::write(
        dir.path().join("bad-index.obj"),
        format!("{cube}\nf 1 2 99\n"),
    )
    .expect("obj");
    std::fs::create_dir(dir.path().join("dir.png")).expect("dir");
    let base = std::fs::read_to_string(repo("scenes/textured.toml")).expect("scene");
    for d in ["meshes", "textures"] {
        std::os::unix::fs::symlink(repo(&format!("scenes/{d}")), dir.path().join(d)).expect("link");
    }
    let cases = [
        ("missing", base.replace("meshes/", "nowhere/"), "nowhere/"),
        (
            "truncated",
            format!("{base}\n[[objects]]\nshape = \"mesh\"\nfile = \"truncated.ply\"\nmaterial = \"checker\"\n"),
            "truncated.ply",
        ),
        (
            "index",
            format!("{base}\n[[objects]]\nshape = \"mesh\"\nfile = \"bad-index.obj\"\nmaterial = \"checker\"\n"),
            "bad-index.obj",
        ),
        (
            "directory",
            base.replace("textures/checker.png", "dir.png"),
            "`dir.png` is not a file",
        ),
    ];
    for (what, text, names) in cases {
        let scene = write(dir.path(), &format!("{what}.toml"), &text);
        let out = dir.path().join("o.exr");
        let render = tessera(&[
            "render",
            &scene,
            "--spp",
            "1",
            "--output",
            out.to_str().expect("utf8"),
        ]);
        assert_clean_failure(&render, &[]);
        let said = String::from_utf8_lossy(&render.stderr).trim().to_string();
        let submit = tessera_at(&["submit", &scene, "--spp", "1"], "http://127.0.0.1:9");
        assert_clean_failure(&submit, &[]);
        let stderr = String::from_utf8_lossy(&submit.stderr);
        assert!(!stderr.contains("not among the files"), "{what}: {stderr}");
        // The same cause, whatever each command puts before it.
        assert!(said.contains(names), "{what}: render said {said:?}");
        let cause = said.rsplit(": ").next().expect("a cause");
        assert!(
            stderr.contains(cause),
            "{what}: render said {said:?}, submit {stderr:?}"
        );
        assert!(stderr.contains(names), "{what}: {stderr:?}");
    }
}

#[test]
fn render_writes_the_aovs_it_is_asked_for_and_names_one_it_does_not_know() {
    let dir = tempfile::tempdir().expect("tmp");
    let plain = dir.path().join("plain.exr");
    let out = dir.path().join("aov.exr");
    let scene = repo("scenes/cornell-box.toml");
    for (path, aov) in [(&plain, None), (&out, Some("albedo,normal,depth"))] {
        let mut args = vec![
            "render",
            &scene,
            "--spp",
            "2",
            "--output",
            path.to_str().expect("utf8"),
        ];
        args.extend(aov.iter().flat_map(|a| ["--aov", *a]));
        let r = tessera(&args);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    // The beauty is the same with or without them.
    for c in ["R", "G", "B"] {
        let (a, b) = (
            read_exr_channel(&plain, c).expect("plain"),
            read_exr_channel(&out, c).expect("aov"),
        );
        assert!(a == b, "channel {c} changed");
    }
    let albedo = read_exr_channel(&out, "albedo.R").expect("albedo.R");
    assert!(albedo.iter().all(|v| (0.0..=1.0).contains(v)));
    assert!(albedo.iter().any(|v| *v > 0.1), "a lit box has some albedo");
    let (nx, ny, nz) = (
        read_exr_channel(&out, "normal.X").expect("normal.X"),
        read_exr_channel(&out, "normal.Y").expect("normal.Y"),
        read_exr_channel(&out, "normal.Z").expect("normal.Z"),
    );
    for i in 0..nx.len() {
        let len2 = nx[i] * nx[i] + ny[i] * ny[i] + nz[i] * nz[i];
        assert!(len2 <= 1.0 + 1e-4, "pixel {i}: |n|² = {len2}");
    }
    let z = read_exr_channel(&out, "Z").expect("Z");
    // Depth is a distance, or +∞ where no sample met a surface (past the box's open front).
    assert!(z.iter().all(|d| *d > 0.0 && !d.is_nan()));
    let met = z.iter().filter(|d| d.is_finite()).count();
    assert!(
        met * 10 > z.len() * 9,
        "{met} of {} pixels met the box",
        z.len()
    );
    assert!(read_exr_metadata(&out)
        .expect("meta")
        .contains(&"aovs=albedo,normal,depth".to_string()));
    let e = read_exr_channel(&plain, "Z").expect_err("no AOVs asked for");
    assert!(e.to_string().contains("no channel \"Z\""), "{e}");
    let bad = tessera(&[
        "render",
        &scene,
        "--aov",
        "albedo,mist",
        "--output",
        dir.path().join("x.exr").to_str().expect("utf8"),
    ]);
    assert_clean_failure(&bad, &["--aov", "\"mist\""]);
}

/// A glTF file is a scene: `--camera` picks its camera by name, `--environment` lights it by
/// an HDR map (named relative to the working directory, as a user types it, and inside the
/// glTF file's folder, as every file a scene reads is), and both flags are refused for a TOML
/// scene, whose text says its own camera and light; a broken glTF file is refused in one line
/// naming it.
#[test]
fn gltf_files_render_with_their_camera_and_an_environment() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("g.exr");
    let out = out.to_str().expect("utf8");
    let model = dir.path().join("model");
    std::fs::create_dir(&model).expect("mkdir");
    std::fs::copy(repo("scenes/gltf/sample.glb"), model.join("sample.glb")).expect("copy");
    std::fs::copy(repo("scenes/textures/sky.exr"), model.join("sky.exr")).expect("copy");
    let sample = model.join("sample.glb").to_str().expect("utf8").to_string();
    let sky = model.join("sky.exr").to_str().expect("utf8").to_string();
    // A map outside the glTF file's folder is refused before anything is read.
    let outside = repo("scenes/textures/sky.exr");
    let r = tessera(&[
        "render",
        &sample,
        "--spp",
        "1",
        "--output",
        out,
        "--environment",
        &outside,
    ]);
    assert_clean_failure(
        &r,
        &["--environment", "must be inside the glTF file's folder"],
    );
    let r = tessera(&[
        "render",
        &sample,
        "--spp",
        "1",
        "--output",
        out,
        "--camera",
        "main",
        "--environment",
        &sky,
        "--threads",
        "2",
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let img = read_exr_rgb(Path::new(out)).expect("valid EXR");
    assert_eq!((img.width, img.height), (1280, 720));
    let r = tessera(&[
        "render", &sample, "--spp", "1", "--output", out, "--camera", "nowhere",
    ]);
    assert_clean_failure(
        &r,
        &[
            "sample.glb: camera.name: no glTF camera is named \"nowhere\"",
            "main",
        ],
    );
    let toml = repo("scenes/cornell-box.toml");
    let r = tessera(&[
        "render", &toml, "--spp", "1", "--output", out, "--camera", "main",
    ]);
    assert_clean_failure(&r, &["--camera is for glTF scenes"]);
    let bad = dir.path().join("bad.glb");
    std::fs::write(&bad, b"glTF\x02\0\0\0\xff\xff\xff\xff").expect("write");
    let r = tessera(&[
        "render",
        bad.to_str().expect("utf8"),
        "--spp",
        "1",
        "--output",
        out,
    ]);
    assert_clean_failure(&r, &["bad.glb: the GLB header gives a length"]);
}

/// #60: `render --guiding` renders in epochs, says so and in the EXR's header, and gives the
/// same file bytes on one thread and two; it refuses --noise-target, naming both flags.
#[test]
fn guided_renders_say_so_and_are_the_same_bytes_on_any_threads() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut files = Vec::new();
    for threads in ["1", "2"] {
        let out = dir.path().join(format!("g{threads}.exr"));
        let o = out.to_str().expect("utf8");
        let r = tessera(&[
            "render",
            &repo("scenes/caustic.toml"),
            "--spp",
            "8",
            "--guiding",
            "--threads",
            threads,
            "--output",
            o,
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let stdout = String::from_utf8_lossy(&r.stdout);
        assert!(
            stdout.contains("at 8 spp, 3 guided epochs (largest guide sampled: "),
            "{stdout}"
        );
        let meta = read_exr_metadata(&out).expect("metadata");
        assert!(meta.iter().any(|x| x == "guiding=sd-tree"), "{meta:?}");
        files.push(std::fs::read(&out).expect("exr"));
    }
    assert!(
        files[0] == files[1],
        "the same guided render differs by thread count"
    );
    let bad = tessera(&[
        "render",
        &repo("scenes/caustic.toml"),
        "--guiding",
        "--noise-target",
        "0.1",
        "--output",
        "x.exr",
    ]);
    assert_clean_failure(&bad, &["--guiding", "--noise-target"]);
}

/// A glTF file may read only files inside its own folder: a buffer or image URI that climbs
/// out (`../secret/id_rsa`), percent-encoded or not, or that is absolute, is refused by
/// `tessera render` and by `tessera submit` before anything is read or uploaded, naming the
/// URI and where it is; a TOML scene's `file` alike.
#[test]
fn scene_files_may_not_read_outside_their_folder() {
    let dir = tempfile::tempdir().expect("tmp");
    let secret = dir.path().join("secret");
    std::fs::create_dir(&secret).expect("mkdir");
    std::fs::write(secret.join("id_rsa"), b"PRIVATE KEY").expect("write");
    std::fs::write(
        secret.join("key.obj"),
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .expect("write");
    let model = dir.path().join("model");
    std::fs::create_dir(&model).expect("mkdir");
    let out = dir.path().join("o.exr");
    let out = out.to_str().expect("utf8");
    let abs = secret.join("id_rsa");
    let abs = abs.to_str().expect("utf8");
    for (uri, said) in [
        ("../secret/id_rsa", "climbs out"),
        ("..%2Fsecret%2Fid_rsa", "decodes to `../secret/id_rsa`"),
        (&abs.replace('/', "%2F"), "absolute"),
        (&format!("file://{abs}"), "scheme"),
    ] {
        let gltf = format!(
            r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"uri":"{uri}","byteLength":4}}]}}"#
        );
        let file = common::write(&model, "evil.gltf", &gltf);
        let r = tessera(&["render", &file, "--spp", "1", "--output", out]);
        assert_clean_failure(&r, &["evil.gltf: /buffers/0/uri: ", said]);
        // Refused before it connects anywhere (nothing listens there) or reads the file.
        let r = tessera_at(&["submit", &file, "--spp", "1"], "http://127.0.0.1:9");
        assert_clean_failure(&r, &["evil.gltf: /buffers/0/uri: ", said]);
        assert!(!String::from_utf8_lossy(&r.stderr).contains("uploaded"));
    }
    let toml = common::write(
        &model,
        "evil.toml",
        "version = 1\n[camera]\nmodel = \"look_at\"\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n\
         fov = 40\n[film]\nwidth = 8\nheight = 8\n[materials.m]\ntype = \"diffuse\"\n\
         albedo = [0.5, 0.5, 0.5]\n[[objects]]\nshape = \"mesh\"\nfile = \"../secret/key.obj\"\n\
         material = \"m\"\n",
    );
    let r = tessera(&["render", &toml, "--spp", "1", "--output", out]);
    assert_clean_failure(&r, &["evil.toml", "objects[0].file", "climbs out"]);
}

/// One sample per pixel gives no pixel variance: the summary says the noise is not estimated
/// rather than σ≈0 (the noisiest image there is once read as clean); two samples estimate it.
#[test]
fn one_sample_per_pixel_says_its_noise_is_not_estimated() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("o.exr");
    let out = out.to_str().expect("utf8");
    let scene = repo("scenes/cornell-box.toml");
    for (spp, said) in [("1", "noise not estimated"), ("2", "noise σ≈")] {
        let r = tessera(&[
            "render",
            &scene,
            "--spp",
            spp,
            "--output",
            out,
            "--threads",
            "2",
        ]);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let stdout = String::from_utf8_lossy(&r.stdout);
        assert!(stdout.contains(said), "--spp {spp}: {stdout}");
    }
}
