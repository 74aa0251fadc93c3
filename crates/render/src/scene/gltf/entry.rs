//! A glTF file as a whole scene (`tessera render model.glb`): the scene text it stands for,
//! which names the file as its one object. The farm is sent that text and the file as an
//! asset, so a job's identity covers the file's bytes, and local and farm renders build the
//! same scene from the same text.

use std::fmt::Write as _;
use std::path::Path;

/// Width of a glTF file's image; its height follows the camera's aspect ratio (16:9 without
/// one).
pub const GLTF_WIDTH: u32 = 1280;

/// How a glTF file is rendered as a whole scene: what the command line may choose.
#[derive(Clone, Debug, Default)]
pub struct GltfOptions {
    /// A camera's name, or its index in the file's `cameras` (`--camera`).
    pub camera: Option<String>,
    /// An HDR environment map, named relative to the glTF file's directory
    /// (`--environment`), in place of the default light.
    pub environment: Option<String>,
}

/// Whether `path` names a glTF file (`.gltf` or `.glb`, by extension).
pub fn is_gltf(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
}

/// What [`scene_text`] reads of the glTF file at `path`: a .glb's JSON chunk alone, so that
/// its buffers, which may be gigabytes, are read once (by the build), or the whole file
/// otherwise (a .gltf is its JSON; a .glb whose header does not hold together is left for the
/// build to refuse). At most `max_bytes`.
pub fn json_part(path: &Path, max_bytes: u64) -> Result<Vec<u8>, String> {
    use std::io::Read as _;
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    let fail = |e: std::io::Error| format!("cannot read `{name}`: {e}");
    let mut f = std::fs::File::open(path).map_err(fail)?;
    let len = f.metadata().map_err(fail)?.len();
    let mut head = [0u8; 20];
    if len >= 20 && f.read_exact(&mut head).is_ok() && head.starts_with(b"glTF") {
        let json = u64::from(u32::from_le_bytes([head[12], head[13], head[14], head[15]]));
        if &head[16..20] == b"JSON" && json <= len - 20 && json <= max_bytes {
            let mut out = vec![0; json as usize];
            f.read_exact(&mut out).map_err(fail)?;
            return Ok(out);
        }
    }
    if len > max_bytes {
        return Err(format!(
            "`{name}` is {len} bytes, above the limit of {max_bytes}"
        ));
    }
    std::fs::read(path).map_err(fail)
}

/// The TOML scene that renders glTF file `name` (a name relative to the scene's directory,
/// whose content, or for a .glb whose JSON chunk, is `bytes`) as a whole scene: from its first camera, or `opts.camera`, or an
/// automatic framing without one; lit by its own lights, or by a uniform white sky when it has
/// neither punctual lights nor emissive materials (or by `opts.environment`). A file that
/// does not parse still gets a text: building it reports what is wrong.
pub fn scene_text(name: &str, bytes: &[u8], opts: &GltfOptions) -> String {
    let doc = super::parse(bytes).ok().map(|(d, _, _)| d);
    describe(name, doc.as_ref(), opts)
}

/// [`scene_text`] of the file's parsed document (`None`: it does not parse).
pub(in crate::scene) fn describe(
    name: &str,
    doc: Option<&gltf::Document>,
    opts: &GltfOptions,
) -> String {
    let quote = |s: &str| toml::Value::String(s.to_string()).to_string();
    let mut camera_key = String::new();
    let mut aspect = None;
    if let Some(doc) = doc {
        let placed: Vec<usize> = doc
            .nodes()
            .filter_map(|n| n.camera().map(|c| c.index()))
            .collect();
        let chosen = match &opts.camera {
            Some(c) => doc
                .cameras()
                .find(|cam| cam.name() == Some(c.as_str()))
                .map(|cam| cam.index())
                .or_else(|| c.parse::<usize>().ok()),
            None => placed.iter().min().copied(),
        };
        // From the JSON: `Camera::projection` may panic on a camera the build refuses.
        if let Some(c) = chosen.and_then(|i| doc.as_json().cameras.get(i)) {
            aspect = match (&c.perspective, &c.orthographic) {
                (Some(p), _) => p.aspect_ratio,
                (None, Some(o)) => Some(o.xmag / o.ymag),
                (None, None) => None,
            }
            .filter(|a| a.is_finite() && *a > 0.01 && *a < 100.0);
        }
    }
    if let Some(c) = &opts.camera {
        let by_name = doc.is_some_and(|d| d.cameras().any(|cam| cam.name() == Some(c.as_str())));
        camera_key = match c.parse::<usize>() {
            Ok(i) if !by_name => format!("index = {i}\n"),
            _ => format!("name = {}\n", quote(c)),
        };
    }
    let height = aspect.map_or(720, |a| ((GLTF_WIDTH as f32 / a).round() as u32).max(1));
    let lit = doc.is_some_and(|d| {
        d.nodes().any(|n| n.light().is_some())
            || d.materials()
                .any(|m| m.emissive_factor().iter().any(|&e| e > 0.0))
    });
    let mut text = String::new();
    let _ = writeln!(
        text,
        "# The scene `tessera render {name}` renders (docs/scene-format.md, \"glTF files\").\n\
         version = 1\n\n[camera]\nmodel = \"gltf\"\n{camera_key}\n[film]\nwidth = {GLTF_WIDTH}\n\
         height = {height}\n"
    );
    match &opts.environment {
        Some(map) => {
            let _ = writeln!(
                text,
                "[environment]\ntype = \"map\"\nfile = {}\n",
                quote(map)
            );
        }
        None if !lit => {
            text.push_str("[environment]\ntype = \"constant\"\nradiance = [1, 1, 1]\n\n");
        }
        None => {}
    }
    let _ = writeln!(
        text,
        "[[objects]]\nshape = \"gltf\"\nfile = {}",
        quote(name)
    );
    text
}
