//! Lights: sampling a point on an emitter as seen from a shading point, and the density of that
//! choice in solid angle (which MIS needs for directions found by BSDF sampling). Area lights
//! are surfaces; punctual lights (point, spot, directional: glTF's) have no surface, so no ray
//! can hit them and only light sampling reaches them: their samples are marked `delta`, take
//! no MIS weight, and are drawn even where BSDF sampling alone is asked for
//! ([`Lights::sample_delta`]).

use std::f32::consts::PI;

use std::sync::Arc;

use glam::{Vec2, Vec3A};

use crate::envmap::EnvMap;

use crate::shape::{sphere_point_error, sphere_roots, sphere_roots_f64, Parallelogram};
use crate::util::distribution::Distribution1D;
use crate::util::math::Frame;
use crate::util::sampling::{square_to_uniform_cone, square_to_uniform_sphere};

mod falloff;
mod lights;
mod sample;

pub use falloff::Falloff;
pub use lights::Lights;
pub use sample::LightSample;

/// The part of an emitter that can be sampled.
#[derive(Clone, Debug)]
pub enum LightShape {
    /// A parallelogram (a rect, or one face of a box).
    Quad(Parallelogram),
    /// A sphere.
    Sphere {
        /// Centre.
        center: Vec3A,
        /// Radius.
        radius: f32,
    },
    /// An emissive mesh, sampled uniformly by area (a triangle by its share of the area,
    /// then a point uniformly on it).
    Mesh(MeshLight),
    /// A point light of intensity [`Light::radiance`] (per steradian) in every direction.
    Point {
        /// Where it is.
        position: Vec3A,
    },
    /// A spot light: a point light whose intensity falls to zero at its outer cone, as
    /// `falloff` says.
    Spot {
        /// Where it is.
        position: Vec3A,
        /// Unit direction it shines along.
        axis: Vec3A,
        /// cos of the outer cone's half-angle.
        cos_outer: f32,
        /// How the intensity falls off towards the outer cone.
        falloff: Falloff,
    },
    /// Parallel light of irradiance [`Light::radiance`] (on a surface facing it) from
    /// infinitely far away.
    Directional {
        /// Unit direction towards the light.
        towards: Vec3A,
        /// The radius of a sphere around the scene's finite objects, which a shadow ray must
        /// leave to reach the light, and whose disk the light's power falls on.
        reach: f32,
    },
    /// A directional light with an angular diameter (a sun): radiance [`Light::radiance`] from
    /// every direction within a cone around `towards`, infinitely far away. Not a delta: a
    /// ray that escapes the scene inside the cone reads it ([`Lights::suns`]), so BSDF
    /// sampling finds it and MIS combines the two.
    Sun {
        /// Unit direction towards the sun's centre.
        towards: Vec3A,
        /// sin² of the cone's half-angle: what a direction's offset from `towards` is tested
        /// against, since |d × towards|² keeps its precision for a small sun where the cosine
        /// rounds to 1.
        sin2_max: f32,
        /// 1 − cos of the cone's half-angle, computed without cancellation.
        one_minus_cos: f32,
        /// As for [`LightShape::Directional`].
        reach: f32,
    },
    /// An environment map: light from every direction, infinitely far away, sampled by the
    /// map's own distribution ([`EnvMap::sample`]). No ray hits it as a surface: a ray that
    /// escapes the scene reads it ([`crate::scene::Environment`]).
    Environment {
        /// The map.
        map: Arc<EnvMap>,
        /// As for [`LightShape::Directional`].
        reach: f32,
    },
}

/// The world-space triangles of an emissive mesh instance.
#[derive(Clone, Debug)]
pub struct MeshLight {
    tris: Vec<LightTriangle>,
    select: Distribution1D,
    area: f32,
}

/// One triangle of a mesh light: its vertices and front normal in one cache line, since a
/// light sample reads both and a large light's triangles are picked at random.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct LightTriangle {
    p: [Vec3A; 3],
    n: Vec3A,
}

impl MeshLight {
    /// From world-space triangles with their front normals and areas; `None` when the total
    /// area is zero.
    pub fn new(tris: Vec<([Vec3A; 3], Vec3A, f32)>) -> Option<Self> {
        let areas: Vec<f32> = tris.iter().map(|t| t.2).collect();
        let select = Distribution1D::new(&areas)?;
        let area = areas.iter().map(|&a| f64::from(a)).sum::<f64>() as f32;
        let tris = tris
            .into_iter()
            .map(|(p, n, _)| LightTriangle { p, n })
            .collect();
        Some(Self { tris, select, area })
    }

    /// Total area.
    pub fn area(&self) -> f32 {
        self.area
    }

    /// The triangle `u.x` picks, with `u.x` stretched back over [0, 1) for the point.
    #[inline]
    fn pick(&self, u: Vec2) -> (usize, [f32; 3]) {
        let (i, ux) = self.select.sample_remap(u.x);
        (i, crate::mesh::triangle::sample_uniform(ux, u.y))
    }

    /// A point uniformly distributed by area: (point, its front normal, the bound on its
    /// rounding error), the triangle picked once for all three.
    #[inline]
    pub fn sample(&self, u: Vec2) -> (Vec3A, Vec3A, Vec3A) {
        let (i, b) = self.pick(u);
        let LightTriangle { p: [p0, p1, p2], n } = self.tris[i];
        let err = crate::mesh::triangle::point_error(b, p0, p1, p2);
        (p0 * b[0] + p1 * b[1] + p2 * b[2], n, err)
    }
}

/// One emitter.
#[derive(Clone, Debug)]
pub struct Light {
    /// Geometry.
    pub shape: LightShape,
    /// Emitted radiance.
    pub radiance: Vec3A,
    /// Whether both sides emit.
    pub two_sided: bool,
    /// A mesh light's emission texture (glTF's `emissiveTexture`), which scales `radiance`
    /// point by point; `None` for every other light.
    pub texture: Option<Arc<EmissionTexture>>,
}

/// An emission texture on a mesh light: the texture, each light triangle's texture
/// coordinates (in the order of [`MeshLight`]'s triangles), and the texture's mean, which
/// scales the light's share of light samples.
#[derive(Debug)]
pub struct EmissionTexture {
    /// The texture (sRGB-decoded colour).
    pub texture: Arc<crate::texture::Texture>,
    /// Texture coordinates of each light triangle's corners.
    pub uvs: Vec<[glam::Vec2; 3]>,
    /// The mean texel.
    pub mean: Vec3A,
}

impl EmissionTexture {
    /// The texel at the point of mesh light `m` that light-sample numbers `u` pick.
    #[inline]
    fn at_sample(&self, m: &MeshLight, u: Vec2) -> Vec3A {
        let (i, b) = m.pick(u);
        let [a, c, d] = self.uvs.get(i).copied().unwrap_or_default();
        self.texture.lookup(a * b[0] + c * b[1] + d * b[2])
    }
}

/// A point sampled on an area light ([`Light::sample`]), before the light is chosen.
struct AreaSample {
    /// The point.
    x: Vec3A,
    /// Its normal.
    n: Vec3A,
    /// The bound on its rounding error.
    err: Vec3A,
    /// Unit direction from the shading point to it.
    wi: Vec3A,
    /// Density in solid angle, without selection.
    pdf: f32,
}

impl Light {
    fn power_weight(&self) -> f32 {
        let radiance = match &self.texture {
            Some(t) => self.radiance * t.mean,
            None => self.radiance,
        };
        let sum = radiance.x + radiance.y + radiance.z;
        let area = match &self.shape {
            LightShape::Quad(q) => q.area,
            LightShape::Sphere { radius, .. } => 4.0 * PI * radius * radius,
            LightShape::Mesh(m) => m.area,
            // Intensity times the solid angle it fills (the spot's cone taken halfway through
            // its falloff), or irradiance times the scene's cross-section.
            LightShape::Point { .. } => return 4.0 * PI * sum,
            LightShape::Spot {
                cos_outer, falloff, ..
            } => return 2.0 * PI * (1.0 - falloff.cos_middle(*cos_outer)) * sum,
            LightShape::Directional { reach, .. } => return PI * reach * reach * sum,
            // Its irradiance on a surface facing it, L·π·sin²θ, through the cross-section.
            LightShape::Sun {
                reach, sin2_max, ..
            } => return PI * reach * reach * PI * sin2_max * sum,
            // Radiance over the sphere through the scene's cross-section π·reach², as a
            // directional light's irradiance is.
            LightShape::Environment { map, reach } => return PI * reach * reach * map.power(),
        };
        let sides = if self.two_sided { 2.0 } else { 1.0 };
        area * sides * (self.radiance.x + self.radiance.y + self.radiance.z)
    }

    /// Radiance leaving point with normal `n` in direction `w` (towards the viewer).
    #[inline]
    pub fn emitted(&self, n: Vec3A, w: Vec3A) -> Vec3A {
        if self.two_sided || n.dot(w) > 0.0 {
            self.radiance
        } else {
            Vec3A::ZERO
        }
    }

    /// Whether it has a surface a ray can hit (quad, sphere, mesh): what [`Lights::sample`]
    /// samples inline.
    #[inline]
    fn is_area(&self) -> bool {
        matches!(
            self.shape,
            LightShape::Quad(_) | LightShape::Sphere { .. } | LightShape::Mesh(_)
        )
    }

    /// Whether it is infinitely far away (a map, a sun, a directional light): its power is
    /// measured through the scene's cross-section.
    #[inline]
    pub fn is_distant(&self) -> bool {
        matches!(
            self.shape,
            LightShape::Environment { .. }
                | LightShape::Sun { .. }
                | LightShape::Directional { .. }
        )
    }

    /// Whether it is punctual (no surface).
    #[inline]
    pub fn is_delta(&self) -> bool {
        matches!(
            self.shape,
            LightShape::Point { .. } | LightShape::Spot { .. } | LightShape::Directional { .. }
        )
    }

    /// A sun's radiance and sampling density (solid angle, without selection) along a ray
    /// leaving in unit direction `d`, if `d` points into its disk.
    #[inline]
    pub fn sun_seen(&self, d: Vec3A) -> Option<(Vec3A, f32)> {
        let LightShape::Sun {
            towards,
            sin2_max,
            one_minus_cos,
            ..
        } = self.shape
        else {
            return None;
        };
        (d.dot(towards) > 0.0 && d.cross(towards).length_squared() <= sin2_max)
            .then(|| (self.radiance, 1.0 / (2.0 * PI * one_minus_cos)))
    }

    /// A punctual light as seen from `p`: the shadow ray's end, the unit direction to it, and
    /// the radiance it delivers along that direction per unit solid-angle density (I/d² for
    /// a point light, times the spot's falloff; E for a directional one). `None` where it
    /// gives nothing.
    fn sample_delta(&self, p: Vec3A) -> Option<(Vec3A, Vec3A, Vec3A)> {
        match self.shape {
            LightShape::Point { position } => {
                let (wi, d2) = dir_and_dist2(p, position)?;
                Some((position, wi, self.radiance / d2))
            }
            LightShape::Spot {
                position,
                axis,
                cos_outer,
                falloff,
            } => {
                let (wi, d2) = dir_and_dist2(p, position)?;
                let f = falloff.at(axis.dot(-wi), cos_outer);
                if f == 0.0 {
                    return None;
                }
                Some((position, wi, self.radiance * (f / d2)))
            }
            LightShape::Directional { towards, reach } => {
                // Past the sphere of the scene's finite objects, wherever `p` is in it.
                let x = p + towards * (2.0 * reach + p.length());
                Some((x, towards, self.radiance))
            }
            _ => None,
        }
    }

    /// Samples a point as seen from `p`: the point, its normal, unit direction from `p`,
    /// density in solid angle without selection, and the bound on the point's rounding error
    /// (found in the same arm as the point: a second match on the shape, and a mesh light's
    /// second pick of its triangle, cost every light sample).
    ///
    /// Inlined for quads, whose sample is a few operations: called, it cost the integrator a
    /// call and the reloads of a dozen spilled registers after it. Spheres stay a call.
    /// Always: with the punctual lights' arm, LLVM stopped inlining it of its own accord.
    #[inline(always)]
    fn sample(&self, p: Vec3A, u: Vec2) -> Option<AreaSample> {
        match &self.shape {
            LightShape::Quad(q) => {
                let x = q.point(u.x, u.y);
                let (wi, pdf) = area_to_solid_angle(p, x, q.normal, q.area)?;
                Some(AreaSample {
                    x,
                    n: q.normal,
                    err: q.point_error(u.x, u.y),
                    wi,
                    pdf,
                })
            }
            LightShape::Sphere { center, radius } => {
                let (x, n, wi, pdf) = sample_sphere(*center, *radius, p, u)?;
                let err = sphere_point_error(*center, x - *center);
                Some(AreaSample { x, n, err, wi, pdf })
            }
            LightShape::Mesh(m) => {
                let (x, n, err) = m.sample(u);
                let (wi, pdf) = area_to_solid_angle(p, x, n, m.area)?;
                Some(AreaSample { x, n, err, wi, pdf })
            }
            _ => None,
        }
    }

    /// Density (solid angle, without selection) of sampling point `x` with normal `n` from `p`.
    fn pdf(&self, p: Vec3A, x: Vec3A, n: Vec3A) -> f32 {
        let area = match &self.shape {
            LightShape::Quad(q) => q.area,
            LightShape::Sphere { center, radius } => {
                let dc2 = (*center - p).length_squared();
                let r2 = radius * radius;
                if cone_applies(dc2, r2) {
                    return 1.0 / (2.0 * PI * cone_one_minus_cos(dc2, r2));
                }
                4.0 * PI * r2
            }
            LightShape::Mesh(m) => m.area,
            _ => return 0.0,
        };
        area_to_solid_angle(p, x, n, area).map_or(0.0, |(_, pdf)| pdf)
    }
}

/// [`Light::sample`] for a sphere light.
#[inline(never)]
fn sample_sphere(
    center: Vec3A,
    radius: f32,
    p: Vec3A,
    u: Vec2,
) -> Option<(Vec3A, Vec3A, Vec3A, f32)> {
    let dc2 = (center - p).length_squared();
    let r2 = radius * radius;
    if !cone_applies(dc2, r2) {
        // Inside, or on the sphere itself: uniform area sampling.
        let n = square_to_uniform_sphere(u);
        let x = center + n * radius;
        let (wi, pdf) = area_to_solid_angle(p, x, n, 4.0 * PI * r2)?;
        return Some((x, n, wi, pdf));
    }
    // Outside: uniform in the cone of directions the sphere subtends.
    let one_minus_cos = cone_one_minus_cos(dc2, r2);
    let axis = (center - p) / dc2.sqrt();
    let wi = Frame::from_normal(axis).to_world(square_to_uniform_cone(u, one_minus_cos));
    let wi = wi.normalize();
    // In f64, as for the sphere's own hits: for a small, distant light, p + t·wi in f32 can be
    // off by more than the radius.
    let (c64, p64, w64) = (center.as_dvec3(), p.as_dvec3(), wi.as_dvec3());
    let t = match sphere_roots_f64(p, wi, center, radius) {
        Some((t0, _)) if t0 > 0.0 => t0,
        // Grazing directions can miss by rounding: use the tangent point.
        _ => (c64 - p64).dot(w64) / w64.length_squared(),
    };
    let n = ((p64 - c64) + w64 * t).normalize().as_vec3a();
    let x = center + n * radius;
    Some((x, n, wi, 1.0 / (2.0 * PI * one_minus_cos)))
}

/// Converts a uniform density 1/`area` at point `x` (normal `n`) into solid angle as seen from
/// `p`: dist²/(|cos θ_light|·area). Returns the unit direction from `p` with it; `None` where
/// the density is undefined (coincident points, or a light seen exactly edge-on).
#[inline]
fn area_to_solid_angle(p: Vec3A, x: Vec3A, n: Vec3A, area: f32) -> Option<(Vec3A, f32)> {
    let (wi, dist2) = dir_and_dist2(p, x)?;
    let cos_l = n.dot(wi).abs();
    if cos_l == 0.0 {
        return None;
    }
    Some((wi, dist2 / (cos_l * area)))
}

/// 1 − cos θmax of the cone a sphere subtends from squared centre distance `dc2`, computed as
/// sin²/(1 + cos) to avoid cancellation for small, distant spheres.
#[inline]
fn cone_one_minus_cos(dc2: f32, r2: f32) -> f32 {
    let sin2 = r2 / dc2;
    let cos_max = (1.0 - sin2).max(0.0).sqrt();
    sin2 / (1.0 + cos_max)
}

/// Whether a point at squared distance `dc2` from a sphere's centre is clearly outside it, so
/// that sampling the cone it subtends is well defined. A shading point on the emitting sphere
/// itself (a furnace, a glowing ball's own bounce) can round to either side; there the cone's
/// near root is the point itself, so such points use area sampling, which is valid anywhere.
/// `sample` and `pdf` must apply the same rule for MIS to stay consistent.
#[inline]
fn cone_applies(dc2: f32, r2: f32) -> bool {
    dc2 > r2 * 1.001
}

/// Whether `x` is in (0, ∞); NaN is not. Written against `f32::MAX` so that it compiles to
/// two float compares: LLVM turns `x > 0.0 && x.is_finite()`, and even `x < f32::INFINITY`,
/// into a class test that x86 does with a dozen or more integer operations on the bits
/// (docs/renderer.md).
#[inline]
fn positive_finite(x: f32) -> bool {
    x > 0.0 && x <= f32::MAX
}

#[inline]
fn dir_and_dist2(p: Vec3A, x: Vec3A) -> Option<(Vec3A, f32)> {
    let d = x - p;
    let dist2 = d.length_squared();
    if !positive_finite(dist2) {
        return None;
    }
    Some((d / dist2.sqrt(), dist2))
}
