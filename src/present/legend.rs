//! Legends under map previews: what the map shows and in what unit, a
//! colour bar with the values at its ends and middle, and the stretch that
//! maps values to colours (which percentiles, and that values beyond them
//! are clipped), so that a map can be read without the command that made
//! it. Text is the public-domain 8 x 8 bitmap font of the `font8x8` crate,
//! scaled by whole pixels with the map's width.

/// A colour ramp: `t` in 0..1 to RGB.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ramp {
    /// Black to white (shaded maps: light is brightness).
    Gray,
    /// The hypsometric tint of relief previews (green lowlands to white peaks).
    Hypsometric,
    /// Viridis (van der Walt and Smith, matplotlib): perceptually uniform
    /// and readable to the colour-blind, for values that are not light.
    Viridis,
}

impl Ramp {
    pub fn colour(self, t: f32) -> [u8; 3] {
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        match self {
            Ramp::Gray => [(t * 255.0).round() as u8; 3],
            Ramp::Hypsometric => hypsometric(t).map(|c| c.round() as u8),
            Ramp::Viridis => {
                // Viridis sampled at ninths, linear between.
                const STOPS: [[f32; 3]; 9] = [
                    [68.0, 1.0, 84.0],
                    [71.0, 44.0, 122.0],
                    [59.0, 81.0, 139.0],
                    [44.0, 113.0, 142.0],
                    [33.0, 144.0, 141.0],
                    [39.0, 173.0, 129.0],
                    [92.0, 200.0, 99.0],
                    [170.0, 220.0, 50.0],
                    [253.0, 231.0, 37.0],
                ];
                let x = t * 8.0;
                let i = (x.floor() as usize).min(7);
                let f = x - i as f32;
                [0, 1, 2].map(|k| (STOPS[i][k] + f * (STOPS[i + 1][k] - STOPS[i][k])).round() as u8)
            }
        }
    }
}

/// How values map to positions `t` in 0..1 along a ramp: piecewise
/// linear through knots, the values at evenly spaced positions, clipped
/// beyond the first and the last. Two knots are a linear stretch; the
/// percentiles as knots equalise the histogram (every colour covers as many
/// posts), for maps whose values crowd at one end.
#[derive(Debug, Clone, PartialEq)]
pub struct Stretch {
    knots: Vec<f32>,
    /// How the knots were chosen, in words for the legend.
    pub note: String,
}

impl Stretch {
    /// From `lo` (t = 0) to `hi` (t = 1).
    pub fn linear(lo: f32, hi: f32, note: &str) -> Self {
        Self {
            knots: vec![lo, hi],
            note: note.into(),
        }
    }

    /// Linear from the 1st to the 99th percentile of the values that are
    /// not NaN (a sky-view factor's few pits would otherwise leave the rest
    /// of the map one colour); `None` when all are NaN.
    pub(crate) fn percentiles(values: Vec<f32>) -> Option<Self> {
        let p = sorted_percentiles(values)?;
        Some(Self::linear(
            p[1],
            p[99],
            "1st to 99th percentile, clipped beyond",
        ))
    }

    /// Equalised between the 1st and the 99th percentile: knots at every
    /// percentile between, so that the middle of the ramp is the median.
    pub(crate) fn equalised(values: Vec<f32>) -> Option<Self> {
        let p = sorted_percentiles(values)?;
        let mut knots = p[1..=99].to_vec();
        // Equal percentiles would divide by zero: keep knots increasing.
        for i in 1..knots.len() {
            knots[i] = knots[i].max(knots[i - 1]);
        }
        Some(Self {
            knots,
            note: "equalised between the 1st and 99th percentiles (the middle is the median)"
                .into(),
        })
    }

    /// The position of `v` on the ramp, 0..1 (NaN stays NaN).
    pub fn position(&self, v: f32) -> f32 {
        let k = &self.knots;
        let last = k.len() - 1;
        if v.is_nan() {
            return f32::NAN;
        }
        if v <= k[0] {
            return 0.0;
        }
        if v >= k[last] {
            return 1.0;
        }
        // The first knot above v; v lies between it and the one before.
        let i = k.partition_point(|&x| x <= v).clamp(1, last);
        let span = k[i] - k[i - 1];
        let f = if span > 0.0 {
            (v - k[i - 1]) / span
        } else {
            0.0
        };
        ((i - 1) as f32 + f) / last as f32
    }

    /// The value at position `t` in 0..1.
    pub(crate) fn value_at(&self, t: f32) -> f32 {
        let last = self.knots.len() - 1;
        let x = t.clamp(0.0, 1.0) * last as f32;
        let i = (x.floor() as usize).min(last.saturating_sub(1));
        let j = (i + 1).min(last);
        self.knots[i] + (x - i as f32) * (self.knots[j] - self.knots[i])
    }
}

/// The 0th to 100th percentiles of the values that are not NaN.
fn sorted_percentiles(mut values: Vec<f32>) -> Option<Vec<f32>> {
    values.retain(|v| !v.is_nan());
    if values.is_empty() {
        return None;
    }
    values.sort_unstable_by(f32::total_cmp);
    Some(
        (0..=100)
            .map(|p| values[(values.len() * p / 100).min(values.len() - 1)])
            .collect(),
    )
}

/// A hypsometric tint for t in 0..1 (lowland green, upland tan, peaks white).
pub(crate) fn hypsometric(t: f32) -> [f32; 3] {
    const STOPS: [(f32, [f32; 3]); 5] = [
        (0.0, [62.0, 128.0, 72.0]),
        (0.3, [150.0, 180.0, 100.0]),
        (0.6, [200.0, 170.0, 120.0]),
        (0.85, [150.0, 120.0, 100.0]),
        (1.0, [250.0, 250.0, 250.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    for pair in STOPS.windows(2) {
        let ((t0, c0), (t1, c1)) = (pair[0], pair[1]);
        if t <= t1 {
            let f = (t - t0) / (t1 - t0);
            return [0, 1, 2].map(|i| c0[i] + f * (c1[i] - c0[i]));
        }
    }
    STOPS[4].1
}

/// What a legend says.
#[derive(Debug, Clone)]
pub struct Legend {
    /// What the map shows, with its unit: "sky-view factor (0-1)".
    pub title: String,
    pub ramp: Ramp,
    /// How values map to the ramp; its note is the legend's last line.
    pub stretch: Stretch,
}

impl Legend {
    /// The colour of value `v` (NaN: the ramp's low end; callers draw
    /// nodata themselves).
    pub fn colour(&self, v: f32) -> [u8; 3] {
        self.ramp.colour(self.stretch.position(v))
    }
}

/// How many pixels a font pixel is for a map `width` wide.
fn text_scale(width: u32) -> u32 {
    (width / 500).clamp(1, 4)
}

/// The legend's height in pixels under a map `width` wide.
pub fn height(width: u32) -> u32 {
    // Padding, title, bar, labels, stretch, padding: in font pixels.
    text_scale(width) * (4 + 11 + 12 + 11 + 11 + 4)
}

/// Values with as many decimals as the range needs to tell its ends apart.
fn format_value(v: f32, span: f32) -> String {
    let decimals = if span > 0.0 {
        ((-span.log10()).ceil() as i32 + 1).clamp(0, 6) as usize
    } else {
        3
    };
    format!("{v:.decimals$}")
}

/// The legend's pixels, RGB, `width x height(width)`, row-major.
pub fn render(width: u32, legend: &Legend) -> Vec<[u8; 3]> {
    let s = text_scale(width);
    let (w, h) = (width as usize, height(width) as usize);
    let mut px = vec![[255u8; 3]; w * h];
    let pad = 4 * s;
    let mut text = |x: u32, y: u32, line: &str| draw_text(&mut px, w, h, x, y, s, line);
    text(pad, pad, &legend.title);
    // The bar.
    let (bar_x0, bar_x1) = (pad, width.saturating_sub(pad).max(pad + 1));
    let (bar_y0, bar_y1) = (pad + 11 * s, pad + 21 * s);
    for y in bar_y0..bar_y1.min(h as u32) {
        for x in bar_x0..bar_x1.min(width) {
            let t = (x - bar_x0) as f32 / (bar_x1 - bar_x0 - 1).max(1) as f32;
            px[y as usize * w + x as usize] = legend.ramp.colour(t);
        }
    }
    // Labels: the low end, the middle and the high end, under the bar.
    let stretch = &legend.stretch;
    let span = stretch.value_at(1.0) - stretch.value_at(0.0);
    let labels = [0.0, 0.5, 1.0].map(|t| format_value(stretch.value_at(t), span));
    let label_y = bar_y1 + 2 * s;
    let chars = |t: &str| t.chars().count() as u32 * 8 * s;
    let mid = (bar_x0 + bar_x1) / 2;
    draw_text(&mut px, w, h, bar_x0, label_y, s, &labels[0]);
    draw_text(
        &mut px,
        w,
        h,
        mid.saturating_sub(chars(&labels[1]) / 2),
        label_y,
        s,
        &labels[1],
    );
    draw_text(
        &mut px,
        w,
        h,
        bar_x1.saturating_sub(chars(&labels[2])),
        label_y,
        s,
        &labels[2],
    );
    draw_text(&mut px, w, h, pad, label_y + 11 * s, s, &stretch.note);
    px
}

/// Draws `line` in black with its top-left corner at `(x, y)`, each font
/// pixel `s x s`; what falls outside the image is left out.
fn draw_text(px: &mut [[u8; 3]], w: usize, h: usize, x: u32, y: u32, s: u32, line: &str) {
    for (i, ch) in line.chars().enumerate() {
        let glyph = font8x8::legacy::BASIC_LEGACY[if ch.is_ascii() {
            ch as usize
        } else {
            b'?' as usize
        }];
        let gx = x as usize + i * 8 * s as usize;
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits >> col & 1 == 0 {
                    continue;
                }
                for dy in 0..s as usize {
                    for dx in 0..s as usize {
                        let (px_x, px_y) = (
                            gx + col * s as usize + dx,
                            y as usize + row * s as usize + dy,
                        );
                        if px_x < w && px_y < h {
                            px[px_y * w + px_x] = [0, 0, 0];
                        }
                    }
                }
            }
        }
    }
}

/// Appends `legend` under an RGB map `width` pixels wide; returns the rows
/// it added.
pub fn append(rgb: &mut Vec<u8>, width: u32, legend: &Legend) -> u32 {
    rgb.extend(render(width, legend).into_iter().flatten());
    height(width)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramps_run_from_their_first_colour_to_their_last() {
        assert_eq!(Ramp::Gray.colour(0.0), [0, 0, 0]);
        assert_eq!(Ramp::Gray.colour(1.0), [255, 255, 255]);
        assert_eq!(Ramp::Viridis.colour(0.0), [68, 1, 84]);
        assert_eq!(Ramp::Viridis.colour(1.0), [253, 231, 37]);
        assert_eq!(Ramp::Viridis.colour(2.0), Ramp::Viridis.colour(1.0));
        assert_eq!(Ramp::Viridis.colour(f32::NAN), Ramp::Viridis.colour(0.0));
        // Viridis brightens monotonically (its point).
        let luma =
            |c: [u8; 3]| 0.3 * f32::from(c[0]) + 0.59 * f32::from(c[1]) + 0.11 * f32::from(c[2]);
        let l: Vec<f32> = (0..=100)
            .map(|i| luma(Ramp::Viridis.colour(i as f32 / 100.0)))
            .collect();
        assert!(l.windows(2).all(|p| p[1] >= p[0]), "{l:?}");
    }

    #[test]
    fn percentile_stretches_skip_nan_and_the_outer_percent() {
        let mut v: Vec<f32> = (0..1000).map(|i| i as f32).collect();
        v.extend([f32::NAN; 50]);
        v[0] = -1e9; // a pit, as a sky-view factor has
        let linear = Stretch::percentiles(v.clone()).unwrap();
        assert_eq!((linear.value_at(0.0), linear.value_at(1.0)), (10.0, 990.0));
        assert_eq!(linear.position(500.0), 0.5);
        assert_eq!(linear.position(-1e9), 0.0);
        assert!(linear.position(f32::NAN).is_nan());
        assert!(Stretch::percentiles(vec![f32::NAN]).is_none());
        // Equalised: position is the rank.
        let skewed: Vec<f32> = (0..1000).map(|i| (i as f32 / 1000.0).powi(8)).collect();
        let eq = Stretch::equalised(skewed.clone()).unwrap();
        for (i, &v) in skewed.iter().enumerate().skip(10).step_by(97).take(9) {
            let rank = (i as f32 / 1000.0 - 0.01) / 0.98;
            assert!(
                (eq.position(v) - rank).abs() < 0.01,
                "{i}: {} {rank}",
                eq.position(v)
            );
        }
        assert_eq!(eq.value_at(0.5), skewed[500]);
        // A constant map: the knots tie, and positions stay finite.
        let ties = Stretch::equalised(vec![1.0; 100]).unwrap();
        assert_eq!(ties.position(1.0), 0.0);
        assert_eq!(ties.position(2.0), 1.0);
    }

    #[test]
    fn labels_carry_the_decimals_the_range_needs() {
        assert_eq!(format_value(0.931, 0.067), "0.931");
        assert_eq!(format_value(1234.0, 2000.0), "1234");
        assert_eq!(format_value(12.3, 3.0), "12.3");
    }

    #[test]
    fn the_legend_shows_its_bar_and_its_text() {
        let legend = Legend {
            title: "sky-view factor (0-1)".into(),
            ramp: Ramp::Viridis,
            stretch: Stretch::linear(0.5, 1.0, "1st to 99th percentile"),
        };
        let px = render(600, &legend);
        assert_eq!(px.len(), 600 * height(600) as usize);
        // The bar's ends are the ramp's ends.
        let bar_row = (4 + 15) as usize;
        assert_eq!(px[bar_row * 600 + 4], Ramp::Viridis.colour(0.0));
        assert_eq!(px[bar_row * 600 + 595], Ramp::Viridis.colour(1.0));
        // Text is black ink on white: the title's row has some.
        let title_ink = (4..12)
            .flat_map(|y| &px[y * 600..y * 600 + 600])
            .filter(|p| **p == [0, 0, 0])
            .count();
        assert!(title_ink > 50, "{title_ink}");
    }
}
