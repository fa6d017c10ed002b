//! Would a search of the max pyramid beat Stewart's tree for sector
//! horizons? A count, not a product path (docs/BENCHMARKS.md, "Valley
//! crossings and a pyramid search", the sector paragraph).
//!
//! For each sampled post, all sectors at once: a depth-first walk of the
//! height's max pyramid, nearer children first, skipping a block when its
//! highest post over its nearest distance (taken along a sector's centre
//! line, at most half a sector off it) cannot beat the best slope found
//! so far in any sector the block spans; blocks of one post are posts.
//! Left out, as the count does not need them: curvature, the narrow-sector
//! check and exact boundary ties (no post lies on a boundary at 64
//! sectors). Printed: blocks visited and posts examined a post, searching
//! from nothing, and searching with every sector's answer known
//! beforehand (less a hair, so that its post must still be found): the
//! least any ordering of the search could visit.
//!
//!     cargo run --release -p terrabake-bench --example sector_pyramid_search -- ASSET [SECTORS] [SAMPLES]

use std::f64::consts::PI;
use terrabake_format::Asset;

struct Search {
    h: usize,
    dx: f64,
    /// Level `k`: blocks of `2^k` posts square, `(blocks across, highest)`;
    /// level 0 is the posts' heights, `w` across.
    /// Not the tracers' `terrain::MaxBlocks`: their blocks of cells hold
    /// their edge posts too, which loosens the bound (34,123 blocks a post
    /// and 4,642 with the answers known, against 26,489 and 3,528 here);
    /// the count asks what the search could do at its best.
    levels: Vec<(usize, Vec<f32>)>,
    /// Unit (east, north) of each sector's centre.
    centres: Vec<(f64, f64)>,
}

/// Compass azimuth of `(east, north)`, radians in `[0, 2 pi)`.
fn azimuth(e: f64, n: f64) -> f64 {
    e.atan2(n).rem_euclid(2.0 * PI)
}

impl Search {
    fn new(z: Vec<f32>, (w, h): (usize, usize), dx: f64, sectors: usize) -> Self {
        let mut levels = vec![(w, z)];
        let (mut lw, mut lh) = (w, h);
        while lw > 1 || lh > 1 {
            let (nw, nh) = (lw.div_ceil(2), lh.div_ceil(2));
            let below = &levels[levels.len() - 1].1;
            let mut up = vec![f32::NEG_INFINITY; nw * nh];
            for y in 0..lh {
                for x in 0..lw {
                    let at = (y / 2) * nw + x / 2;
                    up[at] = up[at].max(below[y * lw + x]);
                }
            }
            levels.push((nw, up));
            (lw, lh) = (nw, nh);
        }
        let width = 2.0 * PI / sectors as f64;
        let centres = (0..sectors).map(|s| (s as f64 * width).sin_cos()).collect();
        Self {
            h,
            dx,
            levels,
            centres,
        }
    }

    fn sector(&self, az: f64) -> i64 {
        let width = 2.0 * PI / self.centres.len() as f64;
        (az / width + 0.5).floor() as i64
    }

    /// Every sector's steepest slope from post `p`, starting from `best`;
    /// with the blocks visited and the posts examined.
    fn run(&self, p: usize, mut best: Vec<f64>) -> (Vec<f64>, u64, u64) {
        let n = self.centres.len() as i64;
        let half = (PI / n as f64).cos();
        let (w, z) = (self.levels[0].0, &self.levels[0].1);
        let (pc, pr) = ((p % w) as i64, (p / w) as i64);
        let zp = f64::from(z[p]);
        let (mut visits, mut posts) = (0u64, 0u64);
        let mut stack = vec![(self.levels.len() - 1, 0usize, 0usize)];
        while let Some((level, bx, by)) = stack.pop() {
            visits += 1;
            let size = 1i64 << level;
            let (c0, r0) = (bx as i64 * size, by as i64 * size);
            let c1 = (c0 + size - 1).min(w as i64 - 1);
            let r1 = (r0 + size - 1).min(self.h as i64 - 1);
            if level == 0 {
                if (c0, r0) == (pc, pr) {
                    continue;
                }
                posts += 1;
                let (e, nn) = ((c0 - pc) as f64, (pr - r0) as f64);
                let s = self.sector(azimuth(e, nn)).rem_euclid(n) as usize;
                let (ce, cn) = self.centres[s];
                let slope = (f64::from(z[r0 as usize * w + c0 as usize]) - zp)
                    / ((ce * e + cn * nn) * self.dx);
                best[s] = best[s].max(slope);
                continue;
            }
            let inside = (c0..=c1).contains(&pc) && (r0..=r1).contains(&pr);
            if !inside {
                let gap = |lo: i64, hi: i64, at: i64| (lo - at).max(at - hi).max(0) as f64;
                let far = |lo: i64, hi: i64, at: i64| (lo - at).abs().max((hi - at).abs()) as f64;
                let nearest = gap(c0, c1, pc).hypot(gap(r0, r1, pr)) * self.dx;
                let farthest = far(c0, c1, pc).hypot(far(r0, r1, pr)) * self.dx;
                let rise = f64::from(self.levels[level].1[by * self.levels[level].0 + bx]) - zp;
                // Along a centre line a post lies at least `half` as far as
                // it is; a margin keeps the bound above its rounding.
                let bound = if rise >= 0.0 {
                    rise / (nearest * half) * (1.0 + 1e-9)
                } else {
                    rise / farthest * (1.0 - 1e-9)
                };
                let mid = azimuth(
                    (c0 + c1) as f64 / 2.0 - pc as f64,
                    pr as f64 - (r0 + r1) as f64 / 2.0,
                );
                let (mut lo, mut hi) = (0.0f64, 0.0f64);
                for (x, y) in [(c0, r0), (c1, r0), (c0, r1), (c1, r1)] {
                    let off = (azimuth((x - pc) as f64, (pr - y) as f64) - mid + PI)
                        .rem_euclid(2.0 * PI)
                        - PI;
                    (lo, hi) = (lo.min(off), hi.max(off));
                }
                let spanned = self.sector(mid + lo - 1e-9)..=self.sector(mid + hi + 1e-9);
                let least = spanned
                    .map(|s| best[s.rem_euclid(n) as usize])
                    .fold(f64::INFINITY, f64::min);
                if bound <= least {
                    continue;
                }
            }
            let (across, rows) = (self.levels[level - 1].0, self.h.div_ceil(1 << (level - 1)));
            let mut kids: Vec<(i64, usize, usize)> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .into_iter()
                .map(|(i, j)| (2 * bx + i, 2 * by + j))
                .filter(|&(x, y)| x < across && y < rows)
                .map(|(x, y)| {
                    let (cx, cy) = ((2 * x as i64 + 1) * size / 4, (2 * y as i64 + 1) * size / 4);
                    ((cx - pc).pow(2) + (cy - pr).pow(2), x, y)
                })
                .collect();
            // Farthest pushed first: the nearest is searched first.
            kids.sort_by_key(|k| std::cmp::Reverse(k.0));
            stack.extend(kids.into_iter().map(|(_, x, y)| (level - 1, x, y)));
        }
        (best, visits, posts)
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let Some(dir) = args.get(1) else {
        return Err("usage: sector_pyramid_search ASSET [SECTORS] [SAMPLES]".into());
    };
    let sectors: usize = args.get(2).map_or(Ok(64), |s| s.parse())?;
    let samples: usize = args.get(3).map_or(Ok(2000), |s| s.parse())?;
    let asset = Asset::open(dir)?;
    let height = asset.height()?;
    let (w, h) = (height.width() as usize, height.height() as usize);
    let mut z = vec![0f32; w * h];
    height.read_window(0, 0, 0, w as u32, h as u32, &mut z)?;
    let dx = asset.manifest().cell_size.dx;
    let search = Search::new(z, (w, h), dx, sectors);
    let (mut cold, mut known) = ([0u64; 2], [0u64; 2]);
    let start = std::time::Instant::now();
    let picked: Vec<usize> = (0..w * h).step_by((w * h / samples).max(1)).collect();
    for &p in &picked {
        let (best, visits, posts) = search.run(p, vec![f64::NEG_INFINITY; sectors]);
        cold[0] += visits;
        cold[1] += posts;
        let hair = best.iter().map(|&b| b - 1e-12 * b.abs()).collect();
        let (again, visits, posts) = search.run(p, hair);
        assert_eq!(again, best, "the known answer is found again");
        known[0] += visits;
        known[1] += posts;
    }
    let n = picked.len() as f64;
    println!(
        "{} posts of {w} x {h}, {sectors} sectors ({:.1} s for both searches)",
        picked.len(),
        start.elapsed().as_secs_f64()
    );
    println!(
        "from nothing: {:.0} blocks visited and {:.0} posts examined a post",
        cold[0] as f64 / n,
        cold[1] as f64 / n
    );
    println!(
        "answer known: {:.0} blocks visited and {:.0} posts examined a post",
        known[0] as f64 / n,
        known[1] as f64 / n
    );
    Ok(())
}
