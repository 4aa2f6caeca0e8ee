//! Machine-readable sidecars of the checked-in reports, so a report cannot silently go stale.
//!
//! A report written with `--out X.md` also writes `X.json`: the command that regenerates it,
//! its headline numbers (`summary`), a hash of the markdown written with it, and the
//! per-run records of its first seeds (`check`). `hal-sim/tests/report_sidecars.rs` re-runs
//! those seeds with the current code and compares them record by record, and checks the
//! markdown against the hash: a change that moves a report's numbers without regenerating
//! it, or a report edited by hand, fails with the command to run.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Seeds per case whose runs are stored for the staleness check (kept small: the test
/// re-runs them in a debug build).
pub const CHECK_SEEDS: u64 = 2;

/// A report's sidecar (`X.json` beside `X.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    /// The `hal-sim` subcommand that writes the report.
    pub report: String,
    /// The full command that regenerates the report and this sidecar.
    pub command: String,
    /// First seed of the report's runs.
    pub first_seed: u64,
    /// Runs per case.
    pub tries: u64,
    /// FNV-1a 64 of the markdown written together with this sidecar, hex.
    pub markdown_fnv64: String,
    /// The report's headline numbers (report-specific keys).
    pub summary: serde_json::Value,
    /// Per-run records of the first seeds, as the report's runner produced them.
    pub check: Vec<serde_json::Value>,
}

impl Sidecar {
    /// A sidecar for `report` run by `command`; the markdown hash is set by [`write`].
    pub fn new(
        report: &str,
        command: &str,
        first_seed: u64,
        tries: u64,
        summary: serde_json::Value,
        check: Vec<serde_json::Value>,
    ) -> Self {
        Self {
            report: report.into(),
            command: command.into(),
            first_seed,
            tries,
            markdown_fnv64: String::new(),
            summary,
            check,
        }
    }
}

/// The seed stored at `pointer` (a JSON pointer, e.g. `/seed`) of a check record.
pub fn seed_of(record: &serde_json::Value, pointer: &str) -> anyhow::Result<u64> {
    record
        .pointer(pointer)
        .and_then(serde_json::Value::as_u64)
        .ok_or_else(|| anyhow::anyhow!("record without a seed at {pointer}"))
}

/// The value stored at `pointer` of a check record (a case, a layout, a preset).
pub fn field<T: serde::de::DeserializeOwned>(
    record: &serde_json::Value,
    pointer: &str,
) -> anyhow::Result<T> {
    let v = record
        .pointer(pointer)
        .ok_or_else(|| anyhow::anyhow!("record without {pointer}"))?;
    Ok(serde_json::from_value(v.clone())?)
}

/// The `--first-seed` part of a report's command: empty for the default seed 1.
pub fn first_seed_flag(first_seed: u64) -> String {
    if first_seed == 1 {
        String::new()
    } else {
        format!(" --first-seed {first_seed}")
    }
}

/// The check records of `runs` (see [`record`]).
pub fn records<'a, T: Serialize + 'a>(
    runs: impl IntoIterator<Item = &'a T>,
    volatile: &[&str],
) -> anyhow::Result<Vec<serde_json::Value>> {
    runs.into_iter().map(|r| record(r, volatile)).collect()
}

/// FNV-1a, 64 bits: a stable content hash (std's hasher is not stable across releases).
pub fn fnv64(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// The sidecar path of a report: `X.md` → `X.json`.
pub fn path_for(markdown: &Path) -> PathBuf {
    markdown.with_extension("json")
}

/// A serializable record as JSON with the named keys removed (e.g. host timings, which
/// depend on the machine and its load, not on the code).
pub fn record<T: Serialize>(value: &T, volatile: &[&str]) -> anyhow::Result<serde_json::Value> {
    let mut v = serde_json::to_value(value)?;
    strip(&mut v, volatile);
    Ok(v)
}

fn strip(v: &mut serde_json::Value, keys: &[&str]) {
    match v {
        serde_json::Value::Object(map) => {
            for k in keys {
                map.remove(*k);
            }
            for child in map.values_mut() {
                strip(child, keys);
            }
        }
        serde_json::Value::Array(items) => {
            for child in items {
                strip(child, keys);
            }
        }
        _ => {}
    }
}

/// Writes the markdown and its sidecar (the hash is taken of exactly what is written; the
/// command gets the `--out` path when it lacks one).
pub fn write(markdown_path: &Path, markdown: &str, mut sidecar: Sidecar) -> anyhow::Result<()> {
    use anyhow::Context as _;
    sidecar.markdown_fnv64 = fnv64(markdown.as_bytes());
    if !sidecar.command.contains("--out") {
        sidecar.command = format!("{} --out {}", sidecar.command, markdown_path.display());
    }
    std::fs::write(markdown_path, markdown)
        .with_context(|| format!("writing {}", markdown_path.display()))?;
    let json_path = path_for(markdown_path);
    let mut json = serde_json::to_string_pretty(&sidecar)?;
    json.push('\n');
    std::fs::write(&json_path, json).with_context(|| format!("writing {}", json_path.display()))
}

/// Reads a sidecar.
pub fn read(path: &Path) -> anyhow::Result<Sidecar> {
    use anyhow::Context as _;
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv64_matches_the_reference_vectors() {
        // Published FNV-1a 64 test vectors.
        assert_eq!(fnv64(b""), "cbf29ce484222325");
        assert_eq!(fnv64(b"a"), "af63dc4c8601ec8c");
        assert_eq!(fnv64(b"foobar"), "85944171f73967e8");
    }

    #[test]
    fn volatile_keys_are_removed_at_every_depth() {
        let v = serde_json::json!({"a": 1, "host_us": 5, "inner": [{"host_us": 2, "b": 3}]});
        let r = record(&v, &["host_us"]).unwrap();
        assert_eq!(r, serde_json::json!({"a": 1, "inner": [{"b": 3}]}));
    }

    #[test]
    fn a_sidecar_round_trips_beside_its_markdown() {
        let dir = std::env::temp_dir().join(format!("sidecar-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let md = dir.join("r.md");
        let s = Sidecar {
            report: "x".into(),
            command: "hal-sim x".into(),
            first_seed: 1,
            tries: 3,
            markdown_fnv64: String::new(),
            summary: serde_json::json!({"median_m": 0.1}),
            check: vec![serde_json::json!({"seed": 1, "error": 0.123_456_789_012_345_6})],
        };
        write(&md, "# report\n", s.clone()).unwrap();
        let back = read(&path_for(&md)).unwrap();
        assert_eq!(back.markdown_fnv64, fnv64(b"# report\n"));
        assert_eq!(back.check, s.check, "floats must round-trip exactly");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
