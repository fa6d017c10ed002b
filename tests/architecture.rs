//! The rules of ARCHITECTURE.md that a test can hold: the pipeline's module
//! graph has no circle, the format crate knows nothing of the pipeline, the
//! CLI's `main.rs` stays thin, and the test build shares the release
//! build's compiled crates.

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

#[test]
fn the_module_graph_has_no_circle() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    // Top-level module -> the top-level modules its code names.
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in &files {
        let rel = file.strip_prefix(&src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let top = top.trim_end_matches(".rs").to_string();
        if top == "lib" || top == "main" {
            continue;
        }
        let text = code(file);
        let deps = graph.entry(top.clone()).or_default();
        for (i, _) in text.match_indices("crate::") {
            let name: String = text[i + 7..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if name != top
                && files.iter().any(|f| {
                    f.file_stem().is_some_and(|s| s == name.as_str()) && f.parent() == Some(&src)
                        || f.parent().is_some_and(|p| p == src.join(&name))
                })
            {
                deps.insert(name);
            }
        }
    }
    // Depth-first search for a back edge.
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == node) {
            let mut cycle = path[i..].to_vec();
            cycle.push(node.to_string());
            return Some(cycle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for dep in graph.get(node).into_iter().flatten() {
            if let Some(c) = visit(dep, graph, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    for node in graph.keys() {
        let cycle = visit(node, &graph, &mut Vec::new(), &mut done);
        assert!(
            cycle.is_none(),
            "module circle: {}",
            cycle.unwrap().join(" -> ")
        );
    }
    assert!(
        graph["recipe"].contains("cones"),
        "the scan sees dependencies"
    );
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

#[test]
fn main_rs_stays_thin() {
    let main = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/main.rs");
    let lines = std::fs::read_to_string(main).unwrap().lines().count();
    assert!(
        lines <= 300,
        "src/main.rs has {lines} lines: move work into the library"
    );
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
