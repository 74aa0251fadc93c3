//! How much memory this worker may use, as it tells the coordinator (jobs can require a
//! least memory: `submit --min-memory 16G`).
//!
//! In a container the machine's memory is not what the worker may use: a pod limited to 8 GiB
//! on a 256 GiB node is killed at 8. So the answer is the smaller of the machine's total and
//! the control group's limit (cgroup v2 `memory.max`, or v1 `memory.limit_in_bytes`).

/// Bytes this process may use; 0 when nothing says (the worker then meets no memory minimum,
/// and `tessera worker --memory` can say it).
pub fn available() -> u64 {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| mem_total(&s));
    let limit = [
        "/sys/fs/cgroup/memory.max",
        "/sys/fs/cgroup/memory/memory.limit_in_bytes",
    ]
    .iter()
    .find_map(|p| cgroup_limit(&std::fs::read_to_string(p).ok()?));
    match (total, limit) {
        (Some(t), Some(l)) => t.min(l),
        (Some(x), None) | (None, Some(x)) => x,
        (None, None) => 0,
    }
}

/// `MemTotal` of /proc/meminfo, in bytes.
fn mem_total(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// A cgroup memory limit file's value; `None` for "max", and for cgroup v1's "no limit"
/// (a huge page-rounded number).
fn cgroup_limit(text: &str) -> Option<u64> {
    let v: u64 = text.trim().parse().ok()?;
    (v < 1 << 60).then_some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_machine_total_and_the_cgroup_limit_are_read() {
        let info = "MemTotal:       24563844 kB\nMemFree:         1000 kB\n";
        assert_eq!(mem_total(info), Some(24_563_844 * 1024));
        assert_eq!(mem_total("MemFree: 1 kB\n"), None);
        assert_eq!(cgroup_limit("max\n"), None);
        assert_eq!(cgroup_limit("8589934592\n"), Some(8 << 30));
        assert_eq!(cgroup_limit("9223372036854771712\n"), None);
        assert!(available() > 0, "this machine has /proc/meminfo");
    }
}
