//! Path guiding's learned distributions (issue #60): where light comes from, learned from
//! the paths already traced, to sample directions from.
//!
//! The structure follows Müller et al. 2017 ("Practical Path Guiding"): a directional
//! quadtree ([`DirTree`]) over the sphere of directions, refined where its energy is, and a
//! spatial binary tree ([`SdTree`]) whose leaves each hold one. What sets this module's
//! design is the farm: a guide is trained by many workers and merged by the coordinator, so
//!
//! - every statistic is an integer sum (energies in fixed point), so training split over
//!   threads, units and machines adds up to the same bits in any order ([`DirTree::add`]),
//!   and the structure of the next guide is a pure function of the last one's sums: the same
//!   training data give the same guide, bit for bit, on any number of machines;
//! - a guide crosses the network as bytes, and [`DirTree::decode`] refuses any that do not
//!   describe a well-formed tree (a hostile coordinator or a corrupted asset must not crash a
//!   worker), before anything samples from it;
//! - sampling and its density agree exactly, whatever the sums are: guided sampling is one
//!   technique in a MIS mix, so a guide learned from garbage costs variance, never bias.

mod dirtree;
mod sdtree;

pub use dirtree::{
    from_square, to_square, DirTree, GuideError, MAX_DEPTH, MAX_NODES, MIN_THRESHOLD,
};
pub use sdtree::{
    SdTree, ALPHAS, DEFAULT_ALPHA, MAX_GUIDE_DIR_NODES, MAX_SPATIAL_DEPTH, MAX_SPATIAL_LEAVES,
    MAX_SPATIAL_NODES,
};
