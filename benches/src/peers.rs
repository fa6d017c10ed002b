//! The peers beside us (`make bench-peers`, `terrabake-bench horizons
//! --peers`): other tools' horizons and sky-view factors, measured against
//! the same exact reference as our methods and charted beside them.
//!
//! `pipelines/peers/bench_peers.sh` installs and runs each peer on the
//! accuracy study's crop and on the whole DEM, converts its output to our
//! conventions (horizon elevation in degrees, one band per azimuth
//! clockwise from north, raw little-endian `f32`, band-major, rows north
//! first) and writes a manifest, [`PeerManifest`]. This module reads it,
//! checks every file's size against the crop, and scores each output:
//!
//! - **horizons**: the RMS and mean error at the reference's azimuths,
//!   interpolated linearly between the peer's own (as our `line` and
//!   `sampled` rows are), and the sky-view factor (Zakšek's) we integrate
//!   from them, so every horizon tool is scored on svf the same way;
//! - **svf**: a peer's own sky-view factor against the reference's in the
//!   definition it computes: Zakšek's (RVT) or the slope-aware view factor
//!   (Dozier and Frew's, which SAGA and topocalc compute).
//!
//! The whole-DEM runs carry the wall time and peak memory of the whole peer
//! process beside ours, for the ratio table.

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};

use super::horizons::{interpolated, svf_errors, svf_of, Reference};
use super::markdown_table;
use terrabake::algorithms::horizon::sky::BandIntegrals;

/// `peers.json`, as `bench_peers.sh` writes it. Paths are relative to the
/// manifest's folder.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PeerManifest {
    /// The DEM every run used, for the tables' captions.
    pub dem: String,
    /// Side of the centred crop the outputs cover (the study's `--crop`).
    pub crop: usize,
    /// Directions asked of every peer.
    pub directions: usize,
    pub peers: Vec<PeerOutput>,
    /// Our own whole-DEM runs, timed the same way.
    pub ours: Vec<WholeRun>,
}

/// One output of one peer (a peer with horizons and its own svf gives two).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PeerOutput {
    /// The peer and the function, e.g. "GRASS r.horizon": the outputs of
    /// one name are one curve on the charts.
    pub name: String,
    /// The setting of the peer's accuracy knob this output ran with, as
    /// the chart labels its point ("K=16", "256 cells"); the outputs of
    /// one name differ in it.
    #[serde(default)]
    pub knob: Option<String>,
    #[serde(default)]
    pub version: Option<String>,
    /// Why the peer has no output: not installable here, failed, timed out.
    #[serde(default)]
    pub missing: Option<String>,
    /// Compass azimuths of the bands of `horizons`, ascending.
    #[serde(default)]
    pub azimuths_deg: Vec<f64>,
    #[serde(default)]
    pub horizons: Option<PathBuf>,
    #[serde(default)]
    pub svf: Option<PathBuf>,
    #[serde(default)]
    pub svf_definition: Option<SvfDefinition>,
    /// The peer's computation on the crop, seconds (its own calls, timed
    /// inside its process).
    #[serde(default)]
    pub crop_seconds: Option<f64>,
    /// The whole peer process on the whole DEM (on the first of a peer's
    /// outputs only: one process gives them all).
    #[serde(default)]
    pub whole: Option<WholeRun>,
    /// The conversions applied, and anything a reader should know.
    #[serde(default)]
    pub notes: Vec<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SvfDefinition {
    /// Zakšek et al. (2011): visible sky over the horizontal.
    Zaksek,
    /// Dozier and Frew (1990): the view factor of the tilted surface.
    SlopeAware,
}

/// One whole process on the whole DEM.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WholeRun {
    pub label: String,
    pub seconds: f64,
    /// Unknown for a process stopped at the limit.
    #[serde(default)]
    pub peak_mib: Option<f64>,
    /// Stopped at the run's time limit: `seconds` is a lower bound.
    #[serde(default)]
    pub timed_out: bool,
    #[serde(default)]
    pub notes: Vec<String>,
    /// One of ours that the table divides every process by, a column each
    /// (none marked: the first of ours).
    #[serde(default)]
    pub ratio: bool,
}

/// A peer's output read and checked against the crop.
#[derive(Debug, Clone)]
pub struct LoadedPeer {
    pub output: PeerOutput,
    horizons: Vec<Vec<f32>>,
    svf: Option<Vec<f32>>,
}

/// A peer output's errors against the reference.
#[derive(Debug, Clone, Serialize)]
pub struct PeerRow {
    pub name: String,
    pub knob: Option<String>,
    pub seconds: f64,
    pub horizon_rms_deg: Option<f64>,
    pub horizon_bias_deg: Option<f64>,
    pub svf_definition: SvfDefinition,
    pub svf_rms: f64,
    pub svf_max: f64,
}

impl PeerManifest {
    pub fn read(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text)
            .with_context(|| format!("{}: not a peers manifest", path.display()))
    }

    /// Every peer output that has files, read and checked (`side^2` values
    /// per band).
    pub fn load(&self, dir: &Path, side: usize) -> Result<Vec<LoadedPeer>> {
        ensure!(
            self.crop == side,
            "the peers ran on a {0} x {0} crop, the study's is {side} x {side}",
            self.crop
        );
        let read = |file: &Path, bands: usize| -> Result<Vec<Vec<f32>>> {
            let path = dir.join(file);
            let bytes =
                std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
            let want = bands * side * side * 4;
            ensure!(
                bytes.len() == want,
                "{}: {} bytes, expected {want} ({bands} bands of {side} x {side} f32)",
                path.display(),
                bytes.len()
            );
            Ok(bytes
                .chunks_exact(side * side * 4)
                .map(|band| {
                    band.chunks_exact(4)
                        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                        .collect()
                })
                .collect())
        };
        self.peers
            .iter()
            .filter(|p| p.missing.is_none())
            .map(|p| {
                let horizons = match &p.horizons {
                    Some(file) => {
                        ensure!(
                            p.azimuths_deg.windows(2).all(|w| w[0] < w[1]),
                            "{}: azimuths_deg must ascend",
                            p.name
                        );
                        read(file, p.azimuths_deg.len())?
                    }
                    None => Vec::new(),
                };
                let svf = match (&p.svf, p.svf_definition) {
                    (Some(file), Some(_)) => Some(read(file, 1)?.remove(0)),
                    (Some(_), None) => bail!("{}: an svf file needs its svf_definition", p.name),
                    (None, _) => None,
                };
                ensure!(
                    !horizons.is_empty() || svf.is_some(),
                    "{}: neither horizons nor svf",
                    p.name
                );
                Ok(LoadedPeer {
                    output: p.clone(),
                    horizons,
                    svf,
                })
            })
            .collect()
    }
}

impl LoadedPeer {
    /// Errors against `reference` (on the same crop). A peer's own svf is
    /// scored when it has one; otherwise Zakšek's from its horizons.
    pub fn score(&self, reference: &Reference) -> PeerRow {
        let p = &self.output;
        let (horizon_rms_deg, horizon_bias_deg) = if self.horizons.is_empty() {
            (None, None)
        } else {
            let (rms, bias) = reference.horizon_errors(|post, az| {
                interpolated(&p.azimuths_deg, az, |i| f64::from(self.horizons[i][post]))
            });
            (Some(rms), Some(bias))
        };
        let (svf_definition, (svf_rms, svf_max)) = match (&self.svf, p.svf_definition) {
            (Some(svf), Some(definition)) => {
                let want = match definition {
                    SvfDefinition::Zaksek => &reference.svf,
                    SvfDefinition::SlopeAware => &reference.svf_cosine,
                };
                let errors = svf_errors(&reference.posts, want, |post| f64::from(svf[post]));
                (definition, errors)
            }
            _ => {
                let integrals = BandIntegrals::of_azimuths(&p.azimuths_deg);
                let errors = svf_errors(&reference.posts, &reference.svf, |post| {
                    svf_of(&integrals, &self.horizons, post)
                });
                (SvfDefinition::Zaksek, errors)
            }
        };
        PeerRow {
            name: p.name.clone(),
            knob: p.knob.clone(),
            seconds: p.crop_seconds.unwrap_or(f64::NAN),
            horizon_rms_deg,
            horizon_bias_deg,
            svf_definition,
            svf_rms,
            svf_max,
        }
    }
}

/// The peers' accuracy rows as a Markdown table.
pub fn accuracy_table_markdown(rows: &[PeerRow]) -> String {
    let opt = |v: Option<f64>, f: &dyn Fn(f64) -> String| v.map_or("-".into(), f);
    markdown_table(
        &[
            "peer",
            "setting",
            "time on the crop (s)",
            "horizon RMS error (deg)",
            "horizon bias (deg)",
            "svf definition",
            "svf RMS error",
            "svf max error",
        ],
        rows.iter().map(|r| {
            vec![
                r.name.clone(),
                r.knob.clone().unwrap_or_else(|| "-".into()),
                format!("{:.3}", r.seconds),
                opt(r.horizon_rms_deg, &|v| format!("{v:.3}")),
                opt(r.horizon_bias_deg, &|v| format!("{v:+.3}")),
                match r.svf_definition {
                    SvfDefinition::Zaksek => "Zakšek".into(),
                    SvfDefinition::SlopeAware => "slope-aware".into(),
                },
                format!("{:.5}", r.svf_rms),
                format!("{:.4}", r.svf_max),
            ]
        }),
    )
}

fn mib(peak: Option<f64>) -> String {
    peak.map_or("-".into(), |m| format!("{m:.0}"))
}

/// Each peer output's conversions and remarks, a bullet each.
pub fn notes_markdown(manifest: &PeerManifest) -> String {
    manifest
        .peers
        .iter()
        .flat_map(|p| p.notes.iter().map(move |n| (&p.name, n)))
        .chain(
            manifest
                .ours
                .iter()
                .flat_map(|o| o.notes.iter().map(move |n| (&o.label, n))),
        )
        .map(|(who, n)| format!("- {who}: {n}\n"))
        .collect()
}

/// The whole-DEM runs: each process against each of ours marked `ratio`
/// (or the first of ours), a column each, and the peers that did not run,
/// with the reason.
pub fn whole_table_markdown(manifest: &PeerManifest) -> Result<String> {
    let mut bases: Vec<&WholeRun> = manifest.ours.iter().filter(|o| o.ratio).collect();
    if bases.is_empty() {
        bases.extend(manifest.ours.first());
    }
    ensure!(!bases.is_empty(), "the peers manifest has no run of ours");
    let ratios = |w: &WholeRun, bound: &str, digits: usize| {
        bases
            .iter()
            .map(|b| format!("{bound}{:.digits$}", w.seconds / b.seconds))
            .collect::<Vec<_>>()
    };
    let mut rows: Vec<Vec<String>> = manifest
        .ours
        .iter()
        .map(|o| {
            let mut row = vec![
                format!("**{}**", o.label),
                "-".into(),
                format!("{:.2}", o.seconds),
                mib(o.peak_mib),
            ];
            row.extend(ratios(o, "", 2));
            row
        })
        .collect();
    // (A peer with several outputs ran once on the whole DEM: its first
    // output carries the run.)
    for p in &manifest.peers {
        let Some(w) = &p.whole else {
            continue;
        };
        let bound = if w.timed_out { "> " } else { "" };
        let mut row = vec![
            w.label.clone(),
            p.version.clone().unwrap_or_default(),
            format!("{bound}{:.2}", w.seconds),
            mib(w.peak_mib),
        ];
        row.extend(ratios(w, bound, 1));
        rows.push(row);
    }
    for p in manifest.peers.iter().filter(|p| p.missing.is_some()) {
        let mut row = vec![
            p.name.clone(),
            p.version.clone().unwrap_or_default(),
            format!("not run: {}", p.missing.as_deref().unwrap_or_default()),
        ];
        row.extend(std::iter::repeat_n("-".to_string(), 1 + bases.len()));
        rows.push(row);
    }
    let mut header: Vec<String> = [
        "whole process",
        "version",
        "wall time (s)",
        "peak RSS (MiB)",
    ]
    .map(String::from)
    .into();
    header.extend(bases.iter().map(|b| format!("time / ours ({})", b.label)));
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    Ok(markdown_table(&header, rows))
}

#[cfg(test)]
mod tests {
    use super::*;
    use terrabake::io::synth::{height, SynthKind};
    use terrabake::terrain::Terrain;

    const SIDE: usize = 24;

    fn fractal() -> Vec<f32> {
        (0..SIDE * SIDE)
            .map(|i| {
                height(
                    SynthKind::Fractal,
                    (i % SIDE) as u32,
                    (i / SIDE) as u32,
                    64,
                    64,
                    7,
                )
            })
            .collect()
    }

    /// A peer output of `bands` at `azimuths`, written under `dir`.
    fn peer(dir: &Path, name: &str, azimuths: Vec<f64>, bands: &[&Vec<f32>]) -> PeerOutput {
        let bytes: Vec<u8> = bands
            .iter()
            .flat_map(|b| b.iter().flat_map(|v| v.to_le_bytes()))
            .collect();
        std::fs::write(dir.join(name), bytes).unwrap();
        PeerOutput {
            name: name.into(),
            knob: None,
            version: None,
            missing: None,
            azimuths_deg: azimuths,
            horizons: Some(name.into()),
            svf: None,
            svf_definition: None,
            crop_seconds: Some(1.0),
            whole: None,
            notes: Vec::new(),
        }
    }

    fn manifest(peers: Vec<PeerOutput>) -> PeerManifest {
        PeerManifest {
            dem: "fractal".into(),
            crop: SIDE,
            directions: 64,
            peers,
            ours: Vec::new(),
        }
    }

    #[test]
    fn the_reference_itself_scores_zero_and_a_turned_convention_does_not() {
        let z = fractal();
        let terrain = Terrain::new(&z, SIDE, SIDE, 30.0, 30.0);
        let reference = Reference::new(&terrain, 64);
        let dir = tempfile::tempdir().unwrap();
        let azimuths: Vec<f64> = reference.bands.iter().map(|b| b.azimuth).collect();
        let same = peer(
            dir.path(),
            "same",
            azimuths.clone(),
            &reference.values.iter().collect::<Vec<_>>(),
        );
        // A peer that counts from east instead of north, left unconverted.
        let mut turned: Vec<(f64, &Vec<f32>)> = azimuths
            .iter()
            .map(|a| (a + 90.0) % 360.0)
            .zip(&reference.values)
            .collect();
        turned.sort_by(|a, b| a.0.total_cmp(&b.0));
        let turned = peer(
            dir.path(),
            "turned",
            turned.iter().map(|t| t.0).collect(),
            &turned.iter().map(|t| t.1).collect::<Vec<_>>(),
        );
        let loaded = manifest(vec![same, turned]).load(dir.path(), SIDE).unwrap();
        let (same, turned) = (loaded[0].score(&reference), loaded[1].score(&reference));
        assert_eq!(same.horizon_rms_deg, Some(0.0));
        assert_eq!(same.horizon_bias_deg, Some(0.0));
        assert_eq!(same.svf_definition, SvfDefinition::Zaksek);
        assert!(same.svf_rms < 1e-12, "{}", same.svf_rms);
        assert!(
            turned.horizon_rms_deg.unwrap() > 1.0,
            "{:?}",
            turned.horizon_rms_deg
        );
    }

    #[test]
    fn a_file_of_the_wrong_size_or_an_svf_without_its_definition_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let band = vec![0f32; SIDE * SIDE - 1];
        let short = peer(dir.path(), "short", vec![0.0], &[&band]);
        let err = manifest(vec![short]).load(dir.path(), SIDE).unwrap_err();
        assert!(
            format!("{err:#}").contains("short: 2300 bytes, expected 2304"),
            "{err:#}"
        );
        let band = vec![0f32; SIDE * SIDE];
        let mut svf = peer(dir.path(), "svf", Vec::new(), &[&band]);
        (svf.horizons, svf.svf) = (None, Some("svf".into()));
        let err = manifest(vec![svf]).load(dir.path(), SIDE).unwrap_err();
        assert!(
            format!("{err:#}").contains("needs its svf_definition"),
            "{err:#}"
        );
        let err = manifest(Vec::new()).load(dir.path(), SIDE + 1).unwrap_err();
        assert!(format!("{err:#}").contains("crop"), "{err:#}");
    }

    /// Every process is divided by each of ours marked `ratio`, a column
    /// each; a manifest without marks divides by the first of ours.
    #[test]
    fn the_whole_table_has_a_ratio_column_per_marked_run_of_ours() {
        let run = |label: &str, seconds: f64, ratio: bool| WholeRun {
            label: label.into(),
            seconds,
            peak_mib: None,
            timed_out: false,
            notes: Vec::new(),
            ratio,
        };
        let dir = tempfile::tempdir().unwrap();
        let mut m = manifest(Vec::new());
        let mut slow = peer(dir.path(), "slow", Vec::new(), &[]);
        slow.whole = Some(run("slow", 12.0, false));
        m.peers.push(slow);
        m.ours = vec![
            run("all", 0.4, true),
            run("alone", 0.2, true),
            run("both", 0.5, false),
        ];
        let table = whole_table_markdown(&m).unwrap();
        assert!(
            table.contains("| time / ours (all) | time / ours (alone) |"),
            "{table}"
        );
        assert!(
            table.contains("| slow |  | 12.00 | - | 30.0 | 60.0 |"),
            "{table}"
        );
        assert!(
            table.contains("| **both** | - | 0.50 | - | 1.25 | 2.50 |"),
            "{table}"
        );
        for o in &mut m.ours {
            o.ratio = false;
        }
        let table = whole_table_markdown(&m).unwrap();
        assert!(
            table.contains("| slow |  | 12.00 | - | 30.0 |\n"),
            "{table}"
        );
    }
}
