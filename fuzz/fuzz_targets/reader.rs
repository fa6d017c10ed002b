//! Mutated assets, read every way a renderer would (see the targets' module).
#![no_main]

#[path = "../../tests/fuzz/targets.rs"]
mod targets;

use std::collections::HashMap;
use std::sync::OnceLock;

fn seed() -> &'static HashMap<String, Vec<u8>> {
    static SEED: OnceLock<HashMap<String, Vec<u8>>> = OnceLock::new();
    SEED.get_or_init(|| {
        let dir = tempfile::tempdir().expect("temp dir");
        targets::seed_asset(dir.path())
    })
}

libfuzzer_sys::fuzz_target!(|ops: &[u8]| {
    targets::reader(seed(), ops);
});
