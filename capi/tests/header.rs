//! The committed header declares exactly the functions the library exports:
//! a drift check that needs no cbindgen (pipelines/capi/test.sh compares
//! the whole header with cbindgen's where it is installed, and compiles a C
//! program against it).

use std::collections::BTreeSet;

fn read(path: &str) -> String {
    std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/").to_string() + path)
        .unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// The identifiers that follow `marker` on any line of `text`.
fn names_after(text: &str, marker: &str) -> BTreeSet<String> {
    text.lines()
        .filter_map(|l| l.split_once(marker))
        .map(|(_, rest)| {
            rest.chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect()
        })
        .collect()
}

#[test]
fn the_header_declares_every_exported_function() {
    let lib = read("src/lib.rs");
    let header = read("include/terrabake.h");
    let exported = names_after(&lib, "extern \"C\" fn ");
    assert!(exported.len() >= 12, "{exported:?}");
    // A declaration: the word before the line's first `(`, outside comments.
    let declared: BTreeSet<String> = header
        .lines()
        .filter(|l| !l.trim_start().starts_with("//") && !l.trim_start().starts_with('*'))
        .filter_map(|l| l.split_once('('))
        .filter_map(|(head, _)| head.split_whitespace().last())
        .map(|name| name.trim_start_matches('*').to_string())
        .filter(|name| name.starts_with("tb_"))
        .collect();
    assert_eq!(
        exported, declared,
        "make capi-header regenerates the header"
    );
    for ty in [
        "tb_asset",
        "tb_layer",
        "tb_window",
        "tb_grid",
        "tb_ray",
        "tb_hit",
        "tb_sun",
        "tb_status",
        "tb_method",
    ] {
        assert!(
            header.contains(&format!("}} {ty};"))
                || header.contains(&format!("typedef struct {ty} {ty};")),
            "{ty}"
        );
    }
}
