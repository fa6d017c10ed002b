//! The posts a horizon layer lists as features
//! (`terrabake_format::features`): those that rise highest above the eight
//! posts around them. Such a post is a narrow wedge of every horizon it
//! sets, which bands between its azimuths miss; the loader serves its exact
//! horizon instead. The choice only decides what the loader looks at: any
//! set of posts is served exactly, so a larger list costs query time, never
//! accuracy.

use terrabake_format::features::FeaturePost;

use crate::terrain::Terrain;

/// A post and how far (metres) it rises above the highest of its eight
/// neighbours.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spike {
    pub rise: f32,
    pub post: FeaturePost,
}

/// The post `(x, y)` of `t` as a [`Spike`], when it is an inner post whose
/// eight neighbours have heights (so that the four cells around it have a
/// surface) and it rises above every one of them.
pub fn spike_at(t: &Terrain, x: usize, y: usize) -> Option<Spike> {
    if x == 0 || y == 0 || x + 1 >= t.width || y + 1 >= t.height {
        return None;
    }
    let c = t.at(x, y);
    let mut highest = f32::NEG_INFINITY;
    for (i, j) in [
        (-1, -1),
        (0, -1),
        (1, -1),
        (-1, 0),
        (1, 0),
        (-1, 1),
        (0, 1),
        (1, 1),
    ] {
        let z = t.at((x as i64 + i) as usize, (y as i64 + j) as usize);
        if z.is_nan() {
            return None;
        }
        highest = highest.max(z);
    }
    (c > highest).then(|| Spike {
        rise: c - highest,
        post: FeaturePost {
            x: x as u32,
            y: y as u32,
            z: [
                c,
                t.at(x - 1, y),
                t.at(x + 1, y),
                t.at(x, y - 1),
                t.at(x, y + 1),
                t.at(x - 1, y + 1),
                t.at(x + 1, y - 1),
            ],
        },
    })
}

/// The spikes among rows `rows` of `t` (which holds them and the rows
/// either side that exist) rising at least `min_rise` metres, added to
/// `found`, which keeps the `count` highest-rising ([`keep_highest`]).
pub fn spikes_in_rows(
    t: &Terrain,
    rows: std::ops::Range<usize>,
    min_rise: f32,
    count: usize,
    found: &mut Vec<Spike>,
) {
    for y in rows {
        found.extend(
            (0..t.width)
                .filter_map(|x| spike_at(t, x, y))
                .filter(|s| s.rise >= min_rise),
        );
        if found.len() > 2 * count.max(1024) {
            keep_highest(found, count);
        }
    }
    keep_highest(found, count);
}

/// Keeps the `count` highest-rising spikes, the highest first (ties in
/// row-major order, so that the list does not depend on how rows were
/// visited).
pub fn keep_highest(spikes: &mut Vec<Spike>, count: usize) {
    spikes.sort_by(|a, b| {
        b.rise
            .total_cmp(&a.rise)
            .then((a.post.y, a.post.x).cmp(&(b.post.y, b.post.x)))
    });
    spikes.truncate(count);
}
