//! Bounding volume hierarchies, apart from what they hold: the SAH-built binary BVH over any
//! boxes ([`bvh`]), the eight-wide BVH meshes collapse it into ([`bvh8`]), and the huge-page
//! arrays their nodes and large meshes' triangles live in ([`pages`]). A tier below the
//! concepts: the scene's aggregate ([`crate::aggregate`]) and meshes ([`crate::mesh`]) both
//! build on it, and it knows neither.

pub mod bvh;
pub mod bvh8;
pub mod pages;
