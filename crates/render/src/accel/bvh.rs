//! A bounding volume hierarchy over the scene's bounded primitives, built with a binned
//! surface area heuristic and flattened depth-first so that a node's first child follows it
//! in memory.

use glam::Vec3A;

use crate::util::math::{Aabb, Ray};

/// A flattened node: 32 bytes, two per cache line.
#[derive(Clone, Copy, Debug)]
struct Node {
    min: [f32; 3],
    /// Leaf: first primitive index into `order`. Interior: index of the second child.
    offset: u32,
    max: [f32; 3],
    /// Leaf: primitive count (> 0). Interior: 0 in the low bits, split axis in bits 30–31.
    count_axis: u32,
}

impl Node {
    /// The primitives (positions in `order`) of a leaf; `None` for an interior node.
    #[inline]
    fn leaf(&self) -> Option<std::ops::Range<usize>> {
        let count = (self.count_axis & COUNT_MASK) as usize;
        let first = self.offset as usize;
        (count > 0).then_some(first..first + count)
    }
}

/// What a node is, for walking the tree ([`Bvh::node`]).
pub(crate) enum NodeKind {
    /// A leaf's positions in [`Bvh::order`].
    Leaf(std::ops::Range<usize>),
    /// An interior node's children (node indices).
    Interior(usize, usize),
}

const AXIS_SHIFT: u32 = 30;
const COUNT_MASK: u32 = (1 << AXIS_SHIFT) - 1;
const MAX_LEAF: usize = 4;
const BINS: usize = 16;
/// Depth cap: deeper subtrees become (large) leaves, which bounds the traversal stack.
const MAX_DEPTH: usize = 60;

/// The hierarchy; it stores primitive indices, not primitives, so the caller keeps ownership.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

struct BuildItem {
    bounds: Aabb,
    centroid: Vec3A,
    index: u32,
}

impl Bvh {
    /// Builds over `bounds[i]` for the listed primitive indices.
    pub fn build(bounds: &[Aabb], indices: &[u32]) -> Self {
        let mut items: Vec<BuildItem> = indices
            .iter()
            .map(|&i| BuildItem::new(bounds[i as usize], i))
            .collect();
        let nodes = if items.is_empty() {
            Vec::new()
        } else {
            build_subtree(&mut items, 0, 0, 0)
        };
        let order = items.iter().map(|it| it.index).collect();
        Bvh { nodes, order }
    }

    /// [`Bvh::build`] over every entry of `bounds`, the large subtrees built in parallel with
    /// rayon (meshes of millions of triangles). The tree is the same whatever the number of
    /// threads: each split depends only on the items below it, so every worker traverses the
    /// same nodes in the same order and picks the same hit among equal ones.
    pub fn build_parallel(bounds: &[Aabb]) -> Self {
        use rayon::prelude::*;
        let mut items: Vec<BuildItem> = bounds
            .par_iter()
            .enumerate()
            .map(|(i, &b)| BuildItem::new(b, i as u32))
            .collect();
        let nodes = if items.is_empty() {
            Vec::new()
        } else {
            build_subtree(&mut items, 0, 0, 0)
        };
        let order = items.par_iter().map(|it| it.index).collect();
        Bvh { nodes, order }
    }

    /// Visits the leaves a ray may hit, nearest subtree first. `f` gets the leaf's range of
    /// positions in [`Bvh::order`] and the current t_max, and returns the new t_max; a negative
    /// t_max ends the traversal at once (any-hit queries). Leaves rather than primitives, so
    /// that the caller can test a leaf's primitives together.
    #[inline]
    pub fn traverse(
        &self,
        ray: &Ray,
        mut t_max: f32,
        mut f: impl FnMut(std::ops::Range<usize>, f32) -> f32,
    ) {
        match self.nodes.as_slice() {
            [] => return,
            // A small scene (the Cornell box) is one leaf, whose bounds every ray inside the
            // scene enters anyway: testing them would only repeat the primitives' own tests.
            [root] => {
                if let Some(leaf) = root.leaf() {
                    f(leaf, t_max);
                }
                return;
            }
            _ => {}
        }
        let inv_d = ray.d.recip();
        let neg = [ray.d.x < 0.0, ray.d.y < 0.0, ray.d.z < 0.0];
        // Not zeroed, as an array would be on every query, which showed in a Cornell box
        // sample's instruction count.
        let mut stack = arrayvec::ArrayVec::<u32, { MAX_DEPTH + 1 }>::new();
        let mut current = 0u32;
        loop {
            let node = &self.nodes[current as usize];
            let b = Aabb {
                min: Vec3A::from(node.min),
                max: Vec3A::from(node.max),
            };
            if b.hit(ray.o, inv_d, t_max) {
                if let Some(leaf) = node.leaf() {
                    t_max = f(leaf, t_max);
                    if t_max < 0.0 {
                        return;
                    }
                } else {
                    let axis = (node.count_axis >> AXIS_SHIFT) as usize;
                    let (near, far) = if neg[axis] {
                        (node.offset, current + 1)
                    } else {
                        (current + 1, node.offset)
                    };
                    // The build caps the depth at MAX_DEPTH < stack size, so this cannot overflow.
                    stack.push(far);
                    current = near;
                    continue;
                }
            }
            match stack.pop() {
                Some(next) => current = next,
                None => break,
            }
        }
    }

    /// Number of nodes (for tests and statistics).
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Primitive indices in leaf order: a leaf holds a contiguous range of positions.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Node `i`'s bounds and what it is: a leaf's range of positions in [`Bvh::order`], or an
    /// interior node's two children. Node 0 is the root; a child's index is above its
    /// parent's, and a subtree's leaves cover one contiguous range of positions.
    pub(crate) fn node(&self, i: usize) -> (Aabb, NodeKind) {
        let n = &self.nodes[i];
        let bounds = Aabb {
            min: Vec3A::from(n.min),
            max: Vec3A::from(n.max),
        };
        let kind = match n.leaf() {
            Some(range) => NodeKind::Leaf(range),
            None => NodeKind::Interior(i + 1, n.offset as usize),
        };
        (bounds, kind)
    }

    /// Each leaf's range of positions in [`Bvh::order`], in node order.
    pub fn leaves(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        self.nodes.iter().filter_map(Node::leaf)
    }
}

impl BuildItem {
    fn new(bounds: Aabb, index: u32) -> Self {
        Self {
            bounds,
            centroid: bounds.centroid(),
            index,
        }
    }
}

/// Subtrees of at least this many items have their two halves built in parallel.
const PARALLEL_ITEMS: usize = 8192;

/// The nodes of the subtree over `items` (positions `first..` in the final order), numbered as
/// if the first of them were node `base`.
fn build_subtree(items: &mut [BuildItem], first: usize, depth: usize, base: u32) -> Vec<Node> {
    let bounds = items.iter().fold(Aabb::EMPTY, |b, it| b.union(it.bounds));
    let Some((axis, mid)) = choose_split(items, depth, bounds) else {
        return vec![Node {
            min: bounds.min.into(),
            offset: first as u32,
            max: bounds.max.into(),
            count_axis: items.len() as u32,
        }];
    };
    let parallel = items.len() >= PARALLEL_ITEMS;
    let (left_items, right_items) = items.split_at_mut(mid);
    let (left, mut right) = if parallel {
        rayon::join(
            || build_subtree(left_items, first, depth + 1, base + 1),
            || build_subtree(right_items, first + mid, depth + 1, 0),
        )
    } else {
        let left = build_subtree(left_items, first, depth + 1, base + 1);
        let right = build_subtree(right_items, first + mid, depth + 1, 0);
        (left, right)
    };
    // The right subtree was numbered from 0; it goes after the parent and the left subtree.
    let right_base = base + 1 + left.len() as u32;
    for node in &mut right {
        if node.count_axis & COUNT_MASK == 0 {
            node.offset += right_base;
        }
    }
    let mut nodes = Vec::with_capacity(1 + left.len() + right.len());
    nodes.push(Node {
        min: bounds.min.into(),
        offset: right_base,
        max: bounds.max.into(),
        count_axis: (axis as u32) << AXIS_SHIFT,
    });
    nodes.extend(left);
    nodes.extend(right);
    nodes
}

/// The split of `items` (whose bounds are `bounds`) by binned SAH (the axis, and how many
/// items go left, after partitioning them so), or `None` where they make a leaf.
fn choose_split(items: &mut [BuildItem], depth: usize, bounds: Aabb) -> Option<(usize, usize)> {
    if items.len() <= MAX_LEAF || depth >= MAX_DEPTH {
        return None;
    }
    let cb = items.iter().fold(Aabb::EMPTY, |b, it| b.grow(it.centroid));
    let extent = cb.max - cb.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    if !(extent[axis] > 0.0) {
        // All centroids coincide: no split separates them.
        return None;
    }
    let split = sah_split(items, axis, cb, bounds)?;
    // The chosen split has items on both sides by construction of `sah_split`.
    let mid = partition(items, |it| bin_of(it.centroid[axis], cb, axis) < split);
    Some((axis, mid))
}

#[inline]
fn bin_of(c: f32, cb: Aabb, axis: usize) -> usize {
    let rel = (c - cb.min[axis]) / (cb.max[axis] - cb.min[axis]);
    ((rel * BINS as f32) as usize).min(BINS - 1)
}

/// Best bin boundary by SAH cost, or `None` when a leaf is cheaper.
fn sah_split(items: &[BuildItem], axis: usize, cb: Aabb, bounds: Aabb) -> Option<usize> {
    let mut bin_bounds = [Aabb::EMPTY; BINS];
    let mut bin_count = [0usize; BINS];
    for it in items {
        let b = bin_of(it.centroid[axis], cb, axis);
        bin_count[b] += 1;
        bin_bounds[b] = bin_bounds[b].union(it.bounds);
    }
    let mut best = (f32::INFINITY, 0usize);
    for split in 1..BINS {
        let (l, lc) = (0..split).fold((Aabb::EMPTY, 0), |(b, c), i| {
            (b.union(bin_bounds[i]), c + bin_count[i])
        });
        let (r, rc) = (split..BINS).fold((Aabb::EMPTY, 0), |(b, c), i| {
            (b.union(bin_bounds[i]), c + bin_count[i])
        });
        if lc == 0 || rc == 0 {
            continue;
        }
        // A node's box test costs about what a primitive test does here (both are a few SSE
        // operations), not pbrt's 1/8: with 1/8 the Cornell box split into seven nodes whose
        // boxes (the walls') every ray enters anyway; with 1 it is one leaf, and faster.
        let cost = 1.0
            + (lc as f32 * l.area() + rc as f32 * r.area()) / bounds.area().max(f32::MIN_POSITIVE);
        if cost < best.0 {
            best = (cost, split);
        }
    }
    let leaf_cost = items.len() as f32;
    if best.0.is_finite() && (best.0 < leaf_cost || items.len() > 16) {
        Some(best.1)
    } else {
        None
    }
}

fn partition(items: &mut [BuildItem], pred: impl Fn(&BuildItem) -> bool) -> usize {
    let mut i = 0;
    for j in 0..items.len() {
        if pred(&items[j]) {
            items.swap(i, j);
            i += 1;
        }
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::sampling::HashRng;

    /// Every primitive a brute-force test hits must be visited by the traversal.
    #[test]
    fn traversal_visits_every_box_the_ray_hits() {
        // 3 boxes make a single-leaf tree, which skips the node test; 500 make a deep one.
        for count in [3, 500] {
            visits_every_box_the_ray_hits(count);
        }
    }

    fn visits_every_box_the_ray_hits(count: usize) {
        let mut rng = HashRng::new(3);
        let mut boxes = Vec::new();
        for _ in 0..count {
            let c = Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 20.0;
            let e = Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 0.5;
            boxes.push(Aabb {
                min: c - e,
                max: c + e,
            });
        }
        let idx: Vec<u32> = (0..boxes.len() as u32).collect();
        let bvh = Bvh::build(&boxes, &idx);
        assert_eq!(bvh.node_count() > 1, count > MAX_LEAF, "{count} boxes");
        for _ in 0..2000 {
            let o = Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 30.0 - 5.0;
            let d = Vec3A::new(
                rng.next_f32() - 0.5,
                rng.next_f32() - 0.5,
                rng.next_f32() - 0.5,
            )
            .normalize();
            let ray = Ray::new(o, d);
            let mut seen = vec![false; boxes.len()];
            bvh.traverse(&ray, f32::INFINITY, |leaf, t| {
                for &p in &bvh.order()[leaf] {
                    seen[p as usize] = true;
                }
                t
            });
            for (i, b) in boxes.iter().enumerate() {
                if b.hit(o, d.recip(), f32::INFINITY) {
                    assert!(seen[i], "box {i} missed");
                }
            }
        }
    }
}
