//! # tessera-render
//!
//! tessera's core renderer: a physically based, unbiased Monte Carlo path tracer. It is a plain
//! synchronous library (no async runtime); parallelism is rayon's.
//!
//! The unit of work is a rectangle of pixels and a range of sample indices,
//! [`render_tile`], which returns per-pixel partial sums ([`TileSums`]: f64 sum of RGB, f64 sum
//! of squares, sample count). Because every random number is a pure function of
//! (job seed, pixel, sample index, dimension), and sums are accumulated per sample batch and
//! merged in batch order, the same job gives the same bits however the frame is cut into
//! tiles, threads, batches of work or machines.
//!
//! Modules follow pbrt-v4's split, lowest first (no module imports one above it; the
//! workspace's layout test checks that there is no import cycle):
//! - [`util`]: [`math`] (vectors, rays, rounding-error bounds), [`lanes`] (f32 SIMD lanes of any
//!   width), [`sampling`] (sample generation and warps), [`files`] (durable file writes, never
//!   through a link), `fields` (a scene file's key paths and value checks).
//! - [`settings`] (what decides a render's bits besides the scene), [`accel`] (BVHs, apart from
//!   what they hold), [`interaction`] (hits and surface points), [`packet`] (rays in SIMD
//!   lanes).
//! - Geometry: [`mesh`] and [`shape`]; [`primitive`] (a shape with its material and lights);
//!   [`aggregate`] (the scene's ray queries: a BVH whose leaves test quads four at a time).
//! - Appearance and light: [`texture`], [`bsdf`] (the materials' arithmetic), [`material`]
//!   (each material in one module behind one interface, which the tracers, the AOV pass and
//!   the scene readers go through), [`envmap`], [`light`], [`camera`].
//! - [`scene`] (file format, parsing, validation, the runtime scene; loaded by
//!   `Scene::file(path, &limits).load()` or `Scene::text(…)`).
//! - Rendering: [`integrator`], [`aov`] (auxiliary images for denoising), [`wide`] (the integrator four to sixteen paths at a time, by
//!   default for the scenes lit by one rectangle light, with the same bits), [`adaptive`] (noise-targeted
//!   sampling), [`film`] (partial sums and images), [`tile`] (the render driver) and
//!   [`output`] (EXR, PNG).
//!
//! ```no_run
//! use tessera_render::{scene::{Limits, Scene}, RenderSettings, render_frame};
//! let scene = Scene::file("scenes/cornell-box.toml".as_ref(), &Limits::default()).load().unwrap();
//! let settings = RenderSettings { spp: 16, ..RenderSettings::default() };
//! let sums = render_frame(&scene, &settings, &|_| {});
//! let image = sums.finalize();
//! ```

pub mod accel;
pub mod adaptive;
pub mod aggregate;
pub mod aov;
pub mod bsdf;
pub mod camera;
pub mod envmap;
pub mod film;
pub mod guide;
pub mod guiding;
pub mod integrator;
pub mod interaction;
pub mod light;
pub mod material;
pub mod mesh;
pub mod output;
pub mod packet;
pub mod primitive;
pub mod scene;
pub mod settings;
pub mod shape;
pub mod texture;
pub mod tile;
pub mod util;
pub mod wide;

pub use adaptive::Adaptive;
pub use film::{
    assemble_frame, assemble_image, assemble_render, Image, MergeError, NoiseSum, OutputChecks,
    PixelRect, Strips, TileSums,
};
pub use settings::{
    unit_batch, Aovs, RenderSettings, Strategy, Tracer, BATCH_RANGE, DEFAULT_TILE,
    DEFAULT_UNIT_SAMPLES, MIN_UNITS_PER_FRAME, TILE_RANGE, UNIT_SAMPLES_RANGE,
};
pub use tile::{render_frame, render_tile};
pub use util::{files, lanes, math, sampling};

/// Revision of the renderer's output bits: bumped by every change that alters any bit that any
/// render returns (a new sampler, a reordered sum, a different warp). One job's partial sums
/// merged from two revisions would be neither revision's image, and the farm's promise is one
/// job, one set of bits; so workers and the coordinator must run the same revision, and the
/// coordinator refuses a worker or a stored job from another. The test
/// `determinism.rs::the_image_revision_pins_the_bits` pins a hash of renders of every bundled
/// scene to this number, so a change that moves bits without bumping it fails there. The pin
/// renders without guiding; guided renders' bits changed too in revision 5 (their units merged
/// by epoch ranges, and what their guides learn), which the pin does not see, and a worker of
/// an older revision would render a guided job's units without its guide. Revision 6 changed
/// them again (each leaf of a guide learns its own selection probability, and guiding turns
/// itself off where the guide does not pay); the pin now hashes a guided render too, so guided
/// bits cannot change unseen either. Revision 7 clamps each sample's AOV albedo into [0, 1]
/// and normal components into [−1, 1] as they enter a sum (a normalised f32 normal can exceed
/// 1 by an ulp, which the farm's bounds refused), which moves AOV bits by an ulp where they
/// had exceeded; the pin hashes AOV renders too since. Revision 8 reads a glTF file's punctual
/// lights in its photometric units (candela and lux, over 683 lm/W), its spots' cones as
/// Blender's blend, and `KHR_materials_specular`'s factor: the same file renders differently,
/// though the bundled files, rewritten in candela, render the bits they did (the pin's hash is
/// revision 7's). Revision 9 makes the `pbr` material energy-preserving (multiple scattering
/// given back, the base albedo-scaled under the coat): every pbr surface renders differently.
/// Revision 10 takes a light sample's radiance from the environment map's cell it was drawn in
/// rather than from its direction mapped back (the same value but for rounding): every scene
/// with a map renders differently by an ulp or so. Revision 11 clips a glTF camera's view at
/// its `znear` (camera rays start on the near plane, as Blender's clip start): every glTF
/// file's camera rays start a little ahead of the eye, so its renders differ by rounding, and
/// what lies nearer than `znear` is no longer seen. Revision 12 records an emitter's colour
/// (its radiance, largest channel 1) as the albedo AOV where the camera sees it from the side
/// it emits to, in place of its material's albedo: the beauty keeps its bits, the albedo AOV
/// of every scene with a visible lamp changes. Revision 13 draws an environment map's column
/// from an alias table rather than by inverting the row's cdf (constant time on a full-size
/// map): the same density, but a number draws another direction, so every scene with a map at
/// least 512 texels wide renders differently. Revision 14 merges the meshes a scene places
/// once into one world-space mesh under one BVH (`crate::mesh::TriMesh::merged`): their
/// triangles are tested in world space, so every scene with two such meshes renders
/// differently by rounding; and it makes every smooth mesh's interpolated shading normal unit,
/// which under an identity transform (every merged mesh's) it was not: an identity-placed
/// smooth mesh renders differently where its normals bend most. Revision 15 draws an
/// environment map's light samples by its luminance less its mean (MIS compensation, as
/// pbrt-v4's image light): another density, so every scene with a non-uniform map renders
/// differently (with less noise), and under `--strategy nee` a ray that escapes into the map's
/// dim part now counts there. Revision 16 splits a scene's lights into the distant ones
/// (maps, suns, directional lights) and the others, and where a scene has both, a vertex takes
/// a light sample of each group (within it by power; `light::Lights::new`), where it took one
/// of all, chosen by power across the groups: every scene with a distant light and another
/// light renders differently (a sky-lit scene with a lamp with far fewer fireflies).
pub const IMAGE_REVISION: u32 = 16;
