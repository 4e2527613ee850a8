//! The cached nearest-neighbour matches of ICP: per source point the last query's answer and
//! how far the point may move before that answer can change (an exact skip test), and the
//! passes (subsets of the source points matched together) that hold them.

use crate::point::Point;
use crate::registration::target::NO_MATCH;

/// A nearest-neighbour match of one source point: the transformed source point and what the
/// last kd-tree query for it found, so that later iterations can skip the query when it
/// cannot have changed.
///
/// Exact skip test: the last query at position q found the nearest target at distance d₁ and
/// the second nearest at d₂. If the point has since moved by δ = |T·p − q|, every other target
/// is at least d₂ − δ away and the old nearest at most d₁ + δ, so it is still the nearest when
/// 2δ < d₂ − d₁. Late ICP iterations move points by far less than the gap, so most queries
/// become one 3×4 product.
/// The moved point T·p itself is not kept (24 bytes a point): rows and the solver recompute it
/// from the pass's copy of p, bit for bit.
/// 8 bytes a source point (the margin and the history index in 16 bits each).
#[derive(Clone, Copy)]
pub(super) struct Match {
    /// Nearest target at the last query.
    pub(super) nearest: u32,
    /// `history` index of the transform of the last query (NEVER_QUERIED: none).
    pub(super) queried_at: u16,
    /// d₂ − d₁ at the last query, rounded down.
    pub(super) margin: Margin,
}

/// The history is cleared (every cached query dropped) when it reaches this many transforms.
pub(super) const NEVER_QUERIED: u16 = u16::MAX;

/// A non-negative distance in 16 bits: the upper half of its f32 (8 bits of mantissa, the
/// full exponent range), rounded towards zero, so never above the distance it stands for and
/// the skip test stays exact. Within 0.8 % below: a few more queries, no other change.
#[derive(Clone, Copy)]
pub(super) struct Margin(u16);

impl Margin {
    /// "Query again".
    pub(super) const ZERO: Margin = Margin(0);

    /// The largest margin at most `distance` (≥ 0; ∞ and values beyond f32 give f32::MAX's).
    pub(super) fn at_most(distance: f64) -> Margin {
        let narrowed = if distance.is_finite() {
            // Rounded to nearest, so possibly up by 6e-8 relative: callers leave room for it.
            (distance as f32).clamp(0.0, f32::MAX)
        } else {
            f32::MAX
        };
        Margin((narrowed.to_bits() >> 16) as u16)
    }

    pub(super) fn get(self) -> f64 {
        f64::from(f32::from_bits(u32::from(self.0) << 16))
    }
}

/// Source points matched together, in curve order, with their cached queries.
#[derive(Default)]
pub(super) struct Pass {
    /// The source points' indices (the caller's), in curve order.
    pub(super) order: Vec<u32>,
    /// `source[order[k]]`: a copy in pass order, so each iteration reads the points
    /// sequentially instead of once per cache line at random (1 M points: 24 MB).
    pub(super) points: Vec<Point>,
    /// Allocated at the pass's first matching: the everything pass of a sampled source is
    /// built while the caller's source still exists, and its 8 bytes a point would otherwise
    /// add to that moment's peak (at 10 M points, the registration's peak).
    pub(super) matches: Vec<Match>,
}

impl Pass {
    pub(super) fn new(source: &[Point], order: Vec<u32>) -> Self {
        let points = order.iter().map(|&i| source[i as usize]).collect();
        Pass {
            order,
            points,
            matches: Vec::new(),
        }
    }
}

impl Match {
    pub(super) const EMPTY: Match = Match {
        nearest: NO_MATCH,
        queried_at: NEVER_QUERIED,
        margin: Margin::ZERO,
    };
}
