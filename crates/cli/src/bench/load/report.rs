//! `tessera loadtest`'s report: the runs' figures as CSV and as a markdown table.

use std::fmt::Write as _;

use super::{Plan, Run, SIZE, TEMPLATE_SPP, TILE};

impl Run {
    /// The measured columns, in the reports' order.
    fn columns(&self) -> [f64; 13] {
        [
            self.samples as f64 / 1e9 / self.seconds,
            self.cpu_per_gsample,
            self.mb_per_gsample,
            self.merged as f64 / self.seconds,
            self.lease_p50_ms,
            self.lease_p99_ms,
            self.lease_max_ms,
            self.probe_p50_ms,
            self.probe_p99_ms,
            self.cpu_share,
            self.rss_mib,
            self.peak_rss_mib,
            self.bytes_per_unit,
        ]
    }
}

/// [`Run::columns`]' names, and the decimals the markdown table gives each.
const COLUMNS: [(&str, &str, usize); 13] = [
    ("gsamples_per_s", "Gsamples merged/s", 3),
    ("cpu_s_per_gsample", "coordinator CPU-s per Gsample", 3),
    ("mb_written_per_gsample", "MB written per Gsample", 1),
    ("units_per_s", "units merged/s", 0),
    ("lease_p50_ms", "lease p50 ms", 2),
    ("lease_p99_ms", "lease p99 ms", 2),
    ("lease_max_ms", "lease max ms", 2),
    ("probe_p50_ms", "probe p50 ms", 2),
    ("probe_p99_ms", "probe p99 ms", 2),
    ("coordinator_cpu_share", "coordinator CPU (cores)", 2),
    ("rss_mib", "RSS MiB", 1),
    ("peak_rss_mib", "peak RSS MiB", 1),
    ("bytes_written_per_unit", "bytes written per unit", 0),
];

pub(super) fn to_csv(runs: &[Run]) -> String {
    let mut s = String::from("workers,guided,seconds,units_merged,units_refused,samples_merged");
    for (name, _, _) in COLUMNS {
        let _ = write!(s, ",{name}");
    }
    s.push('\n');
    for r in runs {
        let _ = write!(
            s,
            "{},{},{:.3},{},{},{}",
            r.workers, r.guided, r.seconds, r.merged, r.refused, r.samples
        );
        for v in r.columns() {
            let _ = write!(s, ",{v:.3}");
        }
        s.push('\n');
    }
    s
}

pub(super) fn report(runs: &[Run], command: &str, machine: &str, plan: &Plan) -> String {
    let mut md = String::from("# Many workers against one coordinator, full-size units\n\n");
    let _ = writeln!(md, "Made by `{command}`.\n");
    let _ = writeln!(md, "Machine: {machine}.\n");
    let cores = if plan.split_cores {
        "The coordinator ran on CPU 0 alone, the simulated workers on the others \
         (`--split-cores`)."
    } else {
        "Both processes shared the machine's cores."
    };
    let pace = if plan.rate > 0.0 {
        format!(
            "The workers were paced to {} Msamples/s together.",
            plan.rate
        )
    } else {
        "The workers were not paced: each sent its next result as soon as the last was \
         answered, so the rate is the most the coordinator took."
            .to_string()
    };
    let flags = if plan.coordinator_args.is_empty() {
        "its default flags".to_string()
    } else {
        format!("`{}`", plan.coordinator_args.join(" "))
    };
    let _ = writeln!(
        md,
        "A `tessera coordinator` process on loopback, with its store on this machine's disk and \
         {flags}; N simulated workers in one other process, each \
         with its own connection and registration, leasing one unit at a time and submitting \
         a full-size result for it: a {TILE}² tile × {batch} samples ({msamples:.1} Msamples, \
         {kb:.0} KB of sums) of a {SIZE}² Cornell box, the sums of one real render of a tile \
         at {TEMPLATE_SPP} spp scaled to the unit's samples. {pace} The coordinator's CPU \
         time and bytes written come from `/proc/PID/stat` and `/proc/PID/io` over the \
         measured window (a checkpoint that falls in it writes what was merged before it), \
         its memory from `/proc/PID/status` at the window's end. Lease latency is a `Lease` \
         call's round trip, for calls that returned a unit, as the N workers saw it (their own \
         process's queueing included) and as one more worker, the probe, saw it from a thread \
         of its own. {cores}\n",
        batch = plan.settings.batch,
        msamples = f64::from(TILE * TILE * plan.settings.batch) / 1e6,
        kb = f64::from(TILE * TILE) * 52.0 / 1e3,
    );
    md.push_str("| workers |");
    for (_, title, _) in COLUMNS {
        let _ = write!(md, " {title} |");
    }
    md.push_str("\n|---:|");
    md.push_str(&"---:|".repeat(COLUMNS.len()));
    md.push('\n');
    for r in runs {
        let guided = if r.guided { " guided" } else { "" };
        let _ = write!(md, "| {}{guided} |", r.workers);
        for (v, (_, _, decimals)) in r.columns().into_iter().zip(COLUMNS) {
            let _ = write!(md, " {v:.decimals$} |");
        }
        md.push('\n');
    }
    if runs.iter().any(|r| r.guided) {
        let _ = writeln!(
            md,
            "\nRows marked guided rendered the same job with `--guiding`, each after the \
             unguided run of its worker count: units are its epochs cut at the batch (so the \
             first epochs' units are 1, 2 and 4 samples), each unit of a training epoch \
             returns a training tree of {} synthetic records in its epoch's structure (fetched \
             and refined by the simulated workers, one per epoch), and the coordinator checks \
             and adds each and freezes each epoch's into the next guide.",
            super::training::RECORDS
        );
    }
    for r in runs.iter().filter(|r| r.guided) {
        let _ = writeln!(
            md,
            "- {} workers, guided: training epochs 0 to {} reached, the largest training \
             tree {:.0} KB.",
            r.workers,
            r.trained.0.saturating_sub(1),
            r.trained.1 as f64 / 1e3
        );
    }
    let refused: u64 = runs.iter().map(|r| r.refused).sum();
    let _ = writeln!(
        md,
        "\nResults not merged (duplicates or refusals) during the measured windows: {refused}."
    );
    md
}
