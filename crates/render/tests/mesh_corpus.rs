//! The mesh readers against a corpus nobody here wrote: every OBJ and PLY file of Debian's
//! `assimp-testmodels` (under /usr/share/assimp/models, installed by `.ci/run`) must load or
//! be refused with a one-line error naming the file, never panic; the files under `invalid/`
//! must be refused. Built only with the `corpus` feature, which requires the corpus.

use std::path::{Path, PathBuf};

use tessera_render::mesh::load::{load, MeshFormat};

const CORPUS: &str = "/usr/share/assimp/models";

fn mesh_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            mesh_files(&p, out);
        } else if MeshFormat::from_name(&p.to_string_lossy()).is_some() {
            out.push(p);
        }
    }
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
