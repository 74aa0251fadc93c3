//! Alpha-tested and alpha-blended surfaces (glTF's `MASK` and `BLEND`): a hit whose material
//! says the surface is not there at that point is passed through, for camera, bounce and shadow
//! rays alike, so a leaf's cut-out casts a leaf-shaped shadow.
//!
//! `MASK` keeps a hit where alpha ≥ the cutoff. `BLEND` is stochastic transparency: a hit is
//! kept with probability alpha, which is unbiased for the blended image (the expected radiance
//! is alpha × the surface's plus (1 − alpha) × what lies behind it). The uniform number that
//! decides is a hash of the ray and the triangle met, so it is a pure function of the path,
//! like every other number of the render: the same job gives the same bits.
//!
//! Only scenes with such a material take this path ([`Scene::intersect`] tests one empty
//! vector otherwise), and the many-path tracer, which models diffuse materials only, never
//! meets one.

use glam::Vec3A;

use super::Scene;
use crate::shape::Hit;
use crate::util::math::{offset_ray_origin, Ray};

/// Most surfaces a ray passes through before the next one counts as met: a bound on the work
/// of one query, far above what foliage stacks up.
const MAX_LAYERS: u32 = 64;

/// A material's alpha: `factor` times the texture's alpha at the hit.
#[derive(Clone, Copy, Debug)]
pub struct AlphaTest {
    /// glTF's base colour factor's alpha.
    pub factor: f32,
    /// A texture holding the base colour's alpha in every channel, by index into the scene's
    /// textures.
    pub texture: Option<u32>,
    /// `MASK`'s cutoff; `None` for `BLEND`.
    pub cutoff: Option<f32>,
}

impl Scene {
    /// Whether the surface is there at `hit` of `ray`.
    fn kept(&self, ray: &Ray, hit: &Hit) -> bool {
        let prim = &self.prims[hit.prim as usize];
        let Some(Some(test)) = self.alpha.get(prim.material as usize) else {
            return true;
        };
        let alpha = test.factor
            * test.texture.map_or(1.0, |t| {
                self.textures[t as usize]
                    .lookup(prim.shape.uv(ray, hit.part))
                    .x
            });
        match test.cutoff {
            Some(cutoff) => alpha >= cutoff,
            None => uniform(ray, hit) < alpha,
        }
    }

    /// The closest hit along `ray` in (0, t_max) that [`Scene::kept`] keeps, `first` being the
    /// closest of all; its `t` is along `ray`.
    #[cold]
    #[inline(never)]
    pub(super) fn alpha_tested(&self, ray: &Ray, t_max: f32, first: Hit) -> Option<Hit> {
        let (mut r, mut hit, mut base) = (*ray, first, 0.0f32);
        for _ in 0..MAX_LAYERS {
            if self.kept(&r, &hit) {
                hit.t += base;
                return Some(hit);
            }
            // On past the surface, from a point its rounding cannot re-hit.
            let s = self.prims[hit.prim as usize]
                .shape
                .surface(&r, hit.t, hit.part);
            let n = if s.n.dot(r.d) > 0.0 { s.n } else { -s.n };
            let o = offset_ray_origin(s.p, s.err, n);
            base = (o - ray.o).dot(ray.d) / ray.d.length_squared();
            r = Ray::new(o, ray.d);
            hit = self.accel().intersect(&self.prims, &r, t_max - base)?;
        }
        hit.t += base;
        Some(hit)
    }
}

/// A uniform number in [0, 1) from the ray and the triangle it meets.
fn uniform(ray: &Ray, hit: &Hit) -> f32 {
    let bits = |v: Vec3A| v.to_array().map(f32::to_bits);
    let mut h = 0x9E37_79B9_7F4A_7C15u64;
    for w in bits(ray.o)
        .into_iter()
        .chain(bits(ray.d))
        .chain([hit.prim, hit.part])
    {
        h = (h ^ u64::from(w)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 31;
    }
    (h >> 40) as f32 / (1u64 << 24) as f32
}
