//! The HTTP API's pipeline script, run exactly as docs/farm.md shows it (its Python, with only
//! the standard library), against the real `tessera coordinator --http` with a token and a real
//! worker: the EXR it downloads must be `tessera render`'s bytes.

use std::process::Command;

mod common;

use common::{repo, worker_with, BIN};

/// The first block of `lang` after the heading `heading` in docs/farm.md.
fn block(heading: &str, lang: &str) -> String {
    let doc = std::fs::read_to_string(repo("docs/farm.md")).expect("docs/farm.md");
    let after = doc
        .split_once(heading)
        .unwrap_or_else(|| panic!("no {heading:?} in docs/farm.md"))
        .1;
    let start = format!("```{lang}\n");
    let body = after.split_once(&start).expect("a code block").1;
    body.split_once("\n```")
        .expect("the block's end")
        .0
        .to_string()
}

// Long because it is one scenario, its steps in the order they happen to the farm (each
// step's state is the next one's start); split into functions, that order would be hidden.
#[test]
fn the_documented_python_pipeline_submits_a_mesh_scene_and_gets_tessera_renders_bits() {
    let dir = tempfile::tempdir().expect("tmp");
    let token = "pipeline-token-0123456789abcdef";
    let token_file = common::private_file(dir.path(), "token", token);
    let token_arg = token_file.to_str().expect("utf8");
    let (coord, grpc, dash) =
        common::coordinator_with_dashboard(&dir.path().join("data"), &["--token-file", token_arg]);
    let log = dir.path().join("worker.log");
    let w = worker_with(&grpc, "py", &["--token-file", token_arg], &log);

    // The script and its command, as the docs give them; only the address is this run's.
    let script = dir.path().join("pipeline.py");
    std::fs::write(&script, block("### The HTTP API for pipelines", "python")).expect("script");
    let commands = block("Saved as `pipeline.py`", "sh");
    let lines: Vec<Vec<&str>> = commands
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(
        lines,
        [
            [
                "python3",
                "pipeline.py",
                "http://127.0.0.1:7880",
                "scenes/cornell-mesh.toml",
                "16",
                "mesh.exr"
            ],
            [
                "python3",
                "pipeline.py",
                "http://127.0.0.1:7880",
                "scenes/gltf/sample.glb",
                "2",
                "sample.exr"
            ]
        ],
        "docs/farm.md's commands changed: {commands}"
    );
    let words = &lines[0];
    // The script as the command runs it, writing to `out`, with the token in the environment
    // or without it.
    let run_line = |words: &[&str], out: &std::path::Path, token: Option<&str>| {
        let mut cmd = Command::new("python3");
        cmd.arg(&script)
            .arg(&dash)
            .args([words[3], words[4]])
            .arg(out)
            .current_dir(repo(""))
            .env_remove("TESSERA_TOKEN");
        if let Some(t) = token {
            cmd.env("TESSERA_TOKEN", t);
        }
        cmd.output()
            .expect("python3 (Debian's python3 package) runs the pipeline script")
    };
    let pipeline = |out: &std::path::Path, token: Option<&str>| run_line(words, out, token);
    let out_exr = dir.path().join("mesh.exr");
    let run = pipeline(&out_exr, Some(token));
    assert!(
        run.status.success(),
        "the pipeline script failed: {}{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    let said = String::from_utf8_lossy(&run.stdout);
    assert!(
        said.contains("submitted job-") && said.contains("wrote"),
        "{said}"
    );

    let local = dir.path().join("local.exr");
    let render = Command::new(BIN)
        .args([
            "render",
            &repo("scenes/cornell-mesh.toml"),
            "--spp",
            "16",
            "--output",
        ])
        .arg(&local)
        .output()
        .expect("render");
    assert!(
        render.status.success(),
        "{}",
        String::from_utf8_lossy(&render.stderr)
    );
    assert!(
        std::fs::read(&out_exr).expect("the script's EXR") == std::fs::read(&local).expect("local"),
        "the EXR the pipeline script downloaded differs from tessera render's"
    );

    // Run again, with the mesh already held (the script asks before it uploads).
    let again = pipeline(&dir.path().join("again.exr"), Some(token));
    assert!(
        again.status.success(),
        "{}",
        String::from_utf8_lossy(&again.stderr)
    );
    // Without the token, the API answers with its JSON error, which the script prints.
    let refused = pipeline(&dir.path().join("never.exr"), None);
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("unauthenticated"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    // The glTF file (a .glb with its textures inside), as `tessera submit` sends it.
    let glb = &lines[1];
    let farm_glb = dir.path().join("sample.exr");
    let run = run_line(glb, &farm_glb, Some(token));
    assert!(
        run.status.success(),
        "the pipeline script failed on the glTF file: {}{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    let local_glb = dir.path().join("local-sample.exr");
    let render = Command::new(BIN)
        .args(["render", &repo(glb[3]), "--spp", glb[4], "--output"])
        .arg(&local_glb)
        .output()
        .expect("render");
    assert!(
        render.status.success(),
        "{}",
        String::from_utf8_lossy(&render.stderr)
    );
    assert!(
        std::fs::read(&farm_glb).expect("the script's EXR")
            == std::fs::read(&local_glb).expect("local"),
        "the glTF EXR the pipeline script downloaded differs from tessera render's"
    );
    drop(w);
    drop(coord);
}
