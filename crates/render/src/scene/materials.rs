//! The `[materials]` table: each material validated and converted into its runtime BSDF
//! (diffuse, mirror, glass of every kind, metals, plastic), with the errors naming the key at
//! fault.

use std::collections::BTreeMap;

use glam::Vec3A;

use super::assets::Assets;
use super::build::SceneFiles;
use super::check::{color, finite3, only, positive, required, root, Invalid};
use super::{AlbedoDesc, KeyPath, Limits, Material, MaterialDesc, MaterialKind, SceneFile};
use crate::bsdf::conductor::{metal, METALS};
use crate::bsdf::microfacet::TrowbridgeReitz;
use crate::bsdf::{Bsdf, Conductor, Fresnel, Metal, Plastic, RoughDielectric};

/// The materials, each one's absorption inside, the plastics they index, and each material's
/// index by name.
pub(super) type BuiltMaterials<'a> = (
    Vec<Material>,
    Vec<Vec3A>,
    Vec<Plastic>,
    BTreeMap<&'a str, u32>,
);

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
    let mut names = BTreeMap::new();
    for (name, m) in &desc.materials {
        let mp = root("materials").key(name);
        let present = [
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
        ];
        let mut texture = None;
        let bsdf = match m.kind {
            MaterialKind::Diffuse => {
                only(&mp, "a diffuse material", &present, &["albedo"])?;
                let a = required(m.albedo.as_ref(), &mp, "a diffuse material", "albedo")?;
                match a {
                    AlbedoDesc::Color(c) => Bsdf::Diffuse(color(*c, &mp.key("albedo"), true)?),
                    AlbedoDesc::Texture(file) => {
                        let path = mp.key("albedo").key("texture");
                        texture = Some(files.texture(file, &path, limits, assets)?);
                        // The texel replaces it at each hit; this is what NEE-free code
                        // paths and tests see.
                        Bsdf::Diffuse(Vec3A::splat(0.5))
                    }
                }
            }
            MaterialKind::Mirror => {
                only(&mp, "a mirror material", &present, &["reflectance"])?;
                Bsdf::Mirror(color(
                    m.reflectance.unwrap_or([1.0; 3]),
                    &mp.key("reflectance"),
                    true,
                )?)
            }
            MaterialKind::Dielectric => {
                let kind = "a dielectric material";
                only(
                    &mp,
                    kind,
                    &present,
                    &["ior", "roughness", "thin", "absorption"],
                )?;
                dielectric(m, &mp)?
            }
            MaterialKind::Conductor => {
                let kind = "a conductor material";
                only(
                    &mp,
                    kind,
                    &present,
                    &["roughness", "metal", "eta", "k", "f0"],
                )?;
                Bsdf::Conductor(Metal::new(&conductor(m, &mp)?))
            }
            MaterialKind::Plastic => {
                let kind = "a plastic material";
                only(&mp, kind, &present, &["albedo", "roughness", "ior"])?;
                let albedo =
                    match required(m.albedo.as_ref(), &mp, kind, "albedo")? {
                        AlbedoDesc::Color(c) => color(*c, &mp.key("albedo"), true)?,
                        AlbedoDesc::Texture(_) => return Err((
                            mp.key("albedo").key("texture"),
                            "a plastic's albedo is a colour: textures are for diffuse materials"
                                .into(),
                        )),
                    };
                let roughness = match m.roughness {
                    None => 0.0,
                    Some(r) => unit(r, &mp.key("roughness"))?,
                };
                let ior = positive(m.ior.unwrap_or(1.5), &mp.key("ior"))?;
                if ior == 1.0 {
                    return Err((
                        mp.key("ior"),
                        "a plastic's coat of index 1 is no coat: use a diffuse material".into(),
                    ));
                }
                plastics.push(Plastic::new(albedo, roughness, ior));
                Bsdf::Plastic(plastics.len() as u32 - 1)
            }
        };
        let emission = match m.emission {
            Some(e) => color(e, &mp.key("emission"), false)?,
            None => Vec3A::ZERO,
        };
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
    Ok((materials, absorptions, plastics, names))
}

/// Glass: smooth, rough, or a thin sheet (smooth only, and with no inside to absorb in).
/// Roughness under the mirror threshold, or an index of 1 (no interface to scatter at), is
/// the smooth dielectric, bit for bit.
fn dielectric(m: &MaterialDesc, mp: &KeyPath) -> Result<Bsdf, Invalid> {
    let ior = required(m.ior, mp, "a dielectric material", "ior")?;
    let ior = positive(ior, &mp.key("ior"))?;
    let roughness = match m.roughness {
        None => 0.0,
        Some(r) => unit(r, &mp.key("roughness"))?,
    };
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
    let roughness = match m.roughness {
        None => 0.0,
        Some(r) => unit(r, &mp.key("roughness"))?,
    };
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
