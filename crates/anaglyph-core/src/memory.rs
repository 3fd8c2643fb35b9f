//! Memory a run will need, estimated from its sizes before it allocates, against what
//! the system has: a run too large for the machine is an error naming both figures
//! instead of an abort part-way through.
//!
//! In: an operation's name and the bytes it will hold at least. Out: nothing, or an
//! [`Error::TooLarge`] with the estimate and the limit (`ANAGLYPH_MAX_MEMORY` in bytes
//! where set, else the memory the system reports available).

use crate::{Error, Result};

/// The memory a run may use, in bytes: `ANAGLYPH_MAX_MEMORY` where set to a number,
/// else `MemAvailable` of `/proc/meminfo`; None where neither is known (no check).
pub fn available_bytes() -> Option<u64> {
    if let Some(limit) = std::env::var("ANAGLYPH_MAX_MEMORY")
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok())
    {
        return Some(limit);
    }
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// Refuses `op` when the `needed` bytes (a lower bound of what it holds at once) exceed
/// [`available_bytes`].
pub fn check_fits(op: &str, needed: u64) -> Result<()> {
    match available_bytes() {
        Some(limit) if needed > limit => Err(Error::TooLarge {
            op: op.into(),
            what: format!(
                "the memory needed in bytes (at least {:.1} GiB; {:.1} GiB available, \
                 ANAGLYPH_MAX_MEMORY sets the limit)",
                gib(needed),
                gib(limit)
            ),
            size: needed,
            limit,
        }),
        _ => Ok(()),
    }
}

/// Bytes of `values` f32 values, saturating.
pub fn f32_bytes(values: u64) -> u64 {
    values.saturating_mul(4)
}

fn gib(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 30) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_larger_than_the_machine_is_refused_with_both_figures() {
        let Some(available) = available_bytes() else {
            return; // no /proc/meminfo: nothing is checked, as documented
        };
        let refused = check_fits("simulation", available.saturating_mul(2).max(1 << 40));
        let message = refused
            .as_ref()
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert_eq!(refused.err().map(|e| e.kind()), Some("TooLarge"));
        assert!(
            message.contains("GiB") && message.contains("ANAGLYPH_MAX_MEMORY"),
            "{message}"
        );
        check_fits("simulation", 1 << 20).unwrap();
    }
}
