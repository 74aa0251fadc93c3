//! Textures are decoded last, within a byte budget shared by the whole process (#55 C).
//!
//! Its own test binary, because the budget is the process's: the tests here change it, so
//! they take turns (`LOCK`) and no other test shares the process.

use std::path::Path;
use std::sync::Mutex;

use tessera_render::scene::{Limits, Scene};
use tessera_render::texture::{decode_bytes, DecodeBudget, DEFAULT_DECODE_BUDGET};

static LOCK: Mutex<()> = Mutex::new(());

/// A grey PNG of `w` × `h` zeros: tiny on disk, `w·h` texels to decode.
fn grey_png(w: u32, h: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut writer = enc.write_header().expect("header");
    writer
        .write_image_data(&vec![0u8; (w * h) as usize])
        .expect("data");
    writer.finish().expect("finish");
    out
}

/// The bundled textured scene with its texture replaced by `png`, and `shape` added as one
/// more object with the textured material.
fn scene_with_texture(dir: &Path, png: &[u8], shape: Option<&str>) -> std::path::PathBuf {
    std::fs::write(dir.join("big.png"), png).expect("png");
    let cornell = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/textured.toml"),
    )
    .expect("scene");
    let mut text = cornell.replace("textures/checker.png", "big.png");
    if let Some(shape) = shape {
        text.push_str(&format!("\n[[objects]]\n{shape}\nmaterial = \"checker\"\n"));
    }
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).expect("scene");
    let meshes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/meshes");
    std::os::unix::fs::symlink(meshes, dir.join("meshes")).expect("link the meshes");
    path
}

/// The attack: a 8192² all-zero PNG (tens of KB) as an analytic sphere's albedo. Before, the
/// image was decoded in full (1.85 GB) and only then was the scene refused. Now the refusal
/// comes first: with a budget far too small to decode it, the error is still the scene's.
#[cfg(unix)]
#[test]
fn a_scene_refused_for_its_shape_never_decodes_its_texture() {
    let _turn = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().expect("tmp");
    let png = grey_png(8192, 8192);
    assert!(png.len() < 1 << 20, "{} bytes", png.len());
    let scene = scene_with_texture(
        dir.path(),
        &png,
        Some("shape = \"sphere\"\ncenter = [0, 1, 0]\nradius = 0.2"),
    );
    let budget = DecodeBudget::global();
    budget.set_total(1 << 20);
    let e = Scene::file(&scene, &Limits::default())
        .load()
        .expect_err("no texture coordinates");
    budget.set_total(DEFAULT_DECODE_BUDGET);
    let e = e.to_string();
    assert!(e.contains("needs a mesh with texture coordinates"), "{e}");
    assert_eq!(budget.used(), 0);
}

/// A texture that fits the scene's texel limit but not the process's budget is refused with a
/// line naming the file, the bytes it needs and the budget; with the budget back, it loads.
#[cfg(unix)]
#[test]
fn a_texture_larger_than_the_budget_is_refused_by_name() {
    let _turn = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().expect("tmp");
    let scene = scene_with_texture(dir.path(), &grey_png(256, 256), None);
    let budget = DecodeBudget::global();
    budget.set_total(decode_bytes(256, 256) - 1);
    let e = Scene::file(&scene, &Limits::default())
        .load()
        .expect_err("over the budget");
    budget.set_total(DEFAULT_DECODE_BUDGET);
    let e = e.to_string();
    assert!(e.contains("big.png"), "{e}");
    assert!(e.contains("decode budget"), "{e}");
    assert!(e.contains(&(decode_bytes(256, 256) - 1).to_string()), "{e}");
    assert_eq!(e.lines().count(), 1, "{e}");
    Scene::file(&scene, &Limits::default())
        .load()
        .expect("loads within the budget");
    assert_eq!(budget.used(), 0);
}

/// Parses in parallel never hold more of the budget than it has: with room for one texture
/// at a time, eight threads loading the same textured scene decode one after another.
#[cfg(unix)]
#[test]
fn parallel_parses_share_the_budget_in_bytes() {
    let _turn = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().expect("tmp");
    let scene = scene_with_texture(dir.path(), &grey_png(1024, 1024), None);
    let one = decode_bytes(1024, 1024);
    let budget = DecodeBudget::global();
    budget.set_total(one);
    let peak = std::sync::atomic::AtomicU64::new(0);
    let done = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|s| {
        s.spawn(|| {
            while !done.load(std::sync::atomic::Ordering::Relaxed) {
                peak.fetch_max(budget.used(), std::sync::atomic::Ordering::Relaxed);
                std::thread::yield_now();
            }
        });
        let loads: Vec<_> = (0..8)
            .map(|_| s.spawn(|| Scene::file(&scene, &Limits::default()).load().map(|_| ())))
            .collect();
        for l in loads {
            l.join().expect("thread").expect("loads");
        }
        done.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    budget.set_total(DEFAULT_DECODE_BUDGET);
    let peak = peak.into_inner();
    assert!(peak > 0, "the budget was never used");
    assert!(peak <= one, "{peak} bytes reserved at once, budget {one}");
}

/// What a coordinator admits a job by (#79.12): `Load::check` decodes no image, so a
/// scene with an 8192² texture (1.85 GB to decode) is checked within a budget of 1 MiB, and
/// it says what the full build says of the scene's identity, size, files and bounds.
#[cfg(unix)]
#[test]
fn a_scene_is_checked_without_decoding_its_textures() {
    use tessera_render::scene::{assets::DirAssets, Format, FIRST_FRAME};
    let _turn = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().expect("tmp");
    let scene = scene_with_texture(dir.path(), &grey_png(8192, 8192), None);
    let text = std::fs::read_to_string(&scene).expect("text");
    let files = DirAssets(dir.path().to_path_buf());
    let limits = Limits::default();
    let check = |limits: &Limits| {
        Scene::text(&text, Format::Toml, "scene.toml", limits)
            .at(FIRST_FRAME)
            .assets(&files)
            .check()
    };
    let budget = DecodeBudget::global();
    budget.set_total(1 << 20);
    let checked = check(&limits);
    let refused = Scene::text(&text, Format::Toml, "s", &limits)
        .at(FIRST_FRAME)
        .assets(&files)
        .load()
        .map(|_| ())
        .expect_err("over the budget");
    budget.set_total(DEFAULT_DECODE_BUDGET);
    let checked = checked.expect("checked without decoding");
    assert!(refused.to_string().contains("big.png"), "{refused}");
    assert_eq!(budget.used(), 0);
    let built = Scene::text(&text, Format::Toml, "s", &limits)
        .at(FIRST_FRAME)
        .assets(&files)
        .load()
        .expect("built");
    assert_eq!(checked.hash, built.hash);
    assert_eq!((checked.width, checked.height), (built.width, built.height));
    assert_eq!(checked.files, built.files);
    assert_eq!(
        checked.bounds,
        tessera_render::guiding::guide_bounds(&built)
    );
    // The header is still read and checked.
    std::fs::write(dir.path().join("big.png"), b"not a png at all").expect("png");
    let e = check(&limits).expect_err("no image");
    assert!(e.to_string().contains("big.png"), "{e}");
}
