//! Tables computed once and shared, built on every core.

/// `f(0)`, …, `f(n − 1)` in that order, the indices split into one contiguous run per core.
/// Each entry depends on its index alone, so the table is the same bits on any number of
/// cores.
///
/// Plain scoped threads, not rayon: tables are built under a lock (a `OnceLock`, a map of
/// shared tables), and a rayon thread that waits for its helpers may steal a job that asks
/// for the same table, and wait on the lock it holds.
pub fn tabulate<T: Send>(n: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    let runs = cores.clamp(1, n.max(1));
    let run = n.div_ceil(runs);
    if runs == 1 {
        return (0..n).map(f).collect();
    }
    let f = &f;
    std::thread::scope(|s| {
        let parts: Vec<_> = (0..runs)
            .map(|r| s.spawn(move || (r * run..((r + 1) * run).min(n)).map(f).collect::<Vec<T>>()))
            .collect();
        parts
            .into_iter()
            .flat_map(|p| p.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::tabulate;

    #[test]
    fn entries_come_in_index_order_whatever_the_split() {
        for n in [0, 1, 2, 3, 7, 64, 1001] {
            let want: Vec<u64> = (0..n as u64).map(|i| i * i + 1).collect();
            assert_eq!(tabulate(n, |i| (i * i + 1) as u64), want, "n = {n}");
        }
    }
}
