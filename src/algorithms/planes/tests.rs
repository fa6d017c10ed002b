use super::*;

/// A floor never exceeds the distance it stands for: exact squares
/// (where the square root rounds to the integer) and the numbers just
/// below them, at several spacings, and saturation far away.
#[test]
fn floors_stay_below_their_distances() {
    for spacing in [1.0, 0.3, 30.0, 92.6] {
        let floor = Floor::new(spacing);
        for i in 0..20_000u32 {
            let d = f64::from(i) * floor.unit;
            for d2 in [d * d, (d * d).next_down(), d * d + 0.5] {
                if d2 >= 0.0 {
                    let f = floor.of(d2);
                    assert!(
                        f64::from(f) * floor.unit <= d2.sqrt(),
                        "{spacing}: {d2} -> {f}"
                    );
                }
            }
        }
        assert_eq!(floor.of(1e300), u16::MAX);
        assert_eq!(floor.of(0.0), 0);
    }
}

/// Marsaglia's xorshift: the tests' random rows, the same on every run.
fn xorshift(mut seed: u64) -> impl FnMut() -> u64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    }
}

/// The open-cell scan over a row through a whole bake's slices (the
/// top slice, then bottom-up), in every kind of lanes the CPU has and
/// one cell at a time, each with its own wakes: at every slice both find exactly the cells the
/// definition names (open cones wider than their floors) and the
/// widest of them, bit for bit, while the blocks whose wake has not
/// come are not read. Between slices only the cells found change, as in
/// the stage: their slopes narrow and their floors move anywhere, often
/// far enough to close them for many slices.
#[test]
fn open_cells_with_wakes_are_the_definition() {
    let mut next = xorshift(0x2545_f491_4f6c_dd1d);
    let k_count = 24usize;
    let slices = Slices::uniform(100.0, 100.0 + 3.5 * (k_count - 1) as f64, k_count);
    let unit = 0.75;
    let (mut slept, mut blocks_seen) = (0u64, 0u64);
    for len in (0..40).chain([1000, 4099]) {
        let mut member: Vec<u16> = (0..len)
            .map(|_| (next() % (k_count as u64 + 1)) as u16)
            .collect();
        // A few cells with no surface around them: in every slice.
        member
            .iter_mut()
            .step_by(13)
            .for_each(|m| *m = k_count as u16);
        let mut slope: Vec<f32> = (0..len)
            .map(|_| match next() % 9 {
                0 => 0.0,
                1 => (next() % 10_000) as f32 / 7.0,
                _ => f32::INFINITY,
            })
            .collect();
        let mut floor = vec![0u16; len];
        // Each kind of lanes with its own wakes and room.
        let kinds = crate::plumbing::simd::available();
        let mut wakes = vec![vec![0u16; len.div_ceil(BLOCK)]; kinds.len()];
        let mut rooms = vec![Vec::new(); kinds.len()];
        for k in std::iter::once(k_count - 1).chain(0..k_count - 1) {
            let rise_of = slices.rise_of(k);
            let width = |c: usize| f64::from(slope[c]) * rise_of[usize::from(member[c])];
            let open: Vec<u32> = (0..len as u32)
                .filter(|&c| {
                    width(c as usize) > 0.0
                        && width(c as usize) > f64::from(floor[c as usize]) * unit
                })
                .collect();
            let widest = open.iter().map(|&c| width(c as usize)).fold(0.0, f64::max);
            for ((&lanes, wakes), room) in kinds.iter().zip(&mut wakes).zip(&mut rooms) {
                let scan = Scan {
                    lanes,
                    ..Scan::new(&slices, k, unit, &rise_of)
                };
                let blocks = wakes.len() as u64;
                let found = open_cells(&member, &slope, &floor, scan, wakes, room);
                (blocks_seen, slept) = (blocks_seen + blocks, slept + blocks - found.blocks_read);
                assert_eq!(found.targets, open, "{lanes:?}, {len} cells, slice {k}");
                assert_eq!(
                    found.reach.to_bits(),
                    widest.to_bits(),
                    "{lanes:?}, {len} cells, slice {k}"
                );
            }
            // The stage's update of the cells found: a narrower cone, and a
            // floor anywhere up to the cone's width some slices above.
            for &c in &open {
                let c = c as usize;
                if next().is_multiple_of(2) {
                    slope[c] = slope[c].min((next() % 4_000) as f32 / 9.0);
                }
                let ahead = (k + 1 + (next() % 6) as usize).min(k_count - 1);
                let far = f64::from(slope[c])
                    * (slices.z[ahead] - slices.z[usize::from(member[c])]).max(0.0);
                floor[c] = (far.min(40_000.0) / unit * (next() % 1000) as f64 / 999.0) as u16;
            }
        }
    }
    // The wakes did leave blocks out (a fifth here), so the equalities
    // above held with blocks unread.
    assert!(
        slept * 10 > blocks_seen,
        "{slept} of {blocks_seen} blocks asleep"
    );
}

/// Column distances found band by band (the bands' ends, the carries
/// walked from them, then each band's own rows) are each cell's
/// distance to the nearest plane cell of its column: on grids of one
/// band, of several, and with a last band cut short; for dense and
/// sparse planes and none; in both widths and from both kinds of apex
/// slices.
#[test]
fn band_columns_are_the_column_distances() {
    fn by_bands<G: ColumnDistance>(plane: Plane, (cw, ch): (usize, usize)) -> Vec<f64> {
        let mut ends: BandEnds = PerBand::new((cw, ch), NO_ROW);
        ends.find(plane);
        let mut carries: BandCarries<G> = PerBand::new((cw, ch), G::NONE);
        carries.walk(&ends);
        let none = |g: &G| {
            if *g == G::NONE {
                f64::INFINITY
            } else {
                g.cells()
            }
        };
        let (mut down, mut column, mut all) = (Vec::new(), Vec::new(), Vec::new());
        for b in 0..ch.div_ceil(BAND) {
            plane.band_columns(b, (cw, ch), carries.of(b), &mut down, &mut column);
            all.extend(column.iter().map(none));
        }
        all
    }
    let mut next = xorshift(0x2545_f491_4f6c_dd1d);
    for (cw, ch) in [(1, 1), (5, 31), (3, 32), (7, 33), (4, 100), (2, 200)] {
        let member: Vec<u16> = (0..cw * ch).map(|_| (next() % 600) as u16).collect();
        let member_u8: Vec<u8> = member.iter().map(|&m| m.min(255) as u8).collect();
        for k in [0, 100, 254, 300, 590, 599] {
            let want: Vec<f64> = (0..cw * ch)
                .map(|i| {
                    let (r, c) = (i / cw, i % cw);
                    (0..ch)
                        .filter(|&q| member[q * cw + c] > k as u16)
                        .map(|q| r.abs_diff(q) as f64)
                        .fold(f64::INFINITY, f64::min)
                })
                .collect();
            let plane = Plane::new(&member, &member_u8, k);
            assert_eq!(
                by_bands::<u16>(plane, (cw, ch)),
                want,
                "{cw} x {ch}, k = {k}"
            );
            assert_eq!(
                by_bands::<u32>(plane, (cw, ch)),
                want,
                "{cw} x {ch}, k = {k}"
            );
            // Below slice 255 also from the two-byte apex slices.
            let wide = Plane::Wide(&member, k as u16);
            assert_eq!(
                by_bands::<u16>(wide, (cw, ch)),
                want,
                "{cw} x {ch}, k = {k}"
            );
        }
    }
}

/// A row's kept columns are those the definition names (a column
/// distance, and its parabola within the reach of the targets' span),
/// with their offsets, less plane cells whose neighbours in the row
/// are within [`Span::hidden`] (some of those kept: the ends of a
/// share), in every kind of `u16` lanes the CPU has and one `u32` at a
/// time alike.
#[test]
fn columns_in_reach_are_the_definition() {
    let mut next = xorshift(0x9e37_79b9_7f4a_7c15);
    // A row's distances in both widths (u16 in lanes, u32 one at a
    // time).
    fn case<G: ColumnDistance + TryFrom<u64>>(
        row: &[u64],
        span: (u32, u32),
        reach: f64,
        aspect: f64,
        lanes: Level,
    ) -> Vec<(u32, f64)> {
        let column: Vec<G> = row
            .iter()
            .map(|&g| G::try_from(g).unwrap_or(G::NONE))
            .collect();
        let mut kept = Kept::default();
        let scale = (reach, aspect, Span::hidden(aspect));
        let n = columns_in_reach(&column, span, scale, lanes, &mut kept);
        kept.columns[..n]
            .iter()
            .copied()
            .zip(kept.offsets[..n].iter().copied())
            .collect()
    }
    let mut hidden_left_out = 0;
    for cw in [1, 7, 64, 65, 200, 517] {
        let ch = 3;
        // Column distances: none, zero (often in runs, as in a plane),
        // one, or up to a few hundred cells.
        let g_of: Vec<u64> = (0..cw * ch)
            .map(|_| match next() % 6 {
                0 => u64::MAX,
                1..=3 => 0,
                4 => 1,
                _ => next() % 300,
            })
            .collect();
        for _ in 0..40 {
            let r = (next() % ch as u64) as usize;
            let first = (next() % cw as u64) as u32;
            let last = first + (next() % (cw as u64 - u64::from(first))) as u32;
            let reach = match next() % 4 {
                0 => f64::INFINITY,
                _ => (next() % 400_000) as f64 / 1000.0,
            };
            let aspect = [1.0, 0.75, 1.3][(next() % 3) as usize];
            let want: Vec<(u32, f64)> = (0..cw as u32)
                .filter_map(|c| {
                    let g = g_of[r * cw + c as usize];
                    let along = f64::from(first.saturating_sub(c).max(c.saturating_sub(last)));
                    let gd = g as f64 * aspect;
                    (g != u64::MAX && gd * gd + along * along < reach * reach * (1.0 + 1e-12))
                        .then_some((c, gd * gd))
                })
                .collect();
            let row = &g_of[r * cw..(r + 1) * cw];
            let args = ((first, last), reach, aspect);
            let got = case::<u32>(row, args.0, args.1, args.2, crate::plumbing::simd::level());
            // Hidden: a plane cell whose neighbours' offsets are at
            // most 1.
            let near = |c: usize| {
                let d = g_of[r * cw + c] as f64 * aspect;
                d * d <= 1.0
            };
            let is_hidden = |c: usize| {
                g_of[r * cw + c] == 0 && c > 0 && c + 1 < cw && near(c - 1) && near(c + 1)
            };
            let mut kept = got.iter().peekable();
            for &(c, offset) in &want {
                if kept.next_if(|k| **k == (c, offset)).is_none() {
                    assert!(is_hidden(c as usize), "column {c} left out, {cw} columns");
                    hidden_left_out += 1;
                }
            }
            assert!(
                kept.next().is_none(),
                "a column kept against the definition"
            );
            for lanes in crate::plumbing::simd::available() {
                assert_eq!(
                    case::<u16>(row, args.0, args.1, args.2, lanes),
                    got,
                    "u16, {lanes:?}, {cw} columns"
                );
            }
        }
    }
    assert!(
        hidden_left_out > 100,
        "{hidden_left_out} hidden columns left out"
    );
}
