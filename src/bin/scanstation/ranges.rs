//! Parsers for numeric arguments: every number the CLI takes has a documented range (shown in `--help`),
//! and a value outside it is a usage error (exit 2) before any work starts.

use std::fmt::Display;
use std::str::FromStr;

/// Parse `s` as a `T` within `[lo, hi]` (finite for floats).
pub fn within<T: FromStr + PartialOrd + Display + Copy>(s: &str, lo: T, hi: T) -> Result<T, String> {
    let v: T = s.trim().parse().map_err(|_| format!("{s:?} is not a number"))?;
    // NaN fails both comparisons, so it is out of every range.
    if v >= lo && v <= hi { Ok(v) } else { Err(format!("{v} is outside the range [{lo}, {hi}]")) }
}

/// A byte size (`512M`, `4G`, `1048576`) within `[lo, hi]` bytes.
pub fn bytes_within(s: &str, lo: u64, hi: u64) -> Result<u64, String> {
    let t = s.trim();
    let (num, mult) = match t.chars().last().map(|c| c.to_ascii_uppercase()) {
        Some('K') => (&t[..t.len() - 1], 1u64 << 10),
        Some('M') => (&t[..t.len() - 1], 1 << 20),
        Some('G') => (&t[..t.len() - 1], 1 << 30),
        Some('T') => (&t[..t.len() - 1], 1 << 40),
        _ => (t, 1),
    };
    let v = num.parse::<u64>().ok().and_then(|n| n.checked_mul(mult)).ok_or_else(|| format!("not a size: {s:?}"))?;
    if (lo..=hi).contains(&v) { Ok(v) } else { Err(format!("{v} bytes is outside the range [{lo}, {hi}] bytes")) }
}

/// `--memory-budget`: 16 MiB to 1 TiB.
pub fn memory_budget(s: &str) -> Result<u64, String> {
    bytes_within(s, 16 << 20, 1 << 40)
}

/// `--max-input-size`: 1 KiB to 1 TiB.
pub fn input_size(s: &str) -> Result<u64, String> {
    bytes_within(s, 1 << 10, 1 << 40)
}

/// One parser per range: `name: type = low, high` with its doc line.
macro_rules! ranged {
    ($($(#[$doc:meta])* $name:ident: $t:ty = $lo:expr, $hi:expr;)*) => {
        $($(#[$doc])* pub fn $name(s: &str) -> Result<$t, String> { within(s, $lo, $hi) })*
    };
}

ranged! {
    /// Control or output vertex counts (`--vertices`, `--target-vertices`): 16 to 10 million.
    vertices: usize = 16usize, 10_000_000;
    /// `submit --vertices`: as [`vertices`], for the D-Bus `u` type.
    #[allow(dead_code)] // only the daemon client uses it
    vertices_u32: u32 = 16u32, 10_000_000;
    /// Grid nodes along the longest side of `reconstruct`: 8 to 1024.
    grid_resolution: usize = 8usize, 1024;
    /// A share or fraction: 0 to 1.
    share: f64 = 0.0, 1.0;
    /// A percentage bound of a gate: above 0 (1e-6) to 100.
    gate_pct: f64 = 1e-6, 100.0;
    /// A percentage that may be 0: 0 to 100.
    pct: f64 = 0.0, 100.0;
    /// Iteration and round counts: 0 to 1000.
    rounds: usize = 0usize, 1000;
    /// Gauss–Seidel sweeps per level: 1 to 1000.
    sweeps: usize = 1usize, 1000;
    /// Dipole transport depth: 0 to 16.
    depth: usize = 0usize, 16;
    /// Working vertices per output vertex: 1 to 64.
    per_vertex: f64 = 1.0, 64.0;
    /// Field weights: 0 to 100.
    weight: f64 = 0.0, 100.0;
    /// A length in the input's units: positive and finite (1e-12 to 1e12).
    length: f64 = 1e-12, 1e12;
    /// Samples per side of `compare`: 100 to 100 million.
    samples: usize = 100usize, 100_000_000;
}

/// An up axis: x, y or z.
pub fn up_axis(s: &str) -> Result<scanstation::pipeline::pictures::Up, String> {
    scanstation::pipeline::pictures::Up::parse(s).ok_or_else(|| format!("{s:?} is not an axis: use x, y or z"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_refuse_what_lies_outside() {
        assert_eq!(vertices("10000"), Ok(10_000));
        assert!(vertices("15").is_err());
        assert!(vertices("18446744073709551615").is_err());
        assert!(samples("18446744073709551615").is_err());
        assert!(share("NaN").is_err());
        assert!(share("inf").is_err());
        assert!(gate_pct("0").is_err());
        assert!(length("-1").is_err());
        assert_eq!(memory_budget("1G"), Ok(1 << 30));
        assert!(memory_budget("1K").is_err());
        assert!(memory_budget("99999999999G").is_err());
        assert!(within("abc", 0u64, 1).is_err());
    }
}
