//! How wide the vector code may go. The kernels that have vector versions
//! (the cone planes' row scans, the line sweep's lanes, the sky stage's
//! sums) each pick at run time the widest the CPU has: AVX-512, else AVX2,
//! else their scalar code. The environment variable `TERRABAKE_SIMD`
//! (`avx512`, `avx2` or `scalar`) caps that choice, so that one machine
//! can run, time and test what other CPUs run. Every kernel gives the same
//! bits as the scalar code, so the cap changes speed, never values.

use std::sync::OnceLock;

/// The environment variable that caps the vector code.
pub const VAR: &str = "TERRABAKE_SIMD";

/// A width of vector code, narrowest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    Scalar,
    Avx2,
    Avx512,
}

/// The cap `TERRABAKE_SIMD` sets (none: `Avx512`, the widest there is), or
/// a message naming the value it cannot use.
pub fn cap_from_env() -> Result<Level, String> {
    let Some(value) = std::env::var_os(VAR) else {
        return Ok(Level::Avx512);
    };
    match value.to_str().map(str::to_ascii_lowercase).as_deref() {
        Some("avx512") => Ok(Level::Avx512),
        Some("avx2") => Ok(Level::Avx2),
        Some("scalar") => Ok(Level::Scalar),
        _ => Err(format!(
            "{VAR}={value:?} is not a vector width: use avx512, avx2 or scalar"
        )),
    }
}

/// Whether code of `level` may run as far as the cap goes (read once; a
/// value the cap cannot use caps nothing: the command line refuses it
/// before any work).
pub fn allows(level: Level) -> bool {
    static CAP: OnceLock<Level> = OnceLock::new();
    level <= *CAP.get_or_init(|| cap_from_env().unwrap_or(Level::Avx512))
}
