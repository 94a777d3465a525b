//! Ranges of user-given numeric parameters, defined once beside each parameter struct and used by
//! every front end (scenario TOML, CLI flags, `[lab]`, Python): a value is finite and inside its
//! physical range, or the load fails with the key and the allowed range.
//!
//! ```
//! use smlworld::sim::params::{Range, check_all};
//! assert!(check_all([("speed", 10.0, Range::non_negative(1e3))]).is_ok());
//! let e = check_all([("speed", f64::NAN, Range::non_negative(1e3))]).unwrap_err();
//! assert_eq!(e.key, "speed");
//! ```

/// A parameter outside its range: the key (relative to the struct) and what is allowed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{key}` {problem}")]
pub struct ParamError {
    /// The key, e.g. `max_deceleration` or `acc.time_gap`.
    pub key: String,
    /// What was wrong and what is allowed.
    pub problem: String,
}

impl ParamError {
    /// The same error with its key under `prefix` (`acc` + `time_gap` -> `acc.time_gap`).
    pub fn within(self, prefix: &str) -> ParamError {
        ParamError { key: format!("{prefix}.{}", self.key), problem: self.problem }
    }
}

impl From<ParamError> for (String, String) {
    fn from(e: ParamError) -> (String, String) {
        (e.key, e.problem)
    }
}

/// The allowed values of one parameter: finite, `min` (exclusive when `min_exclusive`) to `max`
/// inclusive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    /// Smallest value.
    pub min: f64,
    /// Whether `min` itself is excluded (a strictly positive quantity).
    pub min_exclusive: bool,
    /// Largest value.
    pub max: f64,
}

impl Range {
    /// Strictly positive, at most `max`.
    pub const fn positive(max: f64) -> Range {
        Range { min: 0.0, min_exclusive: true, max }
    }

    /// Zero or more, at most `max`.
    pub const fn non_negative(max: f64) -> Range {
        Range { min: 0.0, min_exclusive: false, max }
    }

    /// From `min` to `max`, both included.
    pub const fn between(min: f64, max: f64) -> Range {
        Range { min, min_exclusive: false, max }
    }

    /// Whether `v` is allowed.
    pub fn contains(&self, v: f64) -> bool {
        v.is_finite() && v <= self.max && if self.min_exclusive { v > self.min } else { v >= self.min }
    }

    /// `Ok` when `v` is allowed, else the error naming `key` and this range.
    pub fn check(&self, key: &str, v: f64) -> Result<(), ParamError> {
        if self.contains(v) {
            return Ok(());
        }
        let (min, max) = (self.min, self.max);
        let want = match (self.min_exclusive, min == 0.0) {
            (true, true) => format!("a positive number, at most {max}"),
            (false, true) => format!("zero or more, at most {max}"),
            (true, false) => format!("a number in ({min}, {max}]"),
            (false, false) => format!("a number in [{min}, {max}]"),
        };
        Err(ParamError { key: key.to_string(), problem: format!("must be {want}, got {v}") })
    }
}

/// Check every `(key, value, range)`; the first value outside its range is the error.
pub fn check_all<'a>(checks: impl IntoIterator<Item = (&'a str, f64, Range)>) -> Result<(), ParamError> {
    checks.into_iter().try_for_each(|(key, v, range)| range.check(key, v))
}

/// `min <= max` for two parameters already checked one by one.
pub fn check_order(min_key: &str, min: f64, max_key: &str, max: f64) -> Result<(), ParamError> {
    if min <= max {
        Ok(())
    } else {
        Err(ParamError {
            key: max_key.to_string(),
            problem: format!("must be at least `{min_key}` ({min}), got {max}"),
        })
    }
}

/// Largest speed a user may ask for [m/s] (well above any road vehicle).
pub const MAX_SPEED: f64 = 1e3;
/// Largest acceleration or deceleration a user may ask for [m/s²].
pub const MAX_ACCEL: f64 = 1e3;
/// Largest controller gain a user may give (any unit).
pub const MAX_GAIN: f64 = 1e6;
/// Largest time constant (time gap, timeout, hold) a user may give \[s\]: one day.
pub const MAX_TIME: f64 = 86_400.0;
/// Largest distance or position coordinate a user may give \[m\] (a UTM zone is ~1e6 m wide).
pub const MAX_DISTANCE: f64 = 1e7;
/// Largest vehicle dimension (length, width, wheelbase) \[m\].
pub const MAX_VEHICLE_SIZE: f64 = 100.0;

/// Why a registered plugin's parameters (a controller's, a sensor's or a channel model's table
/// in a scenario) were refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControllerParamError {
    /// The key (relative to the plugin's table), empty when the table as a whole is wrong.
    pub key: String,
    /// What is wrong and what is allowed.
    pub problem: String,
}

/// A plugin's parameter table deserialised into `T` (unknown keys refused when `T` denies them)
/// and checked by `check` (`Err((key, problem))`): the one parse every plugin registry uses.
pub fn parse_plugin_params<T: serde::de::DeserializeOwned>(
    params: toml::Table,
    check: impl FnOnce(&T) -> Result<(), (String, String)>,
) -> Result<T, ControllerParamError> {
    let value: T = toml::Value::Table(params)
        .try_into()
        .map_err(|e: toml::de::Error| ControllerParamError { key: String::new(), problem: e.message().to_string() })?;
    check(&value).map_err(|(key, problem)| ControllerParamError { key, problem })?;
    Ok(value)
}
