//! One range check for every numeric flag of the command line and of the library's clap
//! argument groups such as [`crate::render::FrameOutput`] (issue 24 item 4): clap runs these parsers, so NaN,
//! infinities, negative and huge values are refused before any work starts, with the flag named
//! (`error: invalid value 'nan' for '--speed <SPEED>': must be a finite number above 0 and at
//! most 1e9`) and exit code 2.

use clap::builder::RangedU64ValueParser;
use glam::DVec2;

/// Largest value a real-valued flag takes (seconds, metres, hertz, pixels per metre ...).
pub const HUGE: f64 = 1e9;
/// Largest vehicle count of `bench`.
pub const MAX_VEHICLES: u64 = 10_000_000;
/// Most threads of `--threads`.
pub const MAX_THREADS: u64 = 1024;
/// Image sides \[px\] (the renderer's texture limit).
pub const MIN_PIXELS: u64 = 16;
/// See [`MIN_PIXELS`].
pub const MAX_PIXELS: u64 = 8192;

fn number(s: &str) -> Result<f64, String> {
    s.trim().parse::<f64>().map_err(|_| format!("`{s}` is not a number"))
}

fn within(v: f64, ok: bool, what: &str) -> Result<f64, String> {
    if ok { Ok(v) } else { Err(format!("must be {what}")) }
}

/// A finite number in (0, [`HUGE`]].
pub fn positive(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    within(v, v.is_finite() && v > 0.0 && v <= HUGE, "a finite number above 0 and at most 1e9")
}

/// A finite number in [0, [`HUGE`]].
pub fn non_negative(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    within(v, v.is_finite() && (0.0..=HUGE).contains(&v), "a finite number from 0 to 1e9")
}

/// A point `X,Y` \[m\] (`--center`): each coordinate finite and within [-[`HUGE`], [`HUGE`]].
pub fn point(s: &str) -> Result<DVec2, String> {
    let (x, y) = s.split_once(',').ok_or_else(|| format!("`{s}` is not a point: write X,Y in metres, e.g. 12.5,-3"))?;
    let coordinate = |c: &str| {
        let v = number(c)?;
        within(v, v.is_finite() && v.abs() <= HUGE, "X,Y with each coordinate a finite number from -1e9 to 1e9")
    };
    Ok(DVec2::new(coordinate(x)?, coordinate(y)?))
}

/// A rate in (0, 10,000] Hz.
pub fn rate_hz(s: &str) -> Result<f64, String> {
    let v = number(s)?;
    within(v, v.is_finite() && v > 0.0 && v <= 10_000.0, "a rate above 0 and at most 10000 Hz")
}

/// A count in `min..=max`, for `usize` or `u32` flags.
pub fn count<T: TryFrom<u64> + Clone + Send + Sync + 'static>(min: u64, max: u64) -> RangedU64ValueParser<T> {
    RangedU64ValueParser::<T>::new().range(min..=max)
}

/// `--threads`: 1 to [`MAX_THREADS`].
pub fn threads() -> RangedU64ValueParser<usize> {
    count(1, MAX_THREADS)
}

/// `--width`/`--height`: [`MIN_PIXELS`] to [`MAX_PIXELS`].
pub fn pixels() -> RangedU64ValueParser<u32> {
    count(MIN_PIXELS, MAX_PIXELS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_numbers_are_refused() {
        for bad in ["nan", "NaN", "inf", "-inf", "-1", "0", "1e10", "x", ""] {
            assert!(positive(bad).is_err(), "{bad}");
        }
        assert_eq!(positive(" 2.5 "), Ok(2.5));
        assert_eq!(non_negative("0"), Ok(0.0));
        assert!(non_negative("-0.1").is_err());
        assert!(rate_hz("20000").is_err());
        assert_eq!(rate_hz("100"), Ok(100.0));
        for bad in ["nan,0", "0,inf", "1e300,0", "0,-1e10", "1", "1,2,3", "x,1", ""] {
            assert!(point(bad).is_err(), "{bad}");
        }
        assert_eq!(point(" -12.5, 3 "), Ok(DVec2::new(-12.5, 3.0)));
    }
}
