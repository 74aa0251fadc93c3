//! The one way to load a scene: [`Load`], made by [`Scene::file`] (a TOML, JSON or glTF file
//! on disk) or [`Scene::text`] (a scene's text, as a farm job carries it), told the shot, the
//! glTF options and where the files the scene names come from, then built
//! ([`Load::load`]) or only checked ([`Load::check`], what a coordinator admits a job by).

use std::borrow::Cow;
use std::path::Path;
use std::sync::Mutex;

use super::assets::{self, Assets};
use super::parse::{at_start, io_error, locate, parse};
use super::{
    animate, build, format, gltf, gltf_scene_text, is_gltf, shape_bounds, Format, GltfOptions,
    KeyPath, Limits, Scene, SceneCheck, SceneError, Shot, FIRST_FRAME,
};

/// Where a scene comes from.
#[derive(Clone, Copy)]
enum Source<'a> {
    /// A file on disk: the files it names are read beside it.
    File(&'a Path),
    /// A scene's text, `file` naming it in errors.
    Text {
        text: &'a str,
        format: Format,
        file: &'a str,
    },
}

/// A scene to load: where from, within which limits, at which shot, with which glTF options,
/// and where the files it names come from. Defaults: the first frame at the file's own
/// resolution, glTF's defaults, and the files beside a scene file (none for a text).
#[must_use = "a Load does nothing until `.load()` or `.check()`"]
pub struct Load<'a> {
    source: Source<'a>,
    limits: &'a Limits,
    shot: Shot,
    gltf: Option<&'a GltfOptions>,
    assets: Option<&'a dyn Assets>,
}

impl Scene {
    /// The scene file at `path` (TOML, JSON, or a glTF file as a whole scene), to load.
    pub fn file<'a>(path: &'a Path, limits: &'a Limits) -> Load<'a> {
        Load::new(Source::File(path), limits)
    }

    /// The scene whose text is `text`, in `format`, named `file` in errors, to load.
    pub fn text<'a>(text: &'a str, format: Format, file: &'a str, limits: &'a Limits) -> Load<'a> {
        Load::new(Source::Text { text, format, file }, limits)
    }
}

impl<'a> Load<'a> {
    fn new(source: Source<'a>, limits: &'a Limits) -> Self {
        Self {
            source,
            limits,
            shot: FIRST_FRAME.into(),
            gltf: None,
            assets: None,
        }
    }

    /// At `shot`: a frame of the scene's `[animation]` (a scene without one is the same at
    /// every frame), and a resolution in place of the file's.
    pub fn at(mut self, shot: impl Into<Shot>) -> Self {
        self.shot = shot.into();
        self
    }

    /// A glTF file rendered as a whole scene as `gltf` says (its camera, its light).
    pub fn gltf(mut self, gltf: &'a GltfOptions) -> Self {
        self.gltf = Some(gltf);
        self
    }

    /// The files the scene names (meshes, textures, glTF files) read from `assets`.
    pub fn assets(mut self, assets: &'a dyn Assets) -> Self {
        self.assets = Some(assets);
        self
    }

    /// Reads, parses, validates and builds the scene.
    pub fn load(self) -> Result<Scene, SceneError> {
        if let (Source::File(path), None) = (self.source, self.assets) {
            if is_gltf(path) {
                return self.gltf_file(path);
            }
        }
        let t = self.text()?;
        let files = self.files(&t);
        let place = |p: &KeyPath, m| locate(&t.text, t.format, &t.file, p, m);
        let (limits, shot) = (self.limits, self.shot);
        from_text(
            &t.text, t.format, &t.file, limits, shot, files, None, &place,
        )
    }

    /// The scene's text: its own, a file's, or the scene a glTF file stands for.
    fn text(&self) -> Result<Text<'a>, SceneError> {
        Ok(match self.source {
            Source::Text { text, format, file } => Text {
                text: text.into(),
                format,
                file: file.into(),
                beside: None,
            },
            Source::File(path) => {
                let gltf = self.gltf.cloned().unwrap_or_default();
                let (text, format) = scene_source(path, &gltf, self.limits)?;
                Text {
                    text: text.into(),
                    format,
                    file: path.display().to_string().into(),
                    beside: Some(beside(path)),
                }
            }
        })
    }

    /// Where the files the scene names come from: those given, else a file's directory.
    fn files<'t>(&'t self, t: &'t Text<'a>) -> &'t dyn Assets {
        match (self.assets, &t.beside) {
            (Some(a), _) => a,
            (None, Some(b)) => b,
            (None, None) => &assets::NoAssets,
        }
    }

    /// A glTF file as a whole scene, read and parsed once: its document gives the scene text
    /// it stands for (what a farm job of it carries), and is lent to the build that imports
    /// it. A file that cannot be read or parsed is left for the build to refuse, as any
    /// scene's file is.
    fn gltf_file(&self, path: &Path) -> Result<Scene, SceneError> {
        let file = &path.display().to_string();
        let beside = &beside(path);
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let gltf = self.gltf.cloned().unwrap_or_default();
        let bytes = beside
            .read(&name, self.limits.max_asset_bytes)
            .map_err(|m| at_start(file, m))?;
        let lent = gltf::Lent::parse(&name, &bytes).ok();
        let text = gltf::describe(&name, lent.as_ref().map(gltf::Lent::doc), &gltf);
        let held = Held {
            name: &name,
            bytes: Mutex::new(Some(bytes)),
            beside,
        };
        let place = |p: &KeyPath, m| in_gltf(file, p, m);
        let (limits, shot) = (self.limits, self.shot);
        from_text(&text, Format::Toml, file, limits, shot, &held, lent, &place)
    }

    /// What [`Load::load`] would build, checked as it checks it but with no image decoded and
    /// no BVH built: what a coordinator admits a job by, at a fraction of the memory (an
    /// image's header gives its size; its pixels are the workers' to decode).
    pub fn check(self) -> Result<SceneCheck, SceneError> {
        let t = self.text()?;
        let text = &t.text;
        let place = |p: &KeyPath, m| locate(text, t.format, &t.file, p, m);
        let (limits, shot, files) = (self.limits, self.shot, self.files(&t));
        let assembled = assemble(text, t.format, &t.file, limits, shot, files, None, &place)?;
        let (width, height) = assembled.film();
        let read = assembled.files_read().to_vec();
        Ok(SceneCheck {
            hash: assets::scene_hash(text, &read),
            width,
            height,
            files: read,
            bounds: shape_bounds(assembled.prims()),
            denoise: assembled.denoise().cloned(),
        })
    }
}

/// A scene's text, its syntax, the name errors give it, and the directory of the file it was
/// read from.
struct Text<'a> {
    text: Cow<'a, str>,
    format: Format,
    file: Cow<'a, str>,
    beside: Option<assets::DirAssets>,
}

/// The files beside the scene file at `path`.
fn beside(path: &Path) -> assets::DirAssets {
    assets::DirAssets(path.parent().unwrap_or(Path::new("")).into())
}

/// The files beside a glTF file, with that file's bytes already read: the build takes them
/// rather than read the file again.
struct Held<'a> {
    name: &'a str,
    bytes: Mutex<Option<Vec<u8>>>,
    beside: &'a assets::DirAssets,
}

impl Assets for Held<'_> {
    fn read(&self, name: &str, max_bytes: u64) -> Result<Vec<u8>, String> {
        if name == self.name {
            let held = self.bytes.lock().unwrap_or_else(|p| p.into_inner()).take();
            if let Some(b) = held.filter(|b| b.len() as u64 <= max_bytes) {
                return Ok(b);
            }
        }
        self.beside.read(name, max_bytes)
    }
}

/// A scene built from its text.
#[allow(clippy::too_many_arguments)]
fn from_text(
    text: &str,
    format: Format,
    file: &str,
    limits: &Limits,
    shot: Shot,
    files: &dyn Assets,
    lent: Option<gltf::Lent>,
    place: &Place<'_>,
) -> Result<Scene, SceneError> {
    let assembled = assemble(text, format, file, limits, shot, files, lent, place)?;
    let (mut scene, read) = assembled
        .finish()
        .map_err(|(path, message)| place(&path, message))?;
    scene.hash = assets::scene_hash(text, &read);
    scene.files = read;
    Ok(scene)
}
#[allow(clippy::too_many_arguments)]
fn assemble(
    text: &str,
    format: Format,
    file: &str,
    limits: &Limits,
    shot: Shot,
    files: &dyn Assets,
    lent: Option<gltf::Lent>,
    place: &Place<'_>,
) -> Result<build::Assembled, SceneError> {
    if text.len() > limits.max_bytes {
        return Err(at_start(
            file,
            format!(
                "scene is {} bytes, above the limit of {}",
                text.len(),
                limits.max_bytes
            ),
        ));
    }
    let desc = parse(text, format, file)?;
    animate::at_frame(&desc, f64::from(shot.frame))
        .map(|mut desc| {
            if let Some((width, height)) = shot.resolution {
                desc.film = format::FilmDesc { width, height };
            }
            desc
        })
        .and_then(|desc| build::assemble(&desc, limits, files, lent))
        .map_err(|(path, message)| place(&path, message))
}

/// A scene file's text and syntax: the file's own, or for a glTF file the scene that renders
/// it ([`gltf_scene_text`]), whose one object is the file.
pub fn scene_source(
    path: &Path,
    gltf: &GltfOptions,
    limits: &Limits,
) -> Result<(String, Format), SceneError> {
    let file = path.display().to_string();
    if is_gltf(path) {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        // The text needs the JSON only: a .glb's buffers are read once, by the build.
        let json = gltf::json_part(path, limits.max_asset_bytes).map_err(|m| at_start(&file, m))?;
        return Ok((gltf_scene_text(&name, &json, gltf), Format::Toml));
    }
    let meta = std::fs::metadata(path).map_err(|e| io_error(&file, e))?;
    if meta.len() > limits.max_bytes as u64 {
        return Err(at_start(
            &file,
            format!(
                "scene is {} bytes, above the limit of {}",
                meta.len(),
                limits.max_bytes
            ),
        ));
    }
    let text = std::fs::read_to_string(path).map_err(|e| io_error(&file, e))?;
    Ok((text, Format::from_path(path)))
}

/// How an error found at a key path is placed for the user.
type Place<'a> = dyn Fn(&KeyPath, String) -> SceneError + 'a;

/// An error loading a glTF file as a whole scene, placed in that file (`file`): the place in
/// it where one is known ([`KeyPath::within`]). The scene text the file stands for is
/// generated, so its own lines and keys mean nothing to the user: a key of its one object is
/// the file itself, and another key is said in words.
fn in_gltf(file: &str, path: &KeyPath, message: String) -> SceneError {
    let (path, message) = match path.split_file() {
        Some((_, _, inner)) => (inner.pointer(), message),
        None => match path.to_string().as_str() {
            "" | "objects[0].file" | "objects[0]" => (String::new(), message),
            p => (String::new(), format!("{p}: {message}")),
        },
    };
    SceneError {
        file: file.into(),
        line: 0,
        column: 0,
        path,
        message,
    }
}
