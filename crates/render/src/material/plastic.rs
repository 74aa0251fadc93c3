//! Plastic: a diffuse base under a clear dielectric coat, rough or smooth ([`Plastic`] holds
//! its arithmetic and the tables that make it too large to keep in every material: the scene
//! keeps it in [`Tables`], and the material names it by index).

use super::desc::AlbedoDesc;
use super::port::{follow, At, Lobe, Reading, Seen, Surface, Tables};
use super::{Bsdf, Model};
use crate::bsdf::Plastic;
use crate::util::fields::{color, positive, required, Invalid};
use crate::util::math::{offset_ray_origin, Frame, Ray};

/// A plastic, by its index in the scene's [`Tables`].
#[derive(Clone, Copy, Debug)]
pub struct PlasticRef(pub u32);

impl PlasticRef {
    /// Keeps `p` in `tables` and names it.
    pub(crate) fn add(tables: &mut Tables, p: Plastic) -> Bsdf {
        Bsdf::Plastic(PlasticRef(tables.add_plastic(p)))
    }
}

impl Model for PlasticRef {
    const FAR: bool = true;
    fn draws_choice(&self) -> bool {
        true
    }
    #[inline(always)]
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray> {
        vertex(self.0, v)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, _: f32) -> Seen {
        Seen::Albedo(s.tables().plastic(self.0).albedo())
    }
}

/// A plastic vertex: direct light by next-event estimation (when the vertex samples lights)
/// through both lobes, weighed against the mixture's density under MIS, then a direction from
/// the coat or the base chosen by the choice number (see [`crate::bsdf::plastic`]); a smooth
/// coat's mirror direction is a specular bounce. `None` ends the path.
// Out of line: the loop that diffuse, mirror and glass scenes run stays as small as it was.
#[inline(never)]
fn vertex<'s, A: At<'s>>(index: u32, v: &mut A) -> Option<Ray> {
    let (sp, at, wo) = (*v.point(), *v.shading(), -v.ray().d);
    let u = v.numbers();
    let p_out = offset_ray_origin(sp.p, sp.err, at.n);
    let frame = Frame::from_normal(at.ns);
    let o = frame.to_local(wo);
    let p = v.tables().plastic(index);
    if let Some(u) = u.light {
        let lobe = Lobe {
            frame: &frame,
            eval: |i| p.eval(o, i),
            pdf: |i| p.pdf(o, i),
        };
        v.reflected_light(&at, p_out, u, lobe);
    }
    let s = p.sample(o, u.bsdf, u.choice)?;
    follow(
        v.path(),
        &at,
        p_out,
        frame.to_world(s.wi),
        s.weight,
        s.pdf,
        s.delta,
    )
}

/// `type = "plastic"`: a diffuse albedo (a colour) under a clear coat of index `ior` (1.5 when
/// not given) and some roughness.
pub(crate) fn read(r: &mut Reading<'_, '_>) -> Result<Bsdf, Invalid> {
    let kind = "a plastic material";
    r.only(kind, &["albedo", "roughness", "ior"])?;
    let (m, mp) = (r.desc, r.at);
    let albedo = match required(m.albedo.as_ref(), mp, kind, "albedo")? {
        AlbedoDesc::Color(c) => color(*c, &mp.key("albedo"), true)?,
        AlbedoDesc::Texture(_) => {
            return Err((
                mp.key("albedo").key("texture"),
                "a plastic's albedo is a colour: textures are for diffuse materials".into(),
            ))
        }
    };
    let roughness = m.constant_roughness(mp, kind)?;
    let ior = positive(m.ior.unwrap_or(1.5), &mp.key("ior"))?;
    if ior == 1.0 {
        return Err((
            mp.key("ior"),
            "a plastic's coat of index 1 is no coat: use a diffuse material".into(),
        ));
    }
    Ok(PlasticRef::add(
        r.tables,
        Plastic::new(albedo, roughness, ior),
    ))
}
