//! glTF materials as the scene's: the metallic–roughness model is tessera's `pbr`
//! ([`crate::bsdf::pbr`]) factor for factor and texture for texture, and a transmitting
//! material with a volume (`KHR_materials_volume`) is the refracting `dielectric`, with
//! Beer–Lambert absorption from its attenuation. What tessera does not model is named in one
//! warning line per file and kind.

use std::collections::{BTreeMap, BTreeSet};

use glam::{Vec2, Vec3A};

use super::super::assets::Assets;
use super::super::check::Invalid;
use super::super::files::SceneFiles;
use super::super::{AlphaTest, KeyPath, Limits, Material};
use super::{data, MaterialTables};
use crate::bsdf::pbr::{ClearcoatParams, CoatTable, Distribution, NormalMap, ScalarParam};
use crate::bsdf::PbrMaterial;
use crate::material::pbr::PbrRef;
use crate::material::{glass, Bsdf};
use crate::texture::TextureUse;
use crate::texture::{ImageFormat, Wrap};

/// An affine map of texture coordinates (`KHR_texture_transform`): u' = a·u + b·v + c,
/// v' = d·u + e·v + f.
pub(super) type UvMap = [f32; 6];

/// The materials of one glTF file, converted as primitives first use them.
pub(in crate::scene) struct GltfMaterials<'d> {
    file: &'d str,
    /// Where the file is, for errors placed inside it.
    file_at: &'d KeyPath,
    dir: &'d str,
    root: &'d gltf::json::Root,
    buffers: &'d [Vec<u8>],
    overrides: &'d BTreeMap<String, u32>,
    /// The microfacet model of its pbr materials (the scene's choice: glTF has none).
    distribution: Distribution,
    /// By glTF material index (`None`: the default material), the scene's index.
    built: BTreeMap<Option<usize>, u32>,
    warnings: BTreeSet<String>,
}

impl<'d> GltfMaterials<'d> {
    /// The materials of a document read from `file` (placed at `file_at`) in directory `dir`,
    /// with the scene's replacements by material name and its microfacet model.
    pub(super) fn new(
        (file, file_at): (&'d str, &'d KeyPath),
        dir: &'d str,
        root: &'d gltf::json::Root,
        buffers: &'d [Vec<u8>],
        (overrides, distribution): (&'d BTreeMap<String, u32>, Distribution),
    ) -> Self {
        Self {
            file,
            file_at,
            dir,
            root,
            buffers,
            overrides,
            distribution,
            built: BTreeMap::new(),
            warnings: BTreeSet::new(),
        }
    }

    /// What was read but is not rendered as the file asks.
    pub(super) fn warnings(self) -> impl Iterator<Item = String> {
        self.warnings.into_iter()
    }

    /// The texture coordinate set a material's textures read, and its transform: the base
    /// colour's (else the first texture's), since a mesh carries one set. Textures that
    /// disagree are warned about when the material is built.
    pub(super) fn uv_map(&self, m: &gltf::Material) -> (u32, Option<UvMap>) {
        match infos(m).into_iter().flatten().next() {
            Some(info) => uv_of(&info),
            None => (0, None),
        }
    }

    /// The scene's index of `m`, built at its first use.
    pub(super) fn index(
        &mut self,
        m: &gltf::Material,
        tables: &mut MaterialTables,
        files: &mut SceneFiles,
        limits: &Limits,
        assets: &dyn Assets,
    ) -> Result<u32, Invalid> {
        if let Some(&i) = self.built.get(&m.index()) {
            return Ok(i);
        }
        if let Some(&i) = m.name().and_then(|n| self.overrides.get(n)) {
            self.built.insert(m.index(), i);
            return Ok(i);
        }
        // The default material has no place of its own; its factors are glTF's defaults, so
        // nothing in it can be wrong.
        let at = match m.index() {
            Some(i) => self.file_at.key("materials").index(i),
            None => self.file_at.clone(),
        };
        let (material, absorption, pbr) = self.convert(m, &at, files, limits, assets)?;
        let alpha = self.alpha(m, &at, files, limits, assets)?;
        let mut material = material;
        if let Some(p) = pbr {
            material.bsdf = PbrRef::add(tables.kinds, p);
        }
        let i = tables.materials.len() as u32;
        if let Some(info) = m
            .emissive_texture()
            .filter(|_| material.emission != Vec3A::ZERO)
        {
            let t = self.texture(&info.texture(), TextureUse::Color, files, limits, assets)?;
            tables.emissive.push((i, t));
        }
        tables.materials.push(material);
        tables.absorption.push(absorption);
        if let Some(a) = alpha {
            tables.alpha.push((i, a));
        }
        self.built.insert(m.index(), i);
        Ok(i)
    }

    /// One material: the runtime material (its BSDF a placeholder where a pbr material is
    /// returned beside it), its absorption inside, and the pbr material if it is one.
    fn convert(
        &mut self,
        m: &gltf::Material,
        at: &KeyPath,
        files: &mut SceneFiles,
        limits: &Limits,
        assets: &dyn Assets,
    ) -> Result<(Material, Vec3A, Option<PbrMaterial>), Invalid> {
        let pbr = m.pbr_metallic_roughness();
        let [r, g, b, _] = pbr.base_color_factor();
        let base_color = Vec3A::new(unit(r), unit(g), unit(b));
        let metallic = unit(pbr.metallic_factor());
        let roughness = unit(pbr.roughness_factor());
        let factors = [r, g, b, pbr.metallic_factor(), pbr.roughness_factor()];
        if factors.iter().any(|x| !x.is_finite()) {
            return Err((
                at.key("pbrMetallicRoughness"),
                format!("a factor is not finite: {factors:?}"),
            ));
        }
        let emission = emission_of(m).map_err(|e| (at.key("emissiveFactor"), e))?;
        let (set, map) = self.uv_map(m);
        if infos(m)
            .into_iter()
            .flatten()
            .any(|i| uv_of(&i) != (set, map))
        {
            self.warn("reads every texture of a material through its base colour's texture coordinates and transform");
        }
        let ior = self.ior_of(m);
        let transmission = m.transmission();
        let factor = transmission
            .as_ref()
            .map_or(0.0, |t| unit(t.transmission_factor()));
        let textured_tx = transmission
            .as_ref()
            .is_some_and(|t| t.transmission_texture().is_some());
        // A material that transmits fully through a volume is glass: tessera's refracting
        // dielectric, with the volume's attenuation as Beer–Lambert absorption.
        if let Some(volume) = m.volume() {
            let clear = factor == 1.0 && !textured_tx && metallic == 0.0;
            if clear && volume.thickness_factor() > 0.0 {
                let tinted = pbr.base_color_texture().is_some() || base_color != Vec3A::ONE;
                let (material, sigma) = self
                    .volume_glass(&volume, (roughness, ior), tinted, emission)
                    .map_err(|e| {
                        let ext = at.key("extensions").key("KHR_materials_volume");
                        (ext, e)
                    })?;
                return Ok((material, sigma, None));
            }
            self.warn("renders a volume that does not transmit fully, or is metallic or textured, as a thin wall");
        }
        // A texture's errors are its image's, placed there (`/images/3/uri`).
        let mut texture = |t: Option<gltf::Texture>, usage: TextureUse| {
            t.map(|t| self.texture(&t, usage, files, limits, assets))
                .transpose()
        };
        let base_texture = texture(
            pbr.base_color_texture().map(|i| i.texture()),
            TextureUse::Color,
        )?;
        let mr = texture(
            pbr.metallic_roughness_texture().map(|i| i.texture()),
            TextureUse::Data,
        )?;
        let tx = texture(
            transmission
                .as_ref()
                .and_then(|t| t.transmission_texture())
                .map(|i| i.texture()),
            TextureUse::Data,
        )?;
        let normal_map = match m.normal_texture() {
            Some(n) if !n.scale().is_finite() => {
                let scale = n.scale();
                return Err((
                    at.key("normalTexture").key("scale"),
                    format!("must be finite, got {scale}"),
                ));
            }
            Some(n) => texture(Some(n.texture()), TextureUse::Data)?.map(|t| NormalMap {
                texture: t,
                scale: n.scale(),
            }),
            None => None,
        };
        // glTF packs roughness in green and metalness in blue.
        let param = |factor: f32, t: Option<u32>, channel: u8| ScalarParam {
            factor,
            texture: t.map(|t| (t, channel)),
        };
        let material = PbrMaterial {
            base_color,
            base_texture,
            metallic: param(metallic, mr, 2),
            roughness: param(roughness, mr, 1),
            transmission: param(factor, tx, 0),
            normal_map,
            coat: CoatTable::shared(self.specular_ior(m, ior)),
            distribution: self.distribution,
            clearcoat: self.clearcoat_of(m, at)?,
            sheen: self.sheen_of(m, at)?,
        };
        let runtime = Material {
            bsdf: Bsdf::Pbr(PbrRef(u32::MAX)),
            emission,
            two_sided: m.double_sided(),
        };
        Ok((runtime, Vec3A::ZERO, Some(material)))
    }

    /// The material's `KHR_materials_clearcoat` (Blender's Coat): its weight and roughness
    /// factors, each in [0, 1]; none where the weight is 0. Its textures, and the coat's own
    /// normal map, are not read (said once).
    fn clearcoat_of(
        &mut self,
        m: &gltf::Material,
        at: &KeyPath,
    ) -> Result<Option<ClearcoatParams>, Invalid> {
        let Some(ext) = m.extension_value("KHR_materials_clearcoat") else {
            return Ok(None);
        };
        let at = at.key("extensions").key("KHR_materials_clearcoat");
        let weight = unit_factor(ext, &at, "clearcoatFactor")?;
        let roughness = unit_factor(ext, &at, "clearcoatRoughnessFactor")?;
        let textures = [
            "clearcoatTexture",
            "clearcoatRoughnessTexture",
            "clearcoatNormalTexture",
        ];
        if textures.iter().any(|k| ext.get(k).is_some()) {
            self.warn("reads KHR_materials_clearcoat's factors, not its textures");
        }
        Ok((weight > 0.0).then(|| {
            ClearcoatParams::new(
                ScalarParam::constant(weight),
                ScalarParam::constant(roughness),
            )
        }))
    }

    /// The material's `KHR_materials_sheen` (Blender's Sheen): its colour and roughness
    /// factors, each in [0, 1]; none where the colour is black. Its textures are not read
    /// (said once).
    fn sheen_of(
        &mut self,
        m: &gltf::Material,
        at: &KeyPath,
    ) -> Result<Option<(Vec3A, f32)>, Invalid> {
        let Some(ext) = m.extension_value("KHR_materials_sheen") else {
            return Ok(None);
        };
        let at = at.key("extensions").key("KHR_materials_sheen");
        let key = "sheenColorFactor";
        let color = match ext.get(key) {
            None => Vec3A::ZERO,
            Some(v) => match v.as_array().map(Vec::as_slice) {
                Some([r, g, b]) => Vec3A::new(
                    unit_number(r, &at, key)?,
                    unit_number(g, &at, key)?,
                    unit_number(b, &at, key)?,
                ),
                _ => {
                    return Err((
                        at.key(key),
                        format!("must be three numbers in [0, 1], got {v}"),
                    ))
                }
            },
        };
        let roughness = unit_factor(ext, &at, "sheenRoughnessFactor")?;
        if ["sheenColorTexture", "sheenRoughnessTexture"]
            .iter()
            .any(|k| ext.get(k).is_some())
        {
            self.warn("reads KHR_materials_sheen's factors, not its textures");
        }
        Ok((color.max_element() > 0.0).then_some((color, roughness)))
    }

    /// The index of the dielectric layer's reflection under `KHR_materials_specular`, for a
    /// material of index `ior`. The extension's factor s scales the layer's reflectance at
    /// normal incidence, F0 = ((η − 1)/(η + 1))². Blender writes it from its Principled BSDF
    /// (s = 2 × Specular IOR Level), and Cycles keeps the Fresnel curve's shape by the index
    /// that gives the scaled F0; so does tessera: η' = (1 + √(s F0)) / (1 − √(s F0)). A
    /// factor of 0 (Blender's Specular IOR Level 0, a diffuse wall) is no specular layer at
    /// all, η' = 1; a factor of 1 is the index itself, bit for bit. Its colour and textures are
    /// not read (said once).
    fn specular_ior(&mut self, m: &gltf::Material, ior: f32) -> f32 {
        let Some(spec) = m.specular() else {
            return ior;
        };
        if spec.specular_texture().is_some() || spec.specular_color_texture().is_some() {
            self.warn("reads KHR_materials_specular's factors, not its textures");
        }
        if spec.specular_color_factor() != [1.0; 3] {
            self.warn("does not tint the specular layer by KHR_materials_specular's colour");
        }
        let s = spec.specular_factor();
        if s == 1.0 || !s.is_finite() {
            return ior;
        }
        let root = (((ior - 1.0) / (ior + 1.0)).powi(2) * s.clamp(0.0, 1.0)).sqrt();
        (1.0 + root) / (1.0 - root)
    }

    /// A material's index of refraction (`KHR_materials_ior`), 1.5 when it gives none or one
    /// below 1 (said once).
    fn ior_of(&mut self, m: &gltf::Material) -> f32 {
        match m.ior() {
            Some(x) if x.is_finite() && x >= 1.0 => x,
            None => 1.5,
            Some(x) => {
                self.warn(&format!(
                    "reads an ior of {x} as 1.5 (it must be at least 1)"
                ));
                1.5
            }
        }
    }

    /// Glass for a material that transmits fully through `volume`: smooth or rough by its
    /// `roughness`, of index `ior`, absorbing inside by the volume's attenuation (σ per unit
    /// length, Beer–Lambert).
    fn volume_glass(
        &mut self,
        volume: &gltf::material::Volume<'_>,
        (roughness, ior): (f32, f32),
        tinted: bool,
        emission: Vec3A,
    ) -> Result<(Material, Vec3A), String> {
        if tinted {
            self.warn("does not tint glass by its base colour (only its volume's attenuation)");
        }
        let bsdf = glass::solid(ior, roughness);
        let c = Vec3A::from_array(volume.attenuation_color());
        let d = volume.attenuation_distance();
        if !c.is_finite() || !(d > 0.0) {
            return Err(format!(
                "attenuation colour {:?} and distance {d} must be finite and positive",
                c.to_array()
            ));
        }
        let sigma = if d.is_finite() {
            c.clamp(Vec3A::splat(1e-6), Vec3A::ONE)
                .to_array()
                .map(|x| -x.ln() / d)
        } else {
            [0.0; 3]
        };
        let material = Material {
            bsdf,
            emission,
            two_sided: false,
        };
        Ok((material, Vec3A::from_array(sigma).max(Vec3A::ZERO)))
    }

    /// A `MASK` or `BLEND` material's alpha test: the base colour factor's alpha times its
    /// texture's alpha channel; `None` for an opaque material, or one whose alpha is 1
    /// everywhere.
    fn alpha(
        &mut self,
        m: &gltf::Material,
        at: &KeyPath,
        files: &mut SceneFiles,
        limits: &Limits,
        assets: &dyn Assets,
    ) -> Result<Option<AlphaTest>, Invalid> {
        let cutoff = match m.alpha_mode() {
            gltf::material::AlphaMode::Opaque => return Ok(None),
            gltf::material::AlphaMode::Mask => Some(m.alpha_cutoff().unwrap_or(0.5)),
            gltf::material::AlphaMode::Blend => None,
        };
        let factor = m.pbr_metallic_roughness().base_color_factor()[3];
        if !factor.is_finite() || cutoff.is_some_and(|c| !c.is_finite()) {
            return Err((
                at.clone(),
                "its alpha factor or cutoff is not finite".into(),
            ));
        }
        let texture = match m.pbr_metallic_roughness().base_color_texture() {
            Some(info) => {
                Some(self.texture(&info.texture(), TextureUse::Alpha, files, limits, assets)?)
            }
            None if factor >= 1.0 => return Ok(None),
            None => None,
        };
        Ok(Some(AlphaTest {
            factor: factor.clamp(0.0, 1.0),
            texture,
            cutoff,
        }))
    }

    /// A glTF texture's image, read once per use (colour or data) however many materials
    /// name it. Its errors are placed at the image (`/images/3`), where the fix goes.
    fn texture(
        &mut self,
        t: &gltf::Texture,
        usage: TextureUse,
        files: &mut SceneFiles,
        limits: &Limits,
        assets: &dyn Assets,
    ) -> Result<u32, Invalid> {
        let image = t.source();
        let at = self.file_at.key("images").index(image.index());
        let fail = |msg: String| (at.clone(), msg);
        let wrap = |m: gltf::texture::WrappingMode| match m {
            gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
            gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
            gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
        };
        let sampler = t.sampler();
        // tessera's v runs the other way, which wrapping does not see.
        let wrap = [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())];
        let embedded = |mime: &str, bytes: &[u8], files: &mut SceneFiles| {
            let format = match mime {
                "image/png" => ImageFormat::Png,
                "image/jpeg" => ImageFormat::Jpeg,
                other => {
                    return Err(fail(format!(
                        "is {other}; tessera reads PNG and JPEG images"
                    )))
                }
            };
            let key = format!("{}#images[{}]", self.file, image.index());
            files.embedded_texture(&key, &at, format, bytes, usage, wrap)
        };
        // From the JSON: the crate's `Image::source` unwraps what its validation does not check
        // (an image with neither a view nor a URI, a view without a MIME type).
        let json = &self.root.images[image.index()];
        let mime_type = json.mime_type.as_ref().map(|m| m.0.as_str());
        match (&json.buffer_view, &json.uri) {
            (Some(view), _) => {
                let view = &self.root.buffer_views[view.value()];
                let offset = view.byte_offset.map_or(0, |o| o.0);
                let bytes = usize::try_from(offset)
                    .ok()
                    .zip(usize::try_from(view.byte_length.0).ok())
                    .and_then(|(o, n)| {
                        self.buffers
                            .get(view.buffer.value())?
                            .get(o..o.checked_add(n)?)
                    })
                    .ok_or_else(|| {
                        fail("its buffer view runs past the end of its buffer".into())
                    })?;
                let mime = mime_type
                    .ok_or_else(|| fail("an image in a buffer view needs a mimeType".into()))?;
                embedded(mime, bytes, files)
            }
            (None, Some(uri)) => match data::data_uri(uri) {
                Some(r) => {
                    let (mime, bytes) = r.map_err(|m| (at.key("uri"), m))?;
                    embedded(mime_type.unwrap_or(&mime), &bytes, files)
                }
                None => {
                    let uri_at = at.key("uri");
                    let name = data::uri_file(self.dir, uri).map_err(|m| (uri_at.clone(), m))?;
                    files.texture_wrapped(&name, &uri_at, limits, assets, usage, wrap)
                }
            },
            (None, None) => Err(fail("has neither a bufferView nor a uri".into())),
        }
    }

    fn warn(&mut self, what: &str) {
        self.warnings.insert(what.to_string());
    }
}

/// A material's texture references, base colour first.
fn infos<'a>(m: &gltf::Material<'a>) -> [Option<gltf::texture::Info<'a>>; 3] {
    let pbr = m.pbr_metallic_roughness();
    [
        pbr.base_color_texture(),
        pbr.metallic_roughness_texture(),
        m.transmission().and_then(|t| t.transmission_texture()),
    ]
}

/// The coordinate set and transform a texture reference reads through.
fn uv_of(info: &gltf::texture::Info) -> (u32, Option<UvMap>) {
    match info.texture_transform() {
        None => (info.tex_coord(), None),
        Some(t) => {
            let [ox, oy] = t.offset();
            let [sx, sy] = t.scale();
            // In f64, rounded once: every worker must build the same coordinates.
            let (s, c) = f64::from(t.rotation()).sin_cos();
            let (s, c) = (s as f32, c as f32);
            // The ratified extension: T · R · S with R = [[c, s], [−s, c]].
            let map = [c * sx, s * sy, ox, -s * sx, c * sy, oy];
            (t.tex_coord().unwrap_or(info.tex_coord()), Some(map))
        }
    }
}

/// Applies a [`UvMap`].
pub(super) fn map_uv(m: &UvMap, uv: Vec2) -> Vec2 {
    Vec2::new(
        m[0] * uv.x + m[1] * uv.y + m[2],
        m[3] * uv.x + m[4] * uv.y + m[5],
    )
}

/// A factor clamped into [0, 1], as glTF's schema bounds it (NaN is caught by the caller).
fn unit(x: f32) -> f32 {
    x.clamp(0.0, 1.0)
}
/// A material's emitted radiance: its emissive factor times its strength
/// (`KHR_materials_emissive_strength`), finite and not negative.
fn emission_of(m: &gltf::Material) -> Result<Vec3A, String> {
    let strength = m.emissive_strength().unwrap_or(1.0);
    let emission = Vec3A::from_array(m.emissive_factor()) * strength;
    if !emission.is_finite() || emission.min_element() < 0.0 {
        return Err(format!(
            "emission {:?} × strength {strength} must be finite and not negative",
            m.emissive_factor()
        ));
    }
    Ok(emission)
}

/// An extension's factor `key` (0 where absent), which must be a number in [0, 1]; refused at
/// `at`'s `key` otherwise.
fn unit_factor(ext: &serde_json::Value, at: &KeyPath, key: &str) -> Result<f32, Invalid> {
    ext.get(key).map_or(Ok(0.0), |v| unit_number(v, at, key))
}

/// `v` as a number in [0, 1], or the error at `at`'s `key`.
fn unit_number(v: &serde_json::Value, at: &KeyPath, key: &str) -> Result<f32, Invalid> {
    v.as_f64()
        .filter(|x| (0.0..=1.0).contains(x))
        .map(|x| x as f32)
        .ok_or_else(|| (at.key(key), format!("must be a number in [0, 1], got {v}")))
}
