//! The steepest point a horizon search has met, and what it keeps of that
//! point besides its slope: nothing, or the point's post or distance when
//! the distance to the horizon is asked (`--distance`). The searches are
//! generic over the tag, and `()` is zero-sized, so a search that keeps
//! nothing compiles to the plain maximum it was before distances existed
//! (one `maxsd`; a tag that is kept costs a branch or a blend per point).

/// What is kept of the steepest point: `()` nothing, `Option<X>` its `X`.
pub trait Tag<X>: Copy + Default {
    fn of(x: X) -> Self;
    /// The point's `X`, where the tag keeps one.
    fn get(self) -> Option<X>;
}

impl<X> Tag<X> for () {
    #[inline]
    fn of(_: X) -> Self {}
    #[inline]
    fn get(self) -> Option<X> {
        None
    }
}

impl<X: Copy> Tag<X> for Option<X> {
    #[inline]
    fn of(x: X) -> Self {
        Some(x)
    }
    #[inline]
    fn get(self) -> Option<X> {
        self
    }
}

/// The steepest slope met so far and the tag of the point it goes to
/// (`slope` is -inf and the tag empty until a point is met).
#[derive(Debug, Clone, Copy)]
pub struct Steepest<T> {
    pub slope: f64,
    pub tag: T,
}

impl<T: Copy + Default> Default for Steepest<T> {
    fn default() -> Self {
        Self {
            slope: f64::NEG_INFINITY,
            tag: T::default(),
        }
    }
}

impl<T: Copy + Default> Steepest<T> {
    /// Keeps `slope` if it is steeper: of equally steep points, the first
    /// taken stays. NaN-blind (`f64::max` adds NaN handling the searches
    /// never need).
    #[inline]
    pub fn take(&mut self, slope: f64, tag: T) {
        // Selects, not a branch: whether a point is steeper is a coin toss
        // the predictor loses, and a select stays one `maxsd` for `()`.
        let steeper = slope > self.slope;
        self.tag = if steeper { tag } else { self.tag };
        self.slope = if slope > self.slope {
            slope
        } else {
            self.slope
        };
    }

    /// [`Self::take`], where of equally steep points the last taken stays
    /// (a walk outwards that keeps the farther).
    #[inline]
    pub(crate) fn take_last(&mut self, slope: f64, tag: T) {
        let steeper = slope >= self.slope;
        self.slope = if steeper { slope } else { self.slope };
        self.tag = if steeper { tag } else { self.tag };
    }

    /// The steeper of two.
    #[inline]
    pub(crate) fn steeper(mut self, other: Self) -> Self {
        self.take(other.slope, other.tag);
        self
    }

    /// Whether any point was met.
    pub fn found(&self) -> bool {
        self.slope > f64::NEG_INFINITY
    }
}

/// A kept distance as the layer stores it: metres, NaN where none was kept.
pub fn metres<T: Tag<f64>>(tag: T) -> f32 {
    tag.get().map_or(f32::NAN, |d| d as f32)
}
