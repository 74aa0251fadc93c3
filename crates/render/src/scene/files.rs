//! The files a scene reads (meshes, textures, environment maps, glTF files with their buffers
//! and images): each read and hashed once however many objects or materials name it, counted
//! against the scene's limits, and, for images, decoded only once every check that needs no
//! pixels has passed.

use std::collections::BTreeMap;
use std::sync::Arc;

use super::assets::{sha256_hex, Assets};
use super::check::Invalid;
use super::{KeyPath, Limits};
use crate::mesh::load::{self, MeshFormat};
use crate::mesh::TriMesh;
use crate::texture::{self, ImageFormat, Texture, TextureUse, Wrap};

/// A mesh file's material groups: each one's name in the file, and its mesh.
type MeshGroups = Vec<(Option<String>, Arc<TriMesh>)>;

/// The files a scene has read (meshes and textures): each once, however many objects or
/// materials name it.
#[derive(Default)]
pub(super) struct SceneFiles {
    /// By file name: each material group's name and mesh.
    files: BTreeMap<String, MeshGroups>,
    /// Textures by file name, how they are decoded and how they wrap, as indices into
    /// `pending_textures` (and, once decoded, the scene's texture list).
    textures: BTreeMap<(String, Decode, [Wrap; 2]), u32>,
    /// Each texture's file read and its header checked, its pixels not yet decoded: decoding
    /// waits until every check that needs no pixels has passed ([`SceneFiles::decode_textures`]).
    pending_textures: Vec<PendingTexture>,
    /// Each file read, with its SHA-256, in the order first read.
    pub(super) read: Vec<(String, String)>,

    triangles: usize,
    texels: u64,
    /// Shapes placed so far (TOML objects, glTF mesh primitives under their nodes).
    instances: usize,
}

/// A texture file read, whose header gave its size, waiting to be decoded.
struct PendingTexture {
    name: String,
    /// Where the scene first names it, for errors.
    path: KeyPath,
    format: ImageFormat,
    bytes: Vec<u8>,
    /// Which values are read from it.
    decode: Decode,
    /// Where the scene reads it as one scalar without naming a channel, so it must be grey.
    grey: Option<KeyPath>,
    /// How its coordinates wrap.
    wrap: [Wrap; 2],
}

/// How a texture's file is decoded: one decoded copy per kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Decode {
    /// Through the sRGB curve.
    Color,
    /// Linear codes.
    Data,
    /// The alpha channel, linear.
    Alpha,
}

/// Most texels over a scene's textures.
pub(super) const MAX_TEXELS: u64 = 1 << 28;

impl SceneFiles {
    /// Reads `name` (counting it against the file limit) and records its hash.
    pub(super) fn read_file(
        &mut self,
        name: &str,
        path: &KeyPath,
        limits: &Limits,
        assets: &dyn Assets,
    ) -> Result<Vec<u8>, Invalid> {
        if self.read.len() >= limits.max_assets {
            return Err((
                path.clone(),
                format!(
                    "more than {} files, the limit for one scene",
                    limits.max_assets
                ),
            ));
        }
        super::assets::check_file_name(name).map_err(|m| (path.clone(), m))?;
        let bytes = assets
            .read(name, limits.max_asset_bytes)
            .map_err(|m| (path.clone(), m))?;
        self.read.push((name.to_string(), sha256_hex(&bytes)));
        Ok(bytes)
    }

    /// The texture of file `name` for `usage`, read once and decoded once per kind (colour or
    /// data).
    pub(super) fn texture(
        &mut self,
        name: &str,
        path: &KeyPath,
        limits: &Limits,
        assets: &dyn Assets,
        usage: TextureUse,
    ) -> Result<u32, Invalid> {
        self.texture_wrapped(name, path, limits, assets, usage, [Wrap::Repeat; 2])
    }

    /// [`SceneFiles::texture`] with coordinates outside [0, 1] read as `wrap` says.
    pub(super) fn texture_wrapped(
        &mut self,
        name: &str,
        path: &KeyPath,
        limits: &Limits,
        assets: &dyn Assets,
        usage: TextureUse,
        wrap: [Wrap; 2],
    ) -> Result<u32, Invalid> {
        self.add_texture(name, path, usage, wrap, |files| {
            files.image_file(name, path, limits, assets, "a texture")
        })
    }

    /// A texture whose encoded bytes are inside a file already read (a glTF file's embedded
    /// image), known by `key`: read, hashed and counted with that file, so not again here.
    pub(super) fn embedded_texture(
        &mut self,
        key: &str,
        path: &KeyPath,
        format: ImageFormat,
        bytes: &[u8],
        usage: TextureUse,
        wrap: [Wrap; 2],
    ) -> Result<u32, Invalid> {
        self.add_texture(key, path, usage, wrap, |files| {
            files.count_texels(key, path, bytes, format)?;
            Ok((format, bytes.to_vec()))
        })
    }

    /// Takes `n` placed shapes from what is left of the scene's limit; `shown` is the number
    /// the refusal names (a glTF file's whole tree, of which the file's own object was taken).
    pub(super) fn take_instances(
        &mut self,
        n: usize,
        shown: usize,
        limits: &Limits,
        path: &KeyPath,
    ) -> Result<(), Invalid> {
        let left = limits.max_instances.saturating_sub(self.instances);
        if n > left {
            return Err((
                path.clone(),
                format!(
                    "places {shown} shapes, above the scene's limit of {} placed shapes",
                    limits.max_instances
                ),
            ));
        }
        self.instances += n;
        Ok(())
    }

    /// Whether `n` more triangles fit in what is left of the scene's limit (nothing is taken).
    pub(super) fn triangles_fit(&self, n: usize, limits: &Limits) -> Result<(), String> {
        let left = limits.max_triangles.saturating_sub(self.triangles);
        if n > left {
            return Err(format!(
                "declares {n} triangles, above what is left of the scene's limit of {} ({left})",
                limits.max_triangles
            ));
        }
        Ok(())
    }

    /// Takes `n` triangles from what is left of the scene's limit.
    pub(super) fn take_triangles(
        &mut self,
        n: usize,
        limits: &Limits,
        path: &KeyPath,
    ) -> Result<(), Invalid> {
        let left = limits.max_triangles.saturating_sub(self.triangles);
        if n > left {
            return Err((
                path.clone(),
                format!(
                    "{n} more triangles is above what is left of the scene's limit of {} ({left})",
                    limits.max_triangles
                ),
            ));
        }
        self.triangles += n;
        Ok(())
    }

    fn add_texture(
        &mut self,
        name: &str,
        path: &KeyPath,
        usage: TextureUse,
        wrap: [Wrap; 2],
        load: impl FnOnce(&mut Self) -> Result<(ImageFormat, Vec<u8>), Invalid>,
    ) -> Result<u32, Invalid> {
        let decode = match usage {
            TextureUse::Color => Decode::Color,
            TextureUse::Data | TextureUse::Grey => Decode::Data,
            TextureUse::Alpha => Decode::Alpha,
        };
        let key = (name.to_string(), decode, wrap);
        if let Some(&i) = self.textures.get(&key) {
            let t = &mut self.pending_textures[i as usize];
            if usage == TextureUse::Grey && t.grey.is_none() {
                t.grey = Some(path.clone());
            }
            return Ok(i);
        }
        // The same file read as the other kind or wrapped another way: its bytes again,
        // decoded again (so its texels count twice), but read and hashed once.
        let other = self.pending_textures.iter().position(|t| t.name == name);
        let (format, bytes) = match other {
            Some(o) => {
                let t = &self.pending_textures[o];
                let (format, bytes) = (t.format, t.bytes.clone());
                self.count_texels(name, path, &bytes, format)?;
                (format, bytes)
            }
            None => load(self)?,
        };
        let i = self.pending_textures.len() as u32;
        self.pending_textures.push(PendingTexture {
            name: name.to_string(),
            path: path.clone(),
            format,
            bytes,
            decode,
            grey: (usage == TextureUse::Grey).then(|| path.clone()),
            wrap,
        });
        self.textures.insert(key, i);
        Ok(i)
    }

    /// Reads image file `name` for `what` (a texture, an environment map) and checks its
    /// header: its format by extension, and its size against what is left of the scene's
    /// texel limit, which it then takes.
    pub(super) fn image_file(
        &mut self,
        name: &str,
        path: &KeyPath,
        limits: &Limits,
        assets: &dyn Assets,
        what: &str,
    ) -> Result<(ImageFormat, Vec<u8>), Invalid> {
        let format = ImageFormat::from_name(name).ok_or_else(|| {
            (
                path.clone(),
                format!(
                    "`{name}`: {what} must be .png, .jpg, .jpeg, .exr or .hdr (by its extension)"
                ),
            )
        })?;
        let bytes = self.read_file(name, path, limits, assets)?;
        self.count_texels(name, path, &bytes, format)?;
        Ok((format, bytes))
    }

    /// Reads image `name`'s size from its header and takes it from what is left of the
    /// scene's texel limit.
    fn count_texels(
        &mut self,
        name: &str,
        path: &KeyPath,
        bytes: &[u8],
        format: ImageFormat,
    ) -> Result<(), Invalid> {
        let fail = |m: String| (path.clone(), format!("{name}: {m}"));
        let (w, h) = texture::probe(bytes, format).map_err(fail)?;
        let left = MAX_TEXELS - self.texels;
        if w.saturating_mul(h) > left {
            return Err(fail(format!(
                "{w}×{h} texels, above what is left of the scene's limit of {MAX_TEXELS} \
                 texels over all its images ({left})"
            )));
        }
        self.texels += w * h;
        Ok(())
    }

    /// Decodes the textures, one at a time and each within the process's decode budget
    /// ([`texture::DecodeBudget`]): the last step of a build, after every check that needs no
    /// pixels, so a scene that is refused anyway never decodes an image.
    pub(super) fn decode_textures(&mut self) -> Result<Vec<Arc<Texture>>, Invalid> {
        std::mem::take(&mut self.pending_textures)
            .into_iter()
            .map(|t| {
                let decoded = match t.decode {
                    Decode::Color => Texture::decode(&t.bytes, t.format, MAX_TEXELS),
                    Decode::Data => Texture::decode_data(&t.bytes, t.format, MAX_TEXELS),
                    Decode::Alpha => Texture::decode_alpha(&t.bytes, t.format, MAX_TEXELS),
                };
                let decoded = decoded
                    .map_err(|m| (t.path, format!("{}: {m}", t.name)))?
                    .with_wrap(t.wrap);
                if let Some(path) = t.grey {
                    if !decoded.is_grey() {
                        return Err((
                            path,
                            format!(
                                "{}: a colour image where one number is expected; name the \
                                 channel to read, e.g. {{ texture = \"{}\", channel = \"g\" }}",
                                t.name, t.name
                            ),
                        ));
                    }
                }
                Ok(Arc::new(decoded))
            })
            .collect()
    }

    pub(super) fn get(
        &mut self,
        name: &str,
        path: &KeyPath,
        limits: &Limits,
        assets: &dyn Assets,
    ) -> Result<&MeshGroups, Invalid> {
        if !self.files.contains_key(name) {
            let fail = |m: String| (path.clone(), m);
            let format = MeshFormat::from_name(name).ok_or_else(|| {
                fail(format!(
                    "`{name}`: a mesh file must be .obj or .ply (by its extension)"
                ))
            })?;
            let bytes = self.read_file(name, path, limits, assets)?;
            let left = limits.max_triangles.saturating_sub(self.triangles);
            let groups = load::load(name, &bytes, format, left).map_err(|e| fail(e.to_string()))?;
            let meshes = groups
                .into_iter()
                .map(|g| {
                    self.triangles += g.tris.len();
                    (g.material, Arc::new(TriMesh::new(g.tris, g.normals, g.uvs)))
                })
                .collect();
            self.files.insert(name.to_string(), meshes);
        }
        Ok(&self.files[name])
    }
}
