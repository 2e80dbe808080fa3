//! Configured values against their domains: [`OutOfDomain`] names the key, its domain
//! and the value found; [`check_range`] and [`check_real`] make one.

/// A configured value outside its domain: `{key} must be {domain}, got {value}`.
///
/// Every key of a configuration section has a domain; [`OutOfDomain::within`] prefixes
/// the section, so the error names the key as the file spells it
/// (`estimator.window.size must be in 1..=300, got 1000000000`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key} must be {domain}, got {value}")]
pub struct OutOfDomain {
    /// The key (`size`, or with its section `estimator.window.size`).
    pub key: String,
    /// The domain in words (`in 1..=300`, `finite and > 0`).
    pub domain: String,
    /// The value found.
    pub value: String,
}

impl OutOfDomain {
    /// `key` outside `domain`, holding `value`.
    pub fn new(key: &str, domain: impl Into<String>, value: impl std::fmt::Display) -> Self {
        Self {
            key: key.to_string(),
            domain: domain.into(),
            value: value.to_string(),
        }
    }

    /// The same error with the key inside `section` (`estimator.window`).
    pub fn within(mut self, section: &str) -> Self {
        self.key = format!("{section}.{}", self.key);
        self
    }
}

/// Checks that an integer `value` of `key` lies in `lo..=hi`.
pub fn check_range<T: PartialOrd + std::fmt::Display>(
    key: &str,
    value: T,
    lo: T,
    hi: T,
) -> Result<(), OutOfDomain> {
    if value < lo || value > hi {
        return Err(OutOfDomain::new(key, format!("in {lo}..={hi}"), value));
    }
    Ok(())
}

/// Checks that a real `value` of `key` is finite and lies in `[lo, hi]` (or `(lo, hi]`
/// when `open_below`).
pub fn check_real(
    key: &str,
    value: f64,
    lo: f64,
    hi: f64,
    open_below: bool,
) -> Result<(), OutOfDomain> {
    let above = if open_below { value > lo } else { value >= lo };
    if !(value.is_finite() && above && value <= hi) {
        let bracket = if open_below { '(' } else { '[' };
        return Err(OutOfDomain::new(
            key,
            format!("finite, in {bracket}{lo}, {hi}]"),
            value,
        ));
    }
    Ok(())
}
