//! Simulated time as an integer number of microseconds, so rates never drift.

/// A point in simulated time [µs since the start of the run].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
pub struct SimTime(pub u64);

impl SimTime {
    /// The start of every run.
    pub const ZERO: SimTime = SimTime(0);

    /// Time from seconds \[s\], rounded to the nearest microsecond; negative values give zero.
    pub fn from_secs(seconds: f64) -> SimTime {
        SimTime((seconds.max(0.0) * 1e6).round() as u64)
    }

    /// Time in seconds \[s\].
    pub fn as_secs(self) -> f64 {
        self.0 as f64 * 1e-6
    }

    /// Time in microseconds \[µs\].
    pub fn as_micros(self) -> u64 {
        self.0
    }
}

impl std::fmt::Display for SimTime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:.6} s", self.as_secs())
    }
}
