//! The `[materials]` table: each material read by its kind ([`crate::material`]: its
//! scattering part), with what every kind shares (emission, an emission texture, two sides,
//! absorption inside) read here; the errors name the key at fault.

use std::collections::BTreeMap;

use glam::Vec3A;

use super::assets::Assets;
use super::check::{color, root, Invalid};
use super::files::SceneFiles;
use super::{Limits, Material, MaterialKind, SceneFile};
use crate::material::port::Reading;
use crate::material::Tables;
use crate::texture::TextureUse;

/// The materials and what is kept beside them.
pub(super) struct BuiltMaterials<'a> {
    /// In the order of `[materials]`.
    pub(super) materials: Vec<Material>,
    /// Each one's absorption inside.
    pub(super) absorption: Vec<Vec3A>,
    /// The plastics and glTF materials they index.
    pub(super) tables: Tables,
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
    let mut tables = Tables::default();
    let mut names = BTreeMap::new();
    let mut emissive = Vec::new();
    for (name, m) in &desc.materials {
        let mp = root("materials").key(name);
        let mut load =
            |file: &str, path: &_, usage| files.texture(file, path, limits, assets, usage);
        let bsdf = m.kind.read(&mut Reading {
            desc: m,
            at: &mp,
            textures: &mut load,
            tables: &mut tables,
        })?;
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
        });
    }
    Ok(BuiltMaterials {
        materials,
        absorption: absorptions,
        tables,
        names,
        emissive,
    })
}
