//! An eight-wide BVH, collapsed from the binary one ([`super::bvh::Bvh`]), whose nodes test a
//! ray against their eight children's boxes at once, in two groups of four SIMD lanes. Meshes
//! use it: a large mesh's query waits mostly on memory, one node after another from the root
//! down, and eight children a node make that walk about a third shorter than four did
//! (measured faster, with the same image bits: docs/renderer.md). (The scene's own BVH stays
//! binary: its scenes hold a few dozen primitives, often one leaf.)
//!
//! The tree is a function of the binary tree alone, which is a function of the primitives, so
//! every worker traverses it the same way.

use glam::{Vec3A, Vec4};

use crate::util::math::FAR_INFLATION;

use super::bvh::{Bvh, NodeKind};
use super::pages::PagedArray;

/// Eight children's boxes (structure of arrays: `b[2·axis][h]` the lows of children 4h to
/// 4h + 3, `b[2·axis + 1][h]` their highs) and references: `count[i] == 0` makes `child[i]` a
/// node index, else it is a leaf of `count[i]` items from `child[i]` on (what the items are is
/// the caller's: see [`Bvh8::collapse`]). An empty slot has an empty box (+∞ low, −∞ high), which no ray hits.
/// 256 bytes: four cache lines.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
struct Node8 {
    b: [[Vec4; H]; 6],
    child: [u32; W],
    count: [u32; W],
}

/// Children per node.
const W: usize = 8;
/// Groups of four lanes per node.
const H: usize = W / 4;

/// The traversal stack's size. A wide node pushes at most W − 1 entries, and the wide tree is
/// no deeper than the binary one, whose build caps its depth at 60: at most (W − 1) · 60 + 1.
const STACK: usize = (W - 1) * 60 + 1;

/// The eight-wide hierarchy. Node 0 is the root.
#[derive(Clone, Debug, Default)]
pub struct Bvh8 {
    nodes: PagedArray<Node8>,
}

impl Bvh8 {
    /// Collapses `bvh`: each wide node takes the children of up to seven binary nodes below
    /// it, opening the largest (by surface area) first. A binary subtree of at most
    /// `merge_items` items becomes one leaf (a mesh passes 8: two groups of four triangles in
    /// lanes). `leaf` gets each leaf's range of positions in [`Bvh::order`] and returns what
    /// the traversal hands back for it: a start and a nonzero count.
    pub fn collapse(
        bvh: &Bvh,
        merge_items: usize,
        mut leaf: impl FnMut(std::ops::Range<usize>) -> (u32, u32),
    ) -> Self {
        let n = bvh.node_count();
        if n == 0 {
            return Self::default();
        }
        // Each binary node's range of positions: a subtree's leaves are contiguous, and
        // children have higher indices than their parent, so one backward pass finds them.
        let mut range = vec![0..0; n];
        for i in (0..n).rev() {
            range[i] = match bvh.node(i).1 {
                NodeKind::Leaf(r) => r,
                NodeKind::Interior(a, b) => range[a].start..range[b].end,
            };
        }
        let mut nodes = Vec::new();
        let is_leaf =
            |i: usize| matches!(bvh.node(i).1, NodeKind::Leaf(_)) || range[i].len() <= merge_items;
        if is_leaf(0) {
            // One leaf: a root whose only child it is.
            let (start, count) = leaf(range[0].clone());
            let mut root = Node8::EMPTY;
            root.set(0, bvh.node(0).0, start, count);
            nodes.push(root);
        } else {
            Self::build(&mut nodes, bvh, 0, &range, &is_leaf, &mut leaf);
        }
        Self {
            nodes: PagedArray::new(nodes),
        }
    }

    /// Adds the wide node for binary interior node `i` (and its subtree); returns its index.
    fn build(
        nodes: &mut Vec<Node8>,
        bvh: &Bvh,
        i: usize,
        range: &[std::ops::Range<usize>],
        is_leaf: &impl Fn(usize) -> bool,
        leaf: &mut impl FnMut(std::ops::Range<usize>) -> (u32, u32),
    ) -> u32 {
        let mut children = arrayvec::ArrayVec::<usize, W>::new();
        children.push(i);
        while children.len() < W {
            // Open the interior child with the largest surface area.
            let Some((k, _)) = children
                .iter()
                .enumerate()
                .filter(|&(_, &c)| !is_leaf(c))
                .map(|(k, &c)| (k, bvh.node(c).0.area()))
                .fold(None, |best: Option<(usize, f32)>, (k, a)| match best {
                    Some((_, ba)) if ba >= a => best,
                    _ => Some((k, a)),
                })
            else {
                break;
            };
            let NodeKind::Interior(a, b) = bvh.node(children[k]).1 else {
                unreachable!("is_leaf covers binary leaves")
            };
            children[k] = a;
            children.insert(k + 1, b);
        }
        let index = nodes.len();
        nodes.push(Node8::EMPTY);
        for (slot, &c) in children.iter().enumerate() {
            let bounds = bvh.node(c).0;
            let (start, count) = if is_leaf(c) {
                let (start, count) = leaf(range[c].clone());
                debug_assert!(count > 0);
                (start, count)
            } else {
                (Self::build(nodes, bvh, c, range, is_leaf, leaf), 0)
            };
            nodes[index].set(slot, bounds, start, count);
        }
        index as u32
    }

    /// Number of wide nodes (for tests and statistics).
    pub fn node_count(&self) -> usize {
        self.nodes.as_slice().len()
    }

    /// Visits the leaves the ray `o + t·d` (with `inv_d` = 1/d) may hit, nearest box first.
    /// `f` gets a leaf's (start, count) and the current t_max, and returns the new t_max; a
    /// negative t_max ends the traversal at once (any-hit queries). Boxes entered beyond the
    /// current t_max are skipped, also when they were pushed before it shrank. Any-hit queries
    /// take the same order: visiting children unsorted measured slower on the
    /// million-triangle benchmark, since the nearest box tends to hold the blocker that ends
    /// the query (docs/renderer.md).
    #[inline]
    pub fn traverse(
        &self,
        o: Vec3A,
        inv_d: Vec3A,
        mut t_max: f32,
        mut f: impl FnMut(u32, u32, f32) -> f32,
    ) {
        let nodes = self.nodes.as_slice();
        if nodes.is_empty() {
            return;
        }
        // The near plane of each axis is the low one where the direction is positive.
        let near = |axis: usize| 2 * axis + usize::from(inv_d[axis] < 0.0);
        let (nx, ny, nz) = (near(0), near(1), near(2));
        let (ox, oy, oz) = (Vec4::splat(o.x), Vec4::splat(o.y), Vec4::splat(o.z));
        let (ix, iy, iz) = (
            Vec4::splat(inv_d.x),
            Vec4::splat(inv_d.y),
            Vec4::splat(inv_d.z),
        );
        let inflate = Vec4::splat(FAR_INFLATION);
        let mut stack = arrayvec::ArrayVec::<Entry, STACK>::new();
        let mut cur = Entry {
            child: 0,
            count: 0,
            t_near: 0.0,
        };
        loop {
            if cur.count > 0 {
                t_max = f(cur.child, cur.count, t_max);
                if t_max < 0.0 {
                    return;
                }
            } else {
                let n = &nodes[cur.child as usize];
                let mut mask = 0u32;
                let mut tn = [0.0f32; W];
                for h in 0..H {
                    // Slab distances; 0·∞ (a ray in a box's plane, parallel to it) is NaN, and
                    // `max`/`min` (SSE's) give their second operand for it: that axis does not
                    // constrain the box, as the scalar test's guarded path decides too.
                    let tnx = (n.b[nx][h] - ox) * ix;
                    let tny = (n.b[ny][h] - oy) * iy;
                    let tnz = (n.b[nz][h] - oz) * iz;
                    let tfx = (n.b[nx ^ 1][h] - ox) * ix;
                    let tfy = (n.b[ny ^ 1][h] - oy) * iy;
                    let tfz = (n.b[nz ^ 1][h] - oz) * iz;
                    let t_near = tnx.max(tny.max(tnz.max(Vec4::ZERO)));
                    let t_far = (tfx * inflate)
                        .min((tfy * inflate).min((tfz * inflate).min(Vec4::splat(t_max))));
                    mask |= t_near.cmple(t_far).bitmask() << (4 * h);
                    tn[4 * h..4 * h + 4].copy_from_slice(&t_near.to_array());
                }
                if mask != 0 {
                    let entry = |slot: usize| Entry {
                        child: n.child[slot],
                        count: n.count[slot],
                        t_near: tn[slot],
                    };
                    if mask & (mask - 1) == 0 {
                        // One child hit (the most common case deep in the tree).
                        cur = entry(mask.trailing_zeros() as usize);
                        continue;
                    }
                    let mut hit = [cur; W];
                    let mut len = 0;
                    let mut bits = mask;
                    while bits != 0 {
                        hit[len] = entry(bits.trailing_zeros() as usize);
                        bits &= bits - 1;
                        len += 1;
                    }
                    // Insertion sort of at most eight, nearest first; equal distances keep node
                    // order, so the order is the ray's and the tree's alone.
                    for i in 1..len {
                        let mut j = i;
                        while j > 0 && hit[j - 1].t_near > hit[j].t_near {
                            hit.swap(j - 1, j);
                            j -= 1;
                        }
                    }
                    // The binary build's depth cap bounds the stack (STACK), so this fits.
                    for &e in hit[1..len].iter().rev() {
                        stack.push(e);
                    }
                    cur = hit[0];
                    continue;
                }
            }
            loop {
                match stack.pop() {
                    Some(e) if e.t_near <= t_max => {
                        cur = e;
                        break;
                    }
                    Some(_) => {}
                    None => return,
                }
            }
        }
    }
}

/// A child to visit: a node (`count` 0) or a leaf, and where the ray enters its box.
#[derive(Clone, Copy, Debug)]
struct Entry {
    child: u32,
    count: u32,
    t_near: f32,
}

impl Node8 {
    const EMPTY: Self = Self {
        b: [
            [Vec4::INFINITY; H],
            [Vec4::NEG_INFINITY; H],
            [Vec4::INFINITY; H],
            [Vec4::NEG_INFINITY; H],
            [Vec4::INFINITY; H],
            [Vec4::NEG_INFINITY; H],
        ],
        child: [0; W],
        count: [0; W],
    };

    fn set(&mut self, slot: usize, bounds: crate::util::math::Aabb, child: u32, count: u32) {
        for axis in 0..3 {
            self.b[2 * axis][slot / 4][slot % 4] = bounds.min[axis];
            self.b[2 * axis + 1][slot / 4][slot % 4] = bounds.max[axis];
        }
        self.child[slot] = child;
        self.count[slot] = count;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::math::{Aabb, Ray};
    use crate::util::sampling::HashRng;

    /// Every box a brute-force test hits is in a leaf the traversal visits, for trees of one
    /// leaf, a few nodes and many, with rays along axes (0·∞ slabs) among them.
    #[test]
    fn traversal_visits_every_box_the_ray_hits() {
        for count in [3, 9, 2000] {
            let mut rng = HashRng::new(count as u64);
            let mut u = move || rng.next_f32();
            let boxes: Vec<Aabb> = (0..count)
                .map(|_| {
                    let c = Vec3A::new(u(), u(), u()) * 20.0;
                    let e = Vec3A::new(u(), u(), u()) * 0.5;
                    Aabb {
                        min: c - e,
                        max: c + e,
                    }
                })
                .collect();
            let idx: Vec<u32> = (0..count as u32).collect();
            let bvh = Bvh::build(&boxes, &idx);
            let wide = Bvh8::collapse(&bvh, 4, |r| (r.start as u32, r.len() as u32));
            assert!(wide.node_count() >= 1);
            if count > 100 {
                assert!(
                    wide.node_count() * 2 < bvh.node_count(),
                    "{}",
                    wide.node_count()
                );
            }
            for n in 0..3000 {
                let o = Vec3A::new(u(), u(), u()) * 30.0 - 5.0;
                let mut d = Vec3A::new(u() - 0.5, u() - 0.5, u() - 0.5);
                if n % 3 == 0 {
                    // Parallel to two axes, from a point on a box's face plane.
                    let b = boxes[n % count];
                    d = Vec3A::new(0.0, 0.0, if n % 2 == 0 { 1.0 } else { -1.0 });
                    let o2 = Vec3A::new(b.min.x, (b.min.y + b.max.y) / 2.0, o.z);
                    check(&wide, &bvh, &boxes, Ray::new(o2, d));
                }
                check(&wide, &bvh, &boxes, Ray::new(o, d));
            }
        }
    }

    fn check(wide: &Bvh8, bvh: &Bvh, boxes: &[Aabb], ray: Ray) {
        let mut seen = vec![false; boxes.len()];
        wide.traverse(ray.o, ray.d.recip(), f32::INFINITY, |start, n, t| {
            for &p in &bvh.order()[start as usize..(start + n) as usize] {
                seen[p as usize] = true;
            }
            t
        });
        for (i, b) in boxes.iter().enumerate() {
            if b.hit(ray.o, ray.d.recip(), f32::INFINITY) {
                assert!(seen[i], "box {i} missed by {ray:?}");
            }
        }
    }
}
