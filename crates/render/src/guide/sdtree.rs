//! The spatial half of a guide: a binary tree over the scene's bounds whose leaves each hold a
//! directional tree ([`DirTree`]), Müller et al.'s SD-tree.
//!
//! A node splits its box at the middle of one axis, the axes in turn by depth (x, y, z, x,
//! …), so a node's box follows from its path and is never stored. A leaf counts the vertices
//! recorded in it (an integer, so its sum does not depend on the order units are added in)
//! and splits in the next epoch's structure once that count passes a threshold, each half
//! taking a copy of its directional tree's refinement. The structure of the tree to train
//! next is a pure function of the last one's counts and sums ([`SdTree::refined`]), so every
//! machine derives the same one.

use glam::Vec3A;

use super::dirtree::{check_shape, quantize, DirTree, GuideError, Reader};

/// The selection probabilities of the guide a leaf chooses among ([`SdTree::alpha_at`]). The
/// guide is never sampled with probability 1: its density may be 0 where light arrives, and
/// the cosine lobe's share is what keeps the mixture positive there.
pub const ALPHAS: [f32; 5] = [0.0, 0.125, 0.25, 0.5, 0.75];

/// The selection probability of a trained leaf that measured nothing to choose by (one whose
/// vertices sampled no guide: the first guide's leaves). Müller et al. fix ½; ¼ measured
/// less error at equal time on every scene of `tessera bench --guiding` (docs/renderer.md).
pub const DEFAULT_ALPHA: f32 = 0.25;

/// The deepest a spatial node may be (the root is at depth 1).
pub const MAX_SPATIAL_DEPTH: u32 = 48;

/// The most spatial leaves a tree may have. With [`MAX_GUIDE_DIR_NODES`] this bounds a
/// guide's memory whatever its training data claim: the counts come from workers, and a
/// forged one must not make the next guide huge.
pub const MAX_SPATIAL_LEAVES: usize = 1 << 14;

/// The most directional nodes a guide's leaves may hold together (28 MiB of them): past it,
/// [`SdTree::refined`] gives further leaves a uniform directional tree (one node each, so a
/// guide holds at most this many and one per leaf). Without it the two
/// bounds above multiply to gigabytes, which a forged count could claim (the fuzzer found
/// this).
pub const MAX_GUIDE_DIR_NODES: usize = 1 << 18;

/// The most spatial nodes a tree may have: a full binary tree of [`MAX_SPATIAL_LEAVES`].
pub const MAX_SPATIAL_NODES: usize = 2 * MAX_SPATIAL_LEAVES - 1;

const MAGIC: &[u8; 4] = b"TSGS";
const VERSION: u8 = 2;
/// Magic, version, the bounds' six f32, node and leaf counts.
const HEADER: usize = 4 + 1 + 24 + 4 + 4;
/// A node's two children (0: it is a leaf) and its leaf index.
const NODE_BYTES: usize = 12;

#[derive(Clone, Copy, Debug, PartialEq)]
struct SNode {
    /// The lower and upper halves' nodes; both 0 for a leaf (the root is nobody's child).
    child: [u32; 2],
    /// A leaf's index into the leaves.
    leaf: u32,
}

impl SNode {
    fn is_leaf(&self) -> bool {
        self.child == [0, 0]
    }
}

/// A spatial leaf: where its vertices' light came from, how many it recorded, and what each
/// selection probability of [`ALPHAS`] would have cost them.
#[derive(Clone, Debug, PartialEq)]
struct Leaf {
    dir: DirTree,
    count: u64,
    /// Per candidate of [`ALPHAS`], the estimated second moment of its estimator, summed in
    /// fixed point over the vertices that sampled a guide (integers: any order of additions).
    moments: [u128; ALPHAS.len()],
    /// The selection probability this leaf's guide is sampled with, chosen at
    /// [`SdTree::freeze`] from `moments`: 0 where it learned nothing.
    alpha: f32,
}

impl Leaf {
    fn empty(dir: DirTree) -> Self {
        Self {
            dir,
            count: 0,
            moments: [0; ALPHAS.len()],
            alpha: 0.0,
        }
    }

    /// The candidate of least second moment (the smallest such, on a tie), or
    /// [`DEFAULT_ALPHA`] where nothing was measured; 0 where the directional tree learned
    /// nothing. A pure function of the sums, so every machine chooses alike.
    fn choose_alpha(&self) -> f32 {
        if !self.dir.is_trained() {
            return 0.0;
        }
        if self.moments.iter().all(|&m| m == 0) {
            return DEFAULT_ALPHA;
        }
        let best = (0..ALPHAS.len())
            .min_by_key(|&i| self.moments[i])
            .unwrap_or(0);
        ALPHAS[best]
    }
}

/// A node of [`SdTree::refined`]'s output still to be filled in.
struct Pending {
    /// The node of the old tree it follows.
    old: usize,
    /// Its index in the new tree.
    new: usize,
    /// Its depth.
    depth: u32,
    /// For a node below a split old leaf: that leaf, and the count it is taken to have.
    below: Option<(usize, u64)>,
}

/// A spatial-directional guide: for a point, the directional distribution learned there.
#[derive(Clone, Debug, PartialEq)]
pub struct SdTree {
    lo: Vec3A,
    hi: Vec3A,
    nodes: Vec<SNode>,
    leaves: Vec<Leaf>,
}

impl SdTree {
    /// One leaf over the box from `lo` to `hi`, with a uniform directional tree. A box that
    /// is not finite or is empty along an axis is widened to something that is, so any
    /// point has a leaf.
    pub fn new(lo: Vec3A, hi: Vec3A) -> Self {
        let (mut lo, mut hi) = (lo, hi);
        if !(lo.is_finite() && hi.is_finite()) {
            (lo, hi) = (Vec3A::splat(-1.0), Vec3A::splat(1.0));
        }
        for a in 0..3 {
            if !(hi[a] > lo[a]) {
                let m = 0.5 * (lo[a] + hi[a]);
                let pad = m.abs().max(1.0) * 1e-3;
                lo[a] = m - pad;
                hi[a] = m + pad;
            }
        }
        Self {
            lo,
            hi,
            nodes: vec![SNode {
                child: [0, 0],
                leaf: 0,
            }],
            leaves: vec![Leaf::empty(DirTree::uniform())],
        }
    }

    /// Spatial leaves.
    pub fn leaves(&self) -> usize {
        self.leaves.len()
    }

    /// Bytes it holds (nodes, leaves and their directional trees): what a worker pays.
    pub fn memory_bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + self.nodes.len() * std::mem::size_of::<SNode>()
            + self
                .leaves
                .iter()
                .map(|l| std::mem::size_of::<Leaf>() + l.dir.memory_bytes())
                .sum::<usize>()
    }

    /// Freezes every leaf's directional tree ([`DirTree::freeze`]) and chooses its
    /// selection probability: what it has recorded becomes what it samples.
    pub fn freeze(&mut self) {
        for l in &mut self.leaves {
            l.dir.freeze();
            l.alpha = l.choose_alpha();
        }
    }

    /// Whether any leaf samples its guide (a selection probability above 0). A guide that
    /// does not is off: sampling it is the cosine lobe alone, at the cost of its lookups.
    pub fn guides(&self) -> bool {
        self.leaves.iter().any(|l| l.alpha > 0.0)
    }

    /// The second moment the leaves' chosen mixtures measured, over what the cosine lobe
    /// alone measured, summed over the leaves: how much this guide's vertices would have
    /// gained from sampling the guide their vertices sampled (1: nothing). `None` where no
    /// vertex measured any (a first guide's, or one trained by an epoch that sampled none).
    pub fn second_moment_ratio(&self) -> Option<f64> {
        let (mut chosen, mut cosine) = (0f64, 0f64);
        for l in &self.leaves {
            cosine += l.moments[0] as f64;
            if let Some(i) = ALPHAS.iter().position(|&a| a == l.alpha) {
                chosen += l.moments[i] as f64;
            }
        }
        (cosine > 0.0).then(|| chosen / cosine)
    }

    /// How many leaves chose each of [`ALPHAS`] (one not among them, none: a decoded guide
    /// chooses from its sums).
    pub fn alpha_histogram(&self) -> [usize; ALPHAS.len()] {
        let mut h = [0; ALPHAS.len()];
        for l in &self.leaves {
            if let Some(i) = ALPHAS.iter().position(|&a| a == l.alpha) {
                h[i] += 1;
            }
        }
        h
    }

    /// Whether nothing was recorded in it.
    pub fn is_untrained(&self) -> bool {
        self.leaves.iter().all(|l| l.count == 0)
    }

    /// The leaf whose box holds `p` (a point outside the bounds takes the nearest).
    fn leaf_of(&self, p: Vec3A) -> usize {
        let (mut lo, mut hi) = (self.lo, self.hi);
        let (mut n, mut axis) = (0, 0);
        loop {
            let node = self.nodes[n];
            if node.is_leaf() {
                return node.leaf as usize;
            }
            let mid = 0.5 * (lo[axis] + hi[axis]);
            if p[axis] < mid {
                hi[axis] = mid;
                n = node.child[0] as usize;
            } else {
                lo[axis] = mid;
                n = node.child[1] as usize;
            }
            axis = (axis + 1) % 3;
        }
    }

    /// The directional distribution learned at `p`.
    pub fn at(&self, p: Vec3A) -> &DirTree {
        &self.leaves[self.leaf_of(p)].dir
    }

    /// The directional distribution learned at `p` and the probability of sampling it there
    /// (0 where it learned nothing).
    pub fn alpha_at(&self, p: Vec3A) -> (&DirTree, f32) {
        let l = &self.leaves[self.leaf_of(p)];
        (&l.dir, l.alpha)
    }

    /// Records that `value` of energy arrived at `p` along `d` (unit), and counts the vertex.
    pub fn record(&mut self, p: Vec3A, d: Vec3A, value: f64) {
        self.record_with(p, d, value, None);
    }

    /// [`SdTree::record`], and adds `moments` (one per candidate of [`ALPHAS`], each
    /// quantized as energies are; not positive and finite: nothing) to the leaf's.
    pub fn record_with(
        &mut self,
        p: Vec3A,
        d: Vec3A,
        value: f64,
        moments: Option<&[f64; ALPHAS.len()]>,
    ) {
        let i = self.leaf_of(p);
        let leaf = &mut self.leaves[i];
        leaf.count += 1;
        leaf.dir.record(d, value);
        if let Some(m) = moments {
            for (sum, &v) in leaf.moments.iter_mut().zip(m) {
                *sum = sum.saturating_add(quantize(v));
            }
        }
    }

    /// The structure to train next, with no energy and no counts: a leaf that counted more
    /// than `split_after` vertices splits (its halves, taken to have half the count each,
    /// split again while that is above it), each half with its directional tree refined at
    /// `threshold` ([`DirTree::refined`]).
    pub fn refined(&self, split_after: u64, threshold: f64) -> SdTree {
        let mut out = SdTree {
            lo: self.lo,
            hi: self.hi,
            nodes: Vec::with_capacity(self.nodes.len()),
            leaves: Vec::with_capacity(self.leaves.len()),
        };
        out.nodes.push(SNode {
            child: [0, 0],
            leaf: 0,
        });
        let mut dir_nodes = 0;
        // The copy of the old structure takes as many nodes as it has, whenever its inner
        // nodes come off the stack: a split may only take what is left after all of them, or
        // splits made early leave the copy too little room (the fuzzer found a 4-leaf guide
        // whose refinement had 16,385 leaves, which decode refuses).
        let mut split_nodes = 0usize;
        let mut stack = vec![Pending {
            old: 0,
            new: 0,
            depth: 1,
            below: None,
        }];
        while let Some(Pending {
            old,
            new,
            depth,
            below,
        }) = stack.pop()
        {
            let (leaf, count) = match below {
                Some(b) => b,
                None if !self.nodes[old].is_leaf() => {
                    let child = self.add_inner(&mut out, new);
                    for (k, &c) in self.nodes[old].child.iter().enumerate() {
                        stack.push(Pending {
                            old: c as usize,
                            new: child[k],
                            depth: depth + 1,
                            below: None,
                        });
                    }
                    continue;
                }
                None => {
                    let l = self.nodes[old].leaf as usize;
                    (l, self.leaves[l].count)
                }
            };
            if count > split_after
                && depth < MAX_SPATIAL_DEPTH
                && self.nodes.len() + split_nodes + 2 <= MAX_SPATIAL_NODES
            {
                split_nodes += 2;
                let child = self.add_inner(&mut out, new);
                for c in child {
                    stack.push(Pending {
                        old,
                        new: c,
                        depth: depth + 1,
                        below: Some((leaf, count / 2)),
                    });
                }
            } else {
                let mut dir = DirTree::uniform();
                if dir_nodes < MAX_GUIDE_DIR_NODES {
                    dir = self.leaves[leaf].dir.refined(threshold);
                    if dir_nodes + dir.len() > MAX_GUIDE_DIR_NODES {
                        dir = DirTree::uniform();
                    }
                }
                dir_nodes += dir.len();
                out.nodes[new].leaf = out.leaves.len() as u32;
                out.leaves.push(Leaf::empty(dir));
            }
        }
        out
    }

    /// Makes `new` an inner node of `out` with two fresh children; returns them.
    fn add_inner(&self, out: &mut SdTree, new: usize) -> [usize; 2] {
        let c = out.nodes.len();
        for _ in 0..2 {
            out.nodes.push(SNode {
                child: [0, 0],
                leaf: 0,
            });
        }
        out.nodes[new].child = [c as u32, c as u32 + 1];
        [c, c + 1]
    }

    /// Whether `other` has this tree's structure (spatial nodes, and each leaf's directional
    /// tree), so that [`SdTree::add`] takes it.
    pub fn same_shape(&self, other: &SdTree) -> bool {
        self.nodes == other.nodes
            && self.leaves.len() == other.leaves.len()
            && (self.leaves.iter().zip(&other.leaves)).all(|(a, b)| a.dir.same_shape(&b.dir))
    }

    /// Vertices recorded, over every leaf.
    pub fn records(&self) -> u64 {
        self.leaves
            .iter()
            .fold(0u64, |a, l| a.saturating_add(l.count))
    }

    /// Adds `other`'s counts and energies to this tree's, leaf by leaf; the two must have
    /// the same structure. Counts and energies are integers, so the order of additions cannot
    /// change a bit.
    pub fn add(&mut self, other: &SdTree) -> Result<(), GuideError> {
        // Checked whole before anything is added, so a mismatch leaves this tree as it was.
        if !self.same_shape(other) {
            return Err(GuideError::Mismatch(self.nodes.len(), other.nodes.len()));
        }
        for (a, b) in self.leaves.iter_mut().zip(&other.leaves) {
            a.dir.add(&b.dir)?;
            a.count = a.count.saturating_add(b.count);
            for (x, y) in a.moments.iter_mut().zip(b.moments) {
                *x = x.saturating_add(y);
            }
        }
        Ok(())
    }

    /// The tree as bytes; [`SdTree::decode`] reads them back to the same tree, bit for bit.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        out.push(VERSION);
        for v in [self.lo, self.hi] {
            for a in 0..3 {
                out.extend_from_slice(&v[a].to_le_bytes());
            }
        }
        out.extend_from_slice(&(self.nodes.len() as u32).to_le_bytes());
        out.extend_from_slice(&(self.leaves.len() as u32).to_le_bytes());
        for n in &self.nodes {
            for x in [n.child[0], n.child[1], n.leaf] {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        for l in &self.leaves {
            out.extend_from_slice(&l.count.to_le_bytes());
            for m in l.moments {
                out.extend_from_slice(&m.to_le_bytes());
            }
            let dir = l.dir.encode();
            out.extend_from_slice(&(dir.len() as u32).to_le_bytes());
            out.extend_from_slice(&dir);
        }
        out
    }

    /// A tree from [`SdTree::encode`]'s bytes, refusing any that do not describe one (the
    /// directional trees as [`DirTree::decode`] refuses theirs; each child a later node and
    /// nobody else's; each leaf named by one leaf node; bounds finite and not empty).
    pub fn decode(bytes: &[u8]) -> Result<Self, GuideError> {
        let mut r = Reader { bytes, at: 0 };
        if r.take(4)? != MAGIC || r.take(1)? != [VERSION] {
            return Err(GuideError::Header);
        }
        let mut b = [0f32; 6];
        for x in &mut b {
            *x = f32::from_le_bytes(r.array()?);
        }
        let (lo, hi) = (Vec3A::new(b[0], b[1], b[2]), Vec3A::new(b[3], b[4], b[5]));
        if !(lo.is_finite() && hi.is_finite() && hi.cmpgt(lo).all()) {
            return Err(GuideError::Bounds);
        }
        let count = u32::from_le_bytes(r.array()?) as usize;
        let leaf_count = u32::from_le_bytes(r.array()?) as usize;
        if count == 0 || count > MAX_SPATIAL_NODES || leaf_count == 0 || leaf_count > count {
            return Err(GuideError::NodeCount(count as u64));
        }
        if bytes.len() < HEADER + count * NODE_BYTES {
            return Err(GuideError::Length {
                nodes: count,
                expected: HEADER + count * NODE_BYTES,
                got: bytes.len(),
            });
        }
        let mut nodes = Vec::with_capacity(count);
        for _ in 0..count {
            let mut x = [0u32; 3];
            for v in &mut x {
                *v = u32::from_le_bytes(r.array()?);
            }
            nodes.push(SNode {
                child: [x[0], x[1]],
                leaf: x[2],
            });
        }
        // A node is a leaf (no children) or has both: one child would send half its box
        // back to the root.
        let mut leaf_seen = vec![false; leaf_count];
        for (i, n) in nodes.iter().enumerate() {
            if n.is_leaf() {
                match leaf_seen.get_mut(n.leaf as usize) {
                    Some(seen) if !*seen => *seen = true,
                    _ => return Err(GuideError::Leaf(i)),
                }
            } else if let Some(k) = n.child.iter().position(|&c| c == 0) {
                return Err(GuideError::Child {
                    node: i,
                    quadrant: k,
                    child: 0,
                });
            }
        }
        let children: Vec<[u32; 2]> = nodes.iter().map(|n| n.child).collect();
        check_shape(&children, MAX_SPATIAL_DEPTH)?;
        if let Some(missing) = leaf_seen.iter().position(|&s| !s) {
            return Err(GuideError::Leaf(missing));
        }
        let mut leaves = Vec::with_capacity(leaf_count.min(bytes.len() / 8));
        let mut dir_nodes = 0;
        for _ in 0..leaf_count {
            let count = u64::from_le_bytes(r.array()?);
            let mut moments = [0u128; ALPHAS.len()];
            for m in &mut moments {
                *m = u128::from_le_bytes(r.array()?);
            }
            let len = u32::from_le_bytes(r.array()?) as usize;
            let dir = DirTree::decode(r.take(len)?)?;
            dir_nodes += dir.len();
            if dir_nodes > MAX_GUIDE_DIR_NODES + leaf_count {
                return Err(GuideError::NodeCount(dir_nodes as u64));
            }
            let mut leaf = Leaf {
                dir,
                count,
                moments,
                alpha: 0.0,
            };
            leaf.alpha = leaf.choose_alpha();
            leaves.push(leaf);
        }
        if r.at != bytes.len() {
            return Err(GuideError::Length {
                nodes: count,
                expected: r.at,
                got: bytes.len(),
            });
        }
        Ok(Self {
            lo,
            hi,
            nodes,
            leaves,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::guide::{MAX_DEPTH, MIN_THRESHOLD};
    use crate::util::sampling::HashRng;

    /// A tree trained over the unit cube for `epochs` epochs: light from +z on the upper
    /// half, from −x on the lower.
    fn trained(epochs: usize) -> SdTree {
        let mut guide = SdTree::new(Vec3A::ZERO, Vec3A::ONE);
        for e in 0..epochs {
            let mut next = guide.refined(500, 0.01);
            let mut rng = HashRng::new(e as u64);
            for _ in 0..20_000 {
                let p = Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                let d = crate::sampling::square_to_uniform_sphere(glam::Vec2::new(
                    rng.next_f32(),
                    rng.next_f32(),
                ));
                let towards = if p.z > 0.5 { Vec3A::Z } else { -Vec3A::X };
                next.record(p, d, if d.dot(towards) > 0.9 { 30.0 } else { 0.5 });
            }
            guide = next;
            guide.freeze();
        }
        guide
    }

    #[test]
    fn leaves_split_where_vertices_are_and_learn_their_own_light() {
        let guide = trained(3);
        assert!(guide.leaves() >= 8, "{} leaves", guide.leaves());
        assert_eq!(trained(3), guide, "a pure function of its training");
        let (up, low) = (Vec3A::new(0.5, 0.5, 0.9), Vec3A::new(0.5, 0.5, 0.1));
        // Each leaf draws most directions from its own light (three quarters of the energy
        // arriving there comes from the 5% of the sphere around it), where uniform draws 5%.
        let share = |at: Vec3A, towards: Vec3A| {
            let mut rng = HashRng::new(1);
            let n = 4000;
            let hits = (0..n)
                .filter(|_| {
                    let u = glam::Vec2::new(rng.next_f32(), rng.next_f32());
                    guide.at(at).sample(u).0.dot(towards) > 0.9
                })
                .count();
            hits as f64 / n as f64
        };
        assert!(share(up, Vec3A::Z) > 0.5, "{}", share(up, Vec3A::Z));
        assert!(share(low, -Vec3A::X) > 0.5, "{}", share(low, -Vec3A::X));
        assert!(share(up, -Vec3A::X) < 0.1, "{}", share(up, -Vec3A::X));
        // Outside the bounds: the nearest leaf.
        assert!(std::ptr::eq(
            guide.at(Vec3A::new(0.5, 0.5, 7.0)),
            guide.at(up)
        ));
        assert!(guide.memory_bytes() > guide.leaves() * 48);
    }

    /// Each leaf takes the candidate of least measured second moment, the default where it
    /// measured none, and 0 where it learned nothing; the choice survives the bytes, and a
    /// guide whose every leaf chose 0 samples nowhere.
    #[test]
    fn each_leaf_chooses_the_selection_probability_that_measured_least() {
        let mut g = SdTree::new(Vec3A::ZERO, Vec3A::ONE);
        g.freeze();
        assert_eq!(g.alpha_at(Vec3A::splat(0.5)).1, 0.0, "nothing learned");
        assert!(!g.guides());
        assert_eq!(g.second_moment_ratio(), None);
        g.record(Vec3A::splat(0.5), Vec3A::Z, 1.0);
        g.freeze();
        assert_eq!(
            g.alpha_at(Vec3A::splat(0.5)).1,
            DEFAULT_ALPHA,
            "nothing measured"
        );
        assert!(g.guides());
        for (best, &alpha) in ALPHAS.iter().enumerate() {
            let mut t = g.refined(u64::MAX, 0.01);
            // A bowl of second moments with its bottom at `best`.
            let moments: [f64; ALPHAS.len()] =
                std::array::from_fn(|i| 1.0 + (i as f64 - best as f64).abs());
            t.record_with(Vec3A::splat(0.5), Vec3A::Z, 1.0, Some(&moments));
            t.freeze();
            assert_eq!(t.alpha_at(Vec3A::splat(0.5)).1, alpha);
            assert_eq!(t.guides(), best > 0);
            let ratio = t.second_moment_ratio().expect("measured");
            assert!((ratio - 1.0 / (1.0 + best as f64)).abs() < 1e-9, "{ratio}");
            let back = SdTree::decode(&t.encode()).expect("decodes");
            assert_eq!(back.alpha_at(Vec3A::splat(0.5)).1, alpha);
            assert_eq!(back, t);
        }
        // Moments add like energies: in any order, to the same choice.
        let mut a = g.refined(u64::MAX, 0.01);
        let mut b = a.clone();
        let low = [5.0, 4.0, 1.0, 4.0, 5.0];
        let high = [1.0, 2.0, 3.0, 4.0, 5.0];
        a.record_with(Vec3A::splat(0.5), Vec3A::Z, 1.0, Some(&low));
        b.record_with(Vec3A::splat(0.5), Vec3A::Z, 1.0, Some(&high));
        let (mut ab, mut ba) = (a.clone(), b.clone());
        ab.add(&b).expect("same structure");
        ba.add(&a).expect("same structure");
        ab.freeze();
        ba.freeze();
        assert_eq!(ab, ba);
        // Sums 6, 6, 4, 8, 10: the third.
        assert_eq!(ab.alpha_at(Vec3A::splat(0.5)).1, ALPHAS[2]);
    }

    #[test]
    fn a_guide_survives_its_bytes_and_added_guides_must_match() {
        let guide = trained(2);
        assert_eq!(SdTree::decode(&guide.encode()), Ok(guide.clone()));
        let mut sum = guide.clone();
        sum.add(&guide).expect("same structure");
        assert!(sum.add(&trained(3)).is_err());
        // Training split any way, added in any order, gives the same bits.
        let (mut a, mut b) = (guide.refined(500, 0.01), guide.refined(500, 0.01));
        let mut parts = vec![guide.refined(500, 0.01); 3];
        let mut rng = HashRng::new(5);
        for i in 0..3000 {
            let p = Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let d = crate::guide::from_square(glam::Vec2::new(rng.next_f32(), rng.next_f32()));
            let v = (rng.next_f32() as f64).powi(7) * 1e6;
            a.record(p, d, v);
            parts[i % 3].record(p, d, v);
        }
        for part in parts.iter().rev() {
            b.add(part).expect("same structure");
        }
        assert_eq!(a, b);
        assert!(SdTree::new(Vec3A::ZERO, Vec3A::ONE)
            .add(&SdTree::new(Vec3A::ZERO, Vec3A::ONE))
            .is_ok());
    }

    #[test]
    fn a_forged_count_cannot_make_the_next_guide_huge() {
        let mut g = SdTree::new(Vec3A::ZERO, Vec3A::ONE);
        for i in 0..64 {
            g.record(
                Vec3A::splat(0.5),
                crate::guide::from_square(glam::Vec2::new(i as f32 / 64.0, 0.3)),
                1.0,
            );
        }
        g.leaves[0].count = u64::MAX;
        let next = g.refined(0, 1e-9);
        assert_eq!(next.leaves(), MAX_SPATIAL_LEAVES);
        // Each leaf's directional tree refines to 171 nodes, 2.8 million for all, were it
        // not for the guide's budget: the leaves past it are uniform.
        let dir_nodes: usize = next.leaves.iter().map(|l| l.dir.len()).sum();
        assert!(
            dir_nodes <= MAX_GUIDE_DIR_NODES + MAX_SPATIAL_LEAVES,
            "{dir_nodes}"
        );
        assert_eq!(next.leaves[0].dir.len(), 171);
        assert_eq!(next.leaves[MAX_SPATIAL_LEAVES - 1].dir.len(), 1);
        assert!(next.at(Vec3A::splat(0.5)).len() <= (MAX_DEPTH as f64 / MIN_THRESHOLD) as usize);
        assert!(
            next.memory_bytes() < 48 << 20,
            "{} bytes",
            next.memory_bytes()
        );
        assert!(SdTree::decode(&next.encode()).is_ok());
    }

    /// Leaves that all claim huge counts, refined: the splits of the first leaves off the stack
    /// must leave room for the copy of the others (the fuzzer's 4-leaf guide).
    #[test]
    fn the_refinement_of_many_forged_leaves_still_decodes() {
        let mut g = SdTree::new(Vec3A::ZERO, Vec3A::ONE);
        g.leaves[0].count = 10;
        let mut g = g.refined(6, 0.01);
        g.leaves[0].count = 10;
        g.leaves[1].count = 10;
        let mut g = g.refined(6, 0.01);
        assert_eq!(g.leaves(), 4);
        for l in &mut g.leaves {
            l.count = u64::MAX;
        }
        let next = g.refined(1000, 0.01);
        assert!(
            next.nodes.len() <= MAX_SPATIAL_NODES,
            "{}",
            next.nodes.len()
        );
        assert!(SdTree::decode(&next.encode()).is_ok());
    }

    #[test]
    fn a_mismatch_in_a_later_leaf_leaves_the_sum_as_it_was() {
        let guide = trained(2);
        let mut other = guide.clone();
        let last = other.leaves.len() - 1;
        other.leaves[last].dir = DirTree::uniform();
        assert!(!guide.leaves[last].dir.same_shape(&other.leaves[last].dir));
        let mut sum = guide.clone();
        assert!(sum.add(&other).is_err());
        assert_eq!(sum, guide);
    }

    #[test]
    fn degenerate_bounds_still_hold_every_point() {
        for (lo, hi) in [
            (Vec3A::ZERO, Vec3A::new(1.0, 0.0, 1.0)),
            (Vec3A::splat(f32::NAN), Vec3A::ONE),
            (Vec3A::ONE, Vec3A::ZERO),
        ] {
            let mut g = SdTree::new(lo, hi);
            g.record(Vec3A::new(3.0, -2.0, 0.5), Vec3A::Z, 1.0);
            let g = g.refined(0, 0.01);
            assert!(g.leaves() > 1);
            assert!(SdTree::decode(&g.encode()).is_ok());
        }
    }

    #[test]
    fn mangled_bytes_are_refused_and_never_panic() {
        let good = trained(2).encode();
        // The root with one child: half its box would lead back to the root.
        let mut one = good.clone();
        one[HEADER + 4..HEADER + 8].copy_from_slice(&0u32.to_le_bytes());
        assert_eq!(
            SdTree::decode(&one),
            Err(GuideError::Child {
                node: 0,
                quadrant: 1,
                child: 0
            })
        );
        assert!(SdTree::decode(&good[..good.len() - 1]).is_err());
        let mut extra = good.clone();
        extra.push(0);
        assert!(SdTree::decode(&extra).is_err());
        let mut rng = HashRng::new(9);
        let mut refused = 0;
        for round in 0..2000 {
            let mut bytes = good.clone();
            if round % 2 == 0 {
                // Mostly the header and the spatial nodes, where the structure is.
                let span = (HEADER + 64 * NODE_BYTES).min(bytes.len());
                let at = (rng.next_f32() * span as f32) as usize % span;
                bytes[at] ^= 1 << (round % 8);
            } else {
                bytes.truncate((rng.next_f32() * bytes.len() as f32) as usize);
            }
            match SdTree::decode(&bytes) {
                Ok(g) => {
                    let p = Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
                    let (d, pdf) = g.at(p).sample(glam::Vec2::new(0.3, 0.7));
                    assert!(d.is_finite() && pdf.is_finite());
                }
                Err(_) => refused += 1,
            }
        }
        assert!(refused > 1000, "{refused} refused");
    }
}
