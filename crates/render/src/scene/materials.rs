//! The `[materials]` table: each material validated and converted into its runtime BSDF
//! (diffuse, mirror, glass of every kind, metals, plastic, glTF's pbr), with the errors naming
//! the key at fault.

use std::collections::BTreeMap;

use glam::Vec3A;

use super::assets::Assets;
use super::check::{color, finite3, only, positive, required, root, Invalid};
use super::files::{SceneFiles, TextureUse};
use super::{
    AlbedoDesc, KeyPath, Limits, Material, MaterialDesc, MaterialKind, ScalarDesc, SceneFile,
};
use crate::bsdf::conductor::{metal, METALS};
use crate::bsdf::microfacet::TrowbridgeReitz;
use crate::bsdf::pbr::{CoatTable, NormalMap, ScalarParam};
use crate::bsdf::{Bsdf, Conductor, Fresnel, Metal, PbrMaterial, Plastic, RoughDielectric};

/// The materials and what is kept beside them.
pub(super) struct BuiltMaterials<'a> {
    /// In the order of `[materials]`.
    pub(super) materials: Vec<Material>,
    /// Each one's absorption inside.
    pub(super) absorption: Vec<Vec3A>,
    /// The plastics [`Bsdf::Plastic`] indexes.
    pub(super) plastics: Vec<Plastic>,
    /// The glTF materials [`Bsdf::Pbr`] indexes.
    pub(super) pbrs: Vec<PbrMaterial>,
    /// Each material's index by name.
    pub(super) names: BTreeMap<&'a str, u32>,
    /// Emission textures, as (material index, texture index).
    pub(super) emissive: Vec<(u32, u32)>,
}

/// The materials, and each one's index by name; textures are read through `files`.
pub(super) fn build_materials<'a>(
    desc: &'a SceneFile,
    files: &mut SceneFiles,
    limits: &Limits,
    assets: &dyn Assets,
) -> Result<BuiltMaterials<'a>, Invalid> {
    let mut materials = Vec::with_capacity(desc.materials.len());
    let mut absorptions = Vec::with_capacity(desc.materials.len());
    let mut plastics = Vec::new();
    let mut pbrs = Vec::new();
    let mut names = BTreeMap::new();
    let mut emissive = Vec::new();
    for (name, m) in &desc.materials {
        let mp = root("materials").key(name);
        let (bsdf, texture) =
            scattering(m, &mp, files, limits, assets, (&mut plastics, &mut pbrs))?;
        let emission = match m.emission {
            Some(e) => color(e, &mp.key("emission"), false)?,
            None => Vec3A::ZERO,
        };
        if let Some(file) = &m.emission_texture {
            let path = mp.key("emission_texture");
            if emission.max_element() <= 0.0 {
                return Err((
                    path,
                    "an emission texture scales `emission`: give the radiance it scales, e.g. \
                     emission = [1, 1, 1]"
                        .into(),
                ));
            }
            let t = files.texture(file, &path, limits, assets, TextureUse::Color)?;
            emissive.push((materials.len() as u32, t));
        }
        if m.two_sided.is_some() && m.kind == MaterialKind::Dielectric && m.emission.is_none() {
            return Err((
                mp.key("two_sided"),
                "a dielectric has two sides by nature; `two_sided` does not apply".into(),
            ));
        }
        absorptions.push(match m.absorption {
            Some(a) => color(a, &mp.key("absorption"), false)?,
            None => Vec3A::ZERO,
        });
        names.insert(name.as_str(), materials.len() as u32);
        materials.push(Material {
            bsdf,
            emission,
            two_sided: m.two_sided.unwrap_or(false),
            texture,
        });
    }
    Ok(BuiltMaterials {
        materials,
        absorption: absorptions,
        plastics,
        pbrs,
        names,
        emissive,
    })
}

/// Which of the TOML's keys a material gives: each kind takes its own (`only`).
fn present(m: &MaterialDesc) -> [(&'static str, bool); 14] {
    [
        ("albedo", m.albedo.is_some()),
        ("reflectance", m.reflectance.is_some()),
        ("ior", m.ior.is_some()),
        ("roughness", m.roughness.is_some()),
        ("metal", m.metal.is_some()),
        ("eta", m.eta.is_some()),
        ("k", m.k.is_some()),
        ("f0", m.f0.is_some()),
        ("thin", m.thin.is_some()),
        ("absorption", m.absorption.is_some()),
        ("base_color", m.base_color.is_some()),
        ("metallic", m.metallic.is_some()),
        ("transmission", m.transmission.is_some()),
        ("normal_map", m.normal_map.is_some()),
    ]
}

/// A material's scattering part by its kind, and a diffuse albedo's texture. Plastics and
/// pbr materials go in their tables, which the BSDF indexes.
fn scattering(
    m: &MaterialDesc,
    mp: &KeyPath,
    files: &mut SceneFiles,
    limits: &Limits,
    assets: &dyn Assets,
    (plastics, pbrs): (&mut Vec<Plastic>, &mut Vec<PbrMaterial>),
) -> Result<(Bsdf, Option<u32>), Invalid> {
    let present = present(m);
    let mut texture = None;
    let bsdf = match m.kind {
        MaterialKind::Diffuse => {
            only(mp, "a diffuse material", &present, &["albedo"])?;
            let a = required(m.albedo.as_ref(), mp, "a diffuse material", "albedo")?;
            match a {
                AlbedoDesc::Color(c) => Bsdf::Diffuse(color(*c, &mp.key("albedo"), true)?),
                AlbedoDesc::Texture(file) => {
                    let path = mp.key("albedo").key("texture");
                    texture =
                        Some(files.texture(file, &path, limits, assets, TextureUse::Color)?);
                    // The texel replaces it at each hit; this is what NEE-free code
                    // paths and tests see.
                    Bsdf::Diffuse(Vec3A::splat(0.5))
                }
            }
        }
        MaterialKind::Mirror => {
            only(mp, "a mirror material", &present, &["reflectance"])?;
            Bsdf::Mirror(color(
                m.reflectance.unwrap_or([1.0; 3]),
                &mp.key("reflectance"),
                true,
            )?)
        }
        MaterialKind::Dielectric => {
            let kind = "a dielectric material";
            only(
                mp,
                kind,
                &present,
                &["ior", "roughness", "thin", "absorption"],
            )?;
            dielectric(m, mp)?
        }
        MaterialKind::Conductor => {
            let kind = "a conductor material";
            only(
                mp,
                kind,
                &present,
                &["roughness", "metal", "eta", "k", "f0"],
            )?;
            Bsdf::Conductor(Metal::new(&conductor(m, mp)?))
        }
        MaterialKind::Plastic => {
            plastics.push(plastic(m, mp, &present)?);
            Bsdf::Plastic(plastics.len() as u32 - 1)
        }
        MaterialKind::Pbr => {
            let kind = "a pbr material";
            let keys = [
                "base_color",
                "metallic",
                "roughness",
                "transmission",
                "ior",
                "normal_map",
            ];
            only(mp, kind, &present, &keys)?;
            pbrs.push(pbr(m, mp, files, limits, assets)?);
            Bsdf::Pbr(pbrs.len() as u32 - 1)
        }
    };
    Ok((bsdf, texture))
}

/// A `plastic` material: a diffuse albedo (a colour) under a clear coat of index `ior`.
fn plastic(m: &MaterialDesc, mp: &KeyPath, present: &[(&str, bool)]) -> Result<Plastic, Invalid> {
    let kind = "a plastic material";
    only(mp, kind, present, &["albedo", "roughness", "ior"])?;
    let albedo = match required(m.albedo.as_ref(), mp, kind, "albedo")? {
        AlbedoDesc::Color(c) => color(*c, &mp.key("albedo"), true)?,
        AlbedoDesc::Texture(_) => {
            return Err((
                mp.key("albedo").key("texture"),
                "a plastic's albedo is a colour: textures are for diffuse materials".into(),
            ))
        }
    };
    let roughness = constant_roughness(m, mp, kind)?;
    let ior = positive(m.ior.unwrap_or(1.5), &mp.key("ior"))?;
    if ior == 1.0 {
        return Err((
            mp.key("ior"),
            "a plastic's coat of index 1 is no coat: use a diffuse material".into(),
        ));
    }
    Ok(Plastic::new(albedo, roughness, ior))
}

/// A `pbr` material: glTF's defaults (white, metallic 1, roughness 1, no transmission, index
/// 1.5), each parameter a number in [0, 1] or a texture.
fn pbr(
    m: &MaterialDesc,
    mp: &KeyPath,
    files: &mut SceneFiles,
    limits: &Limits,
    assets: &dyn Assets,
) -> Result<PbrMaterial, Invalid> {
    let (base_color, base_texture) = match &m.base_color {
        None => (Vec3A::ONE, None),
        Some(AlbedoDesc::Color(c)) => (color(*c, &mp.key("base_color"), true)?, None),
        Some(AlbedoDesc::Texture(file)) => {
            let path = mp.key("base_color").key("texture");
            let t = files.texture(file, &path, limits, assets, TextureUse::Color)?;
            (Vec3A::ONE, Some(t))
        }
    };
    let mut scalar = |desc: &Option<ScalarDesc>, key: &str, default: f32| {
        let path = mp.key(key);
        match desc {
            None => Ok(ScalarParam::constant(default)),
            Some(ScalarDesc::Value(x)) => Ok(ScalarParam::constant(unit(*x, &path)?)),
            Some(ScalarDesc::Texture {
                file,
                channel,
                factor,
            }) => {
                let factor = unit(*factor, &path.key("factor"))?;
                let usage = match channel {
                    Some(_) => TextureUse::Data,
                    None => TextureUse::Grey,
                };
                let path = path.key("texture");
                let t = files.texture(file, &path, limits, assets, usage)?;
                Ok::<_, Invalid>(ScalarParam {
                    factor,
                    texture: Some((t, channel.unwrap_or(0))),
                })
            }
        }
    };
    let metallic = scalar(&m.metallic, "metallic", 1.0)?;
    let roughness = scalar(&m.roughness, "roughness", 1.0)?;
    let transmission = scalar(&m.transmission, "transmission", 0.0)?;
    let ior = positive(m.ior.unwrap_or(1.5), &mp.key("ior"))?;
    let normal_map = match &m.normal_map {
        None => None,
        Some(n) => {
            let path = mp.key("normal_map");
            let scale = n.scale.unwrap_or(1.0);
            if !scale.is_finite() {
                return Err((path.key("scale"), format!("must be finite, got {scale}")));
            }
            let texture = files.texture(
                &n.texture,
                &path.key("texture"),
                limits,
                assets,
                TextureUse::Data,
            )?;
            Some(NormalMap { texture, scale })
        }
    };
    Ok(PbrMaterial {
        base_color,
        base_texture,
        metallic,
        roughness,
        transmission,
        normal_map,
        coat: CoatTable::shared(ior),
    })
}

/// The roughness of a conductor, dielectric or plastic: a number in [0, 1], 0 (smooth) when
/// not given; textures are for `pbr` materials.
fn constant_roughness(m: &MaterialDesc, mp: &KeyPath, kind: &str) -> Result<f32, Invalid> {
    match &m.roughness {
        None => Ok(0.0),
        Some(ScalarDesc::Value(r)) => unit(*r, &mp.key("roughness")),
        Some(ScalarDesc::Texture { .. }) => Err((
            mp.key("roughness"),
            format!("{kind}'s roughness is a number: textures are for pbr materials"),
        )),
    }
}

/// Glass: smooth, rough, or a thin sheet (smooth only, and with no inside to absorb in).
/// Roughness under the mirror threshold, or an index of 1 (no interface to scatter at), is
/// the smooth dielectric, bit for bit.
fn dielectric(m: &MaterialDesc, mp: &KeyPath) -> Result<Bsdf, Invalid> {
    let ior = required(m.ior, mp, "a dielectric material", "ior")?;
    let ior = positive(ior, &mp.key("ior"))?;
    let roughness = constant_roughness(m, mp, "a dielectric")?;
    let distribution = TrowbridgeReitz::from_roughness(roughness);
    if m.thin == Some(true) {
        if roughness > 0.0 {
            return Err((
                mp.key("roughness"),
                "a thin dielectric is smooth: rough thin sheets are not modelled".into(),
            ));
        }
        if m.absorption.is_some() {
            return Err((
                mp.key("absorption"),
                "a thin dielectric has no inside to absorb in".into(),
            ));
        }
        return Ok(Bsdf::ThinDielectric(ior));
    }
    if distribution.is_smooth() || ior == 1.0 {
        return Ok(Bsdf::Dielectric(ior));
    }
    Ok(Bsdf::RoughDielectric(RoughDielectric { distribution, ior }))
}

/// A conductor's distribution and Fresnel term: exactly one of `metal`, `eta` with `k`, or
/// `f0`.
fn conductor(m: &MaterialDesc, mp: &KeyPath) -> Result<Conductor, Invalid> {
    let roughness = constant_roughness(m, mp, "a conductor")?;
    let given = [
        m.metal.is_some(),
        m.eta.is_some() || m.k.is_some(),
        m.f0.is_some(),
    ];
    if given.iter().filter(|g| **g).count() != 1 {
        return Err((
            mp.clone(),
            "a conductor needs exactly one of `metal` (a name), `eta` with `k` (a complex \
             index of refraction), or `f0` (its colour at normal incidence)"
                .into(),
        ));
    }
    let fresnel = if let Some(name) = &m.metal {
        let (eta, k) = metal(name).ok_or_else(|| {
            let known: Vec<&str> = METALS.iter().map(|(n, _, _)| *n).collect();
            (
                mp.key("metal"),
                format!("unknown metal {name:?}; known: {}", known.join(", ")),
            )
        })?;
        Fresnel::Complex { eta, k }
    } else if let Some(f0) = m.f0 {
        Fresnel::Schlick(color(f0, &mp.key("f0"), true)?)
    } else {
        let eta = required(m.eta, mp, "a conductor given `k`", "eta")?;
        let k = required(m.k, mp, "a conductor given `eta`", "k")?;
        let eta_p = mp.key("eta");
        let eta = finite3(eta, &eta_p)?;
        if !(eta.min_element() > 0.0) {
            return Err((eta_p, format!("must be greater than 0, got {:?}", m.eta)));
        }
        Fresnel::Complex {
            eta,
            k: color(k, &mp.key("k"), false)?,
        }
    };
    Ok(Conductor {
        distribution: TrowbridgeReitz::from_roughness(roughness),
        fresnel,
    })
}

/// A number in [0, 1].
fn unit(x: f32, path: &KeyPath) -> Result<f32, Invalid> {
    if (0.0..=1.0).contains(&x) {
        Ok(x)
    } else {
        Err((path.clone(), format!("must be between 0 and 1, got {x}")))
    }
}
