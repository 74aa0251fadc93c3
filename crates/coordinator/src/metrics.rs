//! Timings the scheduler cannot see (how long a merge takes, how long a commit takes), kept
//! in atomics so that recording one never takes a lock, and the Prometheus text exposition
//! of them together with the scheduler's [`Counters`].

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Bucket bounds in seconds, from a tenth of a millisecond (a merge that found its commit
/// group open) to ten seconds (a disk that has stalled).
const BOUNDS: [f64; 14] = [
    0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 10.0,
];

/// A latency histogram with fixed buckets.
#[derive(Debug, Default)]
pub struct Histogram {
    buckets: [AtomicU64; BOUNDS.len()],
    count: AtomicU64,
    sum_ns: AtomicU64,
}

impl Histogram {
    /// Records one observation.
    pub fn observe(&self, d: Duration) {
        let s = d.as_secs_f64();
        if let Some(i) = BOUNDS.iter().position(|&b| s <= b) {
            self.buckets[i].fetch_add(1, Ordering::Relaxed);
        }
        self.count.fetch_add(1, Ordering::Relaxed);
        self.sum_ns.fetch_add(
            u64::try_from(d.as_nanos()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
    }

    /// Observations so far.
    pub fn count(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    /// Writes the histogram as `name_bucket`, `name_sum` and `name_count` lines.
    fn write(&self, out: &mut Text, name: &str, help: &str) {
        out.header(name, help, "histogram");
        let mut cumulative = 0;
        for (b, n) in BOUNDS.iter().zip(&self.buckets) {
            cumulative += n.load(Ordering::Relaxed);
            out.line(&format!("{name}_bucket{{le=\"{b}\"}}"), cumulative as f64);
        }
        let count = self.count();
        out.line(&format!("{name}_bucket{{le=\"+Inf\"}}"), count as f64);
        out.line(
            &format!("{name}_sum"),
            self.sum_ns.load(Ordering::Relaxed) as f64 / 1e9,
        );
        out.line(&format!("{name}_count"), count as f64);
    }
}

/// Timings and totals recorded outside the scheduler's lock.
#[derive(Debug, Default)]
pub struct Metrics {
    /// From a result's arrival to its merge in memory (merged results only; the store has it
    /// at the next checkpoint).
    pub merge: Histogram,
    /// One group commit of the state store.
    pub commit: Histogram,
    /// Bytes of partial sums, scenes and records handed to the store.
    pub written_bytes: AtomicU64,
    /// Bytes of closed tiles' sums dropped from memory once stored (read back for the frame).
    pub evicted_bytes: AtomicU64,
    /// Dashboard previews computed (not served from the cache).
    pub previews: AtomicU64,
}

/// One worker's line in the exposition.
#[derive(Debug)]
pub struct WorkerLine {
    /// Public id.
    pub id: String,
    /// The name it gave.
    pub name: String,
    /// Merged samples per second, recently.
    pub rate: f64,
    /// Merged samples since it registered.
    pub samples: u64,
}

/// Totals since the coordinator started, exported as Prometheus counters (docs/farm.md,
/// "Metrics"). Kept by the scheduler, under its lock, because it is the one place that knows
/// what became of each lease and result; defined here, with their exposition.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Units handed out (a unit raced by several workers counts once a lease).
    pub units_leased: u64,
    /// Units merged into their tiles.
    pub units_merged: u64,
    /// Results for units merged already (a raced or retried unit).
    pub units_duplicate: u64,
    /// Results for jobs that had ended.
    pub units_discarded: u64,
    /// Results held for an audit.
    pub units_held: u64,
    /// Units the coordinator rendered itself to settle an audit.
    pub units_refereed: u64,
    /// Results refused (malformed, forged, quoting another's lease, from a quarantined worker).
    pub results_refused: u64,
    /// Samples in the merged units.
    pub samples_merged: u64,
    /// Open tiles read back from the store for a merge, having left memory between batches.
    pub tiles_reloaded: u64,
    /// Results told to come back later because merged sums waited for the store.
    pub results_deferred: u64,
}

/// What the scheduler holds, read under its lock in one go and formatted after it is let go.
#[derive(Debug, Default)]
pub struct Gauges {
    /// Jobs (frames count one each) by state name.
    pub jobs: Vec<(&'static str, u64)>,
    /// Workers seen within a lease time, not gone.
    pub workers_active: u64,
    /// Workers refused work (invalid results or an audit's conviction).
    pub workers_quarantined: u64,
    /// Live leases.
    pub leases: u64,
    /// The scheduler's totals.
    pub counters: Counters,
    /// Workers alive, by id.
    pub workers: Vec<WorkerLine>,
    /// Size of the store's file, when it could be read.
    pub store_file_bytes: Option<u64>,
    /// Bytes of active jobs' logs in memory, and of ended jobs' logs in the store.
    pub log_bytes: (u64, u64),
}

/// Prometheus text exposition format 0.0.4, built line by line.
struct Text(String);

impl Text {
    fn header(&mut self, name: &str, help: &str, kind: &str) {
        let _ = writeln!(self.0, "# HELP {name} {help}");
        let _ = writeln!(self.0, "# TYPE {name} {kind}");
    }

    fn line(&mut self, series: &str, value: f64) {
        let _ = writeln!(self.0, "{series} {value}");
    }

    fn single(&mut self, name: &str, help: &str, kind: &str, value: f64) {
        self.header(name, help, kind);
        self.line(name, value);
    }
}

/// A label value escaped as the text format requires (backslash, quote, newline).
fn label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

impl Metrics {
    /// The exposition of these metrics and `g`.
    pub fn render(&self, g: &Gauges) -> String {
        let mut t = Text(String::with_capacity(4096 + g.workers.len() * 200));
        t.header(
            "tessera_jobs",
            "Jobs by state (each frame of a range counts).",
            "gauge",
        );
        for (state, n) in &g.jobs {
            t.line(&format!("tessera_jobs{{state=\"{state}\"}}"), *n as f64);
        }
        let c = &g.counters;
        for (name, help, v) in [
            (
                "tessera_units_leased_total",
                "Units handed to workers.",
                c.units_leased,
            ),
            (
                "tessera_units_merged_total",
                "Units merged into their tiles.",
                c.units_merged,
            ),
            (
                "tessera_units_duplicate_total",
                "Results for units merged already.",
                c.units_duplicate,
            ),
            (
                "tessera_units_discarded_total",
                "Results for jobs that had ended.",
                c.units_discarded,
            ),
            (
                "tessera_units_held_total",
                "Results held for an audit.",
                c.units_held,
            ),
            (
                "tessera_tiles_reloaded_total",
                "Open tiles of large jobs read back from the store for their next merge.",
                c.tiles_reloaded,
            ),
            (
                "tessera_results_deferred_total",
                "Results told to retry while merged sums waited for a checkpoint to store them.",
                c.results_deferred,
            ),
            (
                "tessera_results_refused_total",
                "Results refused as invalid or not the sender's to give.",
                c.results_refused,
            ),
            (
                "tessera_samples_merged_total",
                "Samples in merged units.",
                c.samples_merged,
            ),
        ] {
            t.single(name, help, "counter", v as f64);
        }
        gauges(&mut t, g);
        self.merge.write(
            &mut t,
            "tessera_merge_seconds",
            "From a result's arrival to its merge (durable at the next checkpoint).",
        );
        self.commit.write(
            &mut t,
            "tessera_store_commit_seconds",
            "One commit of the state store (a checkpoint, or a change a reply waits on).",
        );
        t.single(
            "tessera_store_written_bytes_total",
            "Bytes of sums, scenes and records handed to the state store.",
            "counter",
            self.written_bytes.load(Ordering::Relaxed) as f64,
        );
        t.single(
            "tessera_sums_evicted_bytes_total",
            "Bytes of closed tiles' sums dropped from memory once the store held them.",
            "counter",
            self.evicted_bytes.load(Ordering::Relaxed) as f64,
        );
        if let Some(b) = g.store_file_bytes {
            t.single(
                "tessera_store_file_bytes",
                "Size of the state store's file.",
                "gauge",
                b as f64,
            );
        }
        t.single(
            "tessera_dashboard_previews_total",
            "Dashboard previews computed (cache misses).",
            "counter",
            self.previews.load(Ordering::Relaxed) as f64,
        );
        per_worker(&mut t, &g.workers);
        t.0
    }
}

/// The single-valued gauges of `g`: leases, workers, logs.
fn gauges(t: &mut Text, g: &Gauges) {
    t.single(
        "tessera_leases",
        "Leases live now.",
        "gauge",
        g.leases as f64,
    );
    t.single(
        "tessera_workers_active",
        "Workers that called within a lease time and have not said goodbye.",
        "gauge",
        g.workers_active as f64,
    );
    t.single(
        "tessera_workers_quarantined",
        "Workers refused work after invalid results or an audit's conviction.",
        "gauge",
        g.workers_quarantined as f64,
    );
    t.single(
        "tessera_log_memory_bytes",
        "Bytes of active jobs' worker logs held in memory (about).",
        "gauge",
        g.log_bytes.0 as f64,
    );
    t.single(
        "tessera_log_stored_bytes",
        "Bytes of ended jobs' worker logs kept in the store (until --log-retention or --max-log-bytes).",
        "gauge",
        g.log_bytes.1 as f64,
    );
}

/// A metric family: its name, help and type, and what each worker's line gives it.
type Family = (
    &'static str,
    &'static str,
    &'static str,
    fn(&WorkerLine) -> f64,
);

/// Each live worker's rate and merged samples, labelled by its id and name.
fn per_worker(t: &mut Text, workers: &[WorkerLine]) {
    let families: [Family; 2] = [
        (
            "tessera_worker_samples_per_second",
            "Each live worker's merged samples per second, recently.",
            "gauge",
            |w| w.rate,
        ),
        (
            "tessera_worker_samples_merged_total",
            "Each live worker's merged samples since it registered.",
            "counter",
            |w| w.samples as f64,
        ),
    ];
    for (name, help, kind, value) in families {
        t.header(name, help, kind);
        for w in workers {
            let labels = format!("worker=\"{}\",name=\"{}\"", label(&w.id), label(&w.name));
            t.line(&format!("{name}{{{labels}}}"), value(w));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_are_cumulative_and_the_count_covers_overflow() {
        let m = Metrics::default();
        m.merge.observe(Duration::from_micros(50));
        m.merge.observe(Duration::from_millis(3));
        m.merge.observe(Duration::from_secs(60));
        let text = m.render(&Gauges::default());
        assert!(text.contains("tessera_merge_seconds_bucket{le=\"0.0001\"} 1\n"));
        assert!(text.contains("tessera_merge_seconds_bucket{le=\"0.005\"} 2\n"));
        assert!(text.contains("tessera_merge_seconds_bucket{le=\"10\"} 2\n"));
        assert!(text.contains("tessera_merge_seconds_bucket{le=\"+Inf\"} 3\n"));
        assert!(text.contains("tessera_merge_seconds_count 3\n"));
    }

    #[test]
    fn label_values_are_escaped() {
        assert_eq!(label("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
    }
}
