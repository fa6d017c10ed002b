//! `terrabake-bench` from the command line, on a small synthetic asset.

use std::process::{Command, Output};

use terrabake::plumbing::progress::Progress;
use terrabake::stage::run_stage;

fn bench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terrabake-bench"))
        .args(args)
        .output()
        .expect("terrabake-bench runs")
}

#[test]
fn views_repeats_its_passes_and_refuses_none() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("t.tif");
    terrabake::io::synth::write_geotiff(
        &tif,
        terrabake::io::synth::SynthKind::Sine,
        60,
        40,
        1,
        Progress::hidden(),
    )
    .unwrap();
    let asset = dir.path().join("t.tbake");
    terrabake::stages::ingest::ingest(&tif, &asset, &Default::default(), Progress::hidden())
        .unwrap();
    let pyramid = terrabake::stages::pyramid::PyramidStage;
    run_stage(&asset, &pyramid, false, Progress::hidden()).unwrap();
    let cones = terrabake::stages::cones::ConesStage::default();
    run_stage(&asset, &cones, false, Progress::hidden()).unwrap();
    // Each method's median pass, the same hits for both tracers; no passes
    // at all is a usage error.
    let views = |repeat: &str| {
        bench(&[
            "views",
            asset.to_str().unwrap(),
            "--methods",
            "hierarchical,parametric",
            "--size",
            "64",
            "--every",
            "4",
            "--repeat",
            repeat,
            "--json",
            "-q",
        ])
    };
    let out = views("3");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    let out: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = out["methods"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "{out}");
    assert!(rows[0]["rays"].as_u64().unwrap() > 0, "{out}");
    assert_eq!(rows[0]["hits"], rows[1]["hits"], "{out}");
    assert_eq!(views("0").status.code(), Some(2));
}
