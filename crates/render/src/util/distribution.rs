//! Discrete distributions: [`Distribution1D`], sampled by inverting its cdf (which keeps the
//! sampler's order), and alias tables ([`AliasEntry`]), sampled in constant time.

use super::sampling::ONE_MINUS_EPSILON;

/// A discrete distribution sampled by inversion of its CDF.
///
/// Inversion, not an alias table, because it keeps the sampler's stratification: nearby `u`
/// pick nearby entries (an emissive mesh's triangles are in BVH leaf order, so nearby in
/// space too), and the rest of `u` places the point inside the entry
/// ([`Distribution1D::sample_remap`]).
#[derive(Clone, Debug)]
pub struct Distribution1D {
    /// Each entry's cdf (the probability of it and every entry before it) and pmf, side by
    /// side: a large distribution's sample then waits for one cache line, not two.
    table: Vec<[f32; 2]>,
    /// A guide table (Chen and Asau, 1974), empty for the smallest distributions: slot
    /// k holds the first entry whose cdf exceeds k / len, where the search for a `u` in that
    /// slice of [0, 1) starts. On an emissive mesh of a million triangles a binary search was
    /// a random walk through megabytes for every light sample (docs/renderer.md).
    guide: Vec<u32>,
}

/// Distributions of at least this many entries get a guide table; below it, the binary search
/// of a few cached entries costs what the table's lookup does. Small as it is, a table pays:
/// an environment map's light sample searches its rows (tens of entries) and then a row of
/// cells, and with tables from 8 entries instead of 64 the sky-lit scenes rendered 2 to 4%
/// faster, the same bits (docs/benchmarks/sky-path-2026-11-30.md).
const GUIDE_MIN: usize = 8;

impl Distribution1D {
    /// Builds from non-negative weights. Returns `None` if all weights are zero.
    pub fn new(weights: &[f32]) -> Option<Self> {
        let total: f64 = weights.iter().map(|&w| w.max(0.0) as f64).sum();
        if !(total > 0.0) || !total.is_finite() {
            return None;
        }
        let mut table = Vec::with_capacity(weights.len());
        let mut acc = 0.0f64;
        for &w in weights {
            let w = w.max(0.0) as f64;
            acc += w;
            table.push([(acc / total) as f32, (w / total) as f32]);
        }
        if let Some(last) = table.last_mut() {
            last[0] = 1.0;
        }
        let n = table.len();
        let mut guide = Vec::new();
        if n >= GUIDE_MIN && u32::try_from(n).is_ok() {
            guide.reserve_exact(n);
            let mut i = 0;
            for k in 0..n {
                // Where the slice starts only sets where the search starts: `sample` steps
                // from there to the entry the binary search would find, either way.
                let start = k as f32 / n as f32;
                while i + 1 < n && table[i][0] <= start {
                    i += 1;
                }
                guide.push(i as u32);
            }
        }
        Some(Self { table, guide })
    }

    /// Picks an index for `u` in [0, 1), never one of zero probability.
    #[inline]
    pub fn sample(&self, u: f32) -> usize {
        let t = &self.table;
        let n = t.len();
        // One light is the common case: no search.
        if n == 1 {
            return 0;
        }
        let mut i = if self.guide.is_empty() {
            t.partition_point(|e| e[0] <= u).min(n - 1)
        } else {
            // The first entry whose cdf exceeds u, as the binary search finds it: the cdf does
            // not decrease, so stepping back past entries above u and on past entries at or
            // below it lands there from any start.
            let k = ((u * n as f32) as usize).min(n - 1);
            let mut i = self.guide[k] as usize;
            while i > 0 && t[i - 1][0] > u {
                i -= 1;
            }
            while i + 1 < n && t[i][0] <= u {
                i += 1;
            }
            i
        };
        // Rounding can land on a zero-weight entry at a plateau; step to the next real one.
        while t[i][1] == 0.0 && i + 1 < n {
            i += 1;
        }
        i
    }

    /// [`Distribution1D::sample`], and `u` stretched back over [0, 1) within the chosen
    /// entry's share, so that the one number also places a point inside it.
    #[inline]
    pub fn sample_remap(&self, u: f32) -> (usize, f32) {
        let i = self.sample(u);
        let lo = if i == 0 { 0.0 } else { self.table[i - 1][0] };
        let rel = (u - lo) / self.table[i][1];
        (i, rel.clamp(0.0, ONE_MINUS_EPSILON))
    }

    /// Probability of index `i`.
    #[inline]
    pub fn pmf(&self, i: usize) -> f32 {
        self.table[i][1]
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.table.len()
    }

    /// Whether it has no entries (never true for a constructed distribution).
    pub fn is_empty(&self) -> bool {
        self.table.is_empty()
    }
}

/// One bin of an alias table (Walker's alias method, Vose's construction: [`push_alias_entries`]):
/// the share of the bin's 1/n that keeps its own index, and the index the rest of it gives. One
/// number picks one of n equal bins ([`alias_bin`]), and the rest of it either keeps the bin's
/// own index or takes its alias ([`AliasEntry::pick`]): constant time, where
/// [`Distribution1D`]'s inversion searches its cdf (a walk through a large table, with a branch
/// the predictor cannot guess at every step). It gives up inversion's order (nearby numbers may
/// pick far entries), which costs little where the entries are many more than the samples that
/// meet them (the columns of a full-size environment map's row: [`crate::envmap`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AliasEntry {
    keep: f32,
    alias: u32,
}

/// Appends the alias entries of `weights` (one per weight) to `out`; false, appending nothing,
/// if the weights are all zero or their sum is not finite. The construction is basic f64
/// arithmetic in a fixed order, so every worker builds the same table.
pub fn push_alias_entries(weights: &[f32], out: &mut Vec<AliasEntry>) -> bool {
    let n = weights.len();
    let total: f64 = weights.iter().map(|&w| f64::from(w.max(0.0))).sum();
    if !(total > 0.0) || !total.is_finite() || u32::try_from(n).is_err() {
        return false;
    }
    // Each bin's weight in units of the mean: a bin below one is filled from one above it.
    let mut scaled: Vec<f64> = weights
        .iter()
        .map(|&w| f64::from(w.max(0.0)) * n as f64 / total)
        .collect();
    let start = out.len();
    out.extend((0..n).map(|i| AliasEntry {
        keep: 1.0,
        alias: i as u32,
    }));
    let entries = &mut out[start..];
    let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| scaled[i] < 1.0);
    while let (Some(&s), Some(&l)) = (small.last(), large.last()) {
        small.pop();
        entries[s] = AliasEntry {
            keep: scaled[s] as f32,
            alias: l as u32,
        };
        scaled[l] = (scaled[l] + scaled[s]) - 1.0;
        if scaled[l] < 1.0 {
            large.pop();
            small.push(l);
        }
    }
    // What is left is one bin's worth but for rounding, and keeps its own index; a bin of zero
    // weight left by rounding gives the heaviest bin instead, so it is never drawn.
    let heaviest = (0..n).fold(0, |b, i| if weights[i] > weights[b] { i } else { b });
    for i in small.into_iter().chain(large) {
        entries[i] = if weights[i] > 0.0 {
            AliasEntry {
                keep: 1.0,
                alias: i as u32,
            }
        } else {
            AliasEntry {
                keep: 0.0,
                alias: heaviest as u32,
            }
        };
    }
    true
}

/// The bin of `n` that `u` in [0, 1) falls in, and where in it (in [0, 1)).
#[inline]
pub fn alias_bin(n: usize, u: f32) -> (usize, f32) {
    let x = u * n as f32;
    let k = (x as usize).min(n - 1);
    (k, (x - k as f32).min(ONE_MINUS_EPSILON))
}

impl AliasEntry {
    /// The index the bin gives when it does not keep its own.
    #[inline]
    pub fn alias(&self) -> usize {
        self.alias as usize
    }

    /// For bin `k` (whose entry this is) and the place `f` in it: the index drawn, `f`
    /// stretched back over [0, 1) within its share, and whether the bin kept its own index.
    /// Without a branch on which of the two it gives: that is a coin toss for the predictor.
    #[inline]
    pub fn pick(&self, k: usize, f: f32) -> (usize, f32, bool) {
        let kept = f < self.keep;
        let index = if kept { k } else { self.alias as usize };
        let (num, den) = if kept {
            (f, self.keep)
        } else {
            (f - self.keep, 1.0 - self.keep)
        };
        (index, (num / den).clamp(0.0, ONE_MINUS_EPSILON), kept)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::sampling::HashRng;

    /// One distribution's alias entries sampled at `u`: its index and remainder.
    fn sample(entries: &[AliasEntry], u: f32) -> (usize, f32) {
        let (k, f) = alias_bin(entries.len(), u);
        let (index, rest, _) = entries[k].pick(k, f);
        (index, rest)
    }

    #[test]
    fn distribution_never_picks_zero_weight() {
        let d = Distribution1D::new(&[0.0, 1.0, 0.0, 3.0, 0.0]).expect("non-zero");
        for i in 0..1000 {
            let k = d.sample(i as f32 / 1000.0);
            assert!(k == 1 || k == 3);
        }
        assert_eq!(d.sample(ONE_MINUS_EPSILON), 3);
        assert!(Distribution1D::new(&[0.0, 0.0]).is_none());
        assert!((d.pmf(3) - 0.75).abs() < 1e-6);
    }

    /// The weights a distribution meets, `n` of each shape: equal; random with a `spike` every
    /// `every` entries; runs of `zero_run` zeros between runs of small integers; and
    /// e^(−i/`decay`), a tail that falls to almost nothing.
    fn weight_shapes(
        rng: &mut HashRng,
        n: usize,
        (every, spike): (usize, f32),
        zero_run: usize,
        decay: f32,
    ) -> [Vec<f32>; 4] {
        let equal = vec![1.0f32; n];
        let skewed = (0..n)
            .map(|i| {
                if i % every == 0 {
                    spike
                } else {
                    rng.next_f32()
                }
            })
            .collect();
        let zeros = (0..n)
            .map(|i| {
                if (i / zero_run).is_multiple_of(2) {
                    0.0
                } else {
                    1.0 + (i % 7) as f32
                }
            })
            .collect();
        let decaying = (0..n).map(|i| (-(i as f32) / decay).exp()).collect();
        [equal, skewed, zeros, decaying]
    }

    /// The guide table picks the entry the binary search picks, for every kind of weights a
    /// mesh light or a map's rows can have (equal, skewed by 10⁶, long runs of zeros), at the
    /// slices' edges and at the cdf's own values and their neighbours, where rounding decides;
    /// from the smallest distribution that has a table to a mesh's thousands of triangles.
    #[test]
    fn guided_search_picks_what_the_binary_search_picks() {
        let mut rng = HashRng::new(3);
        let shapes = [
            (GUIDE_MIN, (3, 1e6), 2, 2.0),
            (31, (7, 1e6), 5, 6.0),
            (64, (11, 1e6), 9, 12.0),
            (5000, (97, 1e6), 300, 200.0),
        ];
        for (n, spikes, zero_run, decay) in shapes {
            check_guided_search(&mut rng, n, spikes, zero_run, decay);
        }
        // Small distributions keep the plain search and no table.
        assert!(Distribution1D::new(&[1.0; GUIDE_MIN - 1])
            .expect("non-zero")
            .guide
            .is_empty());
    }

    fn check_guided_search(
        rng: &mut HashRng,
        n: usize,
        spikes: (usize, f32),
        zero_run: usize,
        decay: f32,
    ) {
        for weights in weight_shapes(rng, n, spikes, zero_run, decay) {
            let d = Distribution1D::new(&weights).expect("non-zero");
            assert_eq!(d.guide.len(), n);
            let mut plain = d.clone();
            plain.guide.clear();
            let mut us: Vec<f32> = (0..=4 * n).map(|k| k as f32 / (4 * n) as f32).collect();
            for &[c, _] in &d.table {
                us.extend([c, c.next_down(), c.next_up()]);
            }
            us.extend((0..20_000).map(|_| rng.next_f32()));
            us.push(ONE_MINUS_EPSILON);
            for u in us.into_iter().filter(|u| (0.0..1.0).contains(u)) {
                assert_eq!(d.sample(u), plain.sample(u), "n = {n}, u = {u}");
                assert_eq!(d.sample_remap(u), plain.sample_remap(u), "n = {n}, u = {u}");
            }
        }
    }

    /// The alias table draws each index in proportion to its weight (Pearson's chi-square over
    /// the indices, for equal, skewed, zero-run and decaying weights), never one of zero weight,
    /// and the number it gives back is uniform inside the index it picked (chi-square of the
    /// remainders of one index over 16 bins), including at the domain's end.
    #[test]
    fn alias_table_draws_in_proportion_and_remaps_uniformly() {
        let mut rng = HashRng::new(11);
        let n = 64;
        let samples = 400_000;
        for weights in weight_shapes(&mut rng, n, (13, 1e3), 5, 4.0) {
            let mut table = Vec::new();
            assert!(push_alias_entries(&weights, &mut table));
            let total: f64 = weights.iter().map(|&w| f64::from(w)).sum();
            let mut counts = vec![0u32; n];
            let heaviest = (0..n).fold(0, |b, i| if weights[i] > weights[b] { i } else { b });
            let mut rem = [0u32; 16];
            for _ in 0..samples {
                let (i, r) = sample(&table, rng.next_f32());
                assert!(weights[i] > 0.0, "picked {i} of zero weight");
                assert!((0.0..1.0).contains(&r));
                counts[i] += 1;
                if i == heaviest {
                    rem[(r * 16.0) as usize] += 1;
                }
            }
            // Cells expected below 5 draws are pooled, as the chi-square test asks.
            let (mut chi2, mut dof, mut pool_o, mut pool_e) = (0.0, 0usize, 0.0, 0.0);
            for (c, &w) in counts.iter().zip(&weights) {
                let e = f64::from(w) / total * samples as f64;
                if e < 5.0 {
                    (pool_o, pool_e) = (pool_o + f64::from(*c), pool_e + e);
                    continue;
                }
                chi2 += (f64::from(*c) - e).powi(2) / e;
                dof += 1;
            }
            if pool_e > 0.0 {
                chi2 += (pool_o - pool_e).powi(2) / pool_e;
                dof += 1;
            }
            // Under 99.9% of chi-square's with dof − 1 degrees of freedom (Wilson–Hilferty).
            let k = (dof - 1) as f64;
            let bound = k * (1.0 - 2.0 / (9.0 * k) + 3.09 * (2.0 / (9.0 * k)).sqrt()).powi(3);
            assert!(
                chi2 < bound,
                "chi-square {chi2} over {bound} for {weights:?}"
            );
            let e = f64::from(rem.iter().sum::<u32>()) / 16.0;
            let chi2: f64 = rem.iter().map(|&o| (f64::from(o) - e).powi(2) / e).sum();
            assert!(chi2 < 37.7, "remainders {rem:?}");
        }
        let mut t = Vec::new();
        assert!(push_alias_entries(&[0.0, 2.0, 0.0, 1.0], &mut t));
        let (i, r) = sample(&t, ONE_MINUS_EPSILON);
        assert!(i == 1 || i == 3);
        assert!(r < 1.0);
        let mut none = Vec::new();
        assert!(!push_alias_entries(&[0.0, 0.0], &mut none) && none.is_empty());
        assert!(push_alias_entries(&[f32::MAX; 4], &mut Vec::new()));
        // A single weight is its own table.
        let mut one = Vec::new();
        assert!(push_alias_entries(&[5.0], &mut one));
        assert_eq!(sample(&one, 0.3), (0, 0.3));
    }
}
