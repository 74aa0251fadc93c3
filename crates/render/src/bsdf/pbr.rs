//! The glTF 2.0 metallic–roughness material (`pbr`): the Khronos specification's BRDF
//! (its Appendix B) with `KHR_materials_transmission` and `KHR_materials_ior`, each parameter
//! a constant or a texture, made energy-conserving where the specification's own formula is
//! not.
//!
//! The specification mixes a metal and a dielectric by `metallic` (m):
//!
//! - metal: GGX reflection with Schlick's Fresnel of F0 = the base colour c,
//!   f cos θi = F_s(o·h; c) D(h) G(o, i) / (4 cos θo) ([`super::microfacet`]);
//! - dielectric: a GGX coat of index η over a base that is, by `transmission` (t), a
//!   Lambertian c/π or a thin-walled transmission (the coat's lobe mirrored through the surface
//!   and tinted by c: glTF's default when no volume is given). The specification weighs the
//!   base by 1 − F(o·h) with h the half vector of o and i, which is not energy-conserving: at a
//!   grazing view the coat reflects nearly everything while the base, whose half vectors lie far
//!   from the view, still gets nearly all of its weight: a white base under a rough coat
//!   returns more light than arrives at grazing views (docs/renderer.md has the figure; a test
//!   in `tests/bsdfs.rs` integrates it).
//!
//! Here the dielectric's base is weighted as tessera's `plastic` weighs its base: by the coat's
//! transmittance at both ends, T(cos θo) T(cos θi), with T(μ) = 1 − R(μ) and R the coat's
//! directional albedo, divided by (1 − F̄) η² (the bounces under the coat, and radiance
//! compression). At c = 1 the base then returns exactly what the coat lets through (shown for
//! `plastic`; [`super::plastic`]), so the material's albedo is never above one and it is
//! reciprocal. The coat's Fresnel is the exact dielectric one, where the specification uses
//! Schlick's approximation of it. The thin-walled transmission takes (1 − F(o·h)) of the coat's
//! mirrored lobe: with the coat's F(o·h) reflected and (1 − F) passed, a sheet of white base
//! returns at most the GGX lobe's own albedo. So
//!
//! f cos θi = m F_s(o·h; c) ρ(o, i) + (1 − m) [F(o·h) ρ(o, i) + (1 − t) c S T(cos θo) T(cos θi) cos θi]
//! for i above the surface, and (1 − m) t c (1 − F(o·h')) ρ(o, i') below it, with
//! ρ(o, i) = D(h) G(o, i) / (4 cos θo), i' the mirror image of i through the surface and
//! S = 1 / ((1 − F̄) π η²).
//!
//! Roughness may come from a texture, so the coat's R(μ) and F̄ are tabulated over roughness
//! as well as μ ([`CoatTable`], shared by every material of one index) and interpolated.
//!
//! Sampling picks one of three lobes: the GGX reflection (visible normals), the base's cosine
//! hemisphere, or the mirrored GGX lobe for transmission, with probabilities proportional to an
//! estimate of each lobe's albedo at o; the density is the mixture's, so any lobe's direction
//! is weighed against all of them. Below the mirror threshold the reflection and transmission
//! lobes are deltas (the mirror direction, and straight through), which light sampling cannot
//! find.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, OnceLock};

use glam::{Vec2, Vec3A};

use super::fresnel_dielectric;
use super::microfacet::{half_vector, reflect_about, TrowbridgeReitz};
use super::plastic::coat_albedo;
use crate::mesh::UvFrame;
use crate::texture::Texture;
use crate::util::sampling::{cosine_hemisphere_pdf, square_to_cosine_hemisphere};

/// Roughness steps of a [`CoatTable`] (roughness j / (ROUGHNESS_STEPS − 1)).
const ROUGHNESS_STEPS: usize = 17;
/// Incidence steps of a [`CoatTable`] (cos θ j / (MU_STEPS − 1)).
const MU_STEPS: usize = 32;
/// Midpoints per side of the sample square for each entry.
const QUADRATURE: usize = 24;
/// Midpoints in μ for F̄.
const INSIDE_STEPS: usize = 128;
/// Midpoints in μ for a smooth coat's F̄.
const SMOOTH_INSIDE_STEPS: usize = 8192;

/// A rough dielectric coat of one index, tabulated over roughness and incidence: its
/// transmittance T(μ) = 1 − R(μ) from outside and 1/((1 − F̄) π η²), the base's scale.
#[derive(Debug, PartialEq)]
pub struct CoatTable {
    eta: f32,
    /// T at roughness j and μ k, row-major in roughness.
    transmittance: Vec<f32>,
    /// The base's scale at each roughness.
    scale: [f32; ROUGHNESS_STEPS],
}

impl CoatTable {
    /// The table for a coat of index `eta` (inside over outside), built by a fixed midpoint
    /// rule in basic arithmetic, so every worker builds the same one.
    pub fn new(eta: f32) -> Self {
        let mut transmittance = Vec::with_capacity(ROUGHNESS_STEPS * MU_STEPS);
        let mut scale = [0.0; ROUGHNESS_STEPS];
        for (j, s) in scale.iter_mut().enumerate() {
            let d = TrowbridgeReitz::from_roughness(j as f32 / (ROUGHNESS_STEPS - 1) as f32);
            for k in 0..MU_STEPS {
                let mu = k as f32 / (MU_STEPS - 1) as f32;
                transmittance.push(1.0 - coat_albedo(&d, mu, eta, QUADRATURE));
            }
            // A smooth coat's F(μ) has a kink at the critical angle that a coarse rule
            // misses by a few tenths of a percent (energy the furnace would see); its entries
            // cost no quadrature, so it gets a fine one.
            let steps = if d.is_smooth() {
                SMOOTH_INSIDE_STEPS
            } else {
                INSIDE_STEPS
            };
            let mut inside = 0.0f64;
            for k in 0..steps {
                let mu = (k as f32 + 0.5) / steps as f32;
                inside += f64::from(coat_albedo(&d, mu, 1.0 / eta, QUADRATURE) * mu);
            }
            let f_bar = (2.0 * inside / steps as f64) as f32;
            *s = 1.0 / ((1.0 - f_bar) * std::f32::consts::PI * eta * eta);
        }
        Self {
            eta,
            transmittance,
            scale,
        }
    }

    /// The table for `eta`, built once per process and index and shared.
    pub fn shared(eta: f32) -> Arc<Self> {
        static TABLES: OnceLock<Mutex<BTreeMap<u32, Arc<CoatTable>>>> = OnceLock::new();
        let tables = TABLES.get_or_init(Default::default);
        let mut tables = tables.lock().unwrap_or_else(|e| e.into_inner());
        tables
            .entry(eta.to_bits())
            .or_insert_with(|| Arc::new(Self::new(eta)))
            .clone()
    }

    /// (row, weight) for roughness `r` ∈ [0, 1]: rows `row` and `row + 1` blend by `weight`.
    #[inline]
    fn row(r: f32) -> (usize, f32) {
        let x = r.clamp(0.0, 1.0) * (ROUGHNESS_STEPS - 1) as f32;
        let j = (x as usize).min(ROUGHNESS_STEPS - 2);
        (j, x - j as f32)
    }

    /// T(μ) at roughness `r` (for a smooth coat, 1 − F(μ) exactly), by bilinear interpolation.
    #[inline]
    pub fn transmittance(&self, r: f32, smooth: bool, mu: f32) -> f32 {
        let mu = mu.clamp(0.0, 1.0);
        if smooth {
            return 1.0 - fresnel_dielectric(mu, self.eta).0;
        }
        let (j, wr) = Self::row(r);
        let x = mu * (MU_STEPS - 1) as f32;
        let k = (x as usize).min(MU_STEPS - 2);
        let wm = x - k as f32;
        let at = |j: usize| {
            let row = &self.transmittance[j * MU_STEPS..(j + 1) * MU_STEPS];
            row[k] * (1.0 - wm) + row[k + 1] * wm
        };
        at(j) * (1.0 - wr) + at(j + 1) * wr
    }

    /// 1/((1 − F̄) π η²) at roughness `r`.
    #[inline]
    pub fn scale(&self, r: f32) -> f32 {
        let (j, w) = Self::row(r);
        self.scale[j] * (1.0 - w) + self.scale[j + 1] * w
    }
}

/// The material's parameters at one point of a surface.
#[derive(Clone, Copy, Debug)]
pub struct PbrParams {
    /// Base colour, linear RGB in [0, 1].
    pub base_color: Vec3A,
    /// Metallic, in [0, 1].
    pub metallic: f32,
    /// Perceptual roughness in [0, 1]; α = roughness².
    pub roughness: f32,
    /// Transmission, in [0, 1].
    pub transmission: f32,
}

/// The BSDF at one point: [`PbrParams`] with the coat's table.
#[derive(Clone, Copy, Debug)]
pub struct PbrBsdf<'a> {
    p: PbrParams,
    distribution: TrowbridgeReitz,
    coat: &'a CoatTable,
}

/// A direction drawn from a [`PbrBsdf`].
#[derive(Clone, Copy, Debug)]
pub struct PbrSample {
    /// The direction, in the shading frame (below the surface: transmitted).
    pub wi: Vec3A,
    /// f |cos θi| / pdf (a delta lobe's: its reflectance or transmittance over its
    /// probability).
    pub weight: Vec3A,
    /// The mixture's density per solid angle; 0 for a delta lobe.
    pub pdf: f32,
    /// A delta lobe (smooth reflection or straight-through transmission), which light sampling
    /// cannot find.
    pub delta: bool,
}

/// Schlick's Fresnel term for reflectance `f0` at normal incidence.
#[inline]
fn schlick(f0: Vec3A, cos: f32) -> Vec3A {
    let x = (1.0 - cos).clamp(0.0, 1.0);
    let x2 = x * x;
    f0 + (Vec3A::ONE - f0) * (x2 * x2 * x)
}

/// The mirror image of `w` through the surface.
#[inline]
fn mirror(w: Vec3A) -> Vec3A {
    Vec3A::new(w.x, w.y, -w.z)
}

impl<'a> PbrBsdf<'a> {
    /// The BSDF of parameters `p` over the coat table of the material's index.
    pub fn new(p: PbrParams, coat: &'a CoatTable) -> Self {
        Self {
            p,
            distribution: TrowbridgeReitz::from_roughness(p.roughness),
            coat,
        }
    }

    /// Whether the reflection and transmission lobes are deltas.
    #[inline]
    pub fn is_smooth(&self) -> bool {
        self.distribution.is_smooth()
    }

    /// Whether any light passes through.
    #[inline]
    pub fn transmits(&self) -> bool {
        self.p.metallic < 1.0 && self.p.transmission > 0.0
    }

    #[inline]
    fn coat_t(&self, mu: f32) -> f32 {
        self.coat
            .transmittance(self.p.roughness, self.is_smooth(), mu)
    }

    /// The reflection lobe's colour at o·h = `cos`: the metal's Schlick term and the coat's
    /// dielectric Fresnel, mixed by metallic.
    #[inline]
    fn reflectance(&self, cos: f32) -> Vec3A {
        let m = self.p.metallic;
        let dielectric = fresnel_dielectric(cos.clamp(0.0, 1.0), self.coat.eta).0;
        schlick(self.p.base_color, cos) * m + Vec3A::splat((1.0 - m) * dielectric)
    }

    /// (reflection, base, transmission) lobe probabilities for a view at cos θo = `mu`; all
    /// zero where the material is black from this side.
    fn lobes(&self, mu: f32) -> (f32, f32, f32) {
        let PbrParams {
            base_color: c,
            metallic: m,
            transmission: t,
            ..
        } = self.p;
        let through = self.coat_t(mu);
        let lum = (c.x + c.y + c.z) * (1.0 / 3.0);
        // The coat reflects something at every angle unless its index is one.
        let floor = if self.coat.eta != 1.0 { 1e-3 } else { 0.0 };
        let s = (m + (1.0 - m) * (1.0 - through)).max(floor);
        let d = (1.0 - m) * (1.0 - t) * through * lum;
        let tr = (1.0 - m) * t * through * lum;
        let sum = s + d + tr;
        if !(sum > 0.0) {
            return (0.0, 0.0, 0.0);
        }
        (s / sum, d / sum, tr / sum)
    }

    /// f(o, i) |cos θi| of the lobes light sampling can find (all but the smooth ones), in the
    /// shading frame; zero unless `o` is above the surface.
    pub fn eval(&self, o: Vec3A, i: Vec3A) -> Vec3A {
        if !(o.z > 0.0) {
            return Vec3A::ZERO;
        }
        let PbrParams {
            base_color: c,
            metallic: m,
            transmission: t,
            ..
        } = self.p;
        let d = &self.distribution;
        if i.z > 0.0 {
            let base = c
                * ((1.0 - m)
                    * (1.0 - t)
                    * self.coat.scale(self.p.roughness)
                    * self.coat_t(o.z)
                    * self.coat_t(i.z)
                    * i.z);
            if self.is_smooth() {
                return base;
            }
            let Some(h) = half_vector(o, i) else {
                return base;
            };
            let rho = d.d(h) * d.g(o, i) / (4.0 * o.z);
            base + self.reflectance(o.dot(h).max(0.0)) * rho
        } else if i.z < 0.0 && self.transmits() && !self.is_smooth() {
            let i = mirror(i);
            let Some(h) = half_vector(o, i) else {
                return Vec3A::ZERO;
            };
            let f = fresnel_dielectric(o.dot(h).max(0.0), self.coat.eta).0;
            let rho = d.d(h) * d.g(o, i) / (4.0 * o.z);
            c * ((1.0 - m) * t * (1.0 - f) * rho)
        } else {
            Vec3A::ZERO
        }
    }

    /// The density [`PbrBsdf::sample`] draws `i` with, but for the delta lobes.
    pub fn pdf(&self, o: Vec3A, i: Vec3A) -> f32 {
        if !(o.z > 0.0) {
            return 0.0;
        }
        let (ps, pd, pt) = self.lobes(o.z);
        let smooth = self.is_smooth();
        if i.z > 0.0 {
            let glossy = if smooth {
                0.0
            } else {
                self.distribution.reflection_pdf(o, i)
            };
            ps * glossy + pd * cosine_hemisphere_pdf(i.z)
        } else if i.z < 0.0 && pt > 0.0 && !smooth {
            pt * self.distribution.reflection_pdf(o, mirror(i))
        } else {
            0.0
        }
    }

    /// A direction from `u` (the square) and `u_lobe` (the lobe choice), or `None` where it
    /// would leave on the wrong side, the material is black, or `o` is not above the surface.
    pub fn sample(&self, o: Vec3A, u: Vec2, u_lobe: f32) -> Option<PbrSample> {
        if !(o.z > 0.0) {
            return None;
        }
        let (ps, pd, pt) = self.lobes(o.z);
        let smooth = self.is_smooth();
        let i = if u_lobe < ps {
            if smooth {
                return Some(PbrSample {
                    wi: Vec3A::new(-o.x, -o.y, o.z),
                    weight: self.reflectance(o.z) / ps,
                    pdf: 0.0,
                    delta: true,
                });
            }
            let i = reflect_about(o, self.distribution.sample_visible(o, u));
            if !(i.z > 0.0) {
                return None;
            }
            i
        } else if u_lobe < ps + pd || pt == 0.0 {
            if pd == 0.0 {
                return None;
            }
            square_to_cosine_hemisphere(u)
        } else {
            let PbrParams {
                base_color: c,
                metallic: m,
                transmission: t,
                ..
            } = self.p;
            if smooth {
                let f = fresnel_dielectric(o.z, self.coat.eta).0;
                return Some(PbrSample {
                    wi: -o,
                    weight: c * ((1.0 - m) * t * (1.0 - f) / pt),
                    pdf: 0.0,
                    delta: true,
                });
            }
            let i = reflect_about(o, self.distribution.sample_visible(o, u));
            if !(i.z > 0.0) {
                return None;
            }
            mirror(i)
        };
        let pdf = self.pdf(o, i);
        if !(pdf > 0.0) {
            return None;
        }
        Some(PbrSample {
            wi: i,
            weight: self.eval(o, i) / pdf,
            pdf,
            delta: false,
        })
    }
}

/// A scalar parameter: `factor`, times a texture's channel where one is given (glTF's rule).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScalarParam {
    /// The constant, or the texture's multiplier.
    pub factor: f32,
    /// A texture (an index into the scene's textures) and its channel, 0 to 2 (R, G, B).
    pub texture: Option<(u32, u8)>,
}

impl ScalarParam {
    /// A constant.
    pub fn constant(factor: f32) -> Self {
        Self {
            factor,
            texture: None,
        }
    }

    #[inline]
    fn at(&self, textures: &[Arc<Texture>], uv: Vec2) -> f32 {
        match self.texture {
            None => self.factor,
            Some((t, c)) => {
                let texel = textures[t as usize].lookup(uv);
                (self.factor * texel[usize::from(c.min(2))]).clamp(0.0, 1.0)
            }
        }
    }
}

/// A tangent-space normal map: the texture, and the scale of its x and y (glTF's `scale`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalMap {
    /// An index into the scene's textures (decoded without the sRGB curve).
    pub texture: u32,
    /// Multiplies the map's x and y before normalising.
    pub scale: f32,
}

/// A `pbr` material as a scene builds it: each parameter a constant or a texture, the normal
/// map, and the coat's table. Kept beside the materials ([`crate::material::Bsdf::Pbr`] holds its index).
#[derive(Clone, Debug)]
pub struct PbrMaterial {
    /// Base colour (linear), or the multiplier of `base_texture`.
    pub base_color: Vec3A,
    /// A colour texture (an index into the scene's textures, sRGB-decoded).
    pub base_texture: Option<u32>,
    /// Metallic.
    pub metallic: ScalarParam,
    /// Perceptual roughness.
    pub roughness: ScalarParam,
    /// Transmission (thin-walled).
    pub transmission: ScalarParam,
    /// Normal map, for meshes with texture coordinates.
    pub normal_map: Option<NormalMap>,
    /// The coat of the material's index.
    pub coat: Arc<CoatTable>,
}

impl PbrMaterial {
    /// Whether any parameter or the normal map is read from a texture (which needs texture
    /// coordinates).
    pub fn is_textured(&self) -> bool {
        self.base_texture.is_some()
            || self.metallic.texture.is_some()
            || self.roughness.texture.is_some()
            || self.transmission.texture.is_some()
            || self.normal_map.is_some()
    }

    /// The parameters at texture coordinates `uv`.
    #[inline]
    pub fn params(&self, textures: &[Arc<Texture>], uv: Vec2) -> PbrParams {
        let base_color = match self.base_texture {
            None => self.base_color,
            Some(t) => {
                (self.base_color * textures[t as usize].lookup(uv)).clamp(Vec3A::ZERO, Vec3A::ONE)
            }
        };
        PbrParams {
            base_color,
            metallic: self.metallic.at(textures, uv),
            roughness: self.roughness.at(textures, uv),
            transmission: self.transmission.at(textures, uv),
        }
    }

    /// The shading normal `ns` bent by the normal map at `frame`, or `ns` itself where the
    /// frame is degenerate or the map's normal is not a direction.
    ///
    /// The map's texel t gives n = (2t − 1) scaled by (s, s, 1) in the frame (T, B, ns). Where
    /// the mesh has vertex tangents (glTF's, given or MikkTSpace's), T is the interpolated
    /// tangent's part across ns and B = ns × T · w, glTF's rule, so a map baked against those
    /// tangents reads back as baked, smooth across triangles and mirrored halves alike. Without
    /// them T is the part of the triangle's ∂p/∂u across ns and B = ns × T, turned to point
    /// along ∂p/∂v (Mitsuba's `normalmap` frame). Either way the green channel points up the
    /// image, as in glTF and OpenGL.
    pub fn bend(&self, textures: &[Arc<Texture>], frame: &UvFrame, ns: Vec3A) -> Vec3A {
        let Some(map) = self.normal_map else {
            return ns;
        };
        let t = textures[map.texture as usize].lookup(frame.uv) * 2.0 - Vec3A::ONE;
        let across = |v: Vec3A| (v - ns * ns.dot(v)).try_normalize();
        let vertex = frame
            .tangent
            .and_then(|t4| Some((across(Vec3A::from(t4.truncate()))?, t4.w)));
        let (tangent, bitangent) = match vertex {
            Some((tangent, w)) => (tangent, ns.cross(tangent) * w),
            None => {
                let Some(tangent) = across(frame.dpdu) else {
                    return ns;
                };
                let bitangent = ns.cross(tangent);
                if bitangent.dot(frame.dpdv) < 0.0 {
                    (tangent, -bitangent)
                } else {
                    (tangent, bitangent)
                }
            }
        };
        (tangent * (t.x * map.scale) + bitangent * (t.y * map.scale) + ns * t.z)
            .try_normalize()
            .unwrap_or(ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_matches_a_smooth_coat_and_a_plastics_table() {
        let table = CoatTable::new(1.5);
        for mu in [0.1f32, 0.5, 1.0] {
            let want = 1.0 - fresnel_dielectric(mu, 1.5).0;
            assert!(
                (table.transmittance(0.0, false, mu) - want).abs() < 2e-3,
                "{mu}"
            );
            assert_eq!(table.transmittance(0.3, true, mu), want);
        }
        // At a grid roughness the entry is the plastic's own integral, at a coarser rule.
        let plastic = super::super::Plastic::new(Vec3A::ONE, 0.5, 1.5);
        for mu in [0.2f32, 0.6, 1.0] {
            let (a, b) = (
                table.transmittance(0.5, false, mu),
                plastic.transmittance(mu),
            );
            assert!((a - b).abs() < 5e-3, "μ {mu}: {a} vs {b}");
        }
        // An index of one is no coat: everything passes, and the base is Lambertian.
        let none = CoatTable::new(1.0);
        assert_eq!(none.transmittance(0.7, false, 0.3), 1.0);
        assert!((none.scale(0.7) - std::f32::consts::FRAC_1_PI).abs() < 1e-6);
    }
}
