//! The tier under the renderer's concepts, as pbrt-v4 keeps `util/` apart: vector and ray
//! maths with rounding-error bounds ([`math`]), SIMD lanes ([`lanes`]), low-discrepancy and
//! warping samplers ([`sampling`]), discrete distributions by inversion and alias tables
//! ([`distribution`]), durable file writes ([`files`]), a scene file's key paths and value checks ([`fields`]),
//! and tables built on every core ([`tabulate`]). Nothing here imports
//! anything above it; `crates/tests`' layout test checks that.

pub mod distribution;
pub mod fields;
pub mod files;
pub mod lanes;
pub mod math;
pub mod sampling;
pub mod tabulate;
