//! glTF 2.0's metallic–roughness material: a dielectric or metallic base, optionally
//! transmitting, under GGX reflection, each parameter a number or a texture, and a normal map
//! ([`PbrMaterial`] holds its parameters, [`PbrBsdf`] its arithmetic at a point). Its textures
//! make it too large to keep in every material: the scene keeps it in [`Tables`], and the
//! material names it by index. Both scene readers make one: a `type = "pbr"` table, and every
//! glTF material that is not glass.

use glam::Vec2;

use super::desc::{AlbedoDesc, ScalarDesc};
use super::port::{leave, At, Lobe, Reading, Seen, Surface, Tables};
use super::{Bsdf, Model};
use crate::bsdf::pbr::{ClearcoatParams, CoatTable, NormalMap, ScalarParam};
use crate::bsdf::{PbrMaterial, PbrParams};
use crate::interaction::Shading;
use crate::texture::TextureUse;
use crate::util::fields::{color, positive, unit, Invalid};
use crate::util::math::{offset_ray_origin, Frame, Ray};

/// A glTF material, by its index in the scene's [`Tables`].
#[derive(Clone, Copy, Debug)]
pub struct PbrRef(pub u32);

impl PbrRef {
    /// Keeps `p` in `tables` and names it.
    pub(crate) fn add(tables: &mut Tables, p: PbrMaterial) -> Bsdf {
        Bsdf::Pbr(PbrRef(tables.add_pbr(p)))
    }
}

impl Model for PbrRef {
    const FAR: bool = true;
    fn draws_choice(&self) -> bool {
        true
    }
    /// It decides at its vertex: where it transmits, it has two.
    fn has_two_sides(&self) -> bool {
        true
    }
    fn reads_uv(&self, tables: &Tables) -> bool {
        tables.pbr(self.0).is_textured()
    }
    fn needs_tangents(&self, tables: &Tables) -> bool {
        tables.pbr(self.0).normal_map.is_some()
    }
    #[inline(always)]
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray> {
        vertex(v.tables().pbr(self.0), v)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, _: f32) -> Seen {
        let (params, bent) = at(s.tables().pbr(self.0), s);
        Seen::Shaded {
            albedo: params.base_color,
            normal: bent.ns,
        }
    }
}

/// The material's parameters at `s`, and the normals with its normal map applied (the
/// shading normal bent, and marked as differing from the geometric one so that every side test
/// runs).
#[inline(always)]
fn at<'s, S: Surface<'s>>(mat: &PbrMaterial, s: &S) -> (PbrParams, Shading) {
    let frame = if mat.is_textured() {
        s.uv_frame()
    } else {
        None
    };
    let uv = frame.map_or(Vec2::ZERO, |f| f.uv);
    let params = mat.params(s.textures(), uv);
    let mut shading = *s.shading();
    if let (Some(_), Some(frame)) = (mat.normal_map, frame) {
        let sp = s.point();
        let bent = mat.bend(s.textures(), &frame, sp.ns);
        // A map that tips the normal under the geometric surface is ignored there: no
        // direction above such a normal could leave the surface consistently.
        if bent != sp.ns && bent.dot(sp.n) > 0.0 {
            shading.ns = if s.front() { bent } else { -bent };
            shading.shaded = true;
        }
    }
    (params, shading)
}

/// A `pbr` vertex (see [`crate::bsdf::pbr`]): direct light by next-event estimation (when the
/// vertex samples lights) through every lobe light sampling can find — from both sides where
/// the surface transmits — weighed against the mixture's density under MIS, then a direction
/// from the lobe the choice number picks. A delta lobe's direction (smooth reflection,
/// straight through) is a specular bounce. `None` ends the path.
// Out of line, with its parameters looked up here: the loop that other scenes run stays as
// small as it was.
#[inline(never)]
fn vertex<'s, A: At<'s>>(material: &'s PbrMaterial, v: &mut A) -> Option<Ray> {
    let (params, at) = at(material, v);
    let at = &at;
    let bsdf = material.bsdf(params);
    if !v.front() && !v.two_sided() && !bsdf.transmits() {
        // The back of a one-sided surface absorbs everything.
        return None;
    }
    let bsdf = &bsdf;
    let (sp, wo, u) = (*v.point(), -v.ray().d, v.numbers());
    let frame = Frame::from_normal(at.ns);
    let o = frame.to_local(wo);
    if let Some(u) = u.light {
        let lobe = Lobe {
            frame: &frame,
            eval: |i| bsdf.eval(o, i),
            pdf: |i| bsdf.pdf(o, i),
        };
        if bsdf.transmits() && !bsdf.is_smooth() {
            v.two_sided_light(at, u, lobe);
        } else {
            let p_out = offset_ray_origin(sp.p, sp.err, at.n);
            v.reflected_light(at, p_out, u, lobe);
        }
    }
    let s = bsdf.sample(o, u.bsdf, u.choice)?;
    let wi = frame.to_world(s.wi);
    let path = v.path();
    path.beta *= s.weight;
    path.specular = s.delta;
    path.prev_pdf = s.pdf;
    leave(&sp, at, wi, s.wi.z < 0.0)
}

/// `type = "pbr"`: glTF's defaults (white, metallic 1, roughness 1, no transmission, index
/// 1.5, no clear coat), each parameter a number in [0, 1] or a texture, and a normal map.
pub(crate) fn read(r: &mut Reading<'_, '_>) -> Result<Bsdf, Invalid> {
    let keys = [
        "base_color",
        "metallic",
        "roughness",
        "transmission",
        "ior",
        "normal_map",
        "distribution",
        "clearcoat",
        "clearcoat_roughness",
        "sheen_color",
        "sheen_roughness",
    ];
    r.only("a pbr material", &keys)?;
    let (m, mp) = (r.desc, r.at);
    let textures = &mut *r.textures;
    let (base_color, base_texture) = match &m.base_color {
        None => (glam::Vec3A::ONE, None),
        Some(AlbedoDesc::Color(c)) => (color(*c, &mp.key("base_color"), true)?, None),
        Some(AlbedoDesc::Texture(file)) => {
            let path = mp.key("base_color").key("texture");
            let t = textures(file, &path, TextureUse::Color)?;
            (glam::Vec3A::ONE, Some(t))
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
                let t = textures(file, &path, usage)?;
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
    // A coat of weight 0 is none: the material renders as it would without the key.
    let clearcoat_weight = scalar(&m.clearcoat, "clearcoat", 0.0)?;
    let clearcoat_roughness = scalar(&m.clearcoat_roughness, "clearcoat_roughness", 0.0)?;
    let clearcoat = (clearcoat_weight.factor > 0.0)
        .then(|| ClearcoatParams::new(clearcoat_weight, clearcoat_roughness));
    let ior = positive(m.ior.unwrap_or(1.5), &mp.key("ior"))?;
    let normal_map = match &m.normal_map {
        None => None,
        Some(n) => {
            let path = mp.key("normal_map");
            let scale = n.scale.unwrap_or(1.0);
            if !scale.is_finite() {
                return Err((path.key("scale"), format!("must be finite, got {scale}")));
            }
            let texture = textures(&n.texture, &path.key("texture"), TextureUse::Data)?;
            Some(NormalMap { texture, scale })
        }
    };
    let sheen_roughness = unit(m.sheen_roughness.unwrap_or(0.0), &mp.key("sheen_roughness"))?;
    let sheen = match m.sheen_color {
        None => None,
        Some(c) => Some(color(c, &mp.key("sheen_color"), true)?),
    }
    .filter(|c| c.max_element() > 0.0)
    .map(|c| (c, sheen_roughness));
    let material = PbrMaterial {
        base_color,
        base_texture,
        metallic,
        roughness,
        transmission,
        normal_map,
        coat: CoatTable::shared(ior),
        distribution: m.distribution.unwrap_or_default(),
        clearcoat,
        sheen,
    };
    Ok(PbrRef::add(r.tables, material))
}
