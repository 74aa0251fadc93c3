//! Any bytes as a glTF scene, both as a `.glb` and as a `.gltf` (with the same bytes also
//! offered as its `scene.bin` buffer and `image.png`): building the scene must succeed or give
//! a one-line error, never panic, hang or allocate beyond the limits; and a scene that builds
//! must have finite bounds on every object it places.
#![no_main]

use std::collections::BTreeMap;

use libfuzzer_sys::fuzz_target;
use tessera_render::scene::assets::MemAssets;
use tessera_render::scene::{gltf_scene_text, Format, GltfOptions, Limits, Scene};

fuzz_target!(|data: &[u8]| {
    let limits = Limits {
        max_triangles: 1 << 16,
        max_asset_bytes: 1 << 20,
        ..Limits::default()
    };
    for name in ["scene.glb", "scene.gltf"] {
        let files = MemAssets(BTreeMap::from([
            (name.to_string(), data.to_vec()),
            ("scene.bin".to_string(), data.to_vec()),
            ("image.png".to_string(), data.to_vec()),
        ]));
        let text = gltf_scene_text(name, data, &GltfOptions::default());
        match Scene::text(&text, Format::Toml, name, &limits)
            .at(1)
            .assets(&files)
            .load()
        {
            Ok(scene) => {
                for p in &scene.prims {
                    let b = p.shape.bounds();
                    assert!(b.min.is_finite() && b.max.is_finite());
                }
            }
            Err(e) => {
                let line = e.to_string();
                assert!(!line.is_empty() && !line.contains('\n'), "{line:?}");
            }
        }
    }
});
