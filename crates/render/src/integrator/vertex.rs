//! One vertex of a path: the material the path met scatters it ([`crate::material::Model`]'s
//! `scatter`), through what this module lends it ([`Here`], the path tracer's side of
//! [`At`]): the scene's textures and tables, next-event estimation through a lobe, the
//! Lambertian vertex with guiding, and the medium a path is in.
//!
//! A material whose vertex runs inline updates the loop's own path; one whose vertex runs out
//! of line ([`crate::material::Model::FAR`]) gets a copy, taken back even when the path ends
//! there (its direct light counts): a `&mut` to the loop's own path passed out of line would
//! make its address escape, and keep it in memory rather than in registers for every other
//! bounce. For the same reason [`Here`] holds the vertex by value, built in the branch that
//! lends it.

use std::borrow::BorrowMut;
use std::sync::Arc;

use glam::{Vec2, Vec3A};

use super::lobes::{reflected_light, two_sided_light};
use super::{diffuse, guided_vertex, Guiding};
use crate::interaction::{Hit, Shading, SurfacePoint};
use crate::material::port::{At, Lobe, Numbers, Path, Surface};
use crate::material::Tables;
use crate::mesh::UvFrame;
use crate::primitive::Primitive;
use crate::scene::{Material, Scene};
use crate::settings::Strategy;
use crate::texture::Texture;
use crate::util::math::Ray;

/// Where a path meets a surface, and how it arrived.
#[derive(Clone, Copy)]
pub(super) struct Vertex<'s> {
    pub(super) scene: &'s Scene,
    pub(super) strategy: Strategy,
    /// The ray that arrived.
    pub(super) ray: &'s Ray,
    pub(super) hit: &'s Hit,
    pub(super) prim: &'s Primitive,
    pub(super) mat: &'s Material,
    pub(super) sp: &'s SurfacePoint,
    /// The normals on the side the path arrived from.
    pub(super) at: &'s Shading,
    /// Whether it arrived on the front side.
    pub(super) front: bool,
    /// Whether the scene tracks the medium a path is in (coloured glass).
    pub(super) absorbing: bool,
}

/// Scatters `path` at `v`: adds the direct light its material gathers there and returns the
/// next ray, or `None` where the path ends.
#[inline(always)]
pub(super) fn scatter<'a, G: Guiding<'a>>(
    v: &Vertex<'_>,
    path: &mut Path,
    u: Numbers,
    guiding: &mut G,
    depth: u32,
) -> Option<Ray> {
    let bsdf = v.mat.bsdf;
    if !bsdf.is_far() {
        let mut near = Here {
            v: *v,
            path,
            u,
            guiding,
            depth,
        };
        return bsdf.scatter_if::<_, false>(&mut near).flatten();
    }
    let mut far = Here {
        v: *v,
        path: *path,
        u,
        guiding,
        depth,
    };
    let next = bsdf.scatter_if::<_, true>(&mut far).flatten();
    *path = far.path;
    next
}

/// A vertex as a material sees it: the path tracer's side of [`At`]. `H` holds the path: the
/// loop's own (`&mut Path`), or a copy (`Path`).
struct Here<'s, 'g, G, H> {
    v: Vertex<'s>,
    path: H,
    u: Numbers,
    guiding: &'g mut G,
    depth: u32,
}

impl<'s, G, H> Surface<'s> for Here<'s, '_, G, H> {
    #[inline(always)]
    fn ray(&self) -> &Ray {
        self.v.ray
    }
    #[inline(always)]
    fn point(&self) -> &SurfacePoint {
        self.v.sp
    }
    #[inline(always)]
    fn shading(&self) -> &Shading {
        self.v.at
    }
    #[inline(always)]
    fn front(&self) -> bool {
        self.v.front
    }
    #[inline(always)]
    fn two_sided(&self) -> bool {
        self.v.mat.two_sided
    }
    #[inline(always)]
    fn textures(&self) -> &'s [Arc<Texture>] {
        &self.v.scene.textures
    }
    #[inline(always)]
    fn tables(&self) -> &'s Tables {
        self.v.scene.tables()
    }
    #[inline(always)]
    fn uv(&self) -> Vec2 {
        self.v.prim.shape.uv(self.v.ray, self.v.hit.part)
    }
    #[inline(always)]
    fn uv_frame(&self) -> Option<UvFrame> {
        self.v.prim.shape.uv_frame(self.v.ray, self.v.hit.part)
    }
}

impl<'a, 's, G: Guiding<'a>, H: BorrowMut<Path>> At<'s> for Here<'s, '_, G, H> {
    #[inline(always)]
    fn numbers(&self) -> Numbers {
        self.u
    }
    #[inline(always)]
    fn path(&mut self) -> &mut Path {
        self.path.borrow_mut()
    }
    #[inline(always)]
    fn diffuse(&mut self, albedo: Vec3A) -> Option<Ray> {
        let (v, u) = (self.v, self.u);
        let path = self.path.borrow_mut();
        match self.guiding.path() {
            None => diffuse(
                v.scene, v.strategy, path, albedo, v.sp, v.at, u.bsdf, u.light,
            ),
            Some(g) => guided_vertex::diffuse(
                v.scene,
                v.strategy,
                path,
                albedo,
                v.sp,
                v.at,
                (u.bsdf, u.choice),
                u.light,
                (g, self.depth),
            ),
        }
    }
    #[inline(always)]
    fn reflected_light<E, P>(
        &mut self,
        at: &Shading,
        p_out: Vec3A,
        u: (f32, Vec2),
        lobe: Lobe<'_, E, P>,
    ) where
        E: Fn(Vec3A) -> Vec3A,
        P: Fn(Vec3A) -> f32,
    {
        let v = self.v;
        reflected_light(
            v.scene,
            v.strategy,
            self.path.borrow_mut(),
            v.sp,
            at,
            p_out,
            u,
            lobe,
        );
    }
    #[inline(always)]
    fn two_sided_light<E, P>(&mut self, at: &Shading, u: (f32, Vec2), lobe: Lobe<'_, E, P>)
    where
        E: Fn(Vec3A) -> Vec3A,
        P: Fn(Vec3A) -> f32,
    {
        let v = self.v;
        let path = self.path.borrow_mut();
        two_sided_light(v.scene, v.strategy, path, v.sp, at, u, lobe);
    }
    #[inline(always)]
    fn went_through(&mut self) {
        let v = self.v;
        if v.absorbing {
            self.path.borrow_mut().medium = if v.front {
                v.scene.absorption(v.prim.material)
            } else {
                Vec3A::ZERO
            };
        }
    }
}
