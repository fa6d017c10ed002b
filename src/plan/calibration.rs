//! The time models scaled to the machine at hand (docs/PLANNING.md, "Time
//! on this machine").
//!
//! The models of [`super::models`] are fitted on one machine and are upper
//! bounds there only: on an Intel Xeon 18 of 38 planned bakes ran over the
//! Zen 4 machine's models (docs/BENCHMARKS.md). So before it plans, the
//! planner times a fixed workload: the line sweep, every core busy, of a
//! [`SIZE`]² rough terrain in [`DIRECTIONS`] directions (what the horizons stage
//! spends its time on), [`RUNS`] runs after a warm-up. The fastest against
//! the same workload's seconds on the machine the models were fitted on
//! ([`TimeModels::calibration_seconds`]) is the scale of every predicted
//! time; the runs' spread widens the predicted range. It takes about 1.5
//! seconds, once per machine and binary: the result is cached, keyed by
//! the CPU, the core count and the executable, in
//! `$XDG_CACHE_HOME/terrabake/calibration.json` (or `~/.cache/...`), and
//! [`CALIBRATION_VAR`]` = off` turns it off (scale 1).
//!
//! Models without a calibration time (a `TERRABAKE_TIME_MODELS` file
//! written before fits recorded one) are taken as this machine's own:
//! scale 1.

use std::path::PathBuf;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::models::TimeModels;
use crate::algorithms::horizon::line::{default_tolerance, grid_direction, line_horizons};
use crate::terrain::random::{mix, unit_interval};
use crate::terrain::Terrain;

/// `off` turns the calibration off: the models are taken as they are.
pub const CALIBRATION_VAR: &str = "TERRABAKE_CALIBRATION";
/// The workload: a `SIZE x SIZE` terrain at 30 m, swept in `DIRECTIONS`
/// line directions at the stage's default tolerance, `RUNS` timed runs.
pub const SIZE: usize = 384;
pub const DIRECTIONS: usize = 48;
pub const RUNS: usize = 7;
/// The cache's format; a record of another is measured again.
const CACHE_VERSION: u32 = 1;
/// Records the cache keeps, the latest.
const CACHE_RECORDS: usize = 8;

/// The workload's seconds on this machine and the scale they give.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// The fastest run here, seconds: what the machine can do (the median
    /// of a 2-core virtual machine's runs jumps by a fifth between
    /// calibrations; the fastest by less).
    pub seconds: f64,
    /// The slowest run here, seconds.
    pub slowest: f64,
    /// The workload's seconds on the machine the models were fitted on.
    pub reference_seconds: f64,
}

impl Calibration {
    /// The factor every predicted time is multiplied by.
    pub fn scale(&self) -> f64 {
        self.seconds / self.reference_seconds
    }

    /// How much slower than the fastest the slowest run was: the
    /// machine's own noise, by which the predicted range widens upwards.
    pub fn spread(&self) -> f64 {
        self.slowest / self.seconds
    }
}

/// The workload's runs on this machine, and what they hold for: a record
/// of the cache file (a JSON array of them).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Measured {
    version: u32,
    pub machine: String,
    pub binary: String,
    /// The fastest and the slowest of the runs, seconds.
    pub seconds: f64,
    pub slowest: f64,
}

/// The calibration of `models` on this machine: `None` where it is turned
/// off or the models carry no calibration time. Measured once per process
/// (or read from the cache).
pub fn for_models(models: &TimeModels) -> Option<Calibration> {
    let reference_seconds = models.calibration_seconds?;
    let off = std::env::var(CALIBRATION_VAR).is_ok_and(|v| v.eq_ignore_ascii_case("off"));
    if off {
        return None;
    }
    static MEASURED: std::sync::OnceLock<Measured> = std::sync::OnceLock::new();
    let m = MEASURED.get_or_init(|| measured(false));
    Some(Calibration {
        seconds: m.seconds,
        slowest: m.slowest,
        reference_seconds,
    })
}

/// The workload's runs: from the cache when this binary measured them on
/// this machine (unless `fresh`), else measured and added to the cache
/// where its directory can be written (a cache that cannot be read or
/// written costs only the measurement; one that is not a cache is
/// replaced). The cache keeps the [`CACHE_RECORDS`] latest records, so the
/// command line, test binaries and the Python module each keep theirs.
pub fn measured(fresh: bool) -> Measured {
    let (machine, binary) = (machine(), binary());
    let path = cache_path();
    let mut records: Vec<Measured> = path
        .as_ref()
        .and_then(|p| {
            let bytes = terrabake_format::fsio::read_regular(p, 1 << 20).ok()?;
            serde_json::from_slice(&bytes).ok()
        })
        .unwrap_or_default();
    records.retain(|c| {
        c.version == CACHE_VERSION
            && c.seconds > 0.0
            && c.seconds <= c.slowest
            && c.slowest.is_finite()
    });
    let ours =
        |c: &Measured, machine: &str, binary: &str| c.machine == machine && c.binary == binary;
    if let Some(c) = records
        .iter()
        .find(|c| ours(c, &machine, &binary))
        .filter(|_| !fresh)
    {
        return c.clone();
    }
    let (seconds, slowest) = measure();
    let record = Measured {
        version: CACHE_VERSION,
        machine,
        binary,
        seconds,
        slowest,
    };
    if let Some(path) = path {
        records.retain(|c| !ours(c, &record.machine, &record.binary));
        records.push(record.clone());
        let keep = records.len().saturating_sub(CACHE_RECORDS);
        records.drain(..keep);
        let _ = crate::plumbing::output::write_atomically(&path, |out| {
            serde_json::to_writer_pretty(&mut *out, &records)?;
            Ok(())
        });
    }
    record
}

/// Times the workload: a warm-up, then [`RUNS`] runs; the fastest and the
/// slowest, seconds.
pub fn measure() -> (f64, f64) {
    // Rolling relief with post-to-post roughness, so that the hulls hold
    // what they hold on real terrain; the same posts on every machine.
    let z: Vec<f32> = (0..SIZE * SIZE)
        .map(|i| {
            let (x, y) = ((i % SIZE) as f64, (i / SIZE) as f64);
            let relief =
                600.0 * (x / 97.0).sin() * (y / 131.0).cos() + 300.0 * ((x + y) / 41.0).sin();
            (relief + 40.0 * unit_interval(mix(i as u64))) as f32
        })
        .collect();
    let terrain = Terrain::new(&z, SIZE, SIZE, 30.0, 30.0);
    let directions: Vec<_> = (0..DIRECTIONS)
        .map(|i| {
            let nominal = i as f64 * 360.0 / DIRECTIONS as f64;
            grid_direction(nominal, 30.0, 30.0, default_tolerance(DIRECTIONS))
        })
        .collect();
    let sweep = || {
        directions.par_iter().for_each_init(
            || vec![0f32; SIZE * SIZE],
            |out, dir| {
                line_horizons(&terrain, dir, out);
            },
        )
    };
    sweep();
    let mut runs: Vec<f64> = (0..RUNS)
        .map(|_| {
            let start = Instant::now();
            sweep();
            start.elapsed().as_secs_f64()
        })
        .collect();
    runs.sort_by(f64::total_cmp);
    (runs[0], runs[RUNS - 1])
}

/// The cache file, where there is a home for it.
pub fn cache_path() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| {
            std::env::var_os("HOME")
                .filter(|v| !v.is_empty())
                .map(|h| PathBuf::from(h).join(".cache"))
        })?;
    Some(base.join("terrabake").join("calibration.json"))
}

/// The machine: its CPU model and the cores this process may use.
fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| {
            info.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    format!("{cpu}, {} threads", rayon::current_num_threads())
}

/// The binary: the version and the executable's length and time.
fn binary() -> String {
    let exe = std::env::current_exe()
        .ok()
        .and_then(|p| std::fs::metadata(p).ok());
    let stamp = exe.map_or((0, 0), |m| {
        let modified = m
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos());
        (m.len(), modified)
    });
    format!(
        "terrabake {} ({} bytes, modified {})",
        env!("CARGO_PKG_VERSION"),
        stamp.0,
        stamp.1
    )
}
