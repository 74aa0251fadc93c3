//! A metal: GGX microfacets over a conductor's Fresnel reflectance (a measured metal's complex
//! index, one given, or Schlick's colour at normal incidence), rough or smooth
//! ([`Metal`]/[`Conductor`] hold its arithmetic). A smooth one is a coloured mirror.

use glam::Vec3A;

use super::mirror::mirrored;
use super::port::{follow, At, Lobe, Reading, Seen, Surface};
use super::{Bsdf, Model};
use crate::bsdf::conductor::{metal, METALS};
use crate::bsdf::microfacet::TrowbridgeReitz;
use crate::bsdf::{Conductor, Fresnel, Metal};
use crate::util::fields::{color, finite3, required, Invalid};
use crate::util::math::{offset_ray_origin, Frame, Ray};

impl Model for Metal {
    const FAR: bool = true;
    fn samples_lights(&self) -> bool {
        !self.is_smooth()
    }
    #[inline(always)]
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray> {
        vertex(&self.conductor(), v)
    }
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, _: f32) -> Seen {
        if self.is_smooth() {
            mirrored(s).map_or(Seen::Nothing, Seen::Next)
        } else {
            Seen::Albedo(self.conductor().fresnel.eval(1.0))
        }
    }
}

/// A metal vertex. Smooth: the mirror direction, weighted by the Fresnel reflectance at this
/// angle. Rough: direct light by next-event estimation (when the vertex samples lights),
/// weighted against the BSDF's own density under MIS, then a direction by visible normals
/// with weight f·cos/pdf (= F·G/G1, see [`crate::bsdf::microfacet`]). `None` ends the path.
// Out of line: the loop that diffuse, mirror and glass scenes run stays as small as it was.
#[inline(never)]
fn vertex<'s, A: At<'s>>(c: &Conductor, v: &mut A) -> Option<Ray> {
    let (sp, at, wo) = (*v.point(), *v.shading(), -v.ray().d);
    let u = v.numbers();
    let p_out = offset_ray_origin(sp.p, sp.err, at.n);
    if c.distribution.is_smooth() {
        let path = v.path();
        path.beta *= c.fresnel.eval(at.ns.dot(wo));
        path.specular = true;
        return mirrored(v);
    }
    let frame = Frame::from_normal(at.ns);
    let o = frame.to_local(wo);
    if let Some(u) = u.light {
        let lobe = Lobe {
            frame: &frame,
            eval: |i| c.eval(o, i),
            pdf: |i| c.pdf(o, i),
        };
        v.reflected_light(&at, p_out, u, lobe);
    }
    let s = c.sample(o, u.bsdf)?;
    follow(
        v.path(),
        &at,
        p_out,
        frame.to_world(s.wi),
        s.weight,
        s.pdf,
        false,
    )
}

/// `type = "conductor"`: a roughness, and exactly one of `metal` (a name), `eta` with `k`,
/// or `f0`.
pub(crate) fn read(r: &mut Reading<'_, '_>) -> Result<Bsdf, Invalid> {
    r.only(
        "a conductor material",
        &["roughness", "metal", "eta", "k", "f0"],
    )?;
    let (m, mp) = (r.desc, r.at);
    let roughness = m.constant_roughness(mp, "a conductor")?;
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
        let eta: Vec3A = finite3(eta, &eta_p)?;
        if !(eta.min_element() > 0.0) {
            return Err((eta_p, format!("must be greater than 0, got {:?}", m.eta)));
        }
        Fresnel::Complex {
            eta,
            k: color(k, &mp.key("k"), false)?,
        }
    };
    Ok(Bsdf::Conductor(Metal::new(&Conductor {
        distribution: TrowbridgeReitz::from_roughness(roughness),
        fresnel,
    })))
}
