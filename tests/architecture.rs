//! The rules of ARCHITECTURE.md that a test can hold: the pipeline's
//! file-level import graph has no circle, at most 11 levels, and no import
//! from a room above (nor from one stage to another); ARCHITECTURE.md maps
//! the rooms there are; no file outgrows 1,100 lines; the format crate
//! knows nothing of the pipeline; the CLI's `main.rs` stays thin; and the
//! test build shares the release build's compiled crates.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Code without its `//` comments (doc links are not dependencies).
fn code(path: &Path) -> String {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// A file's module path under `src/` (`src/stages/horizons.rs` is
/// `stages::horizons`, `src/plan/mod.rs` is `plan`).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut path: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if path.last().is_some_and(|l| l == "mod") {
        path.pop();
    }
    path
}

/// The byte ranges of `text` inside inline modules (`mod tests {`, a
/// kernel's `mod avx2 {`), where `super` names the file itself.
fn inline_modules(text: &str) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut at = 0;
    for line in text.split_inclusive('\n') {
        if (line.starts_with("mod ") || line.starts_with("pub mod "))
            && line.trim_end().ends_with('{')
        {
            let end = text[at..].find("\n}\n").map_or(text.len(), |e| at + e);
            out.push(at..end);
        }
        at += line.len();
    }
    out
}

/// Every path `text` names from `super`, `self` or `crate`, or through a
/// child module it declares, as a module path from the crate root (its
/// last segments may be items, not modules).
fn named_paths(text: &str, me: &[String]) -> Vec<Vec<String>> {
    let inline = inline_modules(text);
    let children: Vec<&str> = text
        .lines()
        .filter_map(|l| {
            let l = l
                .trim_start_matches("pub ")
                .trim_start_matches("pub(crate) ");
            l.strip_prefix("mod ")?.strip_suffix(';')
        })
        .collect();
    let word = |c: char| c.is_alphanumeric() || c == '_';
    let mut out = Vec::new();
    let bytes = text.as_bytes();
    let mut i = 0;
    while i < text.len() {
        let starts_word = i == 0 || !(word(bytes[i - 1] as char) || bytes[i - 1] == b':');
        let rest = &text[i..];
        let first: String = rest.chars().take_while(|&c| word(c)).collect();
        if !starts_word || first.is_empty() {
            i += 1;
            continue;
        }
        let is_root = matches!(first.as_str(), "crate" | "super" | "self");
        if !(is_root || children.contains(&first.as_str()))
            || !rest[first.len()..].starts_with("::")
        {
            i += first.len().max(1);
            continue;
        }
        // The path's segments; a `{` group contributes each member's first.
        let mut segs = vec![first.clone()];
        let mut tail = &rest[first.len()..];
        let mut groups = Vec::new();
        while let Some(t) = tail.strip_prefix("::") {
            if let Some(g) = t.strip_prefix('{') {
                let body = &g[..g.find('}').unwrap_or(g.len())];
                groups = body
                    .split(',')
                    .map(|m| m.trim().split("::").next().unwrap_or("").to_string())
                    .filter(|m| !m.is_empty() && m != "self")
                    .collect();
                break;
            }
            let seg: String = t.chars().take_while(|&c| word(c)).collect();
            if seg.is_empty() {
                break;
            }
            tail = &t[seg.len()..];
            segs.push(seg);
        }
        let inside_inline = inline.iter().any(|r| r.contains(&i));
        let mut base: Vec<String> = me.to_vec();
        let mut k = 0;
        match first.as_str() {
            "crate" => {
                base.clear();
                k = 1;
            }
            "super" | "self" => {
                // In an inline module the first `super` is the file itself.
                let mut skip_one = inside_inline;
                while k < segs.len() && (segs[k] == "super" || segs[k] == "self") {
                    if segs[k] == "super" && !std::mem::take(&mut skip_one) {
                        base.pop();
                    }
                    k += 1;
                }
            }
            _ => {}
        }
        let mut path = base;
        path.extend(segs[k..].iter().cloned());
        if groups.is_empty() {
            out.push(path);
        } else {
            for g in groups {
                let mut p = path.clone();
                p.push(g);
                out.push(p);
            }
        }
        i += first.len();
    }
    out
}

/// The pipeline's file-level import graph: each module (one file) and the
/// modules it names. A module naming its own ancestor is not an edge: a
/// child lives inside its parent's scope (`super::` is Rust's nesting);
/// every other name is.
fn import_graph() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let modules: BTreeMap<Vec<String>, &std::path::PathBuf> = files
        .iter()
        .map(|f| (module_of(&src, f), f))
        .filter(|(m, _)| m != &["lib"] && m != &["main"])
        .collect();
    let mut graph = BTreeMap::new();
    for (me, file) in &modules {
        let mut deps = BTreeSet::new();
        for path in named_paths(&code(file), me) {
            let target = (1..=path.len())
                .rev()
                .map(|n| &path[..n])
                .find(|p| modules.contains_key(*p));
            if let Some(t) = target {
                if t != me.as_slice() && !me.starts_with(t) {
                    deps.insert(t.join("::"));
                }
            }
        }
        graph.insert(me.join("::"), deps);
    }
    graph
}

/// The rooms of `src/` and its top files, bottom up, as ARCHITECTURE.md's
/// `src/` section lists them (`- **`plumbing/`**: ...`).
fn rooms() -> Vec<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let section = doc.split("\n## `src/`").nth(1).expect("a `src/` section");
    let section = section.split("\n## ").next().unwrap();
    section
        .lines()
        .filter_map(|l| l.strip_prefix("- **`")?.split_once("`**"))
        .map(|(name, _)| {
            name.trim_end_matches('/')
                .trim_end_matches(".rs")
                .to_string()
        })
        .collect()
}

#[test]
fn the_import_graph_has_no_circle_and_no_import_running_back_up() {
    let graph = import_graph();
    assert!(
        graph["bake::recipe"].contains("stages::cones"),
        "the scan sees dependencies: {:?}",
        graph["bake::recipe"]
    );
    // Depth-first search for a back edge, and each module's level (one
    // above everything it imports).
    fn level(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        levels: &mut BTreeMap<String, usize>,
    ) -> usize {
        if let Some(i) = path.iter().position(|p| p == node) {
            panic!("module circle: {} -> {node}", path[i..].join(" -> "));
        }
        if let Some(&l) = levels.get(node) {
            return l;
        }
        path.push(node.to_string());
        let mut l = 1;
        for dep in graph.get(node).into_iter().flatten() {
            l = l.max(1 + level(dep, graph, path, levels));
        }
        path.pop();
        levels.insert(node.to_string(), l);
        l
    }
    let mut levels = BTreeMap::new();
    for node in graph.keys() {
        level(node, &graph, &mut Vec::new(), &mut levels);
    }
    let (deepest, depth) = levels.iter().max_by_key(|(_, &l)| l).unwrap();
    assert!(
        depth <= &11,
        "the import graph is {depth} levels deep at {deepest}"
    );
    // A room imports only the rooms below it (ARCHITECTURE.md lists them
    // bottom up).
    let rooms = rooms();
    let rank = |m: &str| {
        let room = m.split("::").next().unwrap();
        rooms
            .iter()
            .position(|r| r == room)
            .unwrap_or_else(|| panic!("{m} is in no room that ARCHITECTURE.md lists"))
    };
    for (m, deps) in &graph {
        for d in deps {
            assert!(
                rank(d) <= rank(m),
                "{m} imports {d}, a room above its own (ARCHITECTURE.md lists the rooms bottom up)"
            );
            // No stage imports another stage.
            let stage_of = |p: &str| {
                p.strip_prefix("stages::")
                    .map(|s| s.split("::").next().unwrap().to_string())
            };
            if let (Some(a), Some(b)) = (stage_of(m), stage_of(d)) {
                assert_eq!(a, b, "the {a} stage ({m}) imports the {b} stage ({d})");
            }
        }
    }
}

/// ARCHITECTURE.md maps the rooms that are there: its `src/` section names
/// each folder and file at the top of `src/` (lib.rs aside), and `src/`
/// stays small at its top.
#[test]
fn architecture_md_lists_the_rooms_of_src() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut top: Vec<String> = std::fs::read_dir(&src)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    top.sort();
    assert!(
        top.len() <= 16,
        "src/ has {} entries at its top: {top:?}",
        top.len()
    );
    let mut there: Vec<String> = top
        .iter()
        .map(|n| n.trim_end_matches(".rs").to_string())
        .filter(|n| n != "lib")
        .collect();
    let mut listed = rooms();
    listed.sort();
    there.sort();
    assert_eq!(listed, there, "ARCHITECTURE.md's rooms against src/");
}

/// No source file over 1,100 lines but the per-ISA kernels (files with
/// `#[target_feature]` functions, whose scalar twins the tests hold them to).
#[test]
fn no_source_file_is_over_1100_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in [
        "src",
        "formats/src",
        "capi/src",
        "python/src",
        "gpu/src",
        "benches",
    ] {
        rust_files(&root.join(dir), &mut files);
    }
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        let lines = text.lines().count();
        assert!(
            lines <= 1100 || text.contains("#[target_feature("),
            "{} has {lines} lines: split it at a seam",
            file.display()
        );
    }
}

#[test]
fn the_format_crate_knows_nothing_of_the_pipeline() {
    let formats = Path::new(env!("CARGO_MANIFEST_DIR")).join("formats");
    let manifest = std::fs::read_to_string(formats.join("Cargo.toml")).unwrap();
    let deps = manifest.split("[dependencies]").nth(1).unwrap();
    let deps = deps.split("\n[").next().unwrap();
    assert!(
        !deps.contains("terrabake"),
        "formats/ depends on the pipeline"
    );
    let mut files = Vec::new();
    rust_files(&formats.join("src"), &mut files);
    for file in files {
        assert!(
            !code(&file).contains("terrabake::"),
            "{} names the pipeline crate",
            file.display()
        );
    }
}

/// The binary parses, runs and prints; every command has one shape: a
/// variant of `cli::Command` holding its arguments (`Name(NameArgs)`),
/// whose type implements `Run`, dispatched in one line.
#[test]
fn main_rs_stays_thin_and_every_command_has_one_shape() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let main = std::fs::read_to_string(root.join("src/main.rs")).unwrap();
    let lines = main.lines().count();
    assert!(
        lines <= 60,
        "src/main.rs has {lines} lines: move work into the library"
    );
    let cli = std::fs::read_to_string(root.join("src/cli/mod.rs")).unwrap();
    let grammar = cli
        .split("pub enum Command {")
        .nth(1)
        .and_then(|rest| rest.split("\n}\n").next())
        .expect("cli::Command");
    let variants: Vec<&str> = grammar
        .lines()
        .filter_map(|l| l.strip_prefix("    "))
        .filter(|l| l.chars().next().is_some_and(|c| c.is_ascii_uppercase()))
        .collect();
    assert!(variants.len() >= 18, "{variants:?}");
    let dispatch = cli
        .split("fn args(&self) -> &dyn Run {")
        .nth(1)
        .expect("Command::args");
    for v in variants {
        let name = v.split('(').next().unwrap();
        assert!(
            v.ends_with("),") && !v.contains('{'),
            "cli::Command::{name} is not a variant holding its arguments: {v}"
        );
        assert!(
            dispatch.contains(&format!("Command::{name}(a) => a,")),
            "Command::args does not dispatch {name} in one line"
        );
    }
}

/// `make test` reuses the library that `make demo` built: the normal build
/// turns on every feature that the dev-dependencies turn on in crates both
/// use (Cargo.toml says which), or cargo compiles the library twice.
#[test]
fn the_test_build_shares_the_release_build() {
    let features = |edges: &str| -> BTreeMap<String, String> {
        let out = std::process::Command::new(env!("CARGO"))
            .args([
                "tree",
                "--offline",
                "--locked",
                "-p",
                "terrabake",
                "-p",
                "terrabake-format",
            ])
            .args([
                "-e",
                edges,
                "-f",
                "{p} [{f}]",
                "--prefix",
                "none",
                "--no-dedupe",
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .expect("cargo runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let mut map = BTreeMap::<String, BTreeSet<String>>::new();
        for line in String::from_utf8_lossy(&out.stdout).lines() {
            if let Some((package, rest)) = line.split_once(" [") {
                let features = rest.rsplit_once(']').map_or("", |r| r.0);
                map.entry(package.replace(" (*)", "")).or_default().extend(
                    features
                        .split(',')
                        .filter(|f| !f.is_empty())
                        .map(String::from),
                );
            }
        }
        map.into_iter()
            .map(|(k, v)| (k, v.into_iter().collect::<Vec<_>>().join(",")))
            .collect()
    };
    let (build, test) = (features("normal,build"), features("normal,build,dev"));
    let differ: Vec<String> = build
        .iter()
        .filter(|(package, f)| test.get(*package) != Some(*f))
        .map(|(package, f)| format!("{package}: build [{f}], test [{}]", test[package]))
        .collect();
    assert!(
        differ.is_empty(),
        "turn these features on in Cargo.toml's [dependencies]:\n{}",
        differ.join("\n")
    );
}
