//! A directional quadtree: a piecewise-constant density over the sphere of directions, finer
//! where more energy arrives.
//!
//! Directions map to the unit square by the cylindrical (Lambert) projection, x = φ/2π and
//! y = (1 + cos θ)/2, which preserves area: a region of area A covers 4πA steradians, so a
//! density p over the square is p/4π per steradian everywhere, with no Jacobian to get wrong
//! near the poles. Each node splits its square into four quadrants and holds the energy that
//! arrived through each; a quadrant is a leaf or another node.
//!
//! The invariant that keeps guiding unbiased is that [`DirTree::sample`] draws a direction
//! with exactly the density [`DirTree::pdf`] reports for it. Both descend the same quadrants
//! and multiply the same factor per level, 4·(the quadrant's energy)/(the node's energy),
//! with quadrants picked in sampling by those same shares (one uniform number per axis,
//! reused by remapping), and a leaf sampled uniformly; a node with no energy (or a total
//! that is not finite) counts as uniform in both. No quadrant of zero energy can be picked,
//! so no sample lands where the pdf is zero.
//!
//! Energies are sums of fixed-point numbers (u128 in units of 2⁻⁶⁴, each value recorded at
//! most 2⁴⁰), added with saturation. Integer sums of non-negative numbers do not depend on
//! their order, saturated or not, so the training of a guide can be split over threads,
//! units and machines any way at all and merged in any order to the same bits: the farm needs
//! no merge order for guides, and the local renderer none for its threads. The shares that
//! sampling reads are computed from the sums once, by [`DirTree::freeze`] (which decoding
//! does): f32 per quadrant, so a node fits a cache line and a pdf costs no integer
//! conversions.

use std::f32::consts::PI;

use glam::{Vec2, Vec3A};

use crate::util::math::atan2;
use crate::util::sampling::{sin_cos_turn, ONE_MINUS_EPSILON};

/// The deepest a node may be (the root is at depth 1): a leaf there spans 2⁻²⁰ of the
/// square's side, as in Müller et al.
pub const MAX_DEPTH: u32 = 20;

/// The most nodes a tree may have. Refinement at a share of 1% makes at most 100 nodes a
/// level (see [`MIN_THRESHOLD`]); this bound is for decoding bytes from elsewhere.
pub const MAX_NODES: usize = 1 << 16;

/// The smallest share of the energy [`DirTree::refined`] splits a quadrant for.
pub const MIN_THRESHOLD: f64 = 0.005;

/// The child index of a quadrant that is a leaf (the root, node 0, is nobody's child).
const LEAF: u32 = 0;

/// Bytes before the nodes: magic, version, node count.
const HEADER: usize = 9;
/// Bytes a node takes: four child indices and four energies.
const NODE_BYTES: usize = 4 * 4 + 4 * 16;
const MAGIC: &[u8; 4] = b"TSGQ";
const VERSION: u8 = 2;

/// Fixed-point units per unit of energy.
const ENERGY_ONE: f64 = 18_446_744_073_709_551_616.0; // 2^64
/// The most one record may add, in energy units: a bound on what one sample (or a forged
/// one) can weigh, and so on how few records saturate a sum (2^24 of them at this bound).
const MAX_RECORD: f64 = 1_099_511_627_776.0; // 2^40

/// `value` in fixed point; what is not positive and finite is nothing.
#[inline]
pub(super) fn quantize(value: f64) -> u128 {
    if value > 0.0 && value.is_finite() {
        (value.min(MAX_RECORD) * ENERGY_ONE) as u128
    } else {
        0
    }
}

/// What is wrong with a guide's bytes, or with a merge of two guides.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GuideError {
    /// Not a directional guide, or another version of one.
    #[error("not a directional guide (version {VERSION}): bad header")]
    Header,
    /// The node count is zero or above its bound.
    #[error("a guide has {0} nodes, none or more than it may")]
    NodeCount(u64),
    /// The bytes end inside a field.
    #[error("a guide's bytes end at {0}, inside a field")]
    Truncated(usize),
    /// The length does not match the node count.
    #[error("a guide of {nodes} nodes takes {expected} bytes, not {got}")]
    Length {
        /// Nodes the header gives.
        nodes: usize,
        /// Bytes they take.
        expected: usize,
        /// Bytes there were.
        got: usize,
    },
    /// A child index that is not a later node, or a node that is the child of two.
    #[error("node {node} quadrant {quadrant}: child {child} is not a node of its own")]
    Child {
        /// The parent.
        node: usize,
        /// The quadrant.
        quadrant: usize,
        /// The index it gives.
        child: u32,
    },
    /// A node nobody points at.
    #[error("node {0} is nobody's child")]
    Orphan(usize),
    /// A node deeper than [`MAX_DEPTH`].
    #[error("node {0} is deeper than {MAX_DEPTH} levels")]
    Depth(usize),
    /// A spatial guide's bounds that are not finite or enclose nothing.
    #[error("a spatial guide's bounds are not a finite, non-empty box")]
    Bounds,
    /// A spatial leaf named by no leaf node, or by two, or a leaf node naming none.
    #[error("spatial node or leaf {0} does not pair one leaf node with one leaf")]
    Leaf(usize),
    /// Two trees of different structure cannot be added.
    #[error("the guides have different structures ({0} and {1} nodes, or other children)")]
    Mismatch(usize, usize),
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Node {
    /// The energy that arrived through each quadrant, in fixed point.
    energy: [u128; 4],
    /// Each quadrant's node, or [`LEAF`].
    child: [u32; 4],
    /// What sampling reads: each quadrant's share of the energy at the last
    /// [`DirTree::freeze`].
    share: [f32; 4],
    /// What the density reads: 4 × the probability that sampling picks each quadrant
    /// ([`Node::pick`]), from the same shares.
    factor: [f32; 4],
}

impl Node {
    const EMPTY: Node = Node {
        energy: [0; 4],
        child: [LEAF; 4],
        share: [0.25; 4],
        factor: [1.0; 4],
    };

    /// Each quadrant's share of the node's energy; a quarter each when it has none.
    #[inline]
    fn shares(&self) -> [f64; 4] {
        let e = self.energy.map(|x| x as f64);
        let total = e[0] + e[1] + e[2] + e[3];
        if total > 0.0 {
            e.map(|x| x / total)
        } else {
            [0.25; 4]
        }
    }

    /// The probability that sampling picks quadrant `q`, and `u` past the choice, from the
    /// frozen shares: the column by its share, then the row within the column by its part of
    /// it. [`DirTree::pdf`] multiplies the same probabilities as [`DirTree::sample`] draws
    /// by, computed by the same steps, so the two agree to the bit.
    #[inline]
    fn pick(&self, q: usize) -> f64 {
        let s = self.share.map(f64::from);
        let left = s[0] + s[2];
        let qx = q & 1;
        let column = s[qx] + s[qx + 2];
        let below = if column > 0.0 { s[qx] / column } else { 0.5 };
        // f32 shares may add up to a hair over one: [`choose`] then never takes the right
        // column, which has probability 0, not a negative one.
        let px = if qx == 0 {
            left.min(1.0)
        } else {
            (1.0 - left).max(0.0)
        };
        let py = if q < 2 { below } else { 1.0 - below };
        px * py
    }
}

/// A point of the unit square, as a direction.
pub fn from_square(p: Vec2) -> Vec3A {
    let cos = (2.0 * p.y - 1.0).clamp(-1.0, 1.0);
    let sin = ((1.0 - cos) * (1.0 + cos)).max(0.0).sqrt();
    let (sin_phi, cos_phi) = sin_cos_turn(p.x);
    Vec3A::new(sin * cos_phi, sin * sin_phi, cos)
}

/// A unit direction as a point of the unit square, each coordinate in [0, 1).
pub fn to_square(d: Vec3A) -> Vec2 {
    let x = atan2(d.y, d.x) * (0.5 / PI);
    let x = if x < 0.0 { x + 1.0 } else { x };
    let y = (d.z.clamp(-1.0, 1.0) + 1.0) * 0.5;
    Vec2::new(
        x.clamp(0.0, ONE_MINUS_EPSILON),
        y.clamp(0.0, ONE_MINUS_EPSILON),
    )
}

/// The quadrant of `p` (x to the right, y up: 0 1 below, 2 3 above), and `p` within it.
#[inline]
fn quadrant(p: [f64; 2]) -> (usize, [f64; 2]) {
    let qx = usize::from(p[0] >= 0.5);
    let qy = usize::from(p[1] >= 0.5);
    // Exact: doubling, and subtracting 1 from a number in [1, 2).
    (
        qx + 2 * qy,
        [2.0 * p[0] - qx as f64, 2.0 * p[1] - qy as f64],
    )
}

/// `u` in [0, 1) past a choice with probability `p` of the lower side, stretched back over
/// [0, 1) within the side it chose; returns (whether it chose the upper side, the new `u`).
#[inline]
fn choose(u: f64, p: f64) -> (bool, f64) {
    let (upper, u) = if u < p {
        (false, u / p)
    } else {
        (true, (u - p) / (1.0 - p))
    };
    (upper, u.clamp(0.0, 1.0 - f64::EPSILON / 2.0))
}

/// Checks that `children` (each node's children, 0 for none: the root is nobody's child)
/// describe one tree rooted at node 0: every child a later node and nobody else's, every
/// node reached from the root, none deeper than `max_depth`.
pub(super) fn check_shape<const K: usize>(
    children: &[[u32; K]],
    max_depth: u32,
) -> Result<(), GuideError> {
    // Children come after their parents, so one pass in index order gives every node its
    // depth from its parent's, and a node not yet reached when its turn comes is nobody's.
    let count = children.len();
    let mut depth = vec![0u32; count];
    depth[0] = 1;
    for (i, child) in children.iter().enumerate() {
        if depth[i] == 0 {
            return Err(GuideError::Orphan(i));
        }
        if depth[i] > max_depth {
            return Err(GuideError::Depth(i));
        }
        for (q, &c) in child.iter().enumerate() {
            if c == LEAF {
                continue;
            }
            let bad = GuideError::Child {
                node: i,
                quadrant: q,
                child: c,
            };
            let c = c as usize;
            if c <= i || c >= count || depth[c] != 0 {
                return Err(bad);
            }
            depth[c] = depth[i] + 1;
        }
    }
    Ok(())
}

/// A directional distribution learned from energy arriving along directions.
#[derive(Clone, Debug, PartialEq)]
pub struct DirTree {
    /// Never empty: node 0 is the root.
    nodes: Vec<Node>,
    /// Whether it had energy at the last [`DirTree::freeze`].
    trained: bool,
}

impl Default for DirTree {
    fn default() -> Self {
        Self::uniform()
    }
}

impl DirTree {
    /// One node and no energy: the uniform density over the sphere.
    pub fn uniform() -> Self {
        Self {
            nodes: vec![Node::EMPTY],
            trained: false,
        }
    }

    /// How many nodes it has.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Never true: a tree has its root.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Bytes it holds.
    pub fn memory_bytes(&self) -> usize {
        std::mem::size_of::<Self>() + self.nodes.capacity() * std::mem::size_of::<Node>()
    }

    /// The energy it has recorded.
    pub fn total(&self) -> f64 {
        self.nodes[0].energy.iter().map(|&e| e as f64).sum()
    }

    /// Computes the shares that [`DirTree::sample`] and [`DirTree::pdf`] read from the
    /// energies recorded so far. Until it is called again, recording changes the sums but not
    /// the distribution (which stays a distribution: sampling and its density read the same
    /// shares, whatever they are).
    pub fn freeze(&mut self) {
        for n in &mut self.nodes {
            n.share = n.shares().map(|s| s as f32);
            n.factor = [0, 1, 2, 3].map(|q| (4.0 * n.pick(q)) as f32);
        }
        self.trained = self.total() > 0.0;
    }

    /// Whether it had learned anything at the last [`DirTree::freeze`]: where it had not, its
    /// density is uniform, and a guide does better not to sample it at all.
    pub fn is_trained(&self) -> bool {
        self.trained
    }

    /// Records `value` of energy arriving along `d` (unit): added to the quadrant it falls in
    /// at every level. A value that is not positive and finite is left out.
    pub fn record(&mut self, d: Vec3A, value: f64) {
        let value = quantize(value);
        if value == 0 {
            return;
        }
        let s = to_square(d);
        let mut p = [s.x as f64, s.y as f64];
        let mut n = 0;
        loop {
            let (q, inner) = quadrant(p);
            let e = &mut self.nodes[n].energy[q];
            *e = e.saturating_add(value);
            match self.nodes[n].child[q] {
                LEAF => return,
                c => (n, p) = (c as usize, inner),
            }
        }
    }

    /// A direction from two uniform numbers in [0, 1), with its density in solid angle.
    pub fn sample(&self, u: Vec2) -> (Vec3A, f32) {
        let (mut ux, mut uy) = (u.x as f64, u.y as f64);
        let (mut origin, mut size, mut density) = ([0.0f64; 2], 1.0f64, 1.0f64);
        let mut n = 0;
        loop {
            let node = &self.nodes[n];
            let s = node.share.map(f64::from);
            // The column by its share, then the row within the column by its part of it.
            let (right, x) = choose(ux, s[0] + s[2]);
            let qx = usize::from(right);
            let column = s[qx] + s[qx + 2];
            let below = if column > 0.0 { s[qx] / column } else { 0.5 };
            let (up, y) = choose(uy, below);
            let q = qx + 2 * usize::from(up);
            (ux, uy) = (x, y);
            density *= node.factor[q] as f64;
            size *= 0.5;
            origin[0] += size * qx as f64;
            origin[1] += size * usize::from(up) as f64;
            match node.child[q] {
                LEAF => break,
                c => n = c as usize,
            }
        }
        let p = Vec2::new(
            (origin[0] + ux * size) as f32,
            (origin[1] + uy * size) as f32,
        );
        (
            from_square(p),
            (density / (4.0 * std::f64::consts::PI)) as f32,
        )
    }

    /// The density in solid angle with which [`DirTree::sample`] draws `d` (unit).
    pub fn pdf(&self, d: Vec3A) -> f32 {
        let s = to_square(d);
        let mut p = [s.x as f64, s.y as f64];
        let (mut n, mut density) = (0, 1.0f64);
        loop {
            let node = &self.nodes[n];
            let (q, inner) = quadrant(p);
            density *= node.factor[q] as f64;
            match node.child[q] {
                LEAF => break,
                c => (n, p) = (c as usize, inner),
            }
        }
        (density / (4.0 * std::f64::consts::PI)) as f32
    }

    /// The structure to train next, with no energy: a quadrant holding more than `threshold`
    /// of the energy (Müller's ρ, e.g. 0.01) becomes a node, down to [`MAX_DEPTH`]; a leaf
    /// that does is taken to have spread its energy evenly over its quadrants. A pure
    /// function of this tree's sums, so every machine refines a guide alike.
    pub fn refined(&self, threshold: f64) -> DirTree {
        // At most 1/ρ quadrants a level can hold more than ρ of the energy, so a tree has at
        // most MAX_DEPTH/ρ nodes; ρ is kept at MIN_THRESHOLD or above to bound that.
        let threshold = if threshold >= MIN_THRESHOLD {
            threshold
        } else if threshold > 0.0 {
            MIN_THRESHOLD
        } else {
            1.0
        };
        let mut out = DirTree::uniform();
        if !(self.total() > 0.0) {
            return out;
        }
        // A quadrant's share of the whole is its node's share times its share of the node, as
        // sampling reads it: so the shares of a level add up to one (and the bound above
        // holds) even where a node's sums disagree with its parent's, as forged or corrupted
        // ones may (the fuzzer found such a guide refining to 4^20 nodes).
        // (the old node, or none below a split old leaf; the new node; its share; its depth)
        let mut stack: Vec<(Option<usize>, usize, f64, u32)> = vec![(Some(0), 0, 1.0, 1)];
        while let Some((old, new, share, depth)) = stack.pop() {
            let shares = old.map_or([0.25; 4], |o| self.nodes[o].shares());
            for (q, part) in shares.into_iter().enumerate() {
                let quadrant = share * part;
                if quadrant <= threshold || depth >= MAX_DEPTH || out.len() >= MAX_NODES {
                    continue;
                }
                let child = out.nodes.len();
                out.nodes.push(Node::EMPTY);
                out.nodes[new].child[q] = child as u32;
                let below = old
                    .map(|o| self.nodes[o].child[q])
                    .filter(|&c| c != LEAF)
                    .map(|c| c as usize);
                stack.push((below, child, quadrant, depth + 1));
            }
        }
        out
    }

    /// Whether `other` has this tree's structure (the same nodes and children), so that
    /// [`DirTree::add`] takes it.
    pub fn same_shape(&self, other: &DirTree) -> bool {
        self.nodes.len() == other.nodes.len()
            && (self.nodes.iter().zip(&other.nodes)).all(|(a, b)| a.child == b.child)
    }

    /// Adds `other`'s energies to this tree's, quadrant by quadrant; the two must have the
    /// same structure (both refined from one guide). The sums are integers, so the order of
    /// additions cannot change a bit. The shares stay as they were until [`DirTree::freeze`].
    pub fn add(&mut self, other: &DirTree) -> Result<(), GuideError> {
        if !self.same_shape(other) {
            return Err(GuideError::Mismatch(self.nodes.len(), other.nodes.len()));
        }
        for (a, b) in self.nodes.iter_mut().zip(&other.nodes) {
            for q in 0..4 {
                a.energy[q] = a.energy[q].saturating_add(b.energy[q]);
            }
        }
        Ok(())
    }

    /// The tree as bytes, for the store and the wire: [`DirTree::decode`] reads them back to
    /// the same tree, bit for bit.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER + self.nodes.len() * NODE_BYTES);
        out.extend_from_slice(MAGIC);
        out.push(VERSION);
        out.extend_from_slice(&(self.nodes.len() as u32).to_le_bytes());
        for n in &self.nodes {
            for c in n.child {
                out.extend_from_slice(&c.to_le_bytes());
            }
            for e in n.energy {
                out.extend_from_slice(&e.to_le_bytes());
            }
        }
        out
    }

    /// A tree from [`DirTree::encode`]'s bytes, refusing any that do not describe one: each
    /// child a later node and nobody else's, every node reached from the root, no deeper than
    /// [`MAX_DEPTH`]. The tree comes back frozen ([`DirTree::freeze`]).
    pub fn decode(bytes: &[u8]) -> Result<Self, GuideError> {
        if bytes.len() < HEADER || &bytes[..4] != MAGIC || bytes[4] != VERSION {
            return Err(GuideError::Header);
        }
        let count = u32::from_le_bytes([bytes[5], bytes[6], bytes[7], bytes[8]]) as usize;
        if count == 0 || count > MAX_NODES {
            return Err(GuideError::NodeCount(count as u64));
        }
        let expected = HEADER + count * NODE_BYTES;
        if bytes.len() != expected {
            return Err(GuideError::Length {
                nodes: count,
                expected,
                got: bytes.len(),
            });
        }
        let mut r = Reader { bytes, at: HEADER };
        let mut nodes = Vec::with_capacity(count);
        for _ in 0..count {
            let mut node = Node::EMPTY;
            for c in &mut node.child {
                *c = u32::from_le_bytes(r.array()?);
            }
            for e in &mut node.energy {
                *e = u128::from_le_bytes(r.array()?);
            }
            nodes.push(node);
        }
        let children: Vec<[u32; 4]> = nodes.iter().map(|n| n.child).collect();
        check_shape(&children, MAX_DEPTH)?;
        let mut tree = Self {
            nodes,
            trained: false,
        };
        tree.freeze();
        Ok(tree)
    }
}

/// Bytes read in order, each read refused past the end.
pub(super) struct Reader<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) at: usize,
}

impl<'a> Reader<'a> {
    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8], GuideError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(GuideError::Truncated(self.bytes.len()));
        };
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    pub(super) fn array<const N: usize>(&mut self) -> Result<[u8; N], GuideError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::sampling::HashRng;

    /// A tree trained on directions near +z and a little everywhere, refined `levels` times.
    fn trained(levels: usize) -> DirTree {
        let mut tree = DirTree::uniform();
        for _ in 0..levels {
            let mut next = tree.refined(0.01);
            let mut rng = HashRng::new(7);
            for _ in 0..20_000 {
                let d = from_square(Vec2::new(rng.next_f32(), rng.next_f32()));
                next.record(d, if d.z > 0.9 { 50.0 } else { 1.0 });
            }
            tree = next;
            tree.freeze();
        }
        tree
    }

    #[test]
    fn the_square_and_the_sphere_map_back_and_forth() {
        let mut rng = HashRng::new(1);
        for _ in 0..10_000 {
            let p = Vec2::new(rng.next_f32(), rng.next_f32());
            let d = from_square(p);
            assert!((d.length() - 1.0).abs() < 1e-6, "{d}");
            let back = to_square(d);
            // x is meaningless at the poles.
            let dx = (back.x - p.x).abs().min(1.0 - (back.x - p.x).abs());
            assert!(dx < 1e-5 || p.y < 1e-3 || p.y > 0.999, "{p} {back}");
            assert!((back.y - p.y).abs() < 1e-6, "{p} {back}");
        }
    }

    #[test]
    fn refinement_follows_the_energy_and_is_a_pure_function_of_it() {
        let tree = trained(4);
        assert!(tree.len() > 20, "{} nodes", tree.len());
        assert_eq!(trained(4), tree);
        // Directions near +z are where the nodes are: the density there is far above uniform.
        let uniform = 1.0 / (4.0 * PI);
        assert!(tree.pdf(Vec3A::Z) > 5.0 * uniform);
        assert!(tree.pdf(-Vec3A::Z) < uniform);
        // Nothing learned: nothing refined.
        assert_eq!(DirTree::uniform().refined(0.01), DirTree::uniform());
    }

    #[test]
    fn sample_and_pdf_agree_and_the_density_integrates_to_one() {
        let tree = trained(4);
        let mut rng = HashRng::new(3);
        let mut differ = 0;
        for _ in 0..20_000 {
            let (d, pdf) = tree.sample(Vec2::new(rng.next_f32(), rng.next_f32()));
            let again = tree.pdf(d);
            assert!(pdf > 0.0 && again > 0.0, "{d}: {pdf} {again}");
            // Equal, but for a direction rounded across a leaf's edge.
            differ += usize::from((again / pdf - 1.0).abs() > 1e-5);
        }
        assert!(differ < 20, "{differ} of 20000 samples disagree with pdf");
        // ∫ pdf dω by the midpoint rule over the square (4π steradians per unit area).
        let n = 512;
        let mut sum = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let p = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                sum += tree.pdf(from_square(p)) as f64;
            }
        }
        let integral = sum * 4.0 * std::f64::consts::PI / (n * n) as f64;
        assert!((integral - 1.0).abs() < 2e-3, "{integral}");
    }

    #[test]
    fn sums_that_disagree_between_levels_still_refine_within_the_bound() {
        // The fuzzer's guide: a child whose energy dwarfs its parent's quadrant. Read as
        // absolute shares, every quadrant below it would split to the deepest level.
        let mut t = DirTree::uniform();
        t.nodes[0].energy = [5, 1, 1, 3];
        t.nodes[0].child[0] = 1;
        t.nodes.push(Node {
            energy: [1, u128::MAX, 2, 0],
            ..Node::EMPTY
        });
        let r = t.refined(0.01);
        assert!(
            r.len() <= (MAX_DEPTH as f64 / 0.01) as usize,
            "{} nodes",
            r.len()
        );
        assert!(r.len() > 2);
    }

    #[test]
    fn a_tree_survives_its_bytes_bit_for_bit_and_added_trees_must_match() {
        let tree = trained(3);
        assert_eq!(DirTree::decode(&tree.encode()), Ok(tree.clone()));
        let mut sum = tree.clone();
        sum.add(&tree).expect("same structure");
        assert_eq!(sum.total(), 2.0 * tree.total());
        // Any energies decode, the largest too, and sample within the sphere.
        let mut huge = tree.encode();
        for q in 0..4 {
            let at = HEADER + 16 + 16 * q;
            huge[at..at + 16].copy_from_slice(&u128::MAX.to_le_bytes());
        }
        let huge = DirTree::decode(&huge).expect("any energies are sums");
        let (d, pdf) = huge.sample(Vec2::new(0.3, 0.7));
        assert!(d.is_finite() && pdf > 0.0 && (huge.pdf(d) / pdf - 1.0).abs() < 1e-6);
        assert!(matches!(
            sum.add(&DirTree::uniform()),
            Err(GuideError::Mismatch(_, 1))
        ));
    }

    #[test]
    fn bad_bytes_are_refused_by_what_is_wrong() {
        let good = trained(2).encode();
        let node = |i: usize| HEADER + i * NODE_BYTES;
        let mut cases: Vec<(Vec<u8>, &str)> = vec![
            (b"nope".to_vec(), "bad header"),
            (good[..good.len() - 1].to_vec(), "takes"),
        ];
        let mut zero = good.clone();
        zero[5..9].copy_from_slice(&0u32.to_le_bytes());
        cases.push((zero, "has 0 nodes"));
        // The root pointing at itself, and a cycle back to it.
        let mut own = good.clone();
        own[node(0)..node(0) + 4].copy_from_slice(&0u32.to_le_bytes());
        own[node(0) + 4..node(0) + 8].copy_from_slice(&0u32.to_le_bytes());
        own[node(0) + 8..node(0) + 12].copy_from_slice(&0u32.to_le_bytes());
        own[node(0) + 12..node(0) + 16].copy_from_slice(&0u32.to_le_bytes());
        cases.push((own, "nobody's child"));
        let mut past = good.clone();
        past[node(0)..node(0) + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        cases.push((past, "is not a node of its own"));
        for (bytes, want) in cases {
            let e = DirTree::decode(&bytes).expect_err(want).to_string();
            assert!(e.contains(want), "{e} (wanted {want})");
        }
        // A chain one node too deep.
        let mut chain = DirTree::uniform();
        for i in 0..MAX_DEPTH as usize {
            chain.nodes[i].child[0] = i as u32 + 1;
            chain.nodes.push(Node::EMPTY);
        }
        let e = DirTree::decode(&chain.encode()).expect_err("too deep");
        assert_eq!(e, GuideError::Depth(MAX_DEPTH as usize));
        chain.nodes.pop();
        chain.nodes[MAX_DEPTH as usize - 1].child[0] = LEAF;
        assert!(DirTree::decode(&chain.encode()).is_ok());
    }

    #[test]
    fn random_and_mangled_bytes_never_panic_and_what_decodes_samples_finite() {
        let good = trained(2).encode();
        let mut rng = HashRng::new(11);
        for round in 0..3000 {
            let mut bytes = good.clone();
            if round % 2 == 0 {
                for _ in 0..1 + round % 5 {
                    let at = (rng.next_f32() * bytes.len() as f32) as usize % bytes.len();
                    bytes[at] = (rng.next_f32() * 256.0) as u8;
                }
            } else {
                bytes.truncate((rng.next_f32() * bytes.len() as f32) as usize);
            }
            if let Ok(tree) = DirTree::decode(&bytes) {
                let (d, pdf) = tree.sample(Vec2::new(rng.next_f32(), rng.next_f32()));
                assert!(d.is_finite() && pdf.is_finite() && pdf >= 0.0, "{d} {pdf}");
                assert!(tree.pdf(d).is_finite());
            }
        }
    }
}
