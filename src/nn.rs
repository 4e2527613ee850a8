//! Exact nearest-neighbour search on a fixed cloud: a thin wrapper over a kiddo k-d tree
//! (the only place that names kiddo, so a version bump touches one file).
//!
//! Coordinates are stored as f64: f32 gains a few percent, which does not pay for re-sorting by
//! exact distance. Leaves use kiddo's flat layout (`FlatVec`, Eytzinger stems, 32-point
//! buckets): twice as fast for nearest-one on surface clouds as the arena layout, same cost
//! otherwise. The measurements: see docs/performance.md, "Design measurements behind the code".
use std::num::NonZeroUsize;

use kiddo::SquaredEuclidean;
use kiddo::kd_tree::KdTree;
use kiddo::leaf_strategies::FlatVec;
use kiddo::stem_strategies::Eytzinger;

/// Points per leaf bucket (kiddo's default).
const BUCKET: usize = 32;
type Tree = KdTree<f64, u32, Eytzinger, FlatVec<f64, u32, 3, BUCKET>, 3, BUCKET>;

use crate::error::Error;
use crate::memory::{MemoryError, try_vec};
use crate::point::Point;

/// Clouds whose largest coordinate magnitude lies in [2^-64, 2^64] are indexed as given; others
/// are scaled by a power of two (exact) to bring it to [0.5, 1). Squared distances then never
/// overflow (coordinates ~1e160) or underflow (~1e-160) inside the tree, which would make every
/// distance inf or 0 and the search answer nothing or anything.
const UNSCALED_MAX_EXPONENT: i32 = 64;
/// A query farther than this from the origin (in the tree's coordinates) is moved towards the
/// origin along its ray onto this distance before searching: its squared distances would
/// overflow otherwise. The data lie within 2^64 of the origin, so for such a query the nearest
/// point is decided by the direction alone to well below f64 resolution (the distances differ
/// by less than 2^-400 relative), and the distance reported is the query's own length.
const FAR_QUERY: f64 = 3.273_390_607_896_142e150; // 2^500
/// A cloud whose largest coordinate is more than 2^SPAN_EXPONENTS times its typical one
/// (garbage points far out among measurements) cannot be scaled by its largest coordinate: the
/// typical points' squared distances would underflow to 0 and every match among them would be
/// arbitrary. Such a cloud is scaled by its typical magnitude instead, and the far points are
/// held clamped to ±FAR_QUERY per coordinate: no query near the cloud can have them nearest,
/// and a query out there is moved onto FAR_QUERY anyway.
const SPAN_EXPONENTS: i32 = 400;

/// k-d tree over a cloud; query results are indices into the slice it was built from.
///
/// Robust to the inputs that defeat a plain kd-tree:
/// * exact duplicates (depth frames mark invalid pixels 0 0 0; 30 % of a 640×480 frame): each
///   location is indexed once, so ties between identical points cannot make a query visit
///   every copy (quadratic time); queries still answer over all points, and the index
///   reported for a duplicated location is its lowest;
/// * coordinates whose squares overflow or underflow (beyond 2^±64 the tree holds them
///   scaled by a power of two);
/// * queries that are not finite (no neighbour) or astronomically far (beyond 2^500 from the
///   origin: searched from that distance along the query's ray).
pub struct NearestNeighbours {
    /// Built on the distinct locations, items are location ids (see `locations`).
    tree: Tree,
    len: usize,
    /// Tree coordinates = input coordinates × scale (a power of two, 1 for ordinary clouds).
    scale: f64,
    /// Tree coordinates are clamped to ±FAR_QUERY (see [`SPAN_EXPONENTS`]).
    clamped: bool,
    /// Which input points sit at each tree location; `None` when all are distinct (the tree's
    /// items are then the input indices themselves).
    locations: Option<Locations>,
}

/// The input indices at each distinct location, in ascending order:
/// `members[offsets[l]..offsets[l + 1]]` for location l.
pub(crate) struct Locations {
    offsets: Vec<u32>,
    members: Vec<u32>,
}

impl Locations {
    /// The input indices at `location`, ascending (the first is its first appearance).
    pub(crate) fn of(&self, location: u32) -> &[u32] {
        let l = location as usize;
        &self.members[self.offsets[l] as usize..self.offsets[l + 1] as usize]
    }

    /// Number of distinct locations.
    pub(crate) fn count(&self) -> usize {
        self.offsets.len() - 1
    }
}

/// A query as the tree sees it.
enum Query {
    /// A coordinate is NaN or infinite: no point is nearest.
    NonFinite,
    /// In tree coordinates; `far_distance` is the true distance to report when the query was
    /// moved in from beyond [`FAR_QUERY`].
    Tree { point: Point, far_distance: Option<f64> },
}

impl NearestNeighbours {
    /// Builds the tree on the caller's thread (kiddo's parallel construction needs its rayon
    /// feature, which we leave off; see src/parallel.rs).
    ///
    /// Errors: more than `u32::MAX` points (kiddo stores u32 indices) or a kiddo construction
    /// error ([`Error::InvalidArgument`]), a non-finite coordinate (it would corrupt the tree's
    /// splits; [`Error::NonFinite`]), no memory for the duplicate table ([`Error::OutOfMemory`]).
    pub fn new(points: &[Point]) -> Result<Self, Error> {
        Self::build(points, true)
    }

    /// [`NearestNeighbours::new`] on points the caller has already made distinct (a prepared
    /// target): the duplicate table's pass is skipped.
    pub(crate) fn of_distinct(points: &[Point]) -> Result<Self, Error> {
        Self::build(points, false)
    }

    fn build(points: &[Point], may_repeat: bool) -> Result<Self, Error> {
        if points.len() > u32::MAX as usize {
            return Err(Error::InvalidArgument(format!(
                "nearest-neighbour index: {} points exceed the limit of {}",
                points.len(),
                u32::MAX
            )));
        }
        if let Some(bad) = points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
            return Err(Error::NonFinite(format!(
                "nearest-neighbour index: points[{bad}] has a non-finite coordinate {:?}",
                points[bad]
            )));
        }
        let TreeFrame { scale, clamped } = tree_frame(points);
        let in_tree = move |p: &Point, axis: usize| {
            let c = p[axis] * scale;
            if clamped {
                c.clamp(-FAR_QUERY, FAR_QUERY)
            } else {
                c
            }
        };
        let locations = if may_repeat {
            distinct_locations(points)?
        } else {
            None
        };
        let builder = Tree::builder().with_serial_construction();
        let tree = match &locations {
            None if scale == 1.0 && !clamped => builder.build_from_slice(points),
            None => builder.build_from_source(points, in_tree, |i, _| i as u32),
            Some(locations) => {
                // The first member of each location stands for it.
                let first = |l: usize| points[locations.members[locations.offsets[l] as usize] as usize];
                let count = locations.offsets.len() - 1;
                let mut representatives: Vec<Point> = try_with_capacity(count)?;
                representatives.extend((0..count).map(first));
                builder.build_from_source(&representatives, in_tree, |l, _| l as u32)
            }
        }
        .map_err(|e| Error::InvalidArgument(format!("nearest-neighbour index: {e}")))?;
        Ok(NearestNeighbours {
            tree,
            len: points.len(),
            scale,
            clamped,
            locations,
        })
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the index holds no point.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Number of distinct locations the tree holds (`len()` minus the exact duplicates).
    pub fn distinct_len(&self) -> usize {
        self.locations.as_ref().map_or(self.len, |l| l.offsets.len() - 1)
    }

    fn to_tree(&self, query: &Point) -> Query {
        if query.iter().any(|c| !c.is_finite()) {
            return Query::NonFinite;
        }
        let magnitude = query.iter().fold(0.0f64, |m, c| m.max(c.abs()));
        if magnitude * self.scale <= FAR_QUERY {
            return Query::Tree {
                point: query.map(|c| c * self.scale),
                far_distance: None,
            };
        }
        // magnitude > 0 here; FAR_QUERY / magnitude cannot overflow.
        let shrink = FAR_QUERY / magnitude;
        Query::Tree {
            point: query.map(|c| c * shrink),
            far_distance: Some(length_without_overflow(query, magnitude)),
        }
    }

    /// Input index of the first point at a tree item.
    fn first_index(&self, item: u32) -> usize {
        match &self.locations {
            None => item as usize,
            Some(locations) => locations.of(item)[0] as usize,
        }
    }

    fn multiplicity(&self, item: u32) -> usize {
        self.locations.as_ref().map_or(1, |l| l.of(item).len())
    }

    /// A tree distance (squared, tree units) in input units, not squared.
    fn input_distance(&self, squared: f64) -> f64 {
        squared.sqrt() / self.scale
    }

    /// Index of the nearest point and its squared distance. On an empty index:
    /// `(usize::MAX, ∞)`; for a query with a NaN or infinite coordinate: `(usize::MAX, NaN)`.
    pub fn nearest_one(&self, query: &Point) -> (usize, f64) {
        if self.is_empty() {
            return (usize::MAX, f64::INFINITY);
        }
        let Query::Tree { point, far_distance } = self.to_tree(query) else {
            return (usize::MAX, f64::NAN);
        };
        let nearest = self
            .tree
            .query(&point)
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        let squared = match far_distance {
            Some(distance) => distance * distance,
            // Exact: the scale is a power of two.
            None => nearest.distance / self.scale / self.scale,
        };
        (self.first_index(nearest.item), squared)
    }

    /// Index of the nearest point and the distances (not squared) to the nearest and the second
    /// nearest (∞ when there is only one point; equal when the nearest location holds
    /// duplicates). On an empty index: `(usize::MAX, ∞, ∞)`; for a query with a NaN or
    /// infinite coordinate: `(usize::MAX, NaN, NaN)`.
    pub fn nearest_two(&self, query: &Point) -> (usize, f64, f64) {
        if self.is_empty() {
            return (usize::MAX, f64::INFINITY, f64::INFINITY);
        }
        let Query::Tree { point, far_distance } = self.to_tree(query) else {
            return (usize::MAX, f64::NAN, f64::NAN);
        };
        let found = self
            .tree
            .query(&point)
            .nearest_n::<SquaredEuclidean<f64>>(NonZeroUsize::MIN.saturating_add(1))
            .execute();
        // Tree distances are finite (scaled data, bounded query), so the first is always there.
        let Some(first) = found.first() else {
            return (usize::MAX, f64::NAN, f64::NAN);
        };
        let distance = |squared: f64| far_distance.unwrap_or_else(|| self.input_distance(squared));
        let nearest = distance(first.distance);
        // Out where clamped points may be nearest, their distances are not the true ones: no
        // margin is claimed there (the caller queries again).
        let near_clamped = self.clamped && first.distance >= (0.5 * FAR_QUERY) * (0.5 * FAR_QUERY);
        let second = if self.multiplicity(first.item) > 1 || near_clamped {
            nearest
        } else {
            found.get(1).map_or(f64::INFINITY, |r| distance(r.distance))
        };
        (self.first_index(first.item), nearest, second)
    }

    /// Replaces `out` with the indices of the `min(k, len)` nearest points in ascending
    /// distance (a point identical to `query` is included; ties in any order). Empty for a
    /// query with a NaN or infinite coordinate.
    pub fn nearest_k(&self, query: &Point, k: usize, out: &mut Vec<usize>) {
        out.clear();
        let Some(k) = NonZeroUsize::new(k.min(self.len)) else {
            return;
        };
        let Query::Tree { point, .. } = self.to_tree(query) else {
            return;
        };
        // k locations hold at least k points. kiddo 6 returns a fresh Vec per query; its
        // `with_scratch` path only reuses the traversal stack and is no faster (see
        // docs/performance.md).
        let wanted = k.min(NonZeroUsize::new(self.distinct_len()).unwrap_or(NonZeroUsize::MIN));
        let found = self
            .tree
            .query(&point)
            .nearest_n::<SquaredEuclidean<f64>>(wanted)
            .execute();
        match &self.locations {
            None => out.extend(found.iter().map(|r| r.item as usize)),
            Some(locations) => {
                let members = found.iter().flat_map(|r| locations.of(r.item));
                out.extend(members.take(k.get()).map(|&i| i as usize));
            }
        }
    }
}

/// How the tree holds a cloud's coordinates.
struct TreeFrame {
    /// The power of two they are multiplied by (see [`UNSCALED_MAX_EXPONENT`]).
    scale: f64,
    /// Whether they are then clamped to ±FAR_QUERY (see [`SPAN_EXPONENTS`]).
    clamped: bool,
}

/// The frame of a cloud: scaled by its largest coordinate, or by its typical one when the
/// largest is far beyond it.
fn tree_frame(points: &[Point]) -> TreeFrame {
    let magnitude = |p: &Point| p.iter().fold(0.0f64, |m, c| m.max(c.abs()));
    let largest = points.iter().map(magnitude).fold(0.0f64, f64::max);
    if largest == 0.0 {
        return TreeFrame {
            scale: 1.0,
            clamped: false,
        };
    }
    // frexp: largest = m · 2^e with m in [0.5, 1).
    let mut exponent = exponent_of(largest);
    // The median non-zero magnitude of at most 1024 evenly strided points: robust to a few far
    // points, and exact zeros (invalid depth pixels) say nothing of the scale.
    let stride = points.len().div_ceil(1024).max(1);
    let mut sample: Vec<f64> = points
        .iter()
        .step_by(stride)
        .map(magnitude)
        .filter(|m| *m > 0.0)
        .collect();
    let typical = crate::median::median(&mut sample);
    let clamped = typical.is_some_and(|typical| exponent - exponent_of(typical) > SPAN_EXPONENTS);
    if clamped {
        exponent = exponent_of(typical.unwrap_or(largest));
    }
    let scale = if exponent.abs() <= UNSCALED_MAX_EXPONENT {
        1.0
    } else {
        // 2^-e, within the normal range (a subnormal coordinate ends a little below 0.5).
        power_of_two((-exponent).clamp(-1022, 1023))
    };
    TreeFrame { scale, clamped }
}

/// e with x = m · 2^e, m in [0.5, 1), for finite x > 0.
fn exponent_of(x: f64) -> i32 {
    let biased = ((x.to_bits() >> 52) & 0x7ff) as i32;
    if biased == 0 {
        // Subnormal: scale into the normal range first.
        exponent_of(x * power_of_two(64)) - 64
    } else {
        biased - 1022
    }
}

/// 2^e for e in -1022..=1023, exactly.
fn power_of_two(e: i32) -> f64 {
    f64::from_bits(((e + 1023) as u64) << 52)
}

/// |v| for a finite vector whose largest component magnitude is `largest` (> 0), without
/// overflow in the squares.
fn length_without_overflow(v: &Point, largest: f64) -> f64 {
    let unit = v.map(|c| c / largest);
    largest * (unit[0] * unit[0] + unit[1] * unit[1] + unit[2] * unit[2]).sqrt()
}

/// Groups exact duplicates (−0.0 equals 0.0; points with the same non-finite bits group too):
/// `None` when every point is distinct, otherwise each distinct location with its input
/// indices, locations in order of first appearance.
///
/// Open addressing over u32 ids (load ≤ 2/3): 6–12 bytes per point while it runs, one pass
/// when nothing repeats (the common case).
pub(crate) fn distinct_locations(points: &[Point]) -> Result<Option<Locations>, MemoryError> {
    let n = points.len();
    if n < 2 {
        return Ok(None);
    }
    let slots = (n + n / 2).next_power_of_two();
    let mut table: Vec<u32> = try_with_capacity(slots)?;
    table.resize(slots, EMPTY_SLOT);
    let mask = slots - 1;
    let key = |p: &Point| p.map(|c| (c + 0.0).to_bits());
    // The table slot holding the location of `p`, or the empty slot where it would go.
    let find = |table: &[u32], p: &Point| -> usize {
        let wanted = key(p);
        let mut slot = hash(&wanted) as usize & mask;
        loop {
            let id = table[slot];
            if id == EMPTY_SLOT || key(&points[id as usize]) == wanted {
                return slot;
            }
            slot = (slot + 1) & mask;
        }
    };
    // Pass 1: the table maps each location to its first point.
    let mut distinct = 0usize;
    for (i, p) in points.iter().enumerate() {
        let slot = find(&table, p);
        if table[slot] == EMPTY_SLOT {
            table[slot] = i as u32;
            distinct += 1;
        }
    }
    if distinct == n {
        return Ok(None);
    }
    // Pass 2: location ids in order of first appearance, then a counting sort of the members.
    let mut location_of: Vec<u32> = try_with_capacity(n)?;
    // offsets[l + 1] counts the points at location l, then becomes the running sum.
    let mut offsets: Vec<u32> = try_with_capacity(distinct + 1)?;
    offsets.push(0);
    for (i, p) in points.iter().enumerate() {
        let first = table[find(&table, p)] as usize;
        let id = if first == i {
            offsets.push(0);
            (offsets.len() - 2) as u32
        } else {
            location_of[first]
        };
        location_of.push(id);
        offsets[id as usize + 1] += 1;
    }
    drop(table);
    for l in 0..distinct {
        offsets[l + 1] += offsets[l];
    }
    let mut members: Vec<u32> = try_with_capacity(n)?;
    members.resize(n, 0);
    let mut next: Vec<u32> = try_with_capacity(distinct)?;
    next.extend_from_slice(&offsets[..distinct]);
    for (i, &l) in location_of.iter().enumerate() {
        let at = &mut next[l as usize];
        members[*at as usize] = i as u32;
        *at += 1;
    }
    Ok(Some(Locations { offsets, members }))
}

fn try_with_capacity<T>(count: usize) -> Result<Vec<T>, MemoryError> {
    try_vec(count, "the nearest-neighbour index")
}

const EMPTY_SLOT: u32 = u32::MAX;

/// A well-mixed 64-bit hash of a location's bit patterns.
fn hash(bits: &[u64; 3]) -> u64 {
    let mut h = 0x243f_6a88_85a3_08d3u64;
    for &b in bits {
        h = crate::geometry::splitmix64(h ^ b);
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::Xoshiro256PlusPlus;
    use rand::{RngExt, SeedableRng};

    fn squared_distance(a: &Point, b: &Point) -> f64 {
        (0..3).map(|i| (a[i] - b[i]).powi(2)).sum()
    }

    fn random_points(rng: &mut Xoshiro256PlusPlus, n: usize, scale: f64) -> Vec<Point> {
        (0..n)
            .map(|_| {
                [
                    rng.random::<f64>() * scale,
                    rng.random::<f64>() * scale,
                    rng.random::<f64>() * scale,
                ]
            })
            .collect()
    }

    /// Squared distances from `query` to all points, sorted ascending.
    fn brute_force_distances(points: &[Point], query: &Point) -> Vec<f64> {
        let mut d: Vec<f64> = points.iter().map(|p| squared_distance(p, query)).collect();
        d.sort_by(f64::total_cmp);
        d
    }

    #[test]
    fn nearest_one_matches_brute_force() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        // Coarse grid coordinates make exact ties common, so the tie rule is exercised.
        let mut points = random_points(&mut rng, 2000, 10.0);
        for p in points.iter_mut().take(500) {
            *p = p.map(|c| c.round());
        }
        let index = NearestNeighbours::new(&points).unwrap();
        assert_eq!(index.len(), 2000);
        let mut queries = random_points(&mut rng, 1000, 12.0);
        queries.extend(points.iter().step_by(7).copied());
        for q in &queries {
            let (i, d) = index.nearest_one(q);
            let best = brute_force_distances(&points, q)[0];
            assert_eq!(d, best, "query {q:?}");
            assert_eq!(
                squared_distance(&points[i], q),
                best,
                "reported index is not a nearest point"
            );
        }
    }

    #[test]
    fn nearest_k_matches_brute_force() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
        let points = random_points(&mut rng, 3000, 1.0);
        let index = NearestNeighbours::new(&points).unwrap();
        let mut out = Vec::new();
        for (qi, q) in random_points(&mut rng, 300, 1.2)
            .iter()
            .chain(&points[..100])
            .enumerate()
        {
            // 40 and 80: normals of scan lines take the nearest 20 as the first part of a
            // 40-nearest answer, whatever result collector kiddo picks for its size.
            for k in [1, 5, 10, 30, 40, 80] {
                index.nearest_k(q, k, &mut out);
                assert_eq!(out.len(), k);
                let got: Vec<f64> = out.iter().map(|&i| squared_distance(&points[i], q)).collect();
                assert_eq!(got, brute_force_distances(&points, q)[..k], "query {qi}, k {k}");
                let mut unique = out.clone();
                unique.sort_unstable();
                unique.dedup();
                assert_eq!(unique.len(), k, "duplicate indices");
            }
        }
        // A query on an indexed point finds that point first.
        index.nearest_k(&points[42], 3, &mut out);
        assert_eq!(out[0], 42);
    }

    #[test]
    fn nearest_two_matches_brute_force() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
        let points = random_points(&mut rng, 2000, 1.0);
        let index = NearestNeighbours::new(&points).unwrap();
        for q in random_points(&mut rng, 500, 1.2) {
            let (i, first, second) = index.nearest_two(&q);
            let sorted = brute_force_distances(&points, &q);
            assert_eq!(squared_distance(&points[i], &q), sorted[0]);
            assert_eq!((first, second), (sorted[0].sqrt(), sorted[1].sqrt()));
        }
        let single = NearestNeighbours::new(&[[1.0, 0.0, 0.0]]).unwrap();
        assert_eq!(single.nearest_two(&[0.0; 3]), (0, 1.0, f64::INFINITY));
    }

    #[test]
    fn nearest_k_caps_at_cloud_size_and_handles_zero() {
        let points = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [3.0, 0.0, 0.0]];
        let index = NearestNeighbours::new(&points).unwrap();
        let mut out = vec![99];
        index.nearest_k(&[2.9, 0.0, 0.0], 10, &mut out);
        assert_eq!(out, vec![2, 1, 0]);
        index.nearest_k(&[0.0, 0.0, 0.0], 0, &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn identical_points_do_not_break_the_tree() {
        let points = vec![[1.5, -2.0, 3.0]; 10_000];
        let index = NearestNeighbours::new(&points).unwrap();
        assert_eq!((index.len(), index.distinct_len()), (10_000, 1));
        assert_eq!(index.nearest_one(&[1.5, -2.0, 4.0]), (0, 1.0));
        assert_eq!(index.nearest_two(&[1.5, -2.0, 4.0]), (0, 1.0, 1.0));
        let mut out = Vec::new();
        index.nearest_k(&[0.0, 0.0, 0.0], 20, &mut out);
        assert_eq!(out, (0..20).collect::<Vec<_>>());
    }

    /// A depth frame (640×480) whose invalid pixels are 0 0 0, and duplicates elsewhere: every
    /// location is indexed once (so no query can visit the copies one by one: that made a
    /// frame pair with 30 % invalid pixels take 734 s instead of 2.6 s), and every query still
    /// answers over all points: the lowest index of a duplicated nearest location, the
    /// second distance equal to the first there, k-NN counting each copy.
    #[test]
    fn exact_duplicates_are_indexed_once_and_queries_still_count_them() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(10);
        let (width, height) = (640, 480);
        let mut points: Vec<Point> = Vec::with_capacity(width * height);
        for row in 0..height {
            for col in 0..width {
                let invalid = rng.random::<f64>() < 0.3;
                let depth = 1.0 + rng.random::<f64>();
                points.push(if invalid {
                    // −0.0 is the same location as 0.0.
                    [0.0, if col % 2 == 0 { 0.0 } else { -0.0 }, 0.0]
                } else {
                    [
                        (col as f64 - 320.0) / 500.0 * depth,
                        (row as f64 - 240.0) / 500.0 * depth,
                        depth,
                    ]
                });
            }
        }
        // A few more exact copies of valid points.
        for i in 0..1000 {
            points[5 * i + 1] = points[5 * i];
        }
        let invalid = points.iter().filter(|p| **p == [0.0; 3]).count();
        let index = NearestNeighbours::new(&points).unwrap();
        let first_invalid = points.iter().position(|p| *p == [0.0; 3]).unwrap();
        let mut distinct: Vec<[u64; 3]> = points.iter().map(|p| p.map(|c| (c + 0.0).to_bits())).collect();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(index.len(), points.len());
        assert_eq!(index.distinct_len(), distinct.len());
        assert!(index.distinct_len() <= points.len() - invalid + 1);

        let mut queries = random_points(&mut rng, 100, 2.0);
        queries.extend([[0.0; 3], [0.0, 0.0, 1e-3], [-1e-9, 0.0, 0.0]]);
        queries.extend(points.iter().step_by(3001).copied());
        let mut out = Vec::new();
        for q in &queries {
            let mut sorted: Vec<f64> = points.iter().map(|p| squared_distance(p, q)).collect();
            sorted.select_nth_unstable_by(40, f64::total_cmp);
            sorted.truncate(41);
            sorted.sort_by(f64::total_cmp);
            let (i, d) = index.nearest_one(q);
            assert_eq!(d, sorted[0], "query {q:?}");
            assert_eq!(squared_distance(&points[i], q), sorted[0]);
            // The lowest index at that location.
            assert_eq!(points.iter().position(|p| *p == points[i]), Some(i));
            let (j, first, second) = index.nearest_two(q);
            assert_eq!((j, first, second), (i, sorted[0].sqrt(), sorted[1].sqrt()));
            for k in [1, 10, 40] {
                index.nearest_k(q, k, &mut out);
                let got: Vec<f64> = out.iter().map(|&i| squared_distance(&points[i], q)).collect();
                assert_eq!(got, sorted[..k], "query {q:?}, k {k}");
                let mut unique = out.clone();
                unique.sort_unstable();
                unique.dedup();
                assert_eq!(unique.len(), k, "duplicate indices");
            }
        }
        assert_eq!(index.nearest_one(&[0.0; 3]), (first_invalid, 0.0));
    }

    /// Points spread by ~1e160 or ~1e-160 have squared distances that overflow or underflow;
    /// the index answers exactly as for the same cloud at unit scale (the first of these
    /// panicked in `nearest_two`: kiddo found nothing closer than "infinity").
    #[test]
    fn huge_and_tiny_coordinates_are_searched_exactly() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(13);
        let unit = random_points(&mut rng, 3000, 1.0);
        let queries = random_points(&mut rng, 300, 1.5);
        let reference = NearestNeighbours::new(&unit).unwrap();
        for exponent in [-1000, -600, -300, -100, -65, 65, 100, 250, 530, 1000] {
            // An exact power of two: the scaled problem has the same answers.
            let factor = 2f64.powi(exponent);
            let scaled: Vec<Point> = unit.iter().map(|p| p.map(|c| c * factor)).collect();
            let index = NearestNeighbours::new(&scaled).unwrap();
            let mut out = Vec::new();
            let mut expected = Vec::new();
            for q in &queries {
                let q_scaled = q.map(|c| c * factor);
                let (i, _) = index.nearest_one(&q_scaled);
                let (want, d) = reference.nearest_one(q);
                assert_eq!(
                    squared_distance(&unit[i], q),
                    d,
                    "2^{exponent}: index {i} vs {want}"
                );
                let (_, first, second) = index.nearest_two(&q_scaled);
                let (_, first_unit, second_unit) = reference.nearest_two(q);
                assert_eq!(
                    (first, second),
                    (first_unit * factor, second_unit * factor),
                    "2^{exponent}"
                );
                index.nearest_k(&q_scaled, 8, &mut out);
                reference.nearest_k(q, 8, &mut expected);
                let distances = |ids: &[usize]| -> Vec<f64> {
                    ids.iter().map(|&i| squared_distance(&unit[i], q)).collect()
                };
                assert_eq!(distances(&out), distances(&expected), "2^{exponent}");
            }
        }
    }

    /// A few garbage points far out (1e200, ±f64::MAX) among a unit cloud: queries near the
    /// cloud get the answers of the cloud alone, bit for bit. Scaled by the largest coordinate,
    /// the cloud's squared distances underflowed to 0 and every answer was arbitrary.
    #[test]
    fn far_garbage_points_leave_the_cloud_searched_exactly() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(17);
        let unit = random_points(&mut rng, 3000, 1.0);
        let queries = random_points(&mut rng, 300, 1.5);
        let reference = NearestNeighbours::new(&unit).unwrap();
        for far in [[1e200, 0.5, 0.5], [f64::MAX, -f64::MAX, 0.0], [0.1, 0.2, -3e300]] {
            let mut points = unit.clone();
            points.extend([far, far.map(|c| -c)]);
            let index = NearestNeighbours::new(&points).unwrap();
            let (mut out, mut expected) = (Vec::new(), Vec::new());
            for q in &queries {
                assert_eq!(index.nearest_one(q), reference.nearest_one(q), "{far:?}");
                assert_eq!(index.nearest_two(q), reference.nearest_two(q), "{far:?}");
                index.nearest_k(q, 8, &mut out);
                reference.nearest_k(q, 8, &mut expected);
                assert_eq!(out, expected, "{far:?}");
            }
            // Out there, a query finds something and claims no margin (its distances there
            // are not exact).
            let (i, first, second) = index.nearest_two(&far.map(|c| c * 0.5));
            assert!(
                i < points.len() && first == second,
                "{far:?}: {i} {first} {second}"
            );
        }
    }

    /// A query with a NaN or infinite coordinate (a NaN transform applied to a point) has no
    /// nearest point. One so far away that its squared distances overflow still gets a valid
    /// index and its true distance (in f64 every point of the cloud is equally far from it).
    /// Neither panics (`nearest_two` indexed kiddo's empty result).
    #[test]
    fn non_finite_and_astronomically_far_queries() {
        let points: Vec<Point> = (0..=10).map(|i| [i as f64, 0.0, 0.0]).collect();
        let index = NearestNeighbours::new(&points).unwrap();
        for q in [
            [f64::NAN, 0.0, 0.0],
            [0.0, f64::INFINITY, 0.0],
            [f64::NEG_INFINITY; 3],
        ] {
            let (i, d) = index.nearest_one(&q);
            assert_eq!(i, usize::MAX);
            assert!(d.is_nan());
            let (i, first, second) = index.nearest_two(&q);
            assert_eq!(i, usize::MAX);
            assert!(first.is_nan() && second.is_nan());
            let mut out = vec![3];
            index.nearest_k(&q, 4, &mut out);
            assert!(out.is_empty());
        }
        for (far, distance) in [
            ([1e300, 1.0, 0.0], 1e300),
            ([0.0, -f64::MAX, 0.0], f64::MAX),
            (
                [3.0 * 2f64.powi(600), 4.0 * 2f64.powi(600), 0.0],
                5.0 * 2f64.powi(600),
            ),
            ([1e160, 0.0, 0.0], 1e160),
        ] {
            let (i, squared) = index.nearest_one(&far);
            assert!(i <= 10, "{far:?}");
            assert_eq!(squared, distance * distance, "{far:?}");
            let (j, first, second) = index.nearest_two(&far);
            assert!(j <= 10, "{far:?}");
            assert_eq!((first, second), (distance, distance), "{far:?}");
            let mut out = Vec::new();
            index.nearest_k(&far, 3, &mut out);
            out.sort_unstable();
            out.dedup();
            assert!(out.len() == 3 && out.iter().all(|&k| k <= 10), "{out:?}");
        }
        // Far, but within range: still exact.
        assert_eq!(index.nearest_one(&[-1e100, 0.0, 0.0]).0, 0);
        assert_eq!(index.nearest_one(&[1e15, 0.0, 0.0]).0, 10);
    }

    #[test]
    fn collinear_points_do_not_break_the_tree() {
        let points: Vec<Point> = (0..10_000)
            .map(|i| [0.25 * i as f64, 0.5 * i as f64, 7.0])
            .collect();
        let index = NearestNeighbours::new(&points).unwrap();
        let (i, d) = index.nearest_one(&[0.25 * 1234.0, 0.5 * 1234.0, 7.0]);
        assert_eq!((i, d), (1234, 0.0));
        let mut out = Vec::new();
        index.nearest_k(&[0.25 * 500.0, 0.5 * 500.0, 7.0], 3, &mut out);
        assert_eq!(out[0], 500);
        let mut rest = out[1..].to_vec();
        rest.sort_unstable();
        assert_eq!(rest, vec![499, 501]);
    }

    #[test]
    fn empty_index_and_bad_input() {
        let index = NearestNeighbours::new(&[]).unwrap();
        assert!(index.is_empty());
        assert_eq!(index.nearest_one(&[0.0; 3]), (usize::MAX, f64::INFINITY));
        let mut out = vec![1];
        index.nearest_k(&[0.0; 3], 4, &mut out);
        assert!(out.is_empty());

        let err = NearestNeighbours::new(&[[0.0; 3], [f64::NAN, 0.0, 0.0]])
            .err()
            .unwrap();
        assert!(
            matches!(&err, Error::NonFinite(m) if m.contains("points[1]")),
            "{err}"
        );
        assert!(NearestNeighbours::new(&[[f64::INFINITY, 0.0, 0.0]]).is_err());
    }
}
