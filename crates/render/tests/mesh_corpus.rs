//! The mesh readers against a corpus nobody here wrote: every OBJ and PLY file of Debian's
//! `assimp-testmodels` (under /usr/share/assimp/models, installed by `.ci/run`) must load or
//! be refused with a one-line error naming the file, never panic; the files under `invalid/`
//! must be refused. Built only with the `corpus` feature, which requires the corpus.

use std::path::{Path, PathBuf};

use tessera_render::mesh::load::{load, MeshFormat};

const CORPUS: &str = "/usr/share/assimp/models";

/// The files under `dir`, at any depth, that `keep` keeps.
fn files_under(dir: &Path, keep: &dyn Fn(&Path) -> bool, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            files_under(&p, keep, out);
        } else if keep(&p) {
            out.push(p);
        }
    }
}

fn mesh_files(dir: &Path, out: &mut Vec<PathBuf>) {
    files_under(
        dir,
        &|p| MeshFormat::from_name(&p.to_string_lossy()).is_some(),
        out,
    );
}

#[test]
fn every_corpus_mesh_loads_or_is_refused_in_one_line() {
    let mut files = Vec::new();
    mesh_files(Path::new(CORPUS), &mut files);
    files.sort();
    assert!(
        files.len() >= 20,
        "{CORPUS} holds {} OBJ/PLY files: install Debian's assimp-testmodels (.ci/install-test-corpus.sh)",
        files.len()
    );
    let (mut loaded, mut refused) = (0, 0);
    for path in &files {
        let name = path.to_string_lossy().to_string();
        let bytes = std::fs::read(path).expect("corpus file reads");
        let format = MeshFormat::from_name(&name).expect("filtered above");
        let invalid = name.contains("/invalid/");
        match load(&name, &bytes, format, 1 << 24) {
            Ok(groups) => {
                assert!(!invalid, "{name}: an invalid file loaded");
                let tris: usize = groups.iter().map(|g| g.tris.len()).sum();
                assert!(tris > 0, "{name}");
                println!(
                    "loaded  {name}: {tris} triangles in {} groups",
                    groups.len()
                );
                loaded += 1;
            }
            Err(e) => {
                let line = e.to_string();
                assert!(!line.contains('\n'), "{name}: a multi-line error: {line:?}");
                assert!(
                    line.starts_with(&name),
                    "{name}: the error does not name it: {line}"
                );
                println!("refused {line}");
                refused += 1;
            }
        }
    }
    println!("{loaded} loaded, {refused} refused of {}", files.len());
    assert!(
        loaded > refused,
        "most of the corpus is valid: {loaded} loaded, {refused} refused"
    );
}

/// glTF files (`.gltf`, `.glb`) under `dir`.
fn gltf_files(dir: &Path, out: &mut Vec<PathBuf>) {
    files_under(dir, &tessera_render::scene::is_gltf, out);
}

/// Every glTF file of the corpus, as `tessera render FILE` reads it: either it builds and a
/// few samples of a block of it render to finite sums, or it is refused with one line naming
/// the file. The corpus's deliberately broken files (cycles, indices out of range, a missing
/// buffer, schema failures, wrong types, infinities, Draco) must be refused, its Khronos
/// samples must render, and glTF 1.0 files are refused as such.
#[test]
fn every_corpus_gltf_renders_or_is_refused_in_one_line() {
    use tessera_render::scene::{Limits, Scene};
    use tessera_render::{render_tile, PixelRect, RenderSettings};
    let mut files = Vec::new();
    gltf_files(Path::new(CORPUS), &mut files);
    files.sort();
    assert!(
        files.len() >= 40,
        "{CORPUS} holds {} glTF files: install Debian's assimp-testmodels (.ci/install-test-corpus.sh)",
        files.len()
    );
    let broken = [
        "IncorrectVertexArrays",
        "IndexOutOfRange",
        "MissingBin",
        "RecursiveNodes",
        "SchemaFailures",
        "wrongTypes",
        "BoxWithInfinites",
        "/draco/",
        "/glTF/",
    ];
    let good = [
        "glTF2/2CylinderEngine-glTF-Binary",
        "glTF2/BoxTextured-glTF/",
        "glTF2/BoxTextured-glTF-Binary",
        "glTF2/BoxTextured-glTF-Embedded",
        "glTF2/cameras/",
        "glTF2/textureTransform/",
        "glTF2/glTF-Sample-Models/AnimatedMorphCube",
    ];
    let settings = RenderSettings {
        spp: 2,
        batch: 2,
        ..RenderSettings::default()
    };
    let (mut rendered, mut refused) = (0, 0);
    for path in &files {
        let name = path.to_string_lossy().to_string();
        match Scene::file(path, &Limits::default()).load() {
            Ok(scene) => {
                assert!(
                    !broken.iter().any(|b| name.contains(b)),
                    "{name}: a broken file loaded"
                );
                let rect = PixelRect {
                    x0: scene.width / 2 - 16,
                    y0: scene.height / 2 - 16,
                    width: 32,
                    height: 32,
                };
                let sums = render_tile(&scene, &settings, rect, 0..2);
                assert!(sums.sum.iter().flatten().all(|x| x.is_finite()), "{name}");
                println!("rendered {name} ({} objects)", scene.prims.len());
                rendered += 1;
            }
            Err(e) => {
                let line = e.to_string();
                assert!(!line.contains('\n'), "{name}: a multi-line error: {line:?}");
                assert!(
                    line.starts_with(&name),
                    "{name}: the error does not name it: {line}"
                );
                assert!(
                    !good.iter().any(|g| name.contains(g)),
                    "{name}: a good file was refused: {line}"
                );
                if name.contains("/glTF/") {
                    assert!(line.contains("glTF 2.0"), "{line}");
                }
                println!("refused {line}");
                refused += 1;
            }
        }
    }
    println!("{rendered} rendered, {refused} refused of {}", files.len());
}
