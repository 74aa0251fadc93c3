//! Any bytes, as TOML and as JSON: the scene loader must return a scene or a positioned error,
//! never panic, and never take long (the limits keep builds small).
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera_render::scene::{Format, Limits, Scene};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let limits = Limits {
        max_resolution: 256,
        max_pixels: 256 * 256,
        max_objects: 256,
        max_bytes: 1 << 16,
        max_spp: 1024,
        ..Limits::default()
    };
    // A frame from the input too, so that `[animation]` keys are interpolated between, held
    // before the first and after the last.
    let frame = data.len() as u32 % 64;
    for format in [Format::Toml, Format::Json] {
        match Scene::text(text, format, "fuzz", &limits).at(frame).load() {
            Ok(scene) => {
                // A scene that loads must be renderable: trace one sample of its centre.
                let settings = tessera_render::RenderSettings {
                    spp: 1,
                    ..Default::default()
                };
                let (x, y) = (scene.width / 2, scene.height / 2);
                let sampler = tessera_render::sampling::PixelSampler::new(settings.seed, x, y, 0);
                let _ = tessera_render::integrator::sample_pixel(&scene, &settings, x, y, &sampler);
            }
            Err(e) => assert!(!e.to_string().is_empty()),
        }
    }
});
