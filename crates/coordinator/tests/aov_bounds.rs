//! The farm's AOV bounds accept every result an honest worker gives: real meshes (a glTF
//! file with smooth normals and a normal map, PLY and OBJ meshes with vertex normals, a
//! textured OBJ, pbr with a normal map) rendered with every AOV, each tile's sums through
//! [`check_aov_sums`] as the coordinator runs it. A glTF job's honest workers were once
//! quarantined because a normalised f32 normal has components of 1 + 1 ulp.

use std::path::PathBuf;

use tessera_coordinator::job::check_aov_sums;
use tessera_render::scene::{Limits, Scene};
use tessera_render::{render_tile, Aovs, PixelRect, RenderSettings};

fn scene(name: &str) -> Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes")
        .join(name);
    Scene::file(&path, &Limits::default())
        .load()
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

#[test]
fn honest_aov_sums_of_real_meshes_pass_the_farms_check() {
    let settings = RenderSettings {
        seed: 7,
        spp: 4,
        batch: 2,
        aovs: Aovs::parse("albedo,normal,depth").expect("aovs"),
        ..RenderSettings::default()
    };
    for name in [
        "gltf/sample.glb",
        "gltf/metals.glb",
        "mesh-glass.toml",
        "cornell-mesh.toml",
        "textured.toml",
        "materials.toml",
    ] {
        let scene = scene(name);
        // Every fourth row of the frame, in two batches as units would be.
        for y in (0..scene.height).step_by(4) {
            let rect = PixelRect {
                x0: 0,
                y0: y,
                width: scene.width,
                height: 1,
            };
            for samples in [0..2, 2..4] {
                let sums = render_tile(&scene, &settings, rect, samples.clone());
                let aov = sums.aov.as_ref().expect("AOVs asked for");
                if let Err(e) = check_aov_sums(aov, 2) {
                    panic!("{name}, row {y}, samples {samples:?}: {e}");
                }
            }
        }
    }
}
