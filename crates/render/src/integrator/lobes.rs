//! Next-event estimation through a material's lobe (rough metal, plastic, rough glass,
//! glTF's `pbr`): a light sample, its shadow ray, and the power heuristic against the lobe's
//! own density ([`crate::material::port::Lobe`]). What [`super::vertex`] lends a material
//! through [`crate::material::port::At`].

use glam::{Vec2, Vec3A};

use super::{light_groups, sample_light, visible_light};
use crate::interaction::{Shading, SurfacePoint};
use crate::material::port::{Lobe, Path};
use crate::scene::Scene;
use crate::settings::Strategy;
use crate::util::math::offset_ray_origin;
use crate::util::sampling::power_heuristic;

/// Next-event estimation through a reflection lobe (rough metal, plastic): a light sample
/// from `p_out`, weighed by the power heuristic against the lobe's own density under MIS.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn reflected_light<E, P>(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    sp: &SurfacePoint,
    at: &Shading,
    p_out: Vec3A,
    u: (f32, Vec2),
    lobe: Lobe<'_, E, P>,
) where
    E: Fn(Vec3A) -> Vec3A,
    P: Fn(Vec3A) -> f32,
{
    for group in 0..light_groups(scene, strategy) {
        let Some((ls, _)) = visible_light(scene, strategy, sp, at, p_out, group, u) else {
            continue;
        };
        let i = lobe.frame.to_local(ls.wi);
        let f = (lobe.eval)(i);
        let w = if strategy == Strategy::Mis && !ls.delta {
            power_heuristic(ls.pdf, (lobe.pdf)(i))
        } else {
            1.0
        };
        path.l += path.beta * ls.le() * f * (w / ls.pdf);
    }
}

/// Next-event estimation through a lobe that reflects and transmits (rough glass, a `pbr`
/// surface that lets light through): a light sample on either side, its shadow ray leaving
/// from that side, weighed by the power heuristic against the lobe's own density under MIS.
#[inline(always)]
pub(super) fn two_sided_light<E, P>(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    sp: &SurfacePoint,
    at: &Shading,
    u: (f32, Vec2),
    lobe: Lobe<'_, E, P>,
) where
    E: Fn(Vec3A) -> Vec3A,
    P: Fn(Vec3A) -> f32,
{
    for group in 0..light_groups(scene, strategy) {
        two_sided_sample(scene, strategy, path, sp, at, (group, u), &lobe);
    }
}

/// One light sample of [`two_sided_light`], from group `group`.
#[inline(always)]
fn two_sided_sample<E, P>(
    scene: &Scene,
    strategy: Strategy,
    path: &mut Path,
    sp: &SurfacePoint,
    at: &Shading,
    (group, u): (usize, (f32, Vec2)),
    lobe: &Lobe<'_, E, P>,
) where
    E: Fn(Vec3A) -> Vec3A,
    P: Fn(Vec3A) -> f32,
{
    let Some(ls) = sample_light(scene, strategy, sp.p, group, u) else {
        return;
    };
    let cos = at.ns.dot(ls.wi);
    let side = if cos > 0.0 { at.n } else { -at.n };
    // The geometric normal must put the light on the side the shading one does.
    let reachable = !at.shaded || at.n.dot(ls.wi) * side.dot(at.n) > 0.0;
    if !(cos != 0.0 && reachable && ls.may_emit()) {
        return;
    }
    let p_out = offset_ray_origin(sp.p, sp.err, side);
    let (shadow, t_max) = ls.shadow_ray(p_out);
    if scene.occluded(&shadow, t_max) {
        return;
    }
    let i = lobe.frame.to_local(ls.wi);
    let f = (lobe.eval)(i);
    let w = if strategy == Strategy::Mis && !ls.delta {
        power_heuristic(ls.pdf, (lobe.pdf)(i))
    } else {
        1.0
    };
    path.l += path.beta * ls.le() * (f * w / ls.pdf);
}
