//! The user's error budget: how well a scene must be modelled, in the
//! user's terms (docs/PLANNING.md defines each error: its reference and its
//! statistic). On the command line
//! `--budget horizon=DEG[,horizon_max=DEG][,svf=X][,svf_max=X][,shade=FRACTION][,solar=PERCENT][,total_viewshed=PERCENT][,steps=N][,rays=N][,time=SECONDS][,bytes=SIZE][,memory=MIB]`.
//! It deserialises from a TOML table with the same keys (unknown keys
//! refused), for recipes; recipes do not hold a budget yet.
//!
//! - `horizon`: the 99th percentile, over posts and azimuths, of the
//!   absolute horizon angle error in degrees, at *any* azimuth: what the
//!   loader serves between stored bands (linear interpolation) counts.
//! - `horizon_max`: the largest absolute horizon angle error, degrees, at
//!   any post and azimuth whose horizon the DEM's edge does not cut: what a
//!   percentile hides (a lone spike's shadow falls on about 1 % of the
//!   azimuths at the posts around it). The pilot and `check` add the posts
//!   around the scene's most prominent features to their samples.
//! - `svf`: the 99th percentile over posts of the absolute sky-view factor
//!   error; `svf_max` its largest.
//! - `shade`: the share of posts whose sun/shade state may be wrong.
//! - `total_viewshed`: per cent, the 99th percentile over posts of the
//!   total viewshed's relative error against 720 directions.
//! - `steps`: the mean steps a ray takes through the tracing layers, over
//!   the primary rays of the sixteen built-in views (Paglieroni and
//!   Petersen's Table 1); it counts the work, so it holds on any machine.
//! - `rays`: rays per second per thread over the same views, on the machine
//!   that plans and checks.
//! - `time`, `bytes`, `memory`: limits on the bake's wall seconds, the
//!   asset's bytes on disk and the peak memory in MiB.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::terrain::sun::SunPosition;

#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Degrees: the 99th percentile of the absolute horizon angle error.
    pub horizon: f64,
    /// Degrees: the largest absolute horizon angle error away from the
    /// DEM's edge.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub horizon_max: Option<f64>,
    /// The 99th percentile of the absolute sky-view factor error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub svf: Option<f64>,
    /// The largest absolute sky-view factor error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub svf_max: Option<f64>,
    /// The share of posts whose sun/shade state may be wrong.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shade: Option<f64>,
    /// Per cent: the 99th percentile over posts of the year's beam
    /// irradiation put in shadow or sun wrongly, of the post's beam
    /// (and so an upper bound of the error in its global irradiation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solar: Option<f64>,
    /// Per cent: the 99th percentile over posts of the total viewshed's
    /// relative error, against 720 directions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub total_viewshed: Option<f64>,
    /// The most mean steps per ray of the built-in views' primary rays.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steps: Option<f64>,
    /// The fewest rays per second per thread over the same rays.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rays: Option<f64>,
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
    /// The memory limit in bytes: what the stages may work in, and what
    /// decides whether the planner's pilot holds the DEM or spills it.
    pub fn memory_bytes(&self) -> Option<u64> {
        self.memory.map(|mib| mib << 20)
    }

    /// Every limit positive and finite, the share at most 1: the message
    /// names the key and the value.
    pub(crate) fn validate(&self) -> Result<(), String> {
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
        if let Some(v) = self.horizon_max {
            positive("horizon_max", v)?;
            if v >= 90.0 {
                return Err(format!(
                    "budget horizon_max={v}: an error of 90 degrees or more bounds nothing; give degrees below 90"
                ));
            }
            if v < self.horizon {
                return Err(format!(
                    "budget horizon_max={v} is below horizon={} (the 99th percentile): the largest error is at least the percentile; give horizon_max >= horizon",
                    self.horizon
                ));
            }
        }
        if let Some(v) = self.svf {
            positive("svf", v)?;
        }
        if let Some(v) = self.svf_max {
            positive("svf_max", v)?;
            if self.svf.is_some_and(|p| v < p) {
                return Err(format!(
                    "budget svf_max={v} is below svf={}: give svf_max >= svf",
                    self.svf.unwrap_or_default()
                ));
            }
        }
        if let Some(v) = self.shade {
            positive("shade", v)?;
            if v > 1.0 {
                return Err(format!("budget shade={v}: a share of posts is at most 1"));
            }
        }
        if let Some(v) = self.solar {
            positive("solar", v)?;
        }
        if let Some(v) = self.total_viewshed {
            positive("total_viewshed", v)?;
        }
        for (key, v) in [
            ("steps", self.steps),
            ("rays", self.rays),
            ("time", self.time),
        ] {
            if let Some(v) = v {
                positive(key, v)?;
            }
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
        let mut seen = std::collections::HashSet::new();
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
            let key = key.trim();
            if !seen.insert(key) {
                return Err(format!("{key} is given twice; give each budget key once"));
            }
            match key {
                "horizon" => horizon = Some(number()?),
                "horizon_max" => budget.horizon_max = Some(number()?),
                "svf" => budget.svf = Some(number()?),
                "svf_max" => budget.svf_max = Some(number()?),
                "shade" => budget.shade = Some(number()?),
                "solar" => budget.solar = Some(number()?),
                "total_viewshed" => budget.total_viewshed = Some(number()?),
                "steps" => budget.steps = Some(number()?),
                "rays" => budget.rays = Some(number()?),
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
                    "{other:?}: not a budget key (horizon, horizon_max, svf, svf_max, shade, solar, total_viewshed, steps, rays, time, bytes, memory)"
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
        if let Some(v) = self.horizon_max {
            write!(f, ",horizon_max={v}")?;
        }
        if let Some(v) = self.svf {
            write!(f, ",svf={v}")?;
        }
        if let Some(v) = self.svf_max {
            write!(f, ",svf_max={v}")?;
        }
        if let Some(v) = self.shade {
            write!(f, ",shade={v}")?;
        }
        if let Some(v) = self.solar {
            write!(f, ",solar={v}")?;
        }
        if let Some(v) = self.total_viewshed {
            write!(f, ",total_viewshed={v}")?;
        }
        if let Some(v) = self.steps {
            write!(f, ",steps={v}")?;
        }
        if let Some(v) = self.rays {
            write!(f, ",rays={v}")?;
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

/// One thing a scene needs baked (`--needs`, a comma list).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Need {
    /// Horizon angles at any azimuth (the `horizon` layer).
    Horizons,
    /// Sky-view factors (the `svf` layer, from the horizons).
    Svf,
    /// Sky light on slopes (`svf` and `svf_cosine`, from the horizons).
    Sky,
    /// Sun shadows for given sun positions or a day's sun path (from the
    /// horizons; the `shade` budget measures them).
    Sun,
    /// Exact ray tracing (the max/min pyramid: hierarchical tracing).
    Tracing,
    /// Fast exact ray tracing (the pyramid and the cone planes: parametric
    /// tracing, the same hits in fewer steps).
    FastTracing,
    /// The year's irradiation and sun hours (the solar stage, from the
    /// horizons and `svf_cosine`; the `solar` budget measures them).
    Solar,
    /// The area every post sees (the total viewshed stage; the
    /// `total_viewshed` budget measures it).
    TotalViewshed,
}

impl Need {
    pub const ALL: [Need; 8] = [
        Need::Horizons,
        Need::Svf,
        Need::Sky,
        Need::Sun,
        Need::Tracing,
        Need::FastTracing,
        Need::Solar,
        Need::TotalViewshed,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Need::Horizons => "horizons",
            Need::Svf => "svf",
            Need::Sky => "sky",
            Need::Sun => "sun",
            Need::Tracing => "tracing",
            Need::FastTracing => "fast_tracing",
            Need::Solar => "solar",
            Need::TotalViewshed => "total_viewshed",
        }
    }
}

/// What a scene needs: a set of [`Need`]s, in their declared order. The
/// default is horizons and sky-view factors.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Needs(Vec<Need>);

impl Needs {
    pub fn new(mut needs: Vec<Need>) -> Self {
        needs.sort_unstable();
        needs.dedup();
        Self(needs)
    }

    pub fn has(&self, need: Need) -> bool {
        self.0.contains(&need)
    }

    /// Whether anything needed is derived from horizon maps.
    pub fn horizons(&self) -> bool {
        [Need::Horizons, Need::Svf, Need::Sky, Need::Sun, Need::Solar]
            .iter()
            .any(|&n| self.has(n))
    }

    /// Whether the svf must be baked and budgeted.
    pub fn svf(&self) -> bool {
        self.has(Need::Svf) || self.has(Need::Sky)
    }
}

impl Default for Needs {
    fn default() -> Self {
        Self::new(vec![Need::Horizons, Need::Svf])
    }
}

impl FromStr for Needs {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let needs = s
            .split(',')
            .map(str::trim)
            .filter(|n| !n.is_empty())
            .map(|n| {
                let key = n.replace('-', "_");
                Need::ALL
                    .into_iter()
                    .find(|need| need.name() == key)
                    .ok_or_else(|| {
                        format!(
                            "{n:?}: not a need (horizons, svf, sky, sun, tracing, fast_tracing, solar)"
                        )
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        if needs.is_empty() {
            return Err(
                "--needs: name at least one of horizons, svf, sky, sun, tracing, fast_tracing, solar"
                    .into(),
            );
        }
        Ok(Self::new(needs))
    }
}

impl fmt::Display for Needs {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let names: Vec<&str> = self.0.iter().map(|n| n.name()).collect();
        f.write_str(&names.join(","))
    }
}

/// Sun positions on the command line: `AZ,EL;AZ,EL;...` degrees.
#[derive(Debug, Clone, PartialEq)]
pub struct SunPositions(pub Vec<SunPosition>);

impl FromStr for SunPositions {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let positions = parse_sun_positions(s)?;
        if positions.is_empty() {
            return Err("give at least one sun position: AZ,EL;AZ,EL;... degrees".into());
        }
        Ok(Self(positions))
    }
}

/// A sun position is finite and its elevation lies in 0..90 degrees: on
/// the command line and in a recipe's `[plan]` alike.
fn check_sun_position([az, el]: SunPosition) -> Result<(), String> {
    if !az.is_finite() || !(0.0..=90.0).contains(&el) {
        return Err(format!(
            "sun position [{az}, {el}]: give a finite azimuth and an elevation in 0..90 degrees"
        ));
    }
    Ok(())
}

/// `AZ,EL;AZ,EL;...`: sun positions in degrees.
fn parse_sun_positions(s: &str) -> Result<Vec<SunPosition>, String> {
    s.split(';')
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (az, el) = p
                .split_once(',')
                .ok_or_else(|| format!("{p:?}: expected AZ,EL in degrees"))?;
            let number = |v: &str| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| format!("{p:?}: expected AZ,EL in degrees"))
            };
            let position = [number(az)?.rem_euclid(360.0), number(el)?];
            check_sun_position(position).map_err(|e| format!("{p:?}: {e}"))?;
            Ok(position)
        })
        .collect()
}

/// What to plan for: the budget, the needs, and for `sun` the sun positions
/// (given, or a day's path at the scene's latitude). On the command line
/// `--budget`, `--needs`, `--sun`, `--sun-day`, `--viewshed-distance`; in a recipe a `[plan]`
/// table with the same keys (unknown ones refused).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Request {
    pub budget: Budget,
    #[serde(default)]
    pub needs: Needs,
    /// Sun positions `[azimuth, elevation]`, degrees.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sun: Vec<SunPosition>,
    /// A day of the year (1-366): the sun every 15 minutes while it is up,
    /// at the scene's central latitude.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun_day: Option<u32>,
    /// How far each eye of the total viewshed sees, metres (`None`: the
    /// whole DEM).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub viewshed_distance: Option<f64>,
}

impl Request {
    /// The budget and the needs agree: a shade budget needs the sun and its
    /// positions, the sun needs positions; the message says what to add.
    pub(crate) fn validate(&self) -> Result<(), String> {
        self.budget.validate()?;
        let positions = !self.sun.is_empty() || self.sun_day.is_some();
        if self.needs.has(Need::Sun) && !positions {
            return Err("--needs sun: give the sun positions (--sun AZ,EL;AZ,EL...) or a day of the year (--sun-day N)".into());
        }
        if self.budget.shade.is_some() && !self.needs.has(Need::Sun) {
            return Err(format!(
                "budget shade={}: add sun to --needs (and its positions: --sun or --sun-day)",
                self.budget.shade.unwrap_or_default()
            ));
        }
        if self.budget.solar.is_some() && !self.needs.has(Need::Solar) {
            return Err(format!(
                "budget solar={}: add solar to --needs",
                self.budget.solar.unwrap_or_default()
            ));
        }
        match (self.budget.total_viewshed, self.needs.has(Need::TotalViewshed)) {
            (Some(v), false) => {
                return Err(format!(
                    "budget total_viewshed={v}: add total_viewshed to --needs"
                ))
            }
            (None, true) => {
                return Err("--needs total_viewshed: give its budget, total_viewshed=PERCENT (the 99th percentile of the relative error)".into())
            }
            _ => {}
        }
        let tracing = self.needs.has(Need::Tracing) || self.needs.has(Need::FastTracing);
        for (key, v) in [("steps", self.budget.steps), ("rays", self.budget.rays)] {
            if let Some(v) = v.filter(|_| !tracing) {
                return Err(format!(
                    "budget {key}={v}: a tracing budget needs tracing or fast_tracing in --needs"
                ));
            }
        }
        if let Some(d) = self.viewshed_distance {
            if !(d.is_finite() && d > 0.0) {
                return Err(format!("viewshed_distance={d}: give positive metres"));
            }
            if !self.needs.has(Need::TotalViewshed) {
                return Err(format!(
                    "viewshed_distance={d}: add total_viewshed to --needs"
                ));
            }
        }
        for &position in &self.sun {
            check_sun_position(position)?;
        }
        if let Some(day) = self.sun_day {
            if !(1..=366).contains(&day) {
                return Err(format!("sun_day={day}: a day of the year is 1 to 366"));
            }
        }
        Ok(())
    }
}

/// A limit of the budget that a plan's errors pass: its name as the
/// budget spells it, and the least value that they would meet.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Relax {
    pub(crate) limit: &'static str,
    pub(crate) at_least: f64,
}

impl std::fmt::Display for Relax {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} to at least {}", self.limit, self.at_least)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_documented_syntax_parses_and_prints_back() {
        let b: Budget =
            "horizon=0.5,horizon_max=3,svf=0.01,svf_max=0.05,shade=0.001,solar=2,total_viewshed=3,steps=4,rays=1e6,time=60,bytes=200M,memory=512"
                .parse()
                .unwrap();
        assert_eq!(
            b,
            Budget {
                horizon: 0.5,
                horizon_max: Some(3.0),
                svf: Some(0.01),
                svf_max: Some(0.05),
                shade: Some(0.001),
                solar: Some(2.0),
                total_viewshed: Some(3.0),
                steps: Some(4.0),
                rays: Some(1e6),
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
            ("horizon=2,horizon_max=1", "horizon_max >= horizon"),
            ("horizon=2,svf=0.01,svf_max=0.001", "svf_max >= svf"),
            ("horizon=1,shade=2", "shade=2"),
            ("horizon=1,bytes=12Q", "unknown unit"),
            ("horizon=1,colour=3", "not a budget key"),
            ("horizon", "KEY=VALUE"),
        ] {
            let err = text.parse::<Budget>().unwrap_err();
            assert!(err.contains(says), "{text}: {err}");
        }
    }

    #[test]
    fn sun_positions_are_checked_on_the_command_line_and_in_recipes_alike() {
        assert!("250,15;120,95".parse::<SunPositions>().is_err());
        assert_eq!(
            "-10,5".parse::<SunPositions>().unwrap(),
            SunPositions(vec![[350.0, 5.0]])
        );
        let request: Request =
            toml::from_str("needs = [\"sun\"]\nsun = [[250.0, 95.0]]\nbudget = { horizon = 1.0 }")
                .unwrap();
        assert!(request
            .validate()
            .unwrap_err()
            .contains("elevation in 0..90"));
    }

    #[test]
    fn a_tracing_budget_needs_tracing() {
        let request = Request {
            budget: "horizon=1,rays=2e6".parse().unwrap(),
            ..Default::default()
        };
        assert!(request
            .validate()
            .unwrap_err()
            .contains("tracing or fast_tracing"));
        let request = Request {
            needs: "fast_tracing".parse().unwrap(),
            ..request
        };
        assert_eq!(request.validate(), Ok(()));
        assert!("horizon=1,steps=0"
            .parse::<Budget>()
            .unwrap_err()
            .contains("steps=0"));
    }
}
