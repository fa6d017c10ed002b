//! The user's error budget: how well a scene must be modelled, in the
//! user's terms (docs/PLANNING.md defines each error: its reference and its
//! statistic). On the command line
//! `--budget horizon=DEG[,svf=X][,shade=FRACTION][,time=SECONDS][,bytes=SIZE][,memory=MIB]`.
//! It deserialises from a TOML table with the same keys (unknown keys
//! refused), for recipes; recipes do not hold a budget yet.
//!
//! - `horizon`: the 99th percentile, over posts and azimuths, of the
//!   absolute horizon angle error in degrees, at *any* azimuth: what the
//!   loader serves between stored bands (linear interpolation) counts.
//! - `svf`: the 99th percentile over posts of the absolute sky-view factor
//!   error.
//! - `shade`: the share of posts whose sun/shade state may be wrong.
//! - `time`, `bytes`, `memory`: limits on the bake's wall seconds, the
//!   asset's bytes on disk and the peak memory in MiB.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Degrees: the 99th percentile of the absolute horizon angle error.
    pub horizon: f64,
    /// The 99th percentile of the absolute sky-view factor error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub svf: Option<f64>,
    /// The share of posts whose sun/shade state may be wrong.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shade: Option<f64>,
    /// Wall seconds of the bake.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time: Option<f64>,
    /// Bytes of the asset on disk.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bytes: Option<u64>,
    /// Peak memory of the bake, MiB.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub memory: Option<u64>,
}

impl Budget {
    /// Every limit positive and finite, the share at most 1: the message
    /// names the key and the value.
    pub fn validate(&self) -> Result<(), String> {
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("budget {key}={v}: give a positive number"))
            }
        };
        positive("horizon", self.horizon)?;
        if self.horizon >= 90.0 {
            return Err(format!(
                "budget horizon={}: an error of 90 degrees or more bounds nothing; give degrees below 90",
                self.horizon
            ));
        }
        if let Some(v) = self.svf {
            positive("svf", v)?;
        }
        if let Some(v) = self.shade {
            positive("shade", v)?;
            if v > 1.0 {
                return Err(format!("budget shade={v}: a share of posts is at most 1"));
            }
        }
        if let Some(v) = self.time {
            positive("time", v)?;
        }
        for (key, v) in [("bytes", self.bytes), ("memory", self.memory)] {
            if v == Some(0) {
                return Err(format!("budget {key}=0: give a positive size"));
            }
        }
        Ok(())
    }
}

/// `200M`, `1.5G`, `4096`, `2KiB`: bytes (K, M, G, T are powers of 1024).
fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let digits = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(digits);
    let number: f64 = number
        .parse()
        .map_err(|_| format!("{s:?}: expected a size such as 4096, 200M or 1.5G"))?;
    let scale = match unit
        .trim()
        .to_ascii_uppercase()
        .trim_end_matches("IB")
        .trim_end_matches('B')
    {
        "" => 1u64,
        "K" => 1 << 10,
        "M" => 1 << 20,
        "G" => 1 << 30,
        "T" => 1 << 40,
        _ => return Err(format!("{s:?}: unknown unit {unit:?} (use K, M, G or T)")),
    };
    Ok((number * scale as f64).round() as u64)
}

impl FromStr for Budget {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let mut budget = Budget::default();
        let mut horizon = None;
        for item in s.split(',').map(str::trim).filter(|i| !i.is_empty()) {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| format!("{item:?}: expected KEY=VALUE (horizon=DEG,svf=X,...)"))?;
            let number = || {
                value
                    .trim()
                    .parse::<f64>()
                    .map_err(|_| format!("{key}={value}: expected a number"))
            };
            match key.trim() {
                "horizon" => horizon = Some(number()?),
                "svf" => budget.svf = Some(number()?),
                "shade" => budget.shade = Some(number()?),
                "time" => budget.time = Some(number()?),
                "bytes" => budget.bytes = Some(parse_size(value)?),
                "memory" => {
                    budget.memory = Some(
                        value
                            .trim()
                            .parse()
                            .map_err(|_| format!("memory={value}: expected whole MiB"))?,
                    )
                }
                other => {
                    return Err(format!(
                        "{other:?}: not a budget key (horizon, svf, shade, time, bytes, memory)"
                    ))
                }
            }
        }
        budget.horizon = horizon.ok_or("a budget needs horizon=DEGREES")?;
        budget.validate()?;
        Ok(budget)
    }
}

impl fmt::Display for Budget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "horizon={}", self.horizon)?;
        if let Some(v) = self.svf {
            write!(f, ",svf={v}")?;
        }
        if let Some(v) = self.shade {
            write!(f, ",shade={v}")?;
        }
        if let Some(v) = self.time {
            write!(f, ",time={v}")?;
        }
        if let Some(v) = self.bytes {
            write!(f, ",bytes={v}")?;
        }
        if let Some(v) = self.memory {
            write!(f, ",memory={v}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_documented_syntax_parses_and_prints_back() {
        let b: Budget = "horizon=0.5,svf=0.01,shade=0.001,time=60,bytes=200M,memory=512"
            .parse()
            .unwrap();
        assert_eq!(
            b,
            Budget {
                horizon: 0.5,
                svf: Some(0.01),
                shade: Some(0.001),
                time: Some(60.0),
                bytes: Some(200 << 20),
                memory: Some(512),
            }
        );
        assert_eq!(b.to_string().parse::<Budget>().unwrap(), b);
        assert_eq!(parse_size("1.5G").unwrap(), 3 << 29);
        assert_eq!(parse_size("2KiB").unwrap(), 2048);
        let toml: Budget = toml::from_str("horizon = 1.0\nsvf = 0.02").unwrap();
        assert_eq!((toml.horizon, toml.svf), (1.0, Some(0.02)));
        assert!(toml::from_str::<Budget>("horizon = 1.0\nsfv = 0.02").is_err());
    }

    #[test]
    fn bad_budgets_name_the_key() {
        for (text, says) in [
            ("svf=0.01", "needs horizon"),
            ("horizon=-1", "horizon=-1"),
            ("horizon=nan", "horizon=NaN"),
            ("horizon=95", "below 90"),
            ("horizon=1,shade=2", "shade=2"),
            ("horizon=1,bytes=12Q", "unknown unit"),
            ("horizon=1,colour=3", "not a budget key"),
            ("horizon", "KEY=VALUE"),
        ] {
            let err = text.parse::<Budget>().unwrap_err();
            assert!(err.contains(says), "{text}: {err}");
        }
    }
}
