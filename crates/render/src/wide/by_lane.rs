//! The many-path tracer's steps taken one lane at a time, by the scalar trace's own code: a
//! vertex on a material the lanes do not shade, a light they do not sample, a path leaving
//! the scene, and the queries of a scene that is not one BVH leaf. Each takes the lane's path
//! out of the lanes as the scalar trace holds it and puts back what changed, so a sample has
//! the same bits whichever tracer runs it.

use glam::{Vec2, Vec3A};

use super::{finish, lane3, set3, Lanes, Wide};
use crate::integrator::{diffuse_light, escape, light_groups, NoGuide, Strategy};
use crate::interaction::{Hit, Shading, SurfacePoint};
use crate::material::port::Path;
use crate::packet::{HitKeep, LaneHits};
use crate::primitive::Primitive;
use crate::scene::Scene;
use crate::util::math::{offset_ray_origin, Ray};

impl Wide<'_> {
    /// What lane `lane`'s path finds as it leaves the scene (an environment, suns): the scalar
    /// trace's `escape`.
    #[inline(never)]
    pub(super) fn escape_in_lane<const N: usize>(&self, s: &mut Lanes<N>, lane: usize) {
        let mut path = lane_path(s, lane);
        let d = lane3(&s.d, lane);
        escape(
            &mut path,
            self.scene,
            Strategy::Mis,
            d,
            &mut NoGuide,
            s.depth[lane],
        );
        set3(&mut s.l, lane, path.l);
    }

    /// Next-event estimation at lane `lane`'s diffuse vertex `sp` (albedo `albedo`, the path
    /// leaving towards `wo`) for lights the lanes do not sample in lanes: the scalar trace's
    /// (`integrator::diffuse_light`), with the numbers `u`.
    #[inline(never)]
    pub(super) fn light_in_lane<const N: usize>(
        &self,
        s: &mut Lanes<N>,
        lane: usize,
        sp: &SurfacePoint,
        wo: Vec3A,
        albedo: Vec3A,
        u: (f32, Vec2),
    ) {
        // Only points that shade with their geometric normal reach here.
        let (_, at) = Shading::facing(sp, wo, false);
        let p_out = offset_ray_origin(sp.p, sp.err, at.n);
        for group in 0..light_groups(self.scene, Strategy::Mis) {
            let light = diffuse_light(self.scene, Strategy::Mis, sp, &at, p_out, group, u);
            if let Some((le, f)) = light {
                let l = lane3(&s.l, lane) + lane3(&s.beta, lane) * albedo * le * f;
                set3(&mut s.l, lane, l);
            }
        }
    }

    /// What lane `lane`'s light sample of the second group of lights adds to its path (the
    /// scalar trace's, as [`Wide::light_in_lane`]), where the lanes draw the first group's
    /// themselves (`sky.rs`): added after it, in the scalar trace's order.
    #[inline(never)]
    pub(super) fn later_light_in_lane<const N: usize>(
        &self,
        s: &Lanes<N>,
        lane: usize,
        sp: &SurfacePoint,
        wo: Vec3A,
        albedo: Vec3A,
        u: (f32, Vec2),
    ) -> Option<Vec3A> {
        if light_groups(self.scene, Strategy::Mis) < 2 {
            return None;
        }
        let (_, at) = Shading::facing(sp, wo, false);
        let p_out = offset_ray_origin(sp.p, sp.err, at.n);
        let (le, f) = diffuse_light(self.scene, Strategy::Mis, sp, &at, p_out, 1, u)?;
        Some(lane3(&s.beta, lane) * albedo * le * f)
    }

    /// Lane `lane`'s vertex at `here`, on a material the lanes do not model: the scalar
    /// trace's step ([`Setup::leave`]) on the lane's path, taken out of the lanes and put
    /// back. Returns whether the path goes on; one that ends is written to `out`. Out of line,
    /// so that the diffuse bounce's loop stays as small as the Cornell box had it.
    #[inline(never)]
    pub(super) fn leave_in_lane<const N: usize>(
        &self,
        s: &mut Lanes<N>,
        out: &mut [Vec3A],
        lane: usize,
        here: (&Ray, &Hit, &Primitive, &SurfacePoint),
    ) -> bool {
        let mut path = lane_path(s, lane);
        let mut light_uv = [s.light_uv[0][lane], s.light_uv[1][lane]];
        let mut depth = s.depth[lane];
        let sampler = s.sampler[lane];
        let next = self.setup.leave(
            self.scene,
            here,
            &sampler,
            &mut light_uv,
            &mut path,
            &mut NoGuide,
            &mut depth,
        );
        set3(&mut s.l, lane, path.l);
        let Some(next) = next else {
            finish(s, out, lane);
            return false;
        };
        set3(&mut s.o, lane, next.o);
        set3(&mut s.d, lane, next.d);
        set3(&mut s.beta, lane, path.beta);
        set3(&mut s.prev_p, lane, path.prev_p);
        s.prev_pdf[lane] = path.prev_pdf;
        s.eta[lane] = path.eta_scale;
        s.specular = s.specular & !(1 << lane) | u32::from(path.specular) << lane;
        s.light_uv[0][lane] = light_uv[0];
        s.light_uv[1][lane] = light_uv[1];
        s.depth[lane] = depth;
        true
    }
}

/// Lane `lane`'s path as the scalar trace holds it.
#[inline(always)]
fn lane_path<const N: usize>(s: &Lanes<N>, lane: usize) -> Path {
    Path {
        l: lane3(&s.l, lane),
        beta: lane3(&s.beta, lane),
        eta_scale: s.eta[lane],
        specular: s.specular >> lane & 1 == 1,
        prev_pdf: s.prev_pdf[lane],
        prev_p: lane3(&s.prev_p, lane),
        medium: Vec3A::ZERO,
    }
}

/// The closest hits of the lanes in `active`, asked of the scene one ray at a time, for a scene
/// the packet tests do not answer, each lane's mesh hit kept in `keep`. Out of line, as the
/// Cornell box never calls it.
#[inline(never)]
pub(super) fn closest_by_lane<const N: usize>(
    scene: &Scene,
    active: u32,
    ray: impl Fn(usize) -> Ray,
    keep: &mut HitKeep<N>,
) -> LaneHits<N> {
    let mut hits = LaneHits {
        hit: 0,
        t: [0.0; N],
        prim: [0; N],
        part: [0; N],
    };
    for lane in (0..N).filter(|lane| active >> lane & 1 == 1) {
        if let Some(h) = scene.intersect(&ray(lane), f32::INFINITY) {
            hits.hit |= 1 << lane;
            hits.t[lane] = h.t;
            hits.prim[lane] = h.prim;
            hits.part[lane] = h.part;
            // Where the hit is a mesh, the last mesh hit the query kept is this one (a mesh only
            // reports, and keeps, a hit nearer than any before it).
            keep.mesh_hit[lane] = crate::mesh::kept_hit();
        }
    }
    hits
}

/// Which of the shadow rays of the lanes in `lanes` something blocks (t in (0, `t_max`), as
/// `LightSample::shadow_ray` sets it), asked of the scene one ray at a time.
#[inline(never)]
pub(super) fn blocked_by_lane(
    scene: &Scene,
    lanes: u32,
    ray: impl Fn(usize) -> Ray,
    t_max: f32,
) -> u32 {
    (0..32)
        .filter(|lane| lanes >> lane & 1 == 1)
        .filter(|&lane| scene.occluded(&ray(lane), t_max))
        .fold(0, |bits, lane| bits | 1 << lane)
}
