//! Exact horizon references from the heights alone, at sampled posts: what
//! `check` measures a bake against and what the planner measures a scene
//! with (docs/PLANNING.md).
//!
//! **Posts.** `samples` posts drawn uniformly (seeded, so a measurement
//! repeats) from an area, and a quarter as many again of the highest local
//! relief (the largest height range within four posts, among twenty random
//! candidates each): where horizons are steep, errors are largest. Then the
//! posts a percentile is blind to: around each of the area's
//! [`FEATURES`] most prominent features (the highest post of an 8-post
//! block, by how far it rises above the lowest post within two blocks:
//! lone spikes, peaks, towers in a DSM, cliff tops), posts at
//! [`FEATURE_DISTANCES`] from it in three seeded directions. There the
//! feature is a narrow, high wedge of the horizon that bands between it
//! miss whole, so the largest error of a bake is found there, where random
//! posts would meet it about once in a hundred azimuths.
//!
//! **Horizons.** At each post, the exact line horizon
//! (`horizon::brute::line_horizon`: every crossing of the sight line with
//! the grid, on the two-triangle surface, with the stage's curvature and
//! refraction, and no distance limit) in `directions` grid directions, each
//! within 0.1 degree of `i * 360 / directions`. Each line stops where the
//! DEM's highest post could no longer rise above its horizon so far, and
//! steps over the blocks of cells whose highest post could not
//! (`brute::line_horizon_records_below`: the same records;
//! docs/BENCHMARKS.md has what each saves).

use crate::terrain::sun::SunPosition;
use std::collections::HashSet;

use rayon::prelude::*;
use terrabake_format::{Asset, Mmap};

use crate::algorithms::horizon::sky::{svf_of_horizons, BandIntegrals};
use terrabake_format::features::{HorizonFeatures, SightLine};
use terrabake_format::horizons::{edge_distance_along, edge_may_cut, heading};

use crate::algorithms::horizon::{brute, features, plan_bands, Band, BandKind, Method};
use crate::error::bail;
use crate::plan::{PLANNED_FEATURES, SHARE_DIRECTIONS};
use crate::plumbing::progress::Progress;
use crate::terrain::held::HeldDem;
use crate::terrain::random::SplitMix64;
use crate::terrain::Terrain;

/// How a reference samples.
#[derive(Debug, Clone, Copy)]
pub struct Sampling {
    /// Random posts; a quarter as many of the highest relief are added.
    pub samples: usize,
    pub seed: u64,
    /// Reference directions.
    pub directions: usize,
    /// Distances (metres) at which to keep each sight line's horizon cut
    /// off (the planner's distance limit); empty for none.
    pub cuts: &'static [f64],
}

/// `check`'s sampling: 400 random posts (and 100 of the highest relief),
/// seed 1, 720 directions.
impl Default for Sampling {
    fn default() -> Self {
        Self {
            samples: 400,
            seed: 1,
            directions: 720,
            cuts: &[],
        }
    }
}

/// Prominent features the samples go around.
pub const FEATURES: usize = 6;
/// Distances (posts) from a feature at which posts are sampled: the
/// feature itself (its horizon turns fastest with the azimuth) and its
/// neighbours too.
pub const FEATURE_DISTANCES: [usize; 8] = [0, 1, 3, 6, 12, 24, 48, 96];
/// Posts a side of the blocks whose highest post is a feature candidate.
const FEATURE_BLOCK: usize = 8;

/// The sampled posts `(col, row)`: random ones, then those of the highest
/// relief, then those around the prominent features; no nodata post, none
/// twice.
struct Samples {
    posts: Vec<(usize, usize)>,
    relief_posts: usize,
    feature_posts: usize,
    /// The features `(col, row)` and how far (metres of height) each rises
    /// above the lowest post within two blocks, most prominent first.
    features: Vec<((usize, usize), f32)>,
}

/// The `count` most prominent features of `area` (module docs), each at
/// least four blocks from a more prominent one.
fn prominent_features(
    z: &[f32],
    w: usize,
    [x0, y0, x1, y1]: [usize; 4],
    count: usize,
) -> Vec<((usize, usize), f32)> {
    let b = FEATURE_BLOCK;
    let (bw, bh) = ((x1 - x0).div_ceil(b), (y1 - y0).div_ceil(b));
    // Each block's highest post and its lowest height.
    let mut highest = vec![None::<((usize, usize), f32)>; bw * bh];
    let mut lowest = vec![f32::INFINITY; bw * bh];
    for r in y0..y1 {
        for c in x0..x1 {
            let v = z[r * w + c];
            if v.is_nan() {
                continue;
            }
            let i = ((r - y0) / b) * bw + (c - x0) / b;
            lowest[i] = lowest[i].min(v);
            if highest[i].is_none_or(|(_, h)| v > h) {
                highest[i] = Some(((c, r), v));
            }
        }
    }
    // (the highest post, how far it rises, its block)
    type Candidate = ((usize, usize), f32, (usize, usize));
    let mut candidates: Vec<Candidate> = Vec::new();
    for by in 0..bh {
        for bx in 0..bw {
            let Some((post, top)) = highest[by * bw + bx] else {
                continue;
            };
            let mut floor = f32::INFINITY;
            for ny in by.saturating_sub(2)..(by + 3).min(bh) {
                for nx in bx.saturating_sub(2)..(bx + 3).min(bw) {
                    floor = floor.min(lowest[ny * bw + nx]);
                }
            }
            candidates.push((post, top - floor, (bx, by)));
        }
    }
    candidates.sort_unstable_by(|a, b| b.1.total_cmp(&a.1));
    let mut chosen: Vec<Candidate> = Vec::new();
    for c in candidates {
        if chosen.len() == count || c.1 <= 0.0 {
            break;
        }
        let apart = |o: &Candidate| c.2 .0.abs_diff(o.2 .0) >= 4 || c.2 .1.abs_diff(o.2 .1) >= 4;
        if chosen.iter().all(apart) {
            chosen.push(c);
        }
    }
    chosen
        .into_iter()
        .map(|(p, prominence, _)| (p, prominence))
        .collect()
}

/// Samples the posts of `area` (module docs).
fn sample_posts(z: &[f32], w: usize, area: [usize; 4], opts: &Sampling) -> Samples {
    let [x0, y0, x1, y1] = area;
    let mut rng = SplitMix64(opts.seed);
    let draw = |rng: &mut SplitMix64| -> Option<(usize, usize)> {
        (0..32).find_map(|_| {
            let (c, r) = (x0 + rng.below(x1 - x0), y0 + rng.below(y1 - y0));
            (!z[r * w + c].is_nan()).then_some((c, r))
        })
    };
    // Random posts may repeat; a set keeps each once (and the relief posts
    // apart from them) in time linear in the samples.
    let mut seen = HashSet::new();
    let mut posts: Vec<(usize, usize)> = (0..opts.samples)
        .filter_map(|_| draw(&mut rng))
        .filter(|&p| seen.insert(p))
        .collect();
    let h = z.len() / w;
    let relief = |(c, r): (usize, usize)| -> f32 {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for rr in r.saturating_sub(4)..(r + 5).min(h) {
            for cc in c.saturating_sub(4)..(c + 5).min(w) {
                let v = z[rr * w + cc];
                if !v.is_nan() {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
            }
        }
        hi - lo
    };
    let wanted = opts.samples / 4;
    let mut candidates: Vec<(f32, (usize, usize))> = (0..wanted * 20)
        .filter_map(|_| draw(&mut rng))
        .map(|p| (relief(p), p))
        .collect();
    candidates.sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
    let before = posts.len();
    for (_, p) in candidates {
        if posts.len() - before == wanted {
            break;
        }
        if seen.insert(p) {
            posts.push(p);
        }
    }
    let relief_posts = posts.len() - before;
    let features = prominent_features(z, w, area, FEATURES);
    let before = posts.len();
    for &((fc, fr), _) in &features {
        for &d in &FEATURE_DISTANCES {
            for _ in 0..3 {
                let az = rng.below(3600) as f64 * std::f64::consts::TAU / 3600.0;
                let c = fc as f64 + d as f64 * az.sin();
                let r = fr as f64 - d as f64 * az.cos();
                if c < x0 as f64 || r < y0 as f64 {
                    continue;
                }
                let p = (c.round() as usize, r.round() as usize);
                if p.0 < x1 && p.1 < y1 && !z[p.1 * w + p.0].is_nan() && seen.insert(p) {
                    posts.push(p);
                }
            }
        }
    }
    Samples {
        feature_posts: posts.len() - before,
        posts,
        relief_posts,
        features,
    }
}

/// The exact horizons of sampled posts in dense directions, from the heights
/// alone: what `check` measures a bake against and what the planner
/// measures a scene with. The planner adds the directions a bake would
/// store ([`Pilot::measure_directions`]): they need not be reference
/// directions.
#[derive(Debug)]
pub struct Pilot {
    /// The posts `(col, row)`: random ones, then those of the highest
    /// relief, then those around the prominent features.
    pub posts: Vec<(usize, usize)>,
    pub relief_posts: usize,
    pub feature_posts: usize,
    /// The prominent features the last posts lie around, and how far each
    /// rises above its surroundings (metres).
    pub features: Vec<((usize, usize), f32)>,
    /// The reference directions (grid lines within 0.1 degree of
    /// `i * 360 / directions`), and their bands' integrals for the svf.
    pub reference: Vec<crate::algorithms::horizon::Band>,
    integrals: Vec<BandIntegrals>,
    /// The grid steps measured and their azimuths: the reference's, then
    /// any added, each once.
    steps: Vec<(i64, i64)>,
    azimuths: Vec<f64>,
    /// Per post, the exact horizon in each measured direction (the
    /// reference directions first, in order), degrees.
    pub exact: Vec<Vec<f64>>,
    /// Per post, the horizon of each measured direction `j` cut off at each
    /// of the cut distances `k`, at `j * cuts.len() + k`, degrees (empty
    /// without cuts).
    cut: Vec<Vec<f32>>,
    cuts: &'static [f64],
    /// The DEM's highest post in blocks and overall: where a sight line
    /// can set no more records, and which blocks it can step over
    /// ([`brute::line_horizon_records_below`]).
    heights: brute::BlockMax,
    /// Per post, the terrain's slope there, degrees (`Terrain::normal`).
    pub slope_deg: Vec<f64>,
    /// The east-west post spacing on the first and the last row, metres
    /// (they differ on geographic grids).
    pub dx_range: (f64, f64),
    /// The spikes a line bake would list with its angles, served exactly
    /// between bands at the pilot's posts as the loader serves them
    /// ([`Pilot::list_features`]; `None`: none listed), the posts' heights
    /// (each sight line's eye) and the post spacing, metres.
    pub listed: Option<HorizonFeatures>,
    eyes: Vec<f64>,
    /// Per post, the listed features' crossings with its sight lines in
    /// the reference directions, `(direction, metres, degrees)` ordered by
    /// direction: what every candidate serves there, at any distance limit
    /// (most sight lines cross none, so only crossings are held).
    listed_reference: Vec<Vec<(u32, f32, f32)>>,
    spacing: (f64, f64),
    /// What [`Self::edge_may_cut`] takes: the DEM's posts across and down,
    /// each post's east-west spacing (its row's), and the curvature
    /// coefficient.
    size: (u32, u32),
    post_dx: Vec<f64>,
    curvature: f64,
}

/// Whether the DEM's edge may have made the error of a sample: where it
/// may cut the exact horizon `(azimuth, angle)` (degrees;
/// `horizons::edge_may_cut`, terrain beyond the edge as high as the DEM's
/// highest post, `room` metres above the eye, less the curvature drop
/// `curvature * d^2`, as the `horizon_edge` layer counts it), or where it
/// may cut one of the two `bands` (azimuth, angle) the sample is served
/// from before the distance within which what sets the exact horizon lies
/// (a band whose line leaves the DEM sooner cannot see it). `edge` gives
/// the metres to the edge along an azimuth. Elsewhere the DEM knows both,
/// and a largest error is bounded. A band that passes a spike the
/// reference meets is not excused: its line runs past the spike's distance.
pub fn edge_made_error(
    (room, curvature): (f64, f64),
    edge: impl Fn(f64) -> f64,
    (azimuth, truth): (f64, f64),
    bands: [(f64, f64); 2],
) -> bool {
    let cut = |azimuth: f64, angle: f64| {
        let d = edge(azimuth);
        let rise = room - curvature * d * d;
        (edge_may_cut(rise, d, angle.to_radians().sin_cos()), d)
    };
    if cut(azimuth, truth).0 {
        return true;
    }
    let within = if truth > 0.0 {
        room / truth.to_radians().tan()
    } else {
        f64::INFINITY
    };
    bands.into_iter().any(|(azimuth, angle)| {
        let (may, d) = cut(azimuth, angle);
        may && d < within
    })
}

/// Cells a side of the blocks whose highest posts bound the pilot's sight
/// lines ([`brute::BlockMax`]), coarsest first.
const HEIGHT_BLOCKS: [usize; 2] = [64, 16];

impl Pilot {
    /// Samples the posts of `dem` (`asset`'s heights, read once by the
    /// caller) within `area` and computes their exact horizons with the
    /// curvature coefficient `curvature`.
    pub fn measure(
        asset: &Asset<Mmap>,
        dem: &HeldDem,
        curvature: f64,
        area: [usize; 4],
        opts: &Sampling,
        progress: Progress,
    ) -> crate::Result<Self> {
        let dir = asset.dir();
        if opts.samples == 0 || opts.directions < 4 {
            bail!("a check needs at least one sample and four reference directions");
        }
        let m = asset.manifest();
        let terrain = dem.terrain(curvature);
        let Samples {
            posts,
            relief_posts,
            feature_posts,
            features,
        } = sample_posts(dem.z(), dem.width, area, opts);
        if posts.is_empty() {
            bail!(
                "{}: the area holds no post with a height to measure",
                dir.display()
            );
        }
        // Each grid step once (`plan_bands`): every index into the
        // reference is one direction.
        let reference = plan_bands(
            Method::Line,
            opts.directions,
            m.cell_size.dx,
            m.cell_size.dy,
            Some(0.1),
        );
        let integrals = reference
            .iter()
            .map(|b| BandIntegrals::new(b.lo, b.hi))
            .collect();
        let slope_deg = posts
            .iter()
            .map(|&(c, r)| {
                terrain
                    .normal(c, r)
                    .map_or(0.0, |n| n[2].acos().to_degrees())
            })
            .collect();
        let dx_range = (terrain.dx_at(0), terrain.dx_at(dem.height - 1));
        let eyes = posts
            .iter()
            .map(|&(c, r)| f64::from(terrain.at(c, r)))
            .collect();
        let post_dx = posts.iter().map(|&(_, r)| terrain.dx_at(r)).collect();
        let mut pilot = Self {
            exact: vec![Vec::new(); posts.len()],
            cut: vec![Vec::new(); posts.len()],
            posts,
            relief_posts,
            feature_posts,
            features,
            reference: Vec::new(),
            integrals,
            steps: Vec::new(),
            azimuths: Vec::new(),
            cuts: opts.cuts,
            // From the heights themselves, not the manifest's range: the
            // reference rests on nothing but the heights.
            heights: brute::BlockMax::of(&terrain, &HEIGHT_BLOCKS),
            slope_deg,
            dx_range,
            listed: None,
            eyes,
            listed_reference: Vec::new(),
            spacing: (m.cell_size.dx, m.cell_size.dy),
            size: (dem.width as u32, dem.height as u32),
            post_dx,
            curvature,
        };
        let bar = progress.bar(pilot.posts.len() as u64, "exact horizons", "posts");
        pilot.measure_directions(&terrain, &reference, || bar.inc(1));
        bar.finish_and_clear();
        pilot.reference = reference;
        Ok(pilot)
    }

    /// Lists the spikes a `horizon_max` plan lists with the line's angles,
    /// served exactly between bands (`algorithms::horizon::features`): a
    /// spike rising `e` metres above its eight neighbours moves the horizon
    /// of a post `d` away by at most `atan(e / d)`, so those that could not
    /// move a neighbour's (`d` one spacing) by the directions' share of
    /// `horizon_max` are left out; of the rest, the [`PLANNED_FEATURES`]
    /// that rise highest. Grids of uniform spacing only: elsewhere nothing
    /// is listed. How many were listed and the least rise, metres.
    pub(crate) fn list_features(&mut self, terrain: &Terrain, horizon_max: f64) -> (usize, f64) {
        if !terrain.row_scale.is_uniform() {
            return (0, 0.0);
        }
        let spacing = terrain.dx.min(terrain.dy);
        let min_rise = (spacing * (SHARE_DIRECTIONS * horizon_max).to_radians().tan()) as f32;
        let mut found = Vec::new();
        features::spikes_in_rows(
            terrain,
            0..terrain.height,
            min_rise,
            PLANNED_FEATURES,
            &mut found,
        );
        let listed = HorizonFeatures {
            curvature: terrain.curvature,
            max_distance: None,
            posts: found.into_iter().map(|s| s.post).collect(),
        };
        self.listed_reference = (0..self.posts.len())
            .into_par_iter()
            .map(|post| {
                let mut crossings = Vec::new();
                for (r, band) in self.reference.iter().enumerate() {
                    let line = self.sight_line(post, band.azimuth);
                    crossings.extend(
                        (listed.crossings_deg(&line).into_iter())
                            .map(|(d, angle)| (r as u32, d as f32, angle as f32)),
                    );
                }
                crossings
            })
            .collect();
        let n = listed.posts.len();
        self.listed = Some(listed);
        match n {
            0 => (0, 0.0),
            n => (n, f64::from(min_rise)),
        }
    }

    /// [`Self::feature_horizon`] in reference direction `r`.
    pub(crate) fn feature_horizon_in_reference(
        &self,
        post: usize,
        r: usize,
        max_distance: Option<f64>,
    ) -> Option<f64> {
        let crossings = self.listed_reference.get(post)?;
        let first = crossings.partition_point(|c| (c.0 as usize) < r);
        (crossings[first..].iter())
            .take_while(|c| c.0 as usize == r)
            .filter(|c| max_distance.is_none_or(|m| f64::from(c.1) <= m))
            .map(|c| f64::from(c.2))
            .reduce(f64::max)
    }

    /// [`edge_made_error`] of a sample at `post` in reference direction
    /// `r`, against the DEM's highest post.
    pub(crate) fn edge_may_cut(
        &self,
        (post, r): (usize, usize),
        truth: f64,
        bands: [(f64, f64); 2],
    ) -> bool {
        let (c, row) = self.posts[post];
        let edge = |azimuth: f64| {
            edge_distance_along(
                self.size,
                (self.post_dx[post], self.spacing.1),
                (c as f64, row as f64),
                heading(azimuth),
            )
        };
        edge_made_error(
            (self.heights.top - self.eyes[post], self.curvature),
            edge,
            (self.reference[r].azimuth, truth),
            bands,
        )
    }

    fn sight_line(&self, post: usize, azimuth: f64) -> SightLine {
        let (c, r) = self.posts[post];
        SightLine::new((c as u32, r as u32), self.eyes[post], azimuth, self.spacing)
    }

    /// The listed features' exact horizon from post `post` (an index) at
    /// compass `azimuth`, their sight lines cut at `max_distance` metres.
    pub(crate) fn feature_horizon(
        &self,
        post: usize,
        azimuth: f64,
        max_distance: Option<f64>,
    ) -> Option<f64> {
        let listed = self.listed.as_ref()?;
        listed.horizon_within(&self.sight_line(post, azimuth), max_distance)
    }

    /// What the pilot holds, MiB: the DEM (`dem_bytes`: 4 a post, or none
    /// where it was spilled), its blocks' highest posts and, per post and
    /// reference direction, the exact horizon (8 bytes) and its cuts (4
    /// bytes each).
    pub(crate) fn memory_mib(&self, dem_bytes: u64) -> f64 {
        let per_post = self.directions_measured() * (8 + 4 * self.cuts.len());
        let held = dem_bytes as usize + self.bounds_bytes() + self.posts.len() * per_post;
        held as f64 / 1048576.0
    }

    /// The posts that sample the scene (random and relief), which come
    /// first: the percentiles are over these, the largest errors over
    /// these and the posts around the features after them.
    pub fn scene_posts(&self) -> usize {
        self.posts.len() - self.feature_posts
    }

    /// The memory the blocks bounding its sight lines hold, bytes.
    pub(crate) fn bounds_bytes(&self) -> usize {
        self.heights.bytes()
    }

    /// The indices (into each post's `exact`) of the line directions of
    /// `bands`, measuring at every post those not measured yet (by their
    /// grid step: a direction measured once serves every band on it).
    /// `terrain` is the one the pilot was measured on (its blocks' highest
    /// posts bound the sight lines); `posted` is called once per post
    /// measured.
    pub fn measure_directions(
        &mut self,
        terrain: &Terrain,
        bands: &[Band],
        posted: impl Fn() + Sync,
    ) -> Vec<usize> {
        let step = |band: &Band| match &band.kind {
            BandKind::Line(direction) => direction.step,
            _ => unreachable!("the pilot measures lines"),
        };
        assert!(self.heights.fits(terrain), "the pilot's own terrain");
        let mut new: Vec<(i64, i64)> = Vec::new();
        for b in bands {
            let s = step(b);
            if !self.steps.contains(&s) && !new.contains(&s) {
                new.push(s);
                self.azimuths.push(b.azimuth);
            }
        }
        if !new.is_empty() {
            // Each line's records give its exact horizon (the last) and its
            // horizon cut off at any distance (the last record within it);
            // only the cuts asked for are kept, as a bowl's lines are
            // records all the way out.
            let (cuts, heights) = (self.cuts, &self.heights);
            self.posts
                .par_iter()
                .zip(&mut self.exact)
                .zip(&mut self.cut)
                .for_each(|((&post, exact), cut)| {
                    for &s in &new {
                        let records = brute::line_horizon_records_below(terrain, post, s, heights);
                        exact.push(f64::from(brute::horizon_within(&records, None)));
                        cut.extend(
                            cuts.iter()
                                .map(|&d| brute::horizon_within(&records, Some(d))),
                        );
                    }
                    posted();
                });
            self.steps.extend(new);
        }
        bands
            .iter()
            .map(|b| {
                let s = step(b);
                self.steps.iter().position(|&m| m == s).expect("measured")
            })
            .collect()
    }

    /// Per post, the horizons `method` (sector or sampled: not line, whose
    /// directions [`Self::measure_directions`] measures) gives in its
    /// `count` bands from the whole DEM, as the stage bakes them by
    /// default (Stewart's narrow-sector check on), degrees: what the
    /// planner predicts those methods' errors from, against the same exact
    /// references. `terrain` is the one the pilot was measured on.
    pub fn measure_method(&self, terrain: &Terrain, method: Method, count: usize) -> Vec<Vec<f64>> {
        use crate::algorithms::horizon::sampled::SampledWalk;
        use crate::algorithms::horizon::sector::sector_horizon_of_post;
        assert!(self.heights.fits(terrain), "the pilot's own terrain");
        let top = self.heights.top;
        match method {
            Method::Line => unreachable!("line directions are measured by measure_directions"),
            Method::Sector => self
                .posts
                .par_iter()
                .map(|&post| {
                    (0..count)
                        .map(|i| {
                            f64::from(sector_horizon_of_post(terrain, post, (i, count), true, top))
                        })
                        .collect()
                })
                .collect(),
            Method::Sampled => {
                let walks: Vec<SampledWalk> = plan_bands(method, count, 1.0, 1.0, None)
                    .iter()
                    .map(|band| SampledWalk::new(terrain, band.azimuth))
                    .collect();
                self.posts
                    .par_iter()
                    .map(|&post| {
                        walks
                            .iter()
                            .map(|walk| f64::from(walk.steepest::<()>(post, f64::INFINITY).0))
                            .collect()
                    })
                    .collect()
            }
        }
    }

    /// The azimuth of measured direction `j`, degrees.
    pub fn azimuth(&self, j: usize) -> f64 {
        self.azimuths[j]
    }

    /// Directions measured: the reference's and those added.
    pub(crate) fn directions_measured(&self) -> usize {
        self.steps.len()
    }

    /// Post `i`'s horizon in measured direction `j` from the terrain no
    /// farther than cut distance `k` (`Sampling::cuts`), degrees.
    pub fn bounded(&self, i: usize, j: usize, k: usize) -> f64 {
        f64::from(self.cut[i][j * self.cuts.len() + k])
    }

    /// The reference direction nearest azimuth `az` (degrees, any turn):
    /// where a sun at `az` is compared.
    pub(crate) fn nearest_direction(&self, az: f64) -> usize {
        let gap = |b: &Band| {
            let d = (b.azimuth - az).rem_euclid(360.0);
            d.min(360.0 - d)
        };
        (0..self.reference.len())
            .min_by(|&i, &j| gap(&self.reference[i]).total_cmp(&gap(&self.reference[j])))
            .unwrap_or(0)
    }

    /// The sun at `[azimuth, elevation]` (degrees), weighing `weight`, at
    /// its nearest reference direction.
    pub(crate) fn sun(&self, [azimuth, elevation]: SunPosition, weight: f64) -> PilotSun {
        PilotSun {
            direction: self.nearest_direction(azimuth),
            elevation,
            weight,
        }
    }

    /// Zakšek's sky-view factor of a post's reference horizons (the first
    /// of its `exact`).
    pub fn svf(&self, exact: &[f64]) -> f64 {
        svf_of_horizons(
            &self.integrals,
            exact[..self.reference.len()].iter().copied(),
        )
    }
}

/// Whether a sun `elevation` degrees up is lit under one horizon and not
/// under the other (a wrong sun/shade state; the sun is a point).
pub(crate) fn shade_differs(elevation: f64, served: f64, exact: f64) -> bool {
    (elevation > served) != (elevation > exact)
}

/// A sun position as the pilot and the check see it: the reference
/// direction nearest its azimuth, its elevation (degrees) and its weight
/// (1 for a shade position; the solar budget's are weighed).
#[derive(Debug, Clone, Copy)]
pub(crate) struct PilotSun {
    pub direction: usize,
    pub elevation: f64,
    pub weight: f64,
}

/// The year's sun as the solar budget weighs it: every 15 minutes of the
/// 21st of each month at `latitude` (degrees), weighted by the clear-sky
/// beam on a horizontal surface at sea level (Linke 3, W/m^2), which is
/// what a wrong shadow there takes or adds.
pub(crate) fn solar_year(latitude: f64) -> Vec<(SunPosition, f64)> {
    use crate::algorithms::solar::{beam_transmittance, day_steps, relative_air_mass};
    let phi = latitude.to_radians().sin_cos();
    (0..12u32)
        .flat_map(|month| {
            let day = (f64::from(month) * 30.44 + 21.0).round() as u32;
            day_steps(crate::terrain::sun::PATH_YEAR, day, 15.0, 0.0)
        })
        .filter_map(|step| {
            let sun = step.sun(phi);
            (sun[2] > 0.0).then(|| {
                let s = crate::terrain::sun::Sun::from_direction(sun);
                let h0 = sun[2].asin();
                let beam = step.g0 * beam_transmittance(3.0, relative_air_mass(h0), 0.0) * sun[2];
                ([s.azimuth, s.elevation], beam)
            })
        })
        .collect()
}

/// Per cent of a post's beam weight over `suns` that horizons `served`
/// (degrees, at the reference directions) put in sun or shadow where the
/// `exact` ones do not: the solar budget's error at one post, an upper
/// bound of its global irradiation's (the beam is part of the global). Suns
/// where either horizon is unknown count for neither.
pub(crate) fn solar_error(suns: &[PilotSun], served: &[f64], exact: &[f64]) -> f64 {
    let (mut wrong, mut total) = (0.0, 0.0);
    for sun in suns {
        let (s, e) = (served[sun.direction], exact[sun.direction]);
        if s.is_nan() || e.is_nan() {
            continue;
        }
        total += sun.weight;
        if shade_differs(sun.elevation, s, e) {
            wrong += sun.weight;
        }
    }
    if total > 0.0 {
        100.0 * wrong / total
    } else {
        0.0
    }
}

/// The value at `p` percent of sorted `v` (0 when empty).
pub fn percentile(v: &[f64], p: usize) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v[(v.len() * p / 100).min(v.len() - 1)]
}

/// The value at quantile `q` (0..1) of `v` once sorted, without sorting
/// it all (0 when empty); `v` is left reordered, so that several
/// quantiles of one slice cost a selection each.
pub(crate) fn quantile_unsorted(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let at = ((v.len() as f64 * q) as usize).min(v.len() - 1);
    *v.select_nth_unstable_by(at, f64::total_cmp).1
}
