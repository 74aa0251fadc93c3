//! One object of the runtime scene: its geometry, its material and the lights it is. What the
//! scene's aggregate ([`crate::aggregate`]) is built over and its hits name.

use crate::shape::Shape;

/// One object of the runtime scene.
#[derive(Clone, Debug)]
pub struct Primitive {
    /// Geometry.
    pub shape: Shape,
    /// Index into [`crate::scene::Scene::materials`].
    pub material: u32,
    /// Index of this primitive's first light in [`crate::scene::Scene::lights`] (a box has one per face),
    /// or `u32::MAX` if it does not emit.
    pub light: u32,
    /// 1 where each part of the shape is a light of its own (a box's faces), 0 where the
    /// whole shape is one (a mesh, whose parts are its triangles): a hit's light is
    /// `light + part · light_stride`.
    pub light_stride: u32,
}
