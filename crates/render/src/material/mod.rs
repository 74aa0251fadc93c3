//! Materials, each defined in one module of this folder with everything every consumer asks of
//! it: how a scene file names and reads it (its `read`), what the path tracer does at its
//! vertex (its `Model::scatter`: next-event estimation through its lobe and the next
//! direction), what the AOV pass records there (`Model::first_hit`), and the questions the
//! tracers ask before they scatter (whether light sampling applies, whether a choice number is
//! drawn, whether its back side scatters, whether the eight-lane tracer models it). Its
//! arithmetic (evaluate, sample, pdf) is its own, or the BSDF in [`crate::bsdf`] it wraps.
//!
//! A material knows the scene only through `port`'s traits, which the integrators, the AOV
//! pass and the scene readers implement: so this folder sits below all of them, and adding a
//! material touches none of them. The registry below is the one list of materials: one line
//! per runtime kind in `registry!`, one per scene-file `type` in [`MaterialKind`] and its
//! reader. docs/renderer.md walks through adding one.

pub mod desc;
pub(crate) mod port;

pub mod diffuse;
pub mod glass;
pub mod metal;
pub mod mirror;
pub mod pbr;
pub mod plastic;
pub mod rough_glass;
pub mod thin_glass;

use glam::Vec3A;
use serde::Deserialize;

pub use port::Tables;

use crate::bsdf::{Metal, RoughDielectric};
use crate::util::fields::Invalid;
use crate::util::math::Ray;
use port::{At, Reading, Seen, Surface};

/// What every consumer asks of a material. Implemented by each kind in this folder and
/// dispatched by [`Bsdf`]; generic over the ports, so each call inlines into its caller as the
/// hand-written arms did.
pub(crate) trait Model {
    /// Whether its vertex runs out of line (`#[inline(never)]`, so that the loop other
    /// materials run stays as small as it was): the tracer then lends it a copy of the path,
    /// taken back after, since a reference to the loop's own path passed out of line would
    /// keep that path in memory rather than in registers for every bounce.
    const FAR: bool = false;
    /// Whether a vertex on it samples lights (next-event estimation): false for a delta BSDF
    /// (a mirror, smooth glass, a smooth metal), which no light sample can reach. The defaults
    /// of this and the next two are an opaque reflector's.
    fn samples_lights(&self) -> bool {
        true
    }
    /// Whether a vertex on it draws a choice number: glass's reflection or refraction, a
    /// layered material's lobe.
    fn draws_choice(&self) -> bool {
        false
    }
    /// Whether its back side scatters though the material is not declared two-sided.
    fn has_two_sides(&self) -> bool {
        false
    }
    /// The albedo the eight-lane tracer shades it with, where that tracer models it (an
    /// untextured diffuse surface); `None` sends its scenes to the scalar tracer.
    fn lanes(&self) -> Option<Vec3A> {
        None
    }
    /// Whether it reads texture coordinates (so the shapes it is on need them).
    fn reads_uv(&self, _tables: &Tables) -> bool {
        false
    }
    /// Whether it bends its normal by a tangent-space map (so meshes need tangents).
    fn needs_tangents(&self, _tables: &Tables) -> bool {
        false
    }
    /// Scatters the path at `v`: adds the direct light gathered there and returns the next
    /// ray, or `None` where the path ends.
    fn scatter<'s, A: At<'s>>(&self, v: &mut A) -> Option<Ray>;
    /// What the AOV pass records at `s`, choosing a smooth glass's side by `u_choice` as the
    /// beauty's path does.
    fn first_hit<'s, S: Surface<'s>>(&self, s: &S, u_choice: f32) -> Seen;
}

/// Writes [`Bsdf`], one variant per kind, and its dispatch of [`Model`].
macro_rules! registry {
    ($($(#[$doc:meta])* $variant:ident($kind:ty),)*) => {
        /// A material's scattering part: one of the kinds this folder defines.
        #[derive(Clone, Copy, Debug)]
        pub enum Bsdf {
            $($(#[$doc])* $variant($kind),)*
        }

        impl Bsdf {
            /// `Model::samples_lights`.
            #[inline(always)]
            pub fn samples_lights(&self) -> bool {
                match self { $(Bsdf::$variant(m) => m.samples_lights(),)* }
            }
            /// `Model::draws_choice`.
            #[inline(always)]
            pub fn draws_choice(&self) -> bool {
                match self { $(Bsdf::$variant(m) => m.draws_choice(),)* }
            }
            /// `Model::has_two_sides`.
            #[inline(always)]
            pub fn has_two_sides(&self) -> bool {
                match self { $(Bsdf::$variant(m) => m.has_two_sides(),)* }
            }
            /// `Model::lanes`.
            #[inline(always)]
            pub fn lanes(&self) -> Option<Vec3A> {
                match self { $(Bsdf::$variant(m) => m.lanes(),)* }
            }
            /// `Model::reads_uv`.
            pub fn reads_uv(&self, tables: &Tables) -> bool {
                match self { $(Bsdf::$variant(m) => m.reads_uv(tables),)* }
            }
            /// `Model::needs_tangents`.
            pub fn needs_tangents(&self, tables: &Tables) -> bool {
                match self { $(Bsdf::$variant(m) => m.needs_tangents(tables),)* }
            }
            /// `Model::scatter` for a kind whose `Model::FAR` is `FAR`; `None` (and no code)
            /// for the others.
            #[inline(always)]
            pub(crate) fn scatter_if<'s, A: At<'s>, const FAR: bool>(
                &self,
                v: &mut A,
            ) -> Option<Option<Ray>> {
                match self {
                    $(Bsdf::$variant(m) => {
                        if <$kind as Model>::FAR == FAR {
                            Some(m.scatter(v))
                        } else {
                            None
                        }
                    })*
                }
            }
            /// Whether its vertex runs out of line (`Model::FAR`).
            #[inline(always)]
            pub(crate) fn is_far(&self) -> bool {
                match self { $(Bsdf::$variant(_) => <$kind as Model>::FAR,)* }
            }
            /// `Model::first_hit`.
            pub(crate) fn first_hit<'s, S: Surface<'s>>(&self, s: &S, u_choice: f32) -> Seen {
                match self { $(Bsdf::$variant(m) => m.first_hit(s, u_choice),)* }
            }
        }
    };
}

registry! {
    /// Lambertian, with an albedo or a texture's.
    Diffuse(diffuse::Diffuse),
    /// A perfect mirror.
    Mirror(mirror::Mirror),
    /// Smooth glass: Fresnel reflection and refraction.
    Dielectric(glass::Glass),
    /// A metal, rough or smooth.
    Conductor(Metal),
    /// Rough glass (its roughness above the mirror threshold, its index not 1: otherwise it
    /// is a [`Bsdf::Dielectric`]).
    RoughDielectric(RoughDielectric),
    /// A thin sheet of smooth glass: reflects, or passes straight through.
    ThinDielectric(thin_glass::ThinGlass),
    /// A diffuse base under a clear coat, rough or smooth.
    Plastic(plastic::PlasticRef),
    /// glTF's metallic–roughness material.
    Pbr(pbr::PbrRef),
}

/// A scene file's material types (`type = "…"`), each read by its kind's module.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialKind {
    /// Lambertian reflector.
    Diffuse,
    /// Perfect mirror.
    Mirror,
    /// Smooth dielectric (glass): Fresnel reflection and refraction.
    Dielectric,
    /// A metal: GGX microfacets over a conductor's Fresnel reflectance.
    Conductor,
    /// A diffuse base under a clear dielectric coat, rough or smooth.
    Plastic,
    /// glTF 2.0's metallic–roughness material, each parameter a number or a texture.
    Pbr,
}

impl MaterialKind {
    /// Reads a material of this type (one kind of glass or another for `dielectric`).
    pub(crate) fn read(self, r: &mut Reading<'_, '_>) -> Result<Bsdf, Invalid> {
        match self {
            MaterialKind::Diffuse => diffuse::read(r),
            MaterialKind::Mirror => mirror::read(r),
            MaterialKind::Dielectric => glass::read(r),
            MaterialKind::Conductor => metal::read(r),
            MaterialKind::Plastic => plastic::read(r),
            MaterialKind::Pbr => pbr::read(r),
        }
    }
}
