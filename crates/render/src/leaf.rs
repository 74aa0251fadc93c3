//! BVH leaves in the form the intersection loop reads: a leaf's parallelograms four at a time
//! in structure-of-arrays blocks, and its other primitives one by one.
//!
//! Rooms, boxes and area lights are mostly parallelograms, and the scalar test spends its time
//! on horizontal dot products and on a dispatch per primitive. Four quads in SoA lanes take the
//! same instructions as one. Each lane does exactly the scalar [`Parallelogram::intersect`]
//! arithmetic, in the same order ((x + y) + z for a dot product, as glam's `Vec3A::dot`), so a
//! lane's t is the scalar t, bit for bit; a unit test compares them.

use std::ops::Range;

use glam::{BVec4A, Vec3A, Vec3Swizzles, Vec4};

use crate::math::{Aabb, Ray};
use crate::shape::{Parallelogram, Shape};

/// Four parallelograms, one per lane. Unused lanes have a zero normal, so their t is 0/0 = NaN
/// and they never hit.
#[derive(Clone, Debug)]
struct QuadBlock {
    p0: [Vec4; 3],
    n: [Vec4; 3],
    a1: [Vec4; 3],
    a2: [Vec4; 3],
    prim: [u32; 4],
}

impl QuadBlock {
    fn new(quads: &[(u32, &Parallelogram)]) -> Self {
        debug_assert!(!quads.is_empty() && quads.len() <= 4);
        let lanes = |f: &dyn Fn(&Parallelogram) -> Vec3A| -> [Vec4; 3] {
            let mut out = [[0.0f32; 4]; 3];
            for (lane, (_, q)) in quads.iter().enumerate() {
                let v = f(q);
                for axis in 0..3 {
                    out[axis][lane] = v[axis];
                }
            }
            out.map(Vec4::from_array)
        };
        let mut prim = [u32::MAX; 4];
        for (lane, (p, _)) in quads.iter().enumerate() {
            prim[lane] = *p;
        }
        Self {
            p0: lanes(&|q| q.p0),
            n: lanes(&|q| q.normal),
            a1: lanes(&|q| q.a1),
            a2: lanes(&|q| q.a2),
            prim,
        }
    }

    /// Each used lane's quad on its own, splatted across four lanes.
    fn splat(&self) -> impl Iterator<Item = SplatQuad> + '_ {
        (0..4).filter(|&j| self.prim[j] != u32::MAX).map(move |j| {
            let s = |v: &[Vec4; 3]| v.map(|axis| Vec4::splat(axis[j]));
            SplatQuad {
                lanes: QuadBlock {
                    p0: s(&self.p0),
                    n: s(&self.n),
                    a1: s(&self.a1),
                    a2: s(&self.a2),
                    prim: [self.prim[j]; 4],
                },
                prim: self.prim[j],
            }
        })
    }

    /// Lanes whose quad the ray meets with t in (0, t_max), and each lane's t.
    #[inline]
    fn hits(&self, r: &RayX4, t_max: f32) -> (BVec4A, Vec4) {
        let t = self.plane_t(&r.o, &r.d);
        (in_range(t, t_max) & self.within_edges(&r.o, &r.d, t), t)
    }

    /// Whether any lane's quad blocks the ray in (0, t_max): `hits(..).0.any()`, but a block
    /// whose planes the ray does not cross within range stops before the edge tests. A shadow
    /// ray inside a room crosses none of its walls' planes, so this is the common case there.
    #[inline]
    fn blocks(&self, r: &RayX4, t_max: f32) -> bool {
        let t = self.plane_t(&r.o, &r.d);
        let crossed = in_range(t, t_max);
        crossed.any() && (crossed & self.within_edges(&r.o, &r.d, t)).any()
    }

    /// Each lane's ray parameter at its quad's plane, for the ray (`o`, `d`) in lanes (one ray
    /// splatted, or a ray per lane).
    #[inline]
    fn plane_t(&self, o: &[Vec4; 3], d: &[Vec4; 3]) -> Vec4 {
        let to_p0 = [self.p0[0] - o[0], self.p0[1] - o[1], self.p0[2] - o[2]];
        dot4(&self.n, to_p0) / dot4(&self.n, *d)
    }

    /// Lanes whose plane point at `t` lies inside their quad's edges.
    #[inline]
    fn within_edges(&self, o: &[Vec4; 3], d: &[Vec4; 3], t: Vec4) -> BVec4A {
        let q = [
            (o[0] + d[0] * t) - self.p0[0],
            (o[1] + d[1] * t) - self.p0[1],
            (o[2] + d[2] * t) - self.p0[2],
        ];
        let (u, v) = (dot4(&self.a1, q), dot4(&self.a2, q));
        let (zero, one) = (Vec4::ZERO, Vec4::ONE);
        u.cmpge(zero) & u.cmple(one) & v.cmpge(zero) & v.cmple(one)
    }
}

/// Four dot products, one per lane, summed as (x + y) + z like the scalar test's.
#[inline]
fn dot4(a: &[Vec4; 3], b: [Vec4; 3]) -> Vec4 {
    (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
}

/// Lanes with t in (0, t_max); NaN (a padded lane, or a ray in a quad's plane) is in none.
#[inline]
fn in_range(t: Vec4, t_max: f32) -> BVec4A {
    t.cmpgt(Vec4::ZERO) & t.cmplt(Vec4::splat(t_max))
}

/// A ray's components splatted across four lanes, made once per query, with what the bounding
/// box test of the other primitives needs.
#[derive(Clone, Copy, Debug)]
pub struct RayX4 {
    o: [Vec4; 3],
    d: [Vec4; 3],
    origin: Vec3A,
    inv_d: Vec3A,
}

impl RayX4 {
    /// Splats `ray`.
    #[inline]
    pub fn new(ray: &Ray) -> Self {
        Self {
            o: [ray.o.xxxx(), ray.o.yyyy(), ray.o.zzzz()],
            d: [ray.d.xxxx(), ray.d.yyyy(), ray.d.zzzz()],
            origin: ray.o,
            inv_d: ray.d.recip(),
        }
    }
}

/// A leaf's quad blocks, and its other primitives with their bounds.
type LeafParts<'a> = (&'a [QuadBlock], &'a [(u32, Aabb)]);

/// Where one leaf's primitives are.
#[derive(Clone, Debug, Default)]
struct LeafRef {
    blocks: Range<u32>,
    others: Range<u32>,
}

/// Every leaf of a BVH, keyed by its first position in the BVH's order.
#[derive(Clone, Debug, Default)]
pub struct Leaves {
    by_first: Vec<LeafRef>,
    blocks: Vec<QuadBlock>,
    /// Each other primitive with its world bounds: a rotated box's exact test costs several
    /// times a bounding-box test, and most rays in a room pass its boxes by.
    others: Vec<(u32, Aabb)>,
    /// Whether the BVH is one leaf (the Cornell box): every query then reads the whole of
    /// `blocks` and `others` without looking its leaf up, which saved 2.5% of a Cornell box
    /// sample's instructions (docs/renderer.md).
    single: bool,
    /// For a one-leaf BVH, each quad of `blocks` splatted across four lanes, in the blocks'
    /// order: what [`Leaves::closest4`] tests four rays against.
    splat: Vec<SplatQuad>,
}

impl Leaves {
    /// Splits each leaf (a range of positions in `order`) into quad blocks and other primitives,
    /// keeping their order within each kind.
    pub fn build(
        shapes: &[&Shape],
        order: &[u32],
        leaves: impl Iterator<Item = Range<usize>>,
    ) -> Self {
        let mut out = Leaves {
            by_first: vec![LeafRef::default(); order.len()],
            ..Leaves::default()
        };
        let mut count = 0;
        for leaf in leaves {
            count += 1;
            let first = leaf.start;
            let mut quads = Vec::new();
            let others_start = out.others.len() as u32;
            for &p in &order[leaf] {
                match shapes[p as usize] {
                    Shape::Parallelogram(q) => quads.push((p, q)),
                    shape => out.others.push((p, shape.bounds())),
                }
            }
            let blocks_start = out.blocks.len() as u32;
            out.blocks.extend(quads.chunks(4).map(QuadBlock::new));
            out.by_first[first] = LeafRef {
                blocks: blocks_start..out.blocks.len() as u32,
                others: others_start..out.others.len() as u32,
            };
        }
        out.single = count == 1;
        if out.single {
            out.splat = out.blocks.iter().flat_map(QuadBlock::splat).collect();
        }
        out
    }

    /// The closest hit with t in (0, t_max) among the primitives of `leaf` (a range
    /// [`crate::bvh::Bvh::traverse`] passed), as (t, primitive, part): its quads here, its other
    /// primitives by `other`, which returns (t, part). Ties go to the earlier quad, then to the
    /// quads.
    #[inline]
    pub fn closest(
        &self,
        leaf: Range<usize>,
        ray: &RayX4,
        mut t_max: f32,
        mut other: impl FnMut(u32, f32) -> Option<(f32, u32)>,
    ) -> Option<(f32, u32, u32)> {
        let (blocks, others) = self.parts(leaf)?;
        let mut best = None;
        for b in blocks {
            let (mask, t) = b.hits(ray, t_max);
            if mask.any() {
                let ts = Vec4::select(mask, t, Vec4::INFINITY);
                let t_min = ts.min_element();
                let lane = ts.cmpeq(Vec4::splat(t_min)).bitmask().trailing_zeros() as usize;
                t_max = t_min;
                best = Some((t_min, b.prim[lane], 0));
            }
        }
        for &(p, b) in others {
            if !b.hit(ray.origin, ray.inv_d, t_max) {
                continue;
            }
            if let Some((t, part)) = other(p, t_max) {
                t_max = t;
                best = Some((t, p, part));
            }
        }
        best
    }

    /// Whether any quad of the leaf blocks the ray in (0, t_max), or else whether `other` says
    /// one of its other primitives does.
    #[inline]
    pub fn any(
        &self,
        leaf: Range<usize>,
        ray: &RayX4,
        t_max: f32,
        mut other: impl FnMut(u32) -> bool,
    ) -> bool {
        let Some((blocks, others)) = self.parts(leaf) else {
            return false;
        };
        blocks.iter().any(|b| b.blocks(ray, t_max))
            || others
                .iter()
                .any(|&(p, b)| b.hit(ray.origin, ray.inv_d, t_max) && other(p))
    }

    /// The quad blocks and the other primitives (with their bounds) of `leaf`.
    #[inline]
    fn parts(&self, leaf: Range<usize>) -> Option<LeafParts<'_>> {
        if self.single {
            return Some((&self.blocks, &self.others));
        }
        let r = self.by_first.get(leaf.start)?;
        Some((
            self.blocks
                .get(r.blocks.start as usize..r.blocks.end as usize)?,
            self.others
                .get(r.others.start as usize..r.others.end as usize)?,
        ))
    }
}

/// One quad in every lane, to be tested against four rays at once.
#[derive(Clone, Debug)]
struct SplatQuad {
    /// The quad in all four lanes.
    lanes: QuadBlock,
    prim: u32,
}

impl SplatQuad {
    /// Each ray's t at the quad's plane, and the rays that meet the quad with t in (0, t_max):
    /// [`QuadBlock::hits`]'s arithmetic with the lanes turned around, so each lane's t and
    /// answer are the scalar test's.
    #[inline]
    fn hits(&self, r: &Rays4, t_max: Vec4) -> (BVec4A, Vec4) {
        let t = self.lanes.plane_t(&r.o, &r.d);
        let crossed = t.cmpgt(Vec4::ZERO) & t.cmplt(t_max);
        if !crossed.any() {
            return (crossed, t);
        }
        (crossed & self.lanes.within_edges(&r.o, &r.d, t), t)
    }
}

/// Four rays in structure-of-arrays lanes.
#[derive(Clone, Copy, Debug)]
pub struct Rays4 {
    o: [Vec4; 3],
    d: [Vec4; 3],
    inv_d: [Vec4; 3],
}

impl Rays4 {
    /// Rays whose origins and directions are already in lanes.
    #[inline]
    pub fn from_lanes(o: [Vec4; 3], d: [Vec4; 3]) -> Self {
        Self {
            o,
            d,
            inv_d: d.map(Vec4::recip),
        }
    }

    /// The lanes whose rays meet `b`, with t_max per lane: [`Aabb::hit`]'s answer for each,
    /// computed the way its guarded branch does (an axis whose slab distance is NaN is
    /// unconstrained), which is the answer of its fast branch wherever there is no NaN.
    #[inline]
    fn hit_box(&self, b: &Aabb, t_max: Vec4) -> BVec4A {
        let mut near = Vec4::NEG_INFINITY;
        let mut far = Vec4::INFINITY;
        for axis in 0..3 {
            let t0 = (Vec4::splat(b.min[axis]) - self.o[axis]) * self.inv_d[axis];
            let t1 = (Vec4::splat(b.max[axis]) - self.o[axis]) * self.inv_d[axis];
            let nan = t0.is_nan_mask() | t1.is_nan_mask();
            near = near.max(Vec4::select(nan, Vec4::NEG_INFINITY, t0.min(t1)));
            far = far.min(Vec4::select(
                nan,
                Vec4::INFINITY,
                t0.max(t1) * crate::math::FAR_INFLATION,
            ));
        }
        near.max(Vec4::ZERO).cmple(far.min(t_max))
    }
}

impl Leaves {
    /// Whether the BVH is one leaf.
    pub fn is_single(&self) -> bool {
        self.single
    }

    /// [`Leaves::closest`] for four rays at once, for a one-leaf BVH (`None` otherwise, and the
    /// caller asks ray by ray): each active lane (bit of `active`) gets the closest hit with t
    /// in (0, ∞) as (t, primitive, part), the same as [`Leaves::closest`] gives its ray,
    /// ties included. `other(lane, p, t_max)` tests lane's ray against other primitive `p`.
    #[inline]
    pub fn closest4(
        &self,
        r: &Rays4,
        active: u32,
        mut other: impl FnMut(usize, u32, f32) -> Option<(f32, u32)>,
    ) -> Option<[Option<(f32, u32, u32)>; 4]> {
        if !self.single {
            return None;
        }
        let mut best_t = Vec4::INFINITY;
        // Primitive indices travel as float bits, which a select copies unchanged.
        let mut best_prim = Vec4::splat(f32::from_bits(u32::MAX));
        for q in &self.splat {
            let (mask, t) = q.hits(r, best_t);
            // A strict t < best keeps the earlier quad on a tie, as the blocks' test does.
            best_t = Vec4::select(mask, t, best_t);
            best_prim = Vec4::select(mask, Vec4::splat(f32::from_bits(q.prim)), best_prim);
        }
        let mut t = best_t.to_array();
        let mut best: [Option<(f32, u32, u32)>; 4] = [0, 1, 2, 3].map(|lane| {
            let prim = best_prim[lane].to_bits();
            (prim != u32::MAX).then_some((t[lane], prim, 0))
        });
        for (p, b) in &self.others {
            let lanes = r.hit_box(b, Vec4::from_array(t)).bitmask() & active;
            for lane in (0..4).filter(|lane| lanes >> lane & 1 == 1) {
                if let Some((tp, part)) = other(lane, *p, t[lane]) {
                    t[lane] = tp;
                    best[lane] = Some((tp, *p, part));
                }
            }
        }
        Some(best)
    }

    /// [`Leaves::any`] for four rays at once, for a one-leaf BVH (`None` otherwise): the
    /// active lanes (bits of `active`) whose rays something blocks in (0, t_max), as bits.
    /// `other(lane, p)` tests lane's ray against other primitive `p`.
    #[inline]
    pub fn any4(
        &self,
        r: &Rays4,
        active: u32,
        t_max: f32,
        mut other: impl FnMut(usize, u32) -> bool,
    ) -> Option<u32> {
        if !self.single {
            return None;
        }
        let t_max4 = Vec4::splat(t_max);
        let mut blocked = 0;
        for q in &self.splat {
            blocked |= q.hits(r, t_max4).0.bitmask() & active;
            if blocked == active {
                return Some(blocked);
            }
        }
        for (p, b) in &self.others {
            let lanes = r.hit_box(b, t_max4).bitmask() & active & !blocked;
            for lane in (0..4).filter(|lane| lanes >> lane & 1 == 1) {
                if other(lane, *p) {
                    blocked |= 1 << lane;
                }
            }
        }
        Some(blocked)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::HashRng;

    /// Each lane gives the scalar test's answer and the same t, bit for bit, including rays
    /// parallel to a quad, through its edges and behind it; the shadow-ray test agrees.
    #[test]
    fn lanes_match_the_scalar_quad_test() {
        let mut rng = HashRng::new(11);
        let mut v =
            |s: f32| Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s - s / 2.0;
        let quads: Vec<Parallelogram> = (0..3)
            .map(|_| {
                let (e1, e2) = (v(2.0), v(2.0));
                Parallelogram::new(v(4.0), e1, e2, e1.cross(e2))
            })
            .chain([Parallelogram::new(
                Vec3A::ZERO,
                Vec3A::X,
                Vec3A::Y,
                Vec3A::Z,
            )])
            .collect();
        let indexed: Vec<(u32, &Parallelogram)> = (0..).zip(&quads).collect();
        let block = QuadBlock::new(&indexed);
        // Rays aimed at points in and just around each quad, so that hits, misses by a little
        // and edge cases all occur.
        let mut rays: Vec<Ray> = (0..20_000)
            .map(|i| {
                let q = &quads[i % quads.len()];
                let aim = q.point(v(1.4).x + 0.5, v(1.4).y + 0.5);
                let o = v(8.0);
                Ray::new(o, aim - o)
            })
            .collect();
        // Edges, corners and a ray in the plane of the unit quad.
        for (o, d) in [
            (Vec3A::new(0.0, 0.5, 1.0), -Vec3A::Z),
            (Vec3A::new(1.0, 1.0, 1.0), -Vec3A::Z),
            (Vec3A::new(-1.0, 0.5, 0.0), Vec3A::X),
            (Vec3A::new(0.5, 0.5, -1.0), Vec3A::Z),
        ] {
            rays.push(Ray::new(o, d));
        }
        let mut hits = 0;
        for ray in &rays {
            for t_max in [f32::INFINITY, 3.0] {
                let r4 = RayX4::new(ray);
                let (mask, t) = block.hits(&r4, t_max);
                assert_eq!(block.blocks(&r4, t_max), mask.any(), "{ray:?}");
                for (lane, q) in quads.iter().enumerate() {
                    let scalar = q.intersect(ray, t_max);
                    let lane_hit = mask.bitmask() >> lane & 1 == 1;
                    assert_eq!(scalar.is_some(), lane_hit, "{ray:?} quad {lane}");
                    if let Some(ts) = scalar {
                        assert_eq!(ts.to_bits(), t[lane].to_bits());
                        hits += 1;
                    }
                }
            }
        }
        assert!(hits > 10_000, "the rays must hit the quads often: {hits}");
    }

    /// A BVH of one leaf reads its primitives without the leaf lookup, a BVH of several
    /// looks each leaf up: both find the same closest hits and the same blockers.
    #[test]
    fn one_leaf_and_split_leaves_find_the_same_hits() {
        let mut rng = HashRng::new(23);
        let mut v =
            |s: f32| Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * s - s / 2.0;
        let mut shapes: Vec<Shape> = (0..6)
            .map(|_| {
                let (e1, e2) = (v(2.0), v(2.0));
                Shape::Parallelogram(Parallelogram::new(v(3.0), e1, e2, e1.cross(e2)))
            })
            .collect();
        shapes.push(Shape::Sphere {
            center: v(2.0),
            radius: 0.5,
        });
        let refs: Vec<&Shape> = shapes.iter().collect();
        let order: Vec<u32> = (0..shapes.len() as u32).collect();
        let one = Leaves::build(&refs, &order, std::iter::once(0..7));
        let split = Leaves::build(&refs, &order, [0..3, 3..7].into_iter());
        assert!(one.single && !split.single);
        let mut hits = 0;
        for _ in 0..5_000 {
            // From around the shapes towards the region they fill, so that most rays hit.
            let o = v(8.0);
            let ray = Ray::new(o, v(3.0) - o);
            let r4 = RayX4::new(&ray);
            let other = |p: u32, t: f32| shapes[p as usize].intersect(&ray, t);
            let whole = one.closest(0..7, &r4, f32::INFINITY, other);
            let first = split.closest(0..3, &r4, f32::INFINITY, other);
            let t = first.map_or(f32::INFINITY, |h| h.0);
            let parts = split.closest(3..7, &r4, t, other).or(first);
            assert_eq!(whole, parts, "{ray:?}");
            let blocks = |p: u32| shapes[p as usize].intersect(&ray, 3.0).is_some();
            assert_eq!(
                one.any(0..7, &r4, 3.0, blocks),
                split.any(0..3, &r4, 3.0, blocks) || split.any(3..7, &r4, 3.0, blocks),
                "{ray:?}"
            );
            hits += usize::from(whole.is_some());
        }
        assert!(hits > 1_000, "the rays must hit often: {hits}");
    }

    /// A padded lane never hits, even for a ray through the origin.
    #[test]
    fn empty_lanes_never_hit() {
        let q = Parallelogram::new(Vec3A::ZERO, Vec3A::X, Vec3A::Y, Vec3A::Z);
        let block = QuadBlock::new(&[(0, &q)]);
        let ray = Ray::new(Vec3A::new(0.0, 0.0, 1.0), -Vec3A::Z);
        let (mask, _) = block.hits(&RayX4::new(&ray), f32::INFINITY);
        assert_eq!(mask.bitmask(), 1);
    }
}
