use super::*;

/// The bucket sort gives `sort_unstable`'s order: keys from a grid
/// direction (evenly spread), a diagonal (hundreds to a key), one key
/// for all, and keys that cross zero and span binades.
#[test]
fn the_bucket_sort_sorts_as_sort_unstable() {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut random = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let keys: [&dyn Fn(usize, usize) -> f64; 4] = [
        &|col, row| 0.3 * col as f64 - 0.95 * row as f64,
        &|col, row| col as f64 - row as f64,
        &|_, _| 2.5,
        &|col, row| (col as f64 - 20.0) * 1e-3 * 10f64.powi(row as i32 % 9),
    ];
    for key in keys {
        let keyed: Vec<[u64; 3]> = (0..40 * 30)
            .map(|i| {
                let (col, row) = (i % 40, i / 40);
                [ordered(key(col, row) + 0.0), random() % 4, i as u64]
            })
            .collect();
        let mut expected = keyed.clone();
        expected.sort_unstable();
        // Into whatever the room held before.
        let mut sorted = vec![[7; 3]; keyed.len()];
        sort_keyed(&keyed, &mut sorted);
        assert_eq!(sorted, expected);
    }
    sort_keyed(&[], &mut []);
}

/// A sector that finds the room held by another sorts in room of its
/// own (not waiting), with the same ranks.
#[test]
fn a_held_room_is_not_waited_for() {
    let z: Vec<f32> = (0..30 * 20).map(|i| ((i * 37) % 101) as f32).collect();
    let t = Terrain::new(&z, 30, 20, 30.0, 25.0);
    let posts = DataPosts::of(&t);
    let room = Scratch::default();
    let want = Ranks::of(&t, &posts, (3, 16));
    let held = room.take().expect("a new room is free");
    let got = Ranks::of_in(&t, &posts, (3, 16), &room);
    drop(held);
    assert_eq!((got.sorted, got.ties), (want.sorted, want.ties));
    assert!(room.take().is_some(), "the room is free again");
}

/// Opposite sectors' boundaries are each other's negated to the bit,
/// the last sector's counter-clockwise boundary is sector 0's
/// clockwise one, and so a sector's ranks read backwards are the
/// opposite sector's as sorted, ties and all: on grids with holes,
/// square and not, for counts whose boundaries fall on the diagonals
/// (4, 8) and counts whose boundaries do not.
#[test]
fn opposite_sectors_rank_in_reverse() {
    let (w, h) = (23, 19);
    let z: Vec<f32> = (0..w * h)
        .map(|i| {
            if i % 17 == 5 {
                f32::NAN
            } else {
                ((i * 37) % 101) as f32
            }
        })
        .collect();
    for (dx, dy) in [(30.0, 30.0), (30.0, 25.0), (21.7, 30.9)] {
        let t = Terrain::new(&z, w, h, dx, dy);
        let posts = DataPosts::of(&t);
        for count in [4, 6, 8, 16, 64, 90] {
            let frame = |i| SectorFrame::new(i, count, dx, dy);
            assert_eq!(frame(count - 1).hi, frame(0).lo, "{count} sectors");
            for index in 0..count {
                let (f, o) = (frame(index), frame((index + count / 2) % count));
                let bits = |(e, n): (f64, f64)| (e.to_bits(), n.to_bits());
                assert_eq!(bits(o.lo), bits(opposite(f.lo)), "{index}/{count}");
                assert_eq!(bits(o.hi), bits(opposite(f.hi)), "{index}/{count}");
                let want = Ranks::of(&t, &posts, ((index + count / 2) % count, count));
                let got = Ranks::of(&t, &posts, (index, count)).opposite().unwrap();
                assert_eq!(got.sector(), want.sector());
                assert_eq!(got.in_order(), want.in_order(), "{index}/{count} {dx}x{dy}");
                assert_eq!(
                    got.following(),
                    want.following(),
                    "{index}/{count} {dx}x{dy}"
                );
            }
        }
    }
    let t = Terrain::new(&z, w, h, 30.0, 30.0);
    let odd = Ranks::of(&t, &DataPosts::of(&t), (2, 7));
    assert!(
        odd.opposite().is_none(),
        "an odd count has no opposite sectors"
    );
}

#[test]
fn frames_snap_diagonals() {
    let f = SectorFrame::new(0, 4, 1.0, 1.0);
    assert_eq!(f.lo, (-1.0, 1.0));
    assert_eq!(f.hi, (1.0, 1.0));
    let z = [0f32; 100];
    let t = Terrain::new(&z, 10, 10, 1.0, 1.0);
    let keys = |col, row| f.keys(t.key_position(col, row));
    // The post one up and one right of (5, 5) is on the hi boundary.
    let (p, q) = (keys(5, 5), keys(6, 4));
    assert!(SectorFrame::contains(&p, &q));
    // ... and so is the one up-left; the ones behind are not.
    assert!(SectorFrame::contains(&p, &keys(4, 4)));
    assert!(!SectorFrame::contains(&p, &keys(4, 6)));
    assert!(!SectorFrame::contains(&p, &keys(5, 5)));
}
