//! Wall-clock timings as reports print them: milliseconds in an `f64`.

use std::time::Instant;

/// Milliseconds elapsed since `t` (wall clock, fractional: microsecond resolution and better).
/// The one conversion every report's `*_ms` field goes through.
pub fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
