//! How wide the vector code goes: the one place that asks the CPU. The
//! kernels that have vector versions (the cone planes' row scans, the line
//! sweep's lanes, the sky stage's sums) run at [`level`]: AVX-512, else
//! AVX2, else their scalar code. The environment variable `TERRABAKE_SIMD`
//! (`avx512`, `avx2` or `scalar`) caps it, so that one machine can run,
//! time and test what other CPUs run. Every kernel gives the same bits as
//! the scalar code, so the cap changes speed, never values.

use std::sync::OnceLock;

/// The environment variable that caps the vector code.
pub const VAR: &str = "TERRABAKE_SIMD";

/// A width of vector code, narrowest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    Scalar,
    /// AVX2 and popcnt.
    Avx2,
    /// AVX-512 F, VL, BW and DQ (what the kernels use of it) and popcnt.
    Avx512,
}

/// The cap `TERRABAKE_SIMD` sets (unset or empty: `Avx512`, the widest
/// there is), or a message naming the value it cannot use.
pub fn cap_from_env() -> Result<Level, String> {
    let value = std::env::var_os(VAR).unwrap_or_default();
    if value.is_empty() {
        return Ok(Level::Avx512);
    }
    match value.to_str().map(str::to_ascii_lowercase).as_deref() {
        Some("avx512") => Ok(Level::Avx512),
        Some("avx2") => Ok(Level::Avx2),
        Some("scalar") => Ok(Level::Scalar),
        _ => Err(format!(
            "{VAR}={value:?} is not a vector width: use avx512, avx2 or scalar"
        )),
    }
}

/// The widest level the CPU runs, within the cap; found once. (A value of
/// the cap that cannot be used caps nothing: the command line refuses it
/// before any work.)
pub fn level() -> Level {
    static LEVEL: OnceLock<Level> = OnceLock::new();
    *LEVEL.get_or_init(|| cpu_level().min(cap_from_env().unwrap_or(Level::Avx512)))
}

/// Every level up to [`level`], narrowest first: the kernels this machine
/// can run, which the tests compare.
pub fn available() -> Vec<Level> {
    [Level::Scalar, Level::Avx2, Level::Avx512]
        .into_iter()
        .filter(|&l| l <= level())
        .collect()
}

fn cpu_level() -> Level {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        if has!("popcnt") {
            if has!("avx512f") && has!("avx512vl") && has!("avx512bw") && has!("avx512dq") {
                return Level::Avx512;
            }
            if has!("avx2") {
                return Level::Avx2;
            }
        }
    }
    Level::Scalar
}
