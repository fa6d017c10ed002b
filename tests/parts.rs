//! Partitioned bakes: `bake --parts N --part I` in N local processes (run
//! at once), then `assemble`, give layers that decode bit for bit to one
//! machine's `bake` of the same recipe, for every stage and N in 1, 2, 3, 7;
//! and a bad set of parts is refused by name with nothing committed.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::*;
use terrabake::io::cog::{write_f32, GeoTags};
use terrabake::plumbing::progress::Progress;
use terrabake_format::{Asset, MANIFEST_FILE};

/// A 170 x 230 geographic DEM (the SRTM tile's georeferencing) of fractal
/// heights with a hole of nodata: uneven tile rows for every N, rows of
/// different east-west spacing, and nodata.
fn dem(dir: &Path) -> PathBuf {
    let srtm = dir.join("srtm.tbake");
    terrabake::stages::ingest::ingest(
        &repo_file("data/srtm3_n07w006_geographic_int16.tif"),
        &srtm,
        &Default::default(),
        Progress::hidden(),
    )
    .unwrap();
    let georef = Asset::open(&srtm).unwrap().manifest().georef.clone();
    let (w, h) = (170u32, 230u32);
    let tif = dir.join("dem.tif");
    let tags = GeoTags {
        georef,
        nodata: Some("-9999".into()),
    };
    write_f32(&tif, (w, h), &tags, |r0, rows| {
        for (i, v) in rows.iter_mut().enumerate() {
            let (x, y) = (i as u32 % w, r0 + i as u32 / w);
            let hole = (40..52).contains(&x) && (150..157).contains(&y);
            *v = if hole {
                -9999.0
            } else {
                40.0 * terrabake::io::synth::height(
                    terrabake::io::synth::SynthKind::Fractal,
                    x,
                    y,
                    w,
                    h,
                    5,
                )
            };
        }
        Ok(())
    })
    .unwrap();
    tif
}

/// Recipes that between them take every stage down every split: rows
/// (ingest, bounded line and sector horizons, sky, solar: its groups of
/// rows that share a sun path cut anew by every part), bands (unbounded line
/// and sector horizons) and the join (pyramid, cones, the edge count, sky
/// after band-split horizons).
const RECIPES: [&str; 4] = [
    r#"[ingest]
tile = 16
codec = "zstd"
[[stage]]
name = "pyramid"
[[stage]]
name = "cones"
slices = "auto"
codec = "zstd"
[[stage]]
name = "horizons"
sectors = 8
max_distance = 1500.0
distance = true
codec = "zstd"
[[stage]]
name = "sky"
layers = ["svf", "svf_cosine", "openness"]
codec = "zstd"
"#,
    r#"[ingest]
tile = 16
[[stage]]
name = "horizons"
sectors = 16
method = "line"
distance = true
[[stage]]
name = "sky"
[[stage]]
name = "solar"
days = "172"
step_minutes = 30
"#,
    r#"[ingest]
tile = 16
[[stage]]
name = "horizons"
sectors = 6
method = "sector"
max_distance = 700.0
distance = true
[[stage]]
name = "sky"
layers = ["svf"]
"#,
    r#"[ingest]
tile = 32
[[stage]]
name = "horizons"
sectors = 8
method = "sector"
encoding = "f32"
distance = true
"#,
];

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(o: Output) -> Output {
    assert!(o.status.success(), "failed: {}", stderr(&o));
    o
}

/// `terrabake bake SRC -o OUT --recipe R -q`, to add to and run.
fn bake_command(src: &Path, out: &Path, recipe: &Path) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_terrabake"));
    cmd.args([
        "bake",
        path(src),
        "-o",
        path(out),
        "--recipe",
        path(recipe),
        "-q",
    ]);
    cmd
}

/// `bake` on one machine.
fn bake_one(src: &Path, out: &Path, recipe: &Path) {
    ok(bake_command(src, out, recipe).output().unwrap());
}

/// `bake --parts n --part i` for every i at once, each its own process.
fn bake_parts(src: &Path, out: &Path, recipe: &Path, n: u32) {
    let children: Vec<_> = (0..n)
        .map(|i| {
            bake_command(src, out, recipe)
                .args(["--parts", &n.to_string(), "--part", &i.to_string()])
                .output()
                .expect("run terrabake")
        })
        .collect();
    for child in children {
        ok(child);
    }
}

/// A temporary directory with the DEM, recipe `RECIPES[r]` and its bake
/// on one machine (`one.tbake`).
fn baked_on_one_machine(r: usize) -> (tempfile::TempDir, PathBuf, PathBuf, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let src = dem(tmp.path());
    let recipe = tmp.path().join("r.toml");
    std::fs::write(&recipe, RECIPES[r]).unwrap();
    let one = tmp.path().join("one.tbake");
    bake_one(&src, &one, &recipe);
    (tmp, src, recipe, one)
}

/// Every layer of `a` and `b` decodes to the same values, bit for bit.
fn assert_same_asset(a: &Path, b: &Path, what: &str) {
    let (a, b) = (Asset::open(a).unwrap(), Asset::open(b).unwrap());
    let differences = terrabake::stage::same::differences(&a, &b).unwrap();
    assert!(differences.is_empty(), "{what}: {differences:#?}");
    assert!(a.manifest().layers.len() >= 2, "{what}: nothing compared");
}

#[test]
fn assembled_parts_equal_one_machine_for_every_stage_and_n() {
    let tmp = tempfile::tempdir().unwrap();
    let src = dem(tmp.path());
    for (r, text) in RECIPES.iter().enumerate() {
        let recipe = tmp.path().join(format!("r{r}.toml"));
        std::fs::write(&recipe, text).unwrap();
        let one = tmp.path().join(format!("one{r}.tbake"));
        bake_one(&src, &one, &recipe);
        for n in [1u32, 2, 3, 7] {
            let out = tmp.path().join(format!("r{r}n{n}.tbake"));
            bake_parts(&src, &out, &recipe, n);
            assert!(
                !out.join(MANIFEST_FILE).exists(),
                "a part touched the asset"
            );
            ok(terrabake(&["assemble", path(&out), "-q"]));
            assert!(
                !terrabake::bake::partition::parts_dir(&out).exists(),
                "parts left behind"
            );
            assert_same_asset(&one, &out, &format!("recipe {r}, {n} parts"));
            let verify = ok(terrabake(&["verify", path(&out)]));
            assert!(stdout(&verify).contains("valid"), "{}", stdout(&verify));
        }
    }
}

/// A part run again does nothing; a part killed at any write and run again
/// (on "another node": nothing but the shared directory carries over) ends
/// complete, and the join equals one machine.
#[test]
fn parts_are_idempotent_and_resume_after_a_kill() {
    let (tmp, src, recipe, one) = baked_on_one_machine(0);
    let out = tmp.path().join("p.tbake");
    let part = |i: u32, crash: Option<u32>| {
        let mut cmd = bake_command(&src, &out, &recipe);
        cmd.args(["--parts", "3", "--part", &i.to_string()]);
        if let Some(at) = crash {
            cmd.env("TERRABAKE_CRASH_AT", at.to_string());
        }
        cmd.output().unwrap()
    };
    let listing = |dir: &Path| {
        let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .filter(|e| e.file_type().unwrap().is_file())
            .map(|e| {
                (
                    e.file_name().into_string().unwrap(),
                    std::fs::read(e.path()).unwrap(),
                )
            })
            .collect();
        files.sort();
        files
    };
    ok(part(0, None));
    let parts = terrabake::bake::partition::parts_dir(&out);
    let before = listing(&parts.join("part-0-of-3"));
    ok(part(0, None));
    assert!(
        listing(&parts.join("part-0-of-3")) == before,
        "a second run rewrote part 0"
    );
    // Part 1: killed at its 3rd, 9th, 20th... crash point, then run again
    // each time until it finishes.
    let mut killed = 0;
    for at in [3u32, 9, 20, 40, 80] {
        let o = part(1, Some(at));
        if !o.status.success() {
            killed += 1;
            assert!(
                !parts.join("part-1-of-3.json").exists(),
                "a killed part left its record"
            );
        }
    }
    assert!(killed >= 3, "only {killed} runs were killed");
    ok(part(1, None));
    ok(part(2, None));
    ok(terrabake(&["assemble", path(&out), "-q"]));
    assert_same_asset(&one, &out, "after kills");
}

#[test]
fn a_bad_set_of_parts_is_refused_by_name_and_nothing_is_committed() {
    let tmp = tempfile::tempdir().unwrap();
    let src = dem(tmp.path());
    let recipe = tmp.path().join("r.toml");
    std::fs::write(&recipe, RECIPES[2]).unwrap();
    let other = tmp.path().join("other.toml");
    std::fs::write(&other, RECIPES[3]).unwrap();
    let out = tmp.path().join("a.tbake");
    // A good asset stands there already: every refusal must leave it.
    bake_one(&src, &out, &other);
    let manifest = std::fs::read(out.join(MANIFEST_FILE)).unwrap();
    let part = |i: &str, n: &str, r: &Path| {
        bake_command(&src, &out, r)
            .args(["--parts", n, "--part", i])
            .output()
            .unwrap()
    };
    let assemble = || terrabake(&["assemble", path(&out), "-q"]);
    let refused = |o: Output, needles: &[&str]| {
        assert!(!o.status.success(), "accepted: {}", stderr(&o));
        let e = stderr(&o);
        assert!(!e.contains("panicked"), "{e}");
        for needle in needles {
            assert!(e.contains(needle), "{needle:?} not in: {e}");
        }
        assert_eq!(
            std::fs::read(out.join(MANIFEST_FILE)).unwrap(),
            manifest,
            "committed"
        );
        Asset::open(&out).expect("the previous asset still opens");
    };

    // verify --same-as names the first post that differs.
    let shifted = tmp.path().join("shifted.tbake");
    ok(terrabake(&[
        "ingest",
        path(&src),
        "-o",
        path(&shifted),
        "--z-offset",
        "1",
        "-q",
    ]));
    let compared = terrabake(&["verify", path(&out), "--same-as", path(&shifted)]);
    assert_eq!(compared.status.code(), Some(3));
    assert!(
        stdout(&compared).contains("height@0 band 0: post (0, 0)"),
        "{}",
        stdout(&compared)
    );

    refused(part("3", "3", &recipe), &["--part 3", "0..3"]);
    refused(assemble(), &["no parts"]);
    ok(part("0", "3", &recipe));
    refused(assemble(), &["part 1, 2 of 3 missing", "--part I"]);
    ok(part("1", "3", &other));
    ok(part("2", "3", &recipe));
    refused(assemble(), &["part-1-of-3", "different recipe"]);
    ok(part("1", "3", &recipe));
    ok(part("0", "2", &recipe));
    refused(
        assemble(),
        &["two partitions", "part-0-of-2", "part-0-of-3"],
    );
    std::fs::remove_dir_all(terrabake::bake::partition::parts_dir(&out).join("part-0-of-2"))
        .unwrap();
    std::fs::remove_file(terrabake::bake::partition::parts_dir(&out).join("part-0-of-2.json"))
        .unwrap();
    // A damaged chunk in part 2's horizons.
    let part2 = terrabake::bake::partition::parts_dir(&out).join("part-2-of-3");
    let horizon = Asset::open(&part2)
        .unwrap()
        .layer("horizon", 0)
        .unwrap()
        .entry()
        .file
        .clone();
    let file = part2.join(horizon);
    let mut bytes = std::fs::read(&file).unwrap();
    // The footer's first field is the index's offset; the chunk before the
    // index is the last one the part computed (its last tile row).
    let footer = bytes.len() - 64;
    let index = u64::from_le_bytes(bytes[footer..footer + 8].try_into().unwrap()) as usize;
    bytes[index - 10] ^= 0xff;
    std::fs::write(&file, bytes).unwrap();
    refused(assemble(), &["part-2-of-3 is damaged", "checksum"]);
    // Baked again (the part checks its files, finds the damage), the set joins.
    ok(part("2", "3", &recipe));
    ok(assemble());
    assert_ne!(std::fs::read(out.join(MANIFEST_FILE)).unwrap(), manifest);
}

/// Reliability, third round (docs/RELIABILITY.md 13, 14, 20): parts know their
/// source by its content, not its path or time; a part must be the part it
/// says (a directory copied over another is refused, and a record's counts
/// must match its rows); the join is idempotent.
#[test]
fn parts_prove_their_source_and_identity_and_the_join_is_idempotent() {
    let tmp = tempfile::tempdir().unwrap();
    let src = dem(tmp.path());
    let recipe = tmp.path().join("r.toml");
    std::fs::write(&recipe, RECIPES[2]).unwrap();
    let part = |src: &Path, out: &Path, i: &str| {
        bake_command(src, out, &recipe)
            .args(["--parts", "2", "--part", i])
            .output()
            .unwrap()
    };
    let assemble = |out: &Path| terrabake(&["assemble", path(out), "-q"]);
    let refused = |o: Output, needle: &str, out: &Path| {
        assert!(!o.status.success(), "accepted: {}", stderr(&o));
        assert!(
            stderr(&o).contains(needle),
            "{needle:?} not in: {}",
            stderr(&o)
        );
        assert!(!out.join(MANIFEST_FILE).exists(), "committed");
    };

    // The source replaced between the parts by another DEM of the same
    // length, its modification time set back.
    let moving = tmp.path().join("moving.tif");
    std::fs::copy(&src, &moving).unwrap();
    let out = tmp.path().join("mixed.tbake");
    ok(part(&moving, &out, "0"));
    let time = std::fs::metadata(&moving).unwrap().modified().unwrap();
    let mut bytes = std::fs::read(&moving).unwrap();
    let n = bytes.len();
    // The last strip's bytes: other heights, the same length.
    for b in &mut bytes[n - 4000..n - 8] {
        *b = b.wrapping_add(1);
    }
    std::fs::write(&moving, &bytes).unwrap();
    std::fs::File::options()
        .write(true)
        .open(&moving)
        .unwrap()
        .set_modified(time)
        .unwrap();
    ok(part(&moving, &out, "1"));
    refused(assemble(&out), "ingest.source_xxh3", &out);

    // The same file by two names is one source.
    let out = tmp.path().join("names.tbake");
    ok(part(&src, &out, "0"));
    let relative = Command::new(env!("CARGO_BIN_EXE_terrabake"))
        .current_dir(tmp.path())
        .args([
            "bake",
            "dem.tif",
            "-o",
            path(&out),
            "--recipe",
            path(&recipe),
            "-q",
        ])
        .args(["--parts", "2", "--part", "1"])
        .output()
        .unwrap();
    ok(relative);
    ok(assemble(&out));

    // Idempotent: again after success, and after a kill during the
    // removal of the parts (their directory renamed, then the kill).
    let again = ok(terrabake(&["assemble", path(&out)]));
    assert!(stderr(&again).contains("up to date"), "{}", stderr(&again));
    let manifest = std::fs::read(out.join(MANIFEST_FILE)).unwrap();
    ok(part(&src, &out, "0"));
    ok(part(&src, &out, "1"));
    let parts = terrabake::bake::partition::parts_dir(&out);
    let removing = out.with_file_name("names.tbake.parts.removed-999999");
    std::fs::rename(&parts, &removing).unwrap();
    ok(assemble(&out));
    assert!(!removing.exists(), "a killed removal's leftovers stayed");
    // With the parts back (a kill before the removal began), the join is
    // recognised as done and only the parts go.
    ok(part(&src, &out, "0"));
    ok(part(&src, &out, "1"));
    ok(assemble(&out));
    assert!(!parts.exists());
    assert_eq!(
        std::fs::read(out.join(MANIFEST_FILE)).unwrap(),
        manifest,
        "joined twice"
    );
    // Two at once: both succeed, one join.
    ok(part(&src, &out, "0"));
    ok(part(&src, &out, "1"));
    let (a, b) = (
        Command::new(env!("CARGO_BIN_EXE_terrabake"))
            .args(["assemble", path(&out), "-q"])
            .spawn()
            .unwrap(),
        Command::new(env!("CARGO_BIN_EXE_terrabake"))
            .args(["assemble", path(&out), "-q"])
            .spawn()
            .unwrap(),
    );
    for child in [a, b] {
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
    }
    ok(terrabake(&["verify", path(&out)]));

    // A part's directory replaced by a copy of another's, checksums intact.
    let out = tmp.path().join("copied.tbake");
    ok(part(&src, &out, "0"));
    ok(part(&src, &out, "1"));
    let parts = terrabake::bake::partition::parts_dir(&out);
    std::fs::remove_dir_all(parts.join("part-1-of-2")).unwrap();
    copy_tree(&parts.join("part-0-of-2"), &parts.join("part-1-of-2"));
    refused(
        assemble(&out),
        "is not the part-1-of-2 its record names",
        &out,
    );

    // Records whose counts lie (2^63 nodata posts twice would wrap to 0).
    ok(part(&src, &out, "1"));
    for i in 0..2 {
        let record = parts.join(format!("part-{i}-of-2.json"));
        let text = std::fs::read_to_string(&record).unwrap();
        let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
        v["nodata"] = (1u64 << 63).into();
        std::fs::write(&record, serde_json::to_vec(&v).unwrap()).unwrap();
    }
    refused(assemble(&out), "nodata posts", &out);

    // A million parts: refused as usage, before any work.
    let o = bake_command(&src, &out, &recipe)
        .args(["--parts", "1000000", "--part", "0"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

/// The join killed at every durable step (each create, chunk write,
/// fsync, rename and unlink, by `TERRABAKE_CRASH_AT`): after each kill the
/// asset is absent or opens whole, and `assemble` run again finishes the
/// join (or only what is left of it) to one machine's asset, parts gone.
#[test]
fn an_assemble_killed_at_every_durable_step_resumes() {
    let (tmp, src, recipe, one) = baked_on_one_machine(0);
    let out = tmp.path().join("k.tbake");
    bake_parts(&src, &out, &recipe, 2);
    let parts = terrabake::bake::partition::parts_dir(&out);
    let pristine = tmp.path().join("pristine.parts");
    copy_tree(&parts, &pristine);
    let (mut killed, mut at) = (0, 1u32);
    let every = std::env::var_os("TERRABAKE_EVERY_KILL").is_some();
    loop {
        let _ = std::fs::remove_dir_all(&out);
        let _ = std::fs::remove_dir_all(&parts);
        copy_tree(&pristine, &parts);
        let o = Command::new(env!("CARGO_BIN_EXE_terrabake"))
            .args(["assemble", path(&out), "-q"])
            .env("TERRABAKE_CRASH_AT", at.to_string())
            .output()
            .unwrap();
        if o.status.success() {
            break;
        }
        killed += 1;
        if out.join(MANIFEST_FILE).exists() {
            Asset::open(&out).unwrap_or_else(|e| panic!("killed at step {at}: {e}"));
        }
        let again = terrabake(&["assemble", path(&out), "-q"]);
        assert!(
            again.status.success(),
            "after a kill at step {at}: {}",
            stderr(&again)
        );
        assert!(!parts.exists(), "after a kill at step {at}: parts left");
        let leftovers: Vec<_> = std::fs::read_dir(tmp.path())
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().contains(".parts.removed-"))
            .collect();
        assert!(
            leftovers.is_empty(),
            "after a kill at step {at}: {leftovers:?}"
        );
        assert_same_asset(&one, &out, &format!("killed at step {at}"));
        // Every step early on, then 10 % further each time (about 90
        // points, 10 s); `TERRABAKE_EVERY_KILL=1` takes every third step
        // (1,400 points, 3 minutes: docs/RELIABILITY.md's figure).
        at += match (at < 40, every) {
            (true, _) => 1,
            (false, true) => 3,
            (false, false) => at / 10,
        };
    }
    assert!(killed >= 60, "only {killed} kill points");
    eprintln!("assemble: {killed} kill points, each resumed to one machine's asset");
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}
