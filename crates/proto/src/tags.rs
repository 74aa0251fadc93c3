//! Worker tags and job requirements: what a worker says it is (`tessera worker --tag
//! pool=fast --tag big-mem`, plus the CPU features it detected) and what a job needs
//! (`submit --require big-mem`). One syntax and one matching rule for the worker, the
//! coordinator and the CLI, so that what a flag accepts is what the wire accepts.
//!
//! A tag is `NAME` or `NAME=VALUE`. A requirement `NAME` is met by a tag `NAME` or any
//! `NAME=VALUE` (a job that needs "some pool" says `--require pool`); `NAME=VALUE` only by that
//! tag; and `cpu:FEATURE` by a CPU feature the worker reported, so that a job built around
//! AVX-512 can say `--require cpu:avx512f` without operators tagging every machine.

/// Most tags one worker may advertise: enough for any real pool layout, few enough that a
/// hostile registration cannot make every lease decision expensive.
pub const MAX_TAGS: usize = 32;

/// Most requirements one job may carry.
pub const MAX_REQUIREMENTS: usize = 16;

/// Most CPU features one worker may report.
pub const MAX_CPU_FEATURES: usize = 64;

/// Longest tag, requirement or CPU feature, in bytes.
pub const MAX_TAG_LEN: usize = 64;

/// The prefix that makes a requirement name a CPU feature rather than an operator tag.
pub const CPU_PREFIX: &str = "cpu:";

fn name_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-' | ':')
}

/// Checks one tag (or requirement, which has the same form); the error says what is wrong
/// with it, for the caller to prefix with where it came from.
pub fn check_tag(tag: &str) -> Result<(), String> {
    if tag.len() > MAX_TAG_LEN {
        return Err(format!(
            "tag {:?}… is longer than {MAX_TAG_LEN} bytes",
            tag.chars().take(16).collect::<String>()
        ));
    }
    let (name, value) = match tag.split_once('=') {
        Some((n, v)) => (n, Some(v)),
        None => (tag, None),
    };
    if name.is_empty() {
        return Err(format!("tag {tag:?} has no name before '='"));
    }
    if let Some(c) = name.chars().find(|c| !name_char(*c)) {
        return Err(format!(
            "tag {:?} has {c:?} in its name (use letters, digits, '.', '_', ':' and '-')",
            tag.escape_debug().to_string()
        ));
    }
    if let Some(v) = value {
        if v.is_empty() {
            return Err(format!("tag {tag:?} has an empty value after '='"));
        }
        if let Some(c) = v.chars().find(|c| !(name_char(*c) || *c == '/')) {
            return Err(format!(
                "tag {:?} has {c:?} in its value (use letters, digits, '.', '_', ':', '-' and '/')",
                tag.escape_debug().to_string()
            ));
        }
    }
    Ok(())
}

/// Checks a list of tags (`what`: "tag", "requirement" or "CPU feature", for the message)
/// against a count limit; duplicates are refused, as they are surely a typo.
pub fn check_tags(what: &str, tags: &[String], max: usize) -> Result<(), String> {
    if tags.len() > max {
        return Err(format!("{} {what}s given; at most {max}", tags.len()));
    }
    for (i, t) in tags.iter().enumerate() {
        check_tag(t).map_err(|e| format!("{what} {}: {e}", i + 1))?;
        if tags[..i].contains(t) {
            return Err(format!("{what} {t:?} is given twice"));
        }
    }
    Ok(())
}

/// Whether a worker with `tags` and `cpu_features` meets requirement `req`.
pub fn meets(req: &str, tags: &[String], cpu_features: &[String]) -> bool {
    if let Some(feature) = req.strip_prefix(CPU_PREFIX) {
        return cpu_features.iter().any(|f| f == feature);
    }
    if req.contains('=') {
        return tags.iter().any(|t| t == req);
    }
    tags.iter()
        .any(|t| t == req || t.split_once('=').is_some_and(|(n, _)| n == req))
}

/// `bytes` as people read a memory size: whole GiB where it is a whole number of them, else
/// to a tenth.
pub fn memory_words(bytes: u64) -> String {
    const GIB: u64 = 1 << 30;
    if bytes.is_multiple_of(GIB) {
        format!("{} GiB", bytes / GIB)
    } else {
        format!("{:.1} GiB", bytes as f64 / GIB as f64)
    }
}

/// The CPU features this machine has, of those that matter to a renderer's speed, as
/// `cpu:FEATURE` requirements name them.
pub fn cpu_features() -> Vec<String> {
    #[allow(unused_mut)]
    let mut out: Vec<&str> = Vec::new();
    #[cfg(target_arch = "x86_64")]
    {
        macro_rules! probe {
            ($($f:tt),*) => {$(
                if std::arch::is_x86_feature_detected!($f) {
                    out.push($f);
                }
            )*};
        }
        probe!("sse4.2", "avx", "avx2", "fma", "bmi2", "avx512f", "avx512vl");
    }
    #[cfg(target_arch = "aarch64")]
    {
        out.push("neon");
        if std::arch::is_aarch64_feature_detected!("sve") {
            out.push("sve");
        }
    }
    out.into_iter().map(String::from).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(s: &[&str]) -> Vec<String> {
        s.iter().map(|x| x.to_string()).collect()
    }

    #[test]
    fn a_bare_requirement_matches_the_name_with_any_value_and_a_pair_only_itself() {
        let tags = v(&["pool=fast", "big-mem"]);
        let cpu = v(&["avx2"]);
        assert!(meets("big-mem", &tags, &cpu));
        assert!(meets("pool", &tags, &cpu));
        assert!(meets("pool=fast", &tags, &cpu));
        assert!(!meets("pool=slow", &tags, &cpu));
        assert!(!meets("big-mem=yes", &tags, &cpu));
        assert!(!meets("gpu", &tags, &cpu));
        assert!(meets("cpu:avx2", &tags, &cpu));
        assert!(!meets("cpu:avx512f", &tags, &cpu));
        // A CPU feature is not an operator tag, nor the other way round.
        assert!(!meets("avx2", &tags, &cpu));
        assert!(!meets("cpu:big-mem", &tags, &cpu));
    }

    #[test]
    fn malformed_tags_are_refused_with_what_is_wrong() {
        for ok in [
            "big-mem",
            "pool=fast",
            "cpu:avx2",
            "site=eu/paris",
            "a.b_c-d",
        ] {
            check_tag(ok).unwrap_or_else(|e| panic!("{ok}: {e}"));
        }
        let cases = [
            ("", "no name"),
            ("=x", "no name"),
            ("pool=", "empty value"),
            ("big mem", "' ' in its name"),
            ("pool=a b", "' ' in its value"),
            ("a/b", "'/' in its name"),
            ("x\n", "'\\n' in its name"),
        ];
        for (bad, why) in cases {
            let e = check_tag(bad).expect_err(bad);
            assert!(e.contains(why), "{bad:?}: {e}");
        }
        let long = "x".repeat(MAX_TAG_LEN + 1);
        assert!(check_tag(&long)
            .expect_err("long")
            .contains("longer than 64"));
        let e = check_tags("tag", &v(&["a", "b", "a"]), 4).expect_err("twice");
        assert!(e.contains("\"a\" is given twice"), "{e}");
        let e = check_tags("requirement", &v(&["a", "b c"]), 4).expect_err("bad");
        assert!(e.starts_with("requirement 2: "), "{e}");
        let many: Vec<String> = (0..5).map(|i| format!("t{i}")).collect();
        let e = check_tags("tag", &many, 4).expect_err("many");
        assert_eq!(e, "5 tags given; at most 4");
    }

    #[test]
    fn memory_reads_in_gib() {
        assert_eq!(memory_words(16 << 30), "16 GiB");
        assert_eq!(memory_words(3 << 29), "1.5 GiB");
        assert_eq!(memory_words(0), "0 GiB");
    }

    #[test]
    fn the_features_detected_are_well_formed() {
        let f = cpu_features();
        check_tags("CPU feature", &f, MAX_CPU_FEATURES).expect("well formed");
    }
}
