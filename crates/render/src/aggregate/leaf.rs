//! BVH leaves in the form the intersection loop reads: a leaf's parallelograms four at a time
//! in structure-of-arrays blocks, and its other primitives one by one.
//!
//! Rooms, boxes and area lights are mostly parallelograms, and the scalar test spends its time
//! on horizontal dot products and on a dispatch per primitive. Four quads in SoA lanes take the
//! same instructions as one. Each lane does exactly the scalar [`Parallelogram::intersect`]
//! arithmetic, in the same order ((x + y) + z for a dot product, as glam's `Vec3A::dot`), so a
//! lane's t is the scalar t, bit for bit; a unit test compares them.

use std::ops::Range;

use glam::{Vec3A, Vec4};

use crate::packet::{LaneHits, RayX4, Rays, MAX_LANES};
use crate::shape::{Parallelogram, Shape};
use crate::util::lanes::{dot, splat3, F, M, V3};
use crate::util::math::Aabb;

/// Parallelograms in lanes: four different quads against one ray splatted across the lanes
/// (the one-ray query), or one quad splatted across `N` lanes against `N` rays (the packet
/// query). Unused lanes have a zero normal, so their t is 0/0 = NaN and they never hit.
#[derive(Clone, Debug)]
struct QuadBlock<const N: usize> {
    p0: V3<N>,
    n: V3<N>,
    a1: V3<N>,
    a2: V3<N>,
}

/// Four quads in lanes, and their primitives (`u32::MAX` in unused lanes).
#[derive(Clone, Debug)]
struct Quads4 {
    lanes: QuadBlock<4>,
    prim: [u32; 4],
}

impl Quads4 {
    fn new(quads: &[(u32, &Parallelogram)]) -> Self {
        debug_assert!(!quads.is_empty() && quads.len() <= 4);
        let lanes = |f: &dyn Fn(&Parallelogram) -> Vec3A| -> V3<4> {
            let mut out = [[0.0f32; 4]; 3];
            for (lane, (_, q)) in quads.iter().enumerate() {
                let v = f(q);
                for axis in 0..3 {
                    out[axis][lane] = v[axis];
                }
            }
            out.map(F)
        };
        let mut prim = [u32::MAX; 4];
        for (lane, (p, _)) in quads.iter().enumerate() {
            prim[lane] = *p;
        }
        Self {
            lanes: QuadBlock {
                p0: lanes(&|q| q.p0),
                n: lanes(&|q| q.normal),
                a1: lanes(&|q| q.a1),
                a2: lanes(&|q| q.a2),
            },
            prim,
        }
    }

    /// Each used lane's quad on its own.
    fn splat(&self) -> impl Iterator<Item = SplatQuad> + '_ {
        (0..4).filter(|&j| self.prim[j] != u32::MAX).map(move |j| {
            let s = |v: &V3<4>| Vec3A::new(v[0].0[j], v[1].0[j], v[2].0[j]);
            SplatQuad {
                p0: s(&self.lanes.p0),
                n: s(&self.lanes.n),
                a1: s(&self.lanes.a1),
                a2: s(&self.lanes.a2),
                prim: self.prim[j],
            }
        })
    }

    /// Lanes whose quad the ray meets with t in (0, t_max), and each lane's t.
    #[inline]
    fn hits(&self, r: &RayX4, t_max: f32) -> (M<4>, F<4>) {
        let t = self.lanes.plane_t(&r.o, &r.d);
        (
            in_range(t, F::splat(t_max)) & self.lanes.within_edges(&r.o, &r.d, t),
            t,
        )
    }

    /// Whether any lane's quad blocks the ray in (0, t_max): `hits(..).0.any()`, but a block
    /// whose planes the ray does not cross within range stops before the edge tests. A shadow
    /// ray inside a room crosses none of its walls' planes, so this is the common case there.
    #[inline]
    fn blocks(&self, r: &RayX4, t_max: f32) -> bool {
        let t = self.lanes.plane_t(&r.o, &r.d);
        let crossed = in_range(t, F::splat(t_max));
        crossed.any() && (crossed & self.lanes.within_edges(&r.o, &r.d, t)).any()
    }
}

impl<const N: usize> QuadBlock<N> {
    /// Each lane's ray parameter at its quad's plane, for the ray (`o`, `d`) in lanes (one ray
    /// splatted, or a ray per lane).
    #[inline(always)]
    fn plane_t(&self, o: &V3<N>, d: &V3<N>) -> F<N> {
        let to_p0 = [self.p0[0] - o[0], self.p0[1] - o[1], self.p0[2] - o[2]];
        dot(&self.n, &to_p0) / dot(&self.n, d)
    }

    /// Lanes whose plane point at `t` lies inside their quad's edges.
    #[inline(always)]
    fn within_edges(&self, o: &V3<N>, d: &V3<N>, t: F<N>) -> M<N> {
        let q = [
            (o[0] + d[0] * t) - self.p0[0],
            (o[1] + d[1] * t) - self.p0[1],
            (o[2] + d[2] * t) - self.p0[2],
        ];
        let (u, v) = (dot(&self.a1, &q), dot(&self.a2, &q));
        let (zero, one) = (F::ZERO, F::ONE);
        u.cmpge(zero) & u.cmple(one) & v.cmpge(zero) & v.cmple(one)
    }
}

/// Lanes with t in (0, t_max); NaN (a padded lane, or a ray in a quad's plane) is in none.
#[inline(always)]
fn in_range<const N: usize>(t: F<N>, t_max: F<N>) -> M<N> {
    t.cmpgt(F::ZERO) & t.cmplt(t_max)
}

/// A leaf's quad blocks, and its other primitives with their bounds.
type LeafParts<'a> = (&'a [Quads4], &'a [(u32, Aabb)]);

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
    blocks: Vec<Quads4>,
    /// Each other primitive with its world bounds: a rotated box's exact test costs several
    /// times a bounding-box test, and most rays in a room pass its boxes by.
    others: Vec<(u32, Aabb)>,
    /// Whether the BVH is one leaf (the Cornell box): every query then reads the whole of
    /// `blocks` and `others` without looking its leaf up, which saves instructions on every
    /// Cornell box sample (docs/renderer.md).
    single: bool,
    /// For a one-leaf BVH, each quad of `blocks` splatted across lanes, in the blocks' order:
    /// what [`Leaves::closest_lanes`] tests a packet of rays against.
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
            out.blocks.extend(quads.chunks(4).map(Quads4::new));
            out.by_first[first] = LeafRef {
                blocks: blocks_start..out.blocks.len() as u32,
                others: others_start..out.others.len() as u32,
            };
        }
        out.single = count == 1;
        if out.single {
            out.splat = out.blocks.iter().flat_map(Quads4::splat).collect();
        }
        out
    }

    /// The closest hit with t in (0, t_max) among the primitives of `leaf` (a range
    /// [`crate::accel::bvh::Bvh::traverse`] passed), as (t, primitive, part): its quads here, its other
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
                let ts = Vec4::from_array(F::select(mask, t, F::INFINITY).0);
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

/// One quad, to be splatted across the lanes and tested against a packet of rays at once.
#[derive(Clone, Debug)]
struct SplatQuad {
    p0: Vec3A,
    n: Vec3A,
    a1: Vec3A,
    a2: Vec3A,
    prim: u32,
}

impl SplatQuad {
    /// Each ray's t at the quad's plane, and the rays that meet the quad with t in (0, t_max):
    /// [`Quads4::hits`]'s arithmetic with the lanes turned around, so each lane's t and answer
    /// are the scalar test's.
    #[inline(always)]
    ///
    /// With `early`, rays that cross the plane nowhere in range skip the edge test: worth a
    /// branch for shadow rays, which mostly cross no wall's plane, not for closest hits.
    fn hits<const N: usize>(&self, r: &Rays<N>, t_max: F<N>, early: bool) -> (M<N>, F<N>) {
        let q = QuadBlock::<N> {
            p0: splat3(self.p0),
            n: splat3(self.n),
            a1: splat3(self.a1),
            a2: splat3(self.a2),
        };
        let t = q.plane_t(&r.o, &r.d);
        let crossed = in_range(t, t_max);
        if early && !crossed.any() {
            return (crossed, t);
        }
        (crossed & q.within_edges(&r.o, &r.d, t), t)
    }
}

impl Leaves {
    /// Whether the BVH is one leaf.
    pub fn is_single(&self) -> bool {
        self.single
    }

    /// [`Leaves::closest`] for `N` rays at once (`N` at most [`MAX_LANES`]), for a one-leaf
    /// BVH (`None` otherwise, and the caller asks ray by ray): each active lane (bit of
    /// `active`) gets the closest hit with t in (0, ∞), the same as [`Leaves::closest`] gives
    /// its ray, ties included. `other(p, lanes, t_max)` tests the rays of `lanes` (bits)
    /// against other primitive `p`, each with its own t_max, and answers as
    /// `shape::cuboid_lanes` does: the lanes with a hit, their t and their parts.
    #[inline(always)]
    pub fn closest_lanes<const N: usize>(
        &self,
        r: &Rays<N>,
        active: u32,
        mut other: impl FnMut(u32, u32, &[f32; N]) -> (u32, [f32; N], [u32; N]),
    ) -> Option<LaneHits<N>> {
        const { assert!(N <= MAX_LANES) };
        if !self.single {
            return None;
        }
        let mut best_t = F::INFINITY;
        // Primitive indices travel as float bits, which a select copies unchanged.
        let mut best_prim = F::splat(f32::from_bits(u32::MAX));
        for q in &self.splat {
            let (mask, t) = q.hits(r, best_t, false);
            // A strict t < best keeps the earlier quad on a tie, as the blocks' test does.
            best_t = F::select(mask, t, best_t);
            best_prim = F::select(mask, F::splat(f32::from_bits(q.prim)), best_prim);
        }
        let mut h = LaneHits {
            hit: best_t.cmplt(F::INFINITY).bits() & active,
            t: best_t.0,
            prim: [0; N],
            part: [0; N],
        };
        for (p, b) in h.prim.iter_mut().zip(best_prim.0) {
            *p = b.to_bits();
        }
        for (p, b) in &self.others {
            let lanes = r.hit_box(b, F(h.t)).bits() & active;
            if lanes == 0 {
                continue;
            }
            let (hit, tp, part) = other(*p, lanes, &h.t);
            let hit = hit & lanes;
            for lane in (0..N).filter(|lane| hit >> lane & 1 == 1) {
                h.t[lane] = tp[lane];
                h.prim[lane] = *p;
                h.part[lane] = part[lane];
            }
            h.hit |= hit;
        }
        Some(h)
    }

    /// [`Leaves::any`] for `N` rays at once, for a one-leaf BVH (`None` otherwise): the
    /// active lanes (bits of `active`) whose rays something blocks in (0, t_max), as bits.
    /// `other(p, lanes)` gives the lanes of `lanes` whose rays other primitive `p` blocks.
    #[inline(always)]
    pub fn any_lanes<const N: usize>(
        &self,
        r: &Rays<N>,
        active: u32,
        t_max: f32,
        mut other: impl FnMut(u32, u32) -> u32,
    ) -> Option<u32> {
        if !self.single {
            return None;
        }
        let t_max_n = F::splat(t_max);
        let mut blocked = 0;
        for q in &self.splat {
            blocked |= q.hits(r, t_max_n, true).0.bits() & active;
            if blocked == active {
                return Some(blocked);
            }
        }
        for (p, b) in &self.others {
            let lanes = r.hit_box(b, t_max_n).bits() & active & !blocked;
            if lanes != 0 {
                blocked |= other(*p, lanes) & lanes;
            }
        }
        Some(blocked)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::math::Ray;
    use crate::util::sampling::HashRng;

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
        let block = Quads4::new(&indexed);
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
                    let lane_hit = mask.bits() >> lane & 1 == 1;
                    assert_eq!(scalar.is_some(), lane_hit, "{ray:?} quad {lane}");
                    if let Some(ts) = scalar {
                        assert_eq!(ts.to_bits(), t.0[lane].to_bits());
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
        let block = Quads4::new(&[(0, &q)]);
        let ray = Ray::new(Vec3A::new(0.0, 0.0, 1.0), -Vec3A::Z);
        let (mask, _) = block.hits(&RayX4::new(&ray), f32::INFINITY);
        assert_eq!(mask.bits(), 1);
    }
}
