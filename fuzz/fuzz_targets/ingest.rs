//! Mutated DEM files through ingest (see the targets' module); seed it with
//! tests/fixtures/tiff.
#![no_main]

#[path = "../../tests/fuzz/targets.rs"]
mod targets;

use std::sync::OnceLock;

fn scratch() -> &'static std::path::Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| tempfile::tempdir().expect("temp dir")).path()
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    targets::ingest(data, "tif", scratch());
});
