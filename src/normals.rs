//! Surface normals by k-nearest-neighbour PCA, for point-to-plane ICP when the target cloud
//! comes without normals.
use std::collections::HashMap;
use std::sync::Mutex;

use crate::geometry::{cross, dot, splitmix64};
use crate::nn::NearestNeighbours;
use crate::parallel::Workers;
use crate::point::Point;

/// A neighbourhood counts as a line (or a single point) when its middle covariance eigenvalue
/// is below about this fraction of the largest: no plane, hence no normal. Exactly collinear
/// points give ~1e-16 from rounding; a real surface patch is many orders above.
const LINE_EIGENVALUE_RATIO: f64 = 1e-10;
/// A neighbourhood is one scan line when its middle eigenvalue is below this fraction of its
/// largest (its second extent under a third of its first). k neighbours on a surface sampled
/// evenly give a ratio near 1; on one line of a spinning LiDAR (a ground ring near the sensor,
/// the next ring far away) the second extent is only the range noise (10 points 2.5 cm apart
/// with 1 cm of noise: 0.025), and the smallest eigenvector is merely the direction across both
/// the line and the beam ([`across_line_of_sight`]). Matched along such a "normal", the same
/// beam of two sweeps from nearby poses agrees to micrometres, which holds a registration at
/// zero motion.
const SCAN_LINE_RATIO: f64 = 0.1;
/// |cos| of the angle between a scan line's smallest eigenvector and the line of sight below
/// which that eigenvector is taken for the beam's noise rather than a normal (within 10° of
/// perpendicular).
const ACROSS_SIGHT: f64 = 0.17;
/// A scan line's neighbourhood is widened to 2k, 4k, then up to this many times k nearest
/// points, until it reaches the next line and spans a surface.
const MAX_LINE_WIDENING: usize = 8;
/// The first widening queries this many times k nearest points and tries 2k as their first
/// part: about three scan lines in four need more than 2k, and one query of 4k costs less than
/// queries of 2k and then 4k.
const FIRST_LINE_QUERY: usize = 4;

/// Unit normal of each point from the covariance of its `k` nearest neighbours (the point
/// itself included): the eigenvector of the smallest eigenvalue.
///
/// * `index` must be built from `points` (neighbour indices refer to it).
/// * Orientation: normals point towards the origin, taken as the sensor viewpoint, i.e.
///   `dot(n, p) <= 0`. Clouds in a world frame far from the sensor may need re-orienting.
/// * A neighbourhood with fewer than 3 distinct points, all points on one line, or no unique
///   smallest eigenvalue (isotropic covariance) gives `[0, 0, 0]`, never NaN. With `k < 3`
///   every normal is zero.
/// * A neighbourhood that is one scan line (middle extent under a third of the largest) whose
///   smallest spread lies across the line of sight takes its normal from up to 8k neighbours
///   that reach the neighbouring line of the same surface, or gets `[0, 0, 0]`: those of the
///   nearest anchor among its k neighbours (one point of the cloud in four, fixed by a hash of
///   its index) when the anchor's k nearest are such a line too and its plane holds the point,
///   otherwise its own.
/// * Parallel over fixed chunks of points; the result does not depend on the thread count.
///
/// # Panics
/// If `index.len() != points.len()`.
pub fn estimate_normals(
    points: &[Point],
    index: &NearestNeighbours,
    k: usize,
    workers: &Workers,
) -> Vec<Point> {
    assert_eq!(
        index.len(),
        points.len(),
        "estimate_normals: the index must be built from `points`"
    );
    normals_from(
        points,
        points,
        index,
        k,
        f64::INFINITY,
        &AnchorPlanes::default(),
        workers,
    )
}

/// A k-NN neighbourhood whose thickness (smallest covariance eigenvalue) is above this fraction
/// of its in-plane spread (middle eigenvalue) is dominated by noise: about 4σ²/R² for noise σ
/// and radius R, so 0.05 asks for R ≳ 9σ (a normal within a few degrees from k = 10).
const NOISY_NEIGHBOURHOOD_RATIO: f64 = 0.05;
/// Above this thickness ratio the k nearest points form a ball inside the noise rather than a
/// patch of a surface (a very dense noisy cloud: 10 M points of a room at 1 cm noise, 3.5 mm
/// apart). Thinning then leaves the ratio where it is until the neighbourhood outgrows the
/// noise, so a step that does not help is no reason to stop there.
const BALL_NEIGHBOURHOOD_RATIO: f64 = 0.25;
/// Neighbourhoods sampled to measure that ratio.
const SCALE_PROBES: usize = 512;
/// Each step keeps one point in 4, which doubles the radius of k neighbours on a surface.
const THINNING_STEP: usize = 4;
const MAX_THINNING: usize = 256;

/// [`estimate_normals`] with the neighbourhood scale chosen from the data (see
/// [`NormalScale::choose`]). Returns the normals and the thinning factor used (1 = plain k-NN).
pub fn estimate_normals_at_data_scale(
    points: &[Point],
    index: &NearestNeighbours,
    k: usize,
    workers: &Workers,
) -> (Vec<Point>, usize) {
    let scale = NormalScale::choose(points, None, index, k, workers);
    (
        scale.normals_at(points, index, points, k, workers),
        scale.factor(),
    )
}

/// Where the k neighbours of a normal come from: the cloud itself, or a thinned copy of it
/// when the cloud is dense relative to its noise.
pub struct NormalScale {
    factor: usize,
    thinned: Option<(Vec<Point>, NearestNeighbours)>,
    /// The anchors' planes in the cloud the neighbours come from, kept between calls (a
    /// prepared target estimates its normals in batches as registrations reach them).
    anchors: AnchorPlanes,
}

impl NormalScale {
    /// When the k nearest neighbours are so close that sensor noise dominates them (dense,
    /// noisy clouds: 1 M points of a room at 1 cm noise), the normals come from the k nearest
    /// points of a thinned copy of the cloud instead, thinned just enough for the median
    /// neighbourhood to be a plane (thickness ratio below [`NOISY_NEIGHBOURHOOD_RATIO`]).
    /// Thinning stops when it no longer helps as noise would (the ratio drops by less than a
    /// quarter: curvature or a volumetric cloud), except while the neighbourhoods are still
    /// balls inside the noise ([`BALL_NEIGHBOURHOOD_RATIO`]), and keeps at least 20·k points.
    /// `index` is built on `points`. `ids[i]` names point i for the thinning hash (default: i),
    /// so a reordered copy of a cloud is thinned to the same points.
    /// The probes' neighbourhoods are measured on `workers`; the choice does not depend on them.
    pub fn choose(
        points: &[Point],
        ids: Option<&[u32]>,
        index: &NearestNeighbours,
        k: usize,
        workers: &Workers,
    ) -> Self {
        let probes: Vec<Point> = (0..SCALE_PROBES.min(points.len()))
            .map(|j| points[j * points.len() / SCALE_PROBES.min(points.len())])
            .collect();
        let mut ratio = median_thickness(&probes, points, index, k, workers);
        let mut chosen = NormalScale {
            factor: 1,
            thinned: None,
            anchors: AnchorPlanes::default(),
        };
        // The ratio of the last factor tried, accepted or not.
        let (mut trial, mut trial_ratio) = (1, ratio);
        while ratio > NOISY_NEIGHBOURHOOD_RATIO && trial * THINNING_STEP <= MAX_THINNING {
            trial *= THINNING_STEP;
            let thinned = thin(points, ids, trial);
            if thinned.len() < 20 * k.max(1) {
                break;
            }
            let Ok(thin_index) = NearestNeighbours::new(&thinned) else {
                break;
            };
            let thinner = median_thickness(&probes, &thinned, &thin_index, k, workers);
            let improved = thinner <= 0.75 * trial_ratio && thinner < ratio;
            let in_ball = trial_ratio > BALL_NEIGHBOURHOOD_RATIO;
            trial_ratio = thinner;
            if improved {
                ratio = thinner;
                chosen = NormalScale {
                    factor: trial,
                    thinned: Some((thinned, thin_index)),
                    anchors: AnchorPlanes::default(),
                };
            } else if !in_ball {
                break;
            }
        }
        chosen
    }

    /// One point in `factor` is used for neighbourhoods (1 = the whole cloud).
    pub fn factor(&self) -> usize {
        self.factor
    }

    /// Normals at `queries` from their k nearest points at this scale; `points` and `index` are
    /// the cloud `choose` was given.
    pub fn normals_at(
        &self,
        points: &[Point],
        index: &NearestNeighbours,
        queries: &[Point],
        k: usize,
        workers: &Workers,
    ) -> Vec<Point> {
        self.normals_within(points, index, queries, k, f64::INFINITY, workers)
    }

    /// [`NormalScale::normals_at`] where the neighbourhood is a plane only: `[0, 0, 0]` where
    /// its thickness (λ_min / λ_mid) is above [`NOISY_NEIGHBOURHOOD_RATIO`]. An edge or corner
    /// between surfaces has a "normal" in no surface's direction, and one within the noise
    /// points anywhere: for judging which directions the surfaces fix, both would read as
    /// constraint.
    pub fn planar_normals_at(
        &self,
        points: &[Point],
        index: &NearestNeighbours,
        queries: &[Point],
        k: usize,
        workers: &Workers,
    ) -> Vec<Point> {
        self.normals_within(points, index, queries, k, NOISY_NEIGHBOURHOOD_RATIO, workers)
    }

    fn normals_within(
        &self,
        points: &[Point],
        index: &NearestNeighbours,
        queries: &[Point],
        k: usize,
        max_thickness: f64,
        workers: &Workers,
    ) -> Vec<Point> {
        match &self.thinned {
            None => normals_from(queries, points, index, k, max_thickness, &self.anchors, workers),
            Some((thinned, thin_index)) => normals_from(
                queries,
                thinned,
                thin_index,
                k,
                max_thickness,
                &self.anchors,
                workers,
            ),
        }
    }
}

/// About one point in `factor`, chosen by a hash of the index (no aliasing with the row
/// structure of organised clouds, and deterministic).
fn thin(points: &[Point], ids: Option<&[u32]>, factor: usize) -> Vec<Point> {
    let id = |i: usize| ids.map_or(i as u64, |ids| u64::from(ids[i]));
    points
        .iter()
        .enumerate()
        .filter(|(i, _)| splitmix64(id(*i)) % factor as u64 == 0)
        .map(|(_, p)| *p)
        .collect()
}

/// Median over the probes of λ_min / λ_mid of their k nearest points in `cloud` (∞ when no
/// probe has a plane-like neighbourhood).
fn median_thickness(
    probes: &[Point],
    cloud: &[Point],
    index: &NearestNeighbours,
    k: usize,
    workers: &Workers,
) -> f64 {
    // None: no plane-like neighbourhood at that probe.
    let mut ratios: Vec<Option<f64>> = vec![None; probes.len()];
    workers.for_each_chunk_of(NORMALS_CHUNK, &mut ratios, |first, chunk| {
        let mut neighbours = Vec::with_capacity(k);
        for (offset, ratio) in chunk.iter_mut().enumerate() {
            index.nearest_k(&probes[first + offset], k, &mut neighbours);
            let [smallest, middle, _] = eigenvalues_ascending(&covariance(cloud, &neighbours));
            *ratio = (middle > 0.0).then(|| smallest.max(0.0) / middle);
        }
    });
    let mut ratios: Vec<f64> = ratios.into_iter().flatten().collect();
    crate::median::median(&mut ratios).unwrap_or(f64::INFINITY)
}

/// Eigenvalues of a symmetric 3×3 matrix, ascending (trigonometric form, Smith 1961; accurate
/// to about √ε of the largest when two are close). Zero spread or NaN: the mean three times.
fn eigenvalues_ascending(a: &[[f64; 3]; 3]) -> [f64; 3] {
    let off_diagonal = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    let mean = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
    let spread =
        ((a[0][0] - mean).powi(2) + (a[1][1] - mean).powi(2) + (a[2][2] - mean).powi(2) + 2.0 * off_diagonal)
            / 6.0;
    if spread.is_nan() || spread <= 0.0 {
        return [mean; 3];
    }
    let p = spread.sqrt();
    // B = (A − mean·I) / p has eigenvalues 2·cos(φ + 2πj/3) with cos(3φ) = det(B)/2.
    let b = |r: usize, c: usize| (a[r][c] - if r == c { mean } else { 0.0 }) / p;
    let det_b = b(0, 0) * (b(1, 1) * b(2, 2) - b(1, 2) * b(2, 1))
        - b(0, 1) * (b(1, 0) * b(2, 2) - b(1, 2) * b(2, 0))
        + b(0, 2) * (b(1, 0) * b(2, 1) - b(1, 1) * b(2, 0));
    let phi = (det_b / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    let largest = mean + 2.0 * p * phi.cos();
    let smallest = mean + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    [smallest, 3.0 * mean - largest - smallest, largest]
}

/// Normals per thread's work item: a normal costs about a microsecond (a k-NN query and a
/// 3×3 eigenvector), so a second thread pays for itself from a few hundred of them, and the
/// batches of targets a registration pass newly reaches are often that small. The normals do
/// not depend on it.
const NORMALS_CHUNK: usize = 256;

/// Normal at each of `points` from its k nearest points of `cloud` (`index` is built on `cloud`);
/// `[0, 0, 0]` where their thickness λ_min / λ_mid is above `max_thickness` (∞: never).
fn normals_from(
    points: &[Point],
    cloud: &[Point],
    index: &NearestNeighbours,
    k: usize,
    max_thickness: f64,
    anchors: &AnchorPlanes,
    workers: &Workers,
) -> Vec<Point> {
    let mut normals = vec![[0.0; 3]; points.len()];
    workers.for_each_chunk_of(NORMALS_CHUNK, &mut normals, |first, chunk| {
        let mut lines = LineNormals::new(cloud, index, k, max_thickness, anchors);
        for (offset, normal) in chunk.iter_mut().enumerate() {
            *normal = lines.normal_at(&points[first + offset]);
        }
        lines.keep_found();
    });
    normals
}

/// Anchors' planes kept at most: about 80 bytes each.
const MAX_KEPT_ANCHORS: usize = 1 << 20;

/// The widened planes of the anchors of one cloud found so far, by the anchor's index (`None`:
/// no scan line, or its plane was refused). Each is a function of the anchor alone, so which
/// call or thread found it first does not matter.
#[derive(Default)]
pub(crate) struct AnchorPlanes(Mutex<HashMap<usize, Option<LinePlane>>>);

impl AnchorPlanes {
    /// A poisoned lock only means another chunk panicked; the entries are still right.
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<usize, Option<LinePlane>>> {
        self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn get(&self, anchor: usize) -> Option<Option<LinePlane>> {
        self.lock().get(&anchor).copied()
    }

    /// Keeps `found`, up to [`MAX_KEPT_ANCHORS`] in all (beyond, they are found again).
    fn keep(&self, found: &mut HashMap<usize, Option<LinePlane>>) {
        let mut kept = self.lock();
        for (anchor, plane) in found.drain() {
            if kept.len() >= MAX_KEPT_ANCHORS {
                break;
            }
            kept.insert(anchor, plane);
        }
    }
}

/// One point of a cloud in this many is an anchor: a scan-line point whose widened plane the
/// scan-line points that have it among their k nearest take (see [`LineNormals::normal_at`]).
const ANCHOR_EVERY: u64 = 4;

fn is_anchor(point_index: usize) -> bool {
    splitmix64(point_index as u64) % ANCHOR_EVERY == 0
}

/// The plane a scan line's widened neighbourhood spans ([`widened_plane`]).
#[derive(Clone, Copy)]
pub(crate) struct LinePlane {
    /// Unit normal, towards the origin as seen from the point it was fitted for.
    normal: Point,
    centre: Point,
    /// Variance of the neighbourhood along the normal.
    thickness_squared: f64,
}

impl LinePlane {
    /// Whether `p` lies on the plane, within four standard deviations of its thickness.
    fn holds(&self, p: &Point) -> bool {
        let offset = dot(&self.normal, &[0, 1, 2].map(|d| p[d] - self.centre[d]));
        offset * offset <= 16.0 * self.thickness_squared
    }

    /// The normal oriented towards the origin as seen from `p`.
    fn normal_seen_from(&self, p: &Point) -> Point {
        if dot(&self.normal, p) > 0.0 {
            self.normal.map(|c| -c)
        } else {
            self.normal
        }
    }
}

/// Normals of one chunk of points, with the widened planes of the anchors met so far: a widened
/// query (40 or 80 nearest points) costs several of the k-nearest query every normal makes, and
/// the scan-line points around an anchor share its plane. An anchor's plane depends on the
/// anchor alone, so the normals do not depend on the chunks or their order.
struct LineNormals<'a> {
    cloud: &'a [Point],
    index: &'a NearestNeighbours,
    k: usize,
    max_thickness: f64,
    /// The anchors' planes found before this chunk.
    kept: &'a AnchorPlanes,
    /// Those this chunk found; `None` when the anchor is no scan line or its plane was refused.
    anchors: HashMap<usize, Option<LinePlane>>,
    neighbours: Vec<usize>,
    anchor_neighbours: Vec<usize>,
}

impl<'a> LineNormals<'a> {
    fn new(
        cloud: &'a [Point],
        index: &'a NearestNeighbours,
        k: usize,
        max_thickness: f64,
        kept: &'a AnchorPlanes,
    ) -> Self {
        LineNormals {
            cloud,
            index,
            k,
            max_thickness,
            kept,
            anchors: HashMap::new(),
            neighbours: Vec::with_capacity(k * MAX_LINE_WIDENING),
            anchor_neighbours: Vec::with_capacity(k * MAX_LINE_WIDENING),
        }
    }

    /// The normal at `p` from its k nearest points; when they are one scan line
    /// ([`SCAN_LINE_RATIO`]) whose smallest spread lies across the line of sight, the plane of
    /// the nearest anchor among them if that anchor's own k nearest are such a line and its
    /// widened plane holds `p`, otherwise `p`'s own widened plane ([`widened_plane`]), or
    /// `[0, 0, 0]`.
    fn normal_at(&mut self, p: &Point) -> Point {
        let (cloud, index, k) = (self.cloud, self.index, self.k);
        index.nearest_k(p, k, &mut self.neighbours);
        let Some(line) = scan_line_across_sight(p, cloud, k, &self.neighbours) else {
            return normal_of(p, &covariance(cloud, &self.neighbours), self.max_thickness);
        };
        let Some(line) = line else {
            return [0.0; 3];
        };
        if let Some(&anchor) = self.neighbours.iter().find(|&&i| is_anchor(i)) {
            if cloud[anchor] == *p {
                // The anchor is `p` (or a copy of it): its plane is `p`'s own, found already
                // when an earlier point had the anchor among its nearest, else found now from
                // the neighbours at hand.
                let plane = match self.known_anchor_plane(anchor) {
                    Some(plane) => plane,
                    None => {
                        let plane = widened_plane(
                            p,
                            &line,
                            cloud,
                            index,
                            k,
                            self.max_thickness,
                            &mut self.neighbours,
                        );
                        self.anchors.insert(anchor, plane);
                        plane
                    }
                };
                return plane.map_or([0.0; 3], |plane| plane.normal);
            }
            if let Some(plane) = self.anchor_plane(anchor).filter(|plane| plane.holds(p)) {
                return plane.normal_seen_from(p);
            }
        }
        widened_plane(
            p,
            &line,
            cloud,
            index,
            k,
            self.max_thickness,
            &mut self.neighbours,
        )
        .map_or([0.0; 3], |plane| plane.normal)
    }

    /// Keeps the anchors' planes this chunk found for later chunks and calls.
    fn keep_found(&mut self) {
        self.kept.keep(&mut self.anchors);
    }

    /// The plane of `anchor` when this chunk or an earlier call found it (`Some(None)`: it is
    /// no scan line, or its plane was refused).
    fn known_anchor_plane(&mut self, anchor: usize) -> Option<Option<LinePlane>> {
        if let Some(plane) = self.anchors.get(&anchor) {
            return Some(*plane);
        }
        let plane = self.kept.get(anchor)?;
        self.anchors.insert(anchor, plane);
        Some(plane)
    }

    fn anchor_plane(&mut self, anchor: usize) -> Option<LinePlane> {
        if let Some(plane) = self.known_anchor_plane(anchor) {
            return plane;
        }
        let (cloud, index, k) = (self.cloud, self.index, self.k);
        let a = &cloud[anchor];
        index.nearest_k(a, k, &mut self.anchor_neighbours);
        let plane = match scan_line_across_sight(a, cloud, k, &self.anchor_neighbours) {
            Some(Some(line)) => widened_plane(
                a,
                &line,
                cloud,
                index,
                k,
                self.max_thickness,
                &mut self.anchor_neighbours,
            ),
            _ => None,
        };
        self.anchors.insert(anchor, plane);
        plane
    }
}

/// `None` when the k nearest points `neighbours` of `p` are no scan line whose smallest spread
/// lies across the line of sight (or are fewer than k, or k < 3); `Some(None)` for such a line
/// without a unique direction; otherwise the line.
fn scan_line_across_sight(
    p: &Point,
    cloud: &[Point],
    k: usize,
    neighbours: &[usize],
) -> Option<Option<ScanLine>> {
    let spread = covariance(cloud, neighbours);
    if k < 3 || neighbours.len() < k || !is_scan_line(&spread) || !across_line_of_sight(p, &spread) {
        return None;
    }
    let [_, across, along] = eigenvalues_ascending(&spread);
    Some(null_vector(&spread, along).map(|direction| ScanLine {
        centre: centroid(cloud, neighbours),
        direction,
        width_squared: across.max(0.0),
    }))
}

/// The plane of the smallest of the 2k, 4k, … [`MAX_LINE_WIDENING`]·k nearest points of `p`
/// (a point whose k nearest are the scan line `line`) that is no line and reaches a
/// neighbouring line ([`reaches_a_neighbouring_line`]), accepted only as a thin plane
/// (thickness below [`NOISY_NEIGHBOURHOOD_RATIO`] and `max_thickness`) through `p`.
fn widened_plane(
    p: &Point,
    line: &ScanLine,
    cloud: &[Point],
    index: &NearestNeighbours,
    k: usize,
    max_thickness: f64,
    neighbours: &mut Vec<usize>,
) -> Option<LinePlane> {
    // The widest neighbourhood queried so far, as a multiple of k.
    let mut queried = 1;
    let mut widening = 2;
    while widening <= MAX_LINE_WIDENING {
        if widening > queried {
            queried = widening.max(FIRST_LINE_QUERY);
            index.nearest_k(p, k * queried, neighbours);
        }
        // Ascending distance: the nearest k·widening are the first.
        let neighbours = &neighbours[..(k * widening).min(neighbours.len())];
        let spread = covariance(cloud, neighbours);
        if !is_scan_line(&spread) && reaches_a_neighbouring_line(line, cloud, neighbours) {
            let normal = normal_of(p, &spread, max_thickness.min(NOISY_NEIGHBOURHOOD_RATIO));
            let plane = LinePlane {
                normal,
                centre: centroid(cloud, neighbours),
                thickness_squared: quadratic_form(&spread, &normal),
            };
            return (normal != [0.0; 3] && plane.holds(p)).then_some(plane);
        }
        widening *= 2;
    }
    None
}

/// The k nearest points of a point, found to be one scan line.
struct ScanLine {
    centre: Point,
    /// Unit direction along the line.
    direction: Point,
    /// Variance across the line (its noise).
    width_squared: f64,
}

/// Whether a widened neighbourhood of a scan line holds a neighbouring line of the same surface:
/// the points off the line (beyond 3 of its widths), at least 3, form a line parallel to it or a
/// surface that contains its direction. A blob (copies of one point, a small object) or a
/// surface across the line (the ground below a pole) does not, though the line and either always
/// span some plane.
fn reaches_a_neighbouring_line(line: &ScanLine, cloud: &[Point], neighbours: &[usize]) -> bool {
    const PARALLEL: f64 = 0.9;
    const ACROSS: f64 = 0.3;
    let off: Vec<usize> = neighbours
        .iter()
        .copied()
        .filter(|&i| {
            let d = [0, 1, 2].map(|c| cloud[i][c] - line.centre[c]);
            let along = dot(&d, &line.direction);
            dot(&d, &d) - along * along > 9.0 * line.width_squared
        })
        .collect();
    if off.len() < 3 {
        return false;
    }
    let spread = covariance(cloud, &off);
    match minors_ratio(&spread) {
        None => false,
        Some(ratio) if ratio <= SCAN_LINE_RATIO => {
            let [_, _, largest] = eigenvalues_ascending(&spread);
            null_vector(&spread, largest).is_some_and(|e| dot(&e, &line.direction).abs() >= PARALLEL)
        }
        Some(_) => smallest_eigenvector(&spread).is_some_and(|n| dot(&n, &line.direction).abs() <= ACROSS),
    }
}

/// Whether the smallest eigenvector of `spread` lies across the line of sight from the origin
/// (the sensor, as for the normals' orientation) to `p`, within [`ACROSS_SIGHT`]: on one scan
/// line whose second extent is range noise along the beam, the smallest spread is across the
/// beam by construction. A surface the sensor returned from faces it; only grazing ones do not.
fn across_line_of_sight(p: &Point, spread: &[[f64; 3]; 3]) -> bool {
    let range = dot(p, p).sqrt();
    smallest_eigenvector(spread).is_some_and(|n| range > 0.0 && dot(&n, p).abs() <= ACROSS_SIGHT * range)
}

/// Whether a covariance is one scan line (see [`SCAN_LINE_RATIO`]), tested on the sum of
/// principal 2×2 minors, λ₁λ₂ + λ₁λ₃ + λ₂λ₃ ≈ λ_max·λ_mid.
fn is_scan_line(spread: &[[f64; 3]; 3]) -> bool {
    minors_ratio(spread).is_none_or(|ratio| ratio <= SCAN_LINE_RATIO)
}

/// (λ₁λ₂ + λ₁λ₃ + λ₂λ₃) / trace² ≈ λ_mid / λ_max for a line-like spread: accurate to rounding
/// even for rank 1, unlike λ_mid from the trigonometric eigenvalues. `None` for a zero or
/// non-finite matrix.
fn minors_ratio(matrix: &[[f64; 3]; 3]) -> Option<f64> {
    // Unit scale keeps the products below far from overflow and underflow.
    let scale = matrix.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return None;
    }
    let a = matrix.map(|row| row.map(|x| x / scale));
    let off_diagonal = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    let trace = a[0][0] + a[1][1] + a[2][2];
    let minors = a[0][0] * a[1][1] + a[0][0] * a[2][2] + a[1][1] * a[2][2] - off_diagonal;
    (trace > 0.0).then(|| minors / (trace * trace))
}

/// vᵀ·A·v.
fn quadratic_form(a: &[[f64; 3]; 3], v: &Point) -> f64 {
    (0..3)
        .map(|r| v[r] * (a[r][0] * v[0] + a[r][1] * v[1] + a[r][2] * v[2]))
        .sum()
}

fn centroid(points: &[Point], selected: &[usize]) -> Point {
    let n = selected.len().max(1) as f64;
    selected
        .iter()
        .fold([0.0; 3], |s, &i| [0, 1, 2].map(|d| s[d] + points[i][d]))
        .map(|s| s / n)
}

/// The normal at `p` of a neighbourhood of covariance `spread`, towards the origin; `[0, 0, 0]`
/// when it is no plane or thicker than `max_thickness` (λ_min / λ_mid).
fn normal_of(p: &Point, spread: &[[f64; 3]; 3], max_thickness: f64) -> Point {
    if max_thickness < f64::INFINITY {
        let [smallest, middle, _] = eigenvalues_ascending(spread);
        // Not `<=`: a NaN or a middle of 0 is no plane either.
        if !(smallest.max(0.0) <= max_thickness * middle && middle > 0.0) {
            return [0.0; 3];
        }
    }
    match smallest_eigenvector(spread) {
        Some(n) if dot(&n, p) > 0.0 => n.map(|c| -c),
        Some(n) => n,
        None => [0.0; 3],
    }
}

/// Covariance (divided by n) of the selected points about their mean; centring first keeps
/// precision for clouds far from the origin.
fn covariance(points: &[Point], selected: &[usize]) -> [[f64; 3]; 3] {
    if selected.is_empty() {
        return [[0.0; 3]; 3];
    }
    let n = selected.len() as f64;
    let mean = centroid(points, selected);
    // Upper triangle xx, xy, xz, yy, yz, zz.
    let mut upper = [0.0; 6];
    for &i in selected {
        let [x, y, z] = [0, 1, 2].map(|d| points[i][d] - mean[d]);
        for (acc, term) in upper.iter_mut().zip([x * x, x * y, x * z, y * y, y * z, z * z]) {
            *acc += term;
        }
    }
    let [xx, xy, xz, yy, yz, zz] = upper.map(|u| u / n);
    [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric positive semi-definite 3×3
/// matrix, or `None` when it is not a plane-like spread (see `estimate_normals`).
///
/// Closed form after Eberly ("A robust eigensolver for 3×3 symmetric matrices"): trigonometric
/// eigenvalues (Smith 1961), then the eigenvector of whichever extreme eigenvalue is better
/// separated, from the longest cross product of two rows of A − λ·I; if that is the largest
/// one, the smallest comes from the 2×2 problem in its orthogonal complement. Accurate to
/// rounding / eigen-gap like nalgebra's iterative `SymmetricEigen` (the tests compare the two)
/// and about 3× faster (see docs/performance.md, "Design measurements behind the code").
fn smallest_eigenvector(matrix: &[[f64; 3]; 3]) -> Option<Point> {
    // Unit scale keeps the products below far from overflow and underflow.
    let scale = matrix.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return None;
    }
    let a = matrix.map(|row| row.map(|x| x / scale));
    if minors_ratio(&a).is_none_or(|ratio| ratio <= LINE_EIGENVALUE_RATIO) {
        return None;
    }
    let [smallest, middle, largest] = eigenvalues_ascending(&a);
    // All eigenvalues equal (isotropic): no unique normal.
    if largest.is_nan() || largest <= smallest {
        return None;
    }
    if middle - smallest >= largest - middle {
        return null_vector(&a, smallest);
    }
    // The two smallest are close: their eigenvalues carry √ε errors from acos, so take the
    // well-separated largest eigenvector and solve the rest in its orthogonal complement.
    let top = null_vector(&a, largest)?;
    let helper = if top[0].abs() > top[1].abs() {
        [0.0, 1.0, 0.0]
    } else {
        [1.0, 0.0, 0.0]
    };
    let u = normalised(&cross(&top, &helper))?;
    let w = cross(&top, &u);
    let quadratic = |x: &Point, y: &Point| {
        (0..3)
            .map(|r| x[r] * (a[r][0] * y[0] + a[r][1] * y[1] + a[r][2] * y[2]))
            .sum::<f64>()
    };
    let (uu, uw, ww) = (quadratic(&u, &u), quadratic(&u, &w), quadratic(&w, &w));
    // Rotation angle of the larger 2×2 eigenvector; the smaller one is perpendicular to it.
    let theta = 0.5 * (2.0 * uw).atan2(uu - ww);
    let (sin, cos) = theta.sin_cos();
    normalised(&[0, 1, 2].map(|d| -sin * u[d] + cos * w[d]))
}

/// Unit vector spanning the null space of A − λ·I for a simple eigenvalue λ: the rows span
/// the orthogonal plane, so their longest cross product is the best-conditioned estimate.
fn null_vector(a: &[[f64; 3]; 3], eigenvalue: f64) -> Option<Point> {
    let rows = [0, 1, 2].map(|r| [0, 1, 2].map(|c| a[r][c] - if r == c { eigenvalue } else { 0.0 }));
    let candidates = [
        cross(&rows[0], &rows[1]),
        cross(&rows[0], &rows[2]),
        cross(&rows[1], &rows[2]),
    ];
    let best = candidates.iter().max_by(|x, y| dot(x, x).total_cmp(&dot(y, y)))?;
    normalised(best)
}

/// `v / |v|`, or `None` for a zero or non-finite vector (no unique direction).
fn normalised(v: &Point) -> Option<Point> {
    let norm = dot(v, v).sqrt();
    (norm > 0.0 && norm.is_finite()).then(|| v.map(|c| c / norm))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, SymmetricEigen, Vector3};
    use rand::rngs::Xoshiro256PlusPlus;
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, Normal};

    fn angle_degrees(a: &Point, b: &Point) -> f64 {
        let c = dot(a, b) / (dot(a, a) * dot(b, b)).sqrt();
        c.clamp(-1.0, 1.0).acos().to_degrees()
    }

    fn normals_with(points: &[Point], k: usize, threads: usize) -> Vec<Point> {
        let index = NearestNeighbours::new(points).unwrap();
        estimate_normals(points, &index, k, &Workers::new(threads).unwrap())
    }

    /// Points on the plane through `centre` with unit normal `normal`, plus Gaussian noise.
    fn noisy_plane(
        rng: &mut Xoshiro256PlusPlus,
        normal: &Point,
        centre: &Point,
        n: usize,
        sigma: f64,
    ) -> Vec<Point> {
        let helper = if normal[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let u = cross(normal, &helper);
        let u = u.map(|c| c / dot(&u, &u).sqrt());
        let v = cross(normal, &u);
        let noise = Normal::new(0.0, sigma).unwrap();
        (0..n)
            .map(|_| {
                let (s, t) = (rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0));
                [0, 1, 2].map(|d| centre[d] + s * u[d] + t * v[d] + noise.sample(rng))
            })
            .collect()
    }

    #[test]
    fn tilted_noisy_plane_gives_its_normal() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let tilted = [0.3, -0.5, 0.8];
        let normal = tilted.map(|c| c / dot(&tilted, &tilted).sqrt());
        // Plane well away from the origin, so the orientation rule is exercised.
        let centre = [2.0, -1.0, 5.0];
        // σ = 0.5 mm against a ~9 cm neighbourhood radius.
        let points = noisy_plane(&mut rng, &normal, &centre, 20_000, 0.0005);
        let normals = normals_with(&points, 30, 1);
        let worst = normals
            .iter()
            .map(|n| angle_degrees(n, &normal.map(|c| -c)))
            .fold(0.0, f64::max);
        // dot(normal, centre) > 0, so every estimate must be flipped to −normal.
        assert!(dot(&normal, &centre) > 0.0);
        assert!(worst < 1.0, "worst deviation {worst}°");
        for n in &normals {
            assert!((dot(n, n) - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn sphere_normals_are_radial_and_face_the_centre() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let gauss = Normal::new(0.0, 1.0).unwrap();
        let points: Vec<Point> = (0..50_000)
            .map(|_| {
                let v: Point = [0, 1, 2].map(|_| gauss.sample(&mut rng));
                v.map(|c| 3.0 * c / dot(&v, &v).sqrt())
            })
            .collect();
        let normals = normals_with(&points, 15, 2);
        // PCA gives the normal at the neighbourhood's centroid, which a random sample places
        // off the query point: small mean deviation, occasional larger ones.
        let deviations: Vec<f64> = points
            .iter()
            .zip(&normals)
            .map(|(p, n)| angle_degrees(n, &p.map(|c| -c)))
            .collect();
        let mean = deviations.iter().sum::<f64>() / deviations.len() as f64;
        let worst = deviations.iter().copied().fold(0.0, f64::max);
        assert!(
            mean < 0.4 && worst < 2.0,
            "mean {mean}°, worst {worst}° from radial"
        );
    }

    #[test]
    fn degenerate_neighbourhoods_give_zero_normals() {
        let line: Vec<Point> = (0..500)
            .map(|i| [1.0 + 0.1 * i as f64, 2.0 - 0.3 * i as f64, 0.5 * i as f64])
            .collect();
        assert!(normals_with(&line, 10, 1).iter().all(|n| *n == [0.0; 3]));

        let same = vec![[4.0, 5.0, 6.0]; 300];
        assert!(normals_with(&same, 10, 1).iter().all(|n| *n == [0.0; 3]));

        // Two distinct locations only: rank 1, a line.
        let two: Vec<Point> = (0..300)
            .map(|i| {
                if i % 2 == 0 {
                    [0.0, 0.0, 1.0]
                } else {
                    [1.0, 1.0, 1.0]
                }
            })
            .collect();
        assert!(normals_with(&two, 8, 1).iter().all(|n| *n == [0.0; 3]));

        let tiny = [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]];
        assert_eq!(normals_with(&tiny, 10, 1), vec![[0.0; 3]; 2]);

        // k < 3 cannot define a plane even on a good surface.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let plane = noisy_plane(&mut rng, &[0.0, 0.0, 1.0], &[0.0, 0.0, 1.0], 200, 0.0);
        assert!(normals_with(&plane, 2, 1).iter().all(|n| *n == [0.0; 3]));
        assert!(normals_with(&[], 10, 1).is_empty());
    }

    #[test]
    fn no_nan_on_mixed_input() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
        let mut points = noisy_plane(&mut rng, &[0.0, 1.0, 0.0], &[0.0, 2.0, 0.0], 1000, 0.01);
        points.extend(vec![[9.0, 9.0, 9.0]; 50]);
        points.extend((0..50).map(|i| [20.0 + i as f64, 0.0, 0.0]));
        let normals = normals_with(&points, 12, 1);
        assert!(normals.iter().flatten().all(|c| c.is_finite()));
        assert!(normals[1000..].iter().all(|n| *n == [0.0; 3]));
        assert!(normals[..1000].iter().all(|n| (dot(n, n) - 1.0).abs() < 1e-12));
    }

    /// Ground rings of a spinning LiDAR 1.8 m above the ground: a circle for each of `radii`, a
    /// point every 0.35° of azimuth, range noise of 1 cm along each beam.
    fn ground_rings(rng: &mut Xoshiro256PlusPlus, radii: &[f64]) -> Vec<Point> {
        let noise = Normal::new(0.0, 0.01).unwrap();
        let mut points = Vec::new();
        for &radius in radii {
            for column in 0..1024 {
                let azimuth = std::f64::consts::TAU * column as f64 / 1024.0;
                let p = [radius * azimuth.cos(), radius * azimuth.sin(), -1.8];
                let range = dot(&p, &p).sqrt();
                let scale = 1.0 + noise.sample(rng) / range;
                points.push(p.map(|c| c * scale));
            }
        }
        points
    }

    /// One ring's 10 nearest points are a line whose second extent is the range noise: their
    /// smallest eigenvector lies across the beam, not up. Widened to the next ring, the normal
    /// is the ground's.
    #[test]
    fn a_scan_line_takes_its_normal_from_the_next_line() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
        let rings = ground_rings(&mut rng, &[4.0, 4.35, 4.75, 5.2]);
        let normals = normals_with(&rings, 10, 1);
        let up = [0.0, 0.0, 1.0];
        let tilt = |n: &Point| angle_degrees(n, &up).min(180.0 - angle_degrees(n, &up));
        let mut errors: Vec<f64> = normals.iter().map(tilt).collect();
        errors.sort_by(f64::total_cmp);
        let (median, worst) = (errors[errors.len() / 2], errors[errors.len() * 99 / 100]);
        assert!(
            median < 2.0 && worst < 6.0,
            "median {median}°, 99th percentile {worst}°"
        );
        // Without the widening, the k nearest points alone would give a normal about
        // perpendicular to the beam: check the scene has that trap.
        let p = rings[5];
        let index = NearestNeighbours::new(&rings).unwrap();
        let mut nearest = Vec::new();
        index.nearest_k(&p, 10, &mut nearest);
        let line = covariance(&rings, &nearest);
        assert!(is_scan_line(&line));
        let trap = smallest_eigenvector(&line).unwrap();
        assert!(tilt(&trap) > 15.0, "{}", tilt(&trap));
    }

    /// Scan-line points take the plane of an anchor among their neighbours: a point's normal
    /// must still depend on that point alone, not on which other points are asked with it or
    /// in what order (a prepared target estimates them in batches as a registration reaches
    /// them).
    #[test]
    fn shared_scan_line_planes_do_not_depend_on_the_batch() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(23);
        let rings = ground_rings(&mut rng, &[4.0, 4.35, 4.75, 5.2]);
        let index = NearestNeighbours::new(&rings).unwrap();
        let whole = normals_from(
            &rings,
            &rings,
            &index,
            10,
            f64::INFINITY,
            &AnchorPlanes::default(),
            &Workers::new(1).unwrap(),
        );
        // Every seventh point, backwards, on two threads.
        let picked: Vec<usize> = (0..rings.len()).rev().step_by(7).collect();
        let queries: Vec<Point> = picked.iter().map(|&i| rings[i]).collect();
        // The second round starts from the anchors' planes the first one kept.
        let kept = AnchorPlanes::default();
        for round in 0..2 {
            let batch = normals_from(
                &queries,
                &rings,
                &index,
                10,
                f64::INFINITY,
                &kept,
                &Workers::new(2).unwrap(),
            );
            for (n, &i) in batch.iter().zip(&picked) {
                assert_eq!(*n, whole[i], "round {round}, point {i}");
            }
        }
        // The rings are scan lines, and most of their points take an anchor's plane.
        let shared = rings
            .iter()
            .zip(&whole)
            .enumerate()
            .filter(|(i, (p, n))| {
                let mut nearest = Vec::new();
                index.nearest_k(p, 10, &mut nearest);
                !is_anchor(*i) && nearest.iter().any(|&j| is_anchor(j) && whole[j] == **n)
            })
            .count();
        assert!(
            shared > rings.len() / 2,
            "{shared} of {} share a plane",
            rings.len()
        );
    }

    /// A pole standing on the ground: its points form a line, the ground beside it a surface
    /// across it; together they span no surface of the pole, so the pole gets no normal.
    #[test]
    fn a_pole_gets_no_normal_from_the_ground_below_it() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(22);
        let noise = Normal::new(0.0, 0.002).unwrap();
        let mut points: Vec<Point> = (0..60).map(|i| [0.0, 0.0, 0.05 * i as f64]).collect();
        for i in -20..=20 {
            for j in -20..=20 {
                points.push([0.1 * i as f64, 0.1 * j as f64, 0.0]);
            }
        }
        let points: Vec<Point> = points
            .iter()
            .map(|p| p.map(|c| c + noise.sample(&mut rng)))
            .collect();
        let normals = normals_with(&points, 10, 1);
        // Pole points from 0.5 m up: far enough from the ground that their 10 nearest are the pole.
        for (i, n) in normals.iter().enumerate().take(60).skip(10) {
            assert_eq!(*n, [0.0; 3], "pole point {i} at {:?}", points[i]);
        }
        // The ground keeps its normal.
        let up = [0.0, 0.0, 1.0];
        let level = normals[60..]
            .iter()
            .filter(|n| angle_degrees(n, &up).min(180.0 - angle_degrees(n, &up)) < 5.0);
        assert!(level.count() > 1600);
    }

    /// Median over the first 2000 normals of the angle to ±`truth` (degrees).
    fn median_angle_error(normals: &[Point], truth: &Point) -> f64 {
        let mut errors: Vec<f64> = normals[..2000]
            .iter()
            .map(|n| angle_degrees(n, truth).min(angle_degrees(n, &truth.map(|c| -c))))
            .collect();
        errors.sort_by(f64::total_cmp);
        errors[errors.len() / 2]
    }

    /// 200 000 points on a 4 × 4 plane with σ = 1 cm: the 10 nearest points lie within ~1.6 cm,
    /// so plain k-NN normals are noise; the data-chosen scale thins the cloud until they are
    /// planes. A clean plane keeps plain k-NN (factor 1, identical normals).
    #[test]
    fn data_scale_thins_dense_noisy_clouds_only() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let normal = [0.0, 0.0, 1.0];
        let centre = [0.0, 0.0, -2.0];
        let workers = Workers::new(2).unwrap();
        let median_error = |points: &[Point], normals: &[Point]| {
            assert_eq!(points.len(), normals.len());
            median_angle_error(normals, &normal)
        };
        let noisy = noisy_plane(&mut rng, &normal, &centre, 200_000, 0.01);
        let index = NearestNeighbours::new(&noisy).unwrap();
        let plain = estimate_normals(&noisy, &index, 10, &workers);
        let (scaled, factor) = estimate_normals_at_data_scale(&noisy, &index, 10, &workers);
        let (plain_error, scaled_error) = (median_error(&noisy, &plain), median_error(&noisy, &scaled));
        assert!(factor >= 16, "factor {factor}");
        assert!(plain_error > 20.0, "plain k-NN median error {plain_error}°");
        assert!(scaled_error < 5.0, "data-scale median error {scaled_error}°");

        let clean = noisy_plane(&mut rng, &normal, &centre, 20_000, 0.0005);
        let index = NearestNeighbours::new(&clean).unwrap();
        let (scaled, factor) = estimate_normals_at_data_scale(&clean, &index, 10, &workers);
        assert_eq!(factor, 1);
        assert_eq!(scaled, estimate_normals(&clean, &index, 10, &workers));
    }

    /// 200 000 points on a 4 × 4 plane with σ = 3 cm: the 10 nearest points lie within ~1.6 cm,
    /// a ball inside the noise whose thickness ratio the first thinning steps do not change.
    /// Thinning must go on until the neighbourhoods outgrow the noise (the 10 M-point room).
    #[test]
    fn data_scale_thins_through_noise_balls() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
        let normal = [0.0, 0.0, 1.0];
        let workers = Workers::new(2).unwrap();
        let noisy = noisy_plane(&mut rng, &normal, &[0.0, 0.0, -2.0], 200_000, 0.03);
        let index = NearestNeighbours::new(&noisy).unwrap();
        let probes: Vec<Point> = noisy.iter().step_by(400).copied().collect();
        let plain_ratio = median_thickness(&probes, &noisy, &index, 10, &Workers::new(1).unwrap());
        assert!(
            plain_ratio > BALL_NEIGHBOURHOOD_RATIO,
            "plain ratio {plain_ratio}"
        );
        let (scaled, factor) = estimate_normals_at_data_scale(&noisy, &index, 10, &workers);
        let median_error = median_angle_error(&scaled, &normal);
        assert!(factor >= 64, "factor {factor}");
        assert!(median_error < 10.0, "median error {median_error}°");
    }

    #[test]
    fn eigenvalues_of_a_diagonal_and_a_rotated_matrix() {
        assert_eq!(
            eigenvalues_ascending(&[[3.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]])
                .map(|v| (v * 1e9).round()),
            [1e9, 2e9, 3e9]
        );
        // R·diag(0.01, 1, 4)·Rᵀ for a rotation about (1, 1, 1).
        let m = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(0.01, 1.0, 4.0));
        let r = nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::x_axis(), 0.7)
            * nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), 0.4);
        let a = r.matrix() * m * r.matrix().transpose();
        let values = eigenvalues_ascending(&[0, 1, 2].map(|i| [0, 1, 2].map(|j| a[(i, j)])));
        for (got, want) in values.iter().zip([0.01, 1.0, 4.0]) {
            assert!((got - want).abs() < 1e-12, "{values:?}");
        }
    }

    #[test]
    fn same_result_for_one_and_two_threads() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        // More than two chunks, so both threads get work.
        let points: Vec<Point> = (0..3 * crate::parallel::CHUNK + 123)
            .map(|_| {
                [
                    rng.random::<f64>(),
                    rng.random::<f64>(),
                    0.1 * rng.random::<f64>(),
                ]
            })
            .collect();
        assert_eq!(normals_with(&points, 10, 1), normals_with(&points, 10, 2));
    }

    #[test]
    fn closed_form_agrees_with_nalgebra() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
        let gauss = Normal::new(0.0, 1.0).unwrap();
        for trial in 0..20_000 {
            let m = if trial % 2 == 0 {
                // Random PSD matrix Σ wᵢ vᵢvᵢᵀ, eigenvalues spanning up to 8 decades.
                let mut m = Matrix3::zeros();
                for _ in 0..3 {
                    let v = Vector3::from_fn(|_, _| gauss.sample(&mut rng));
                    m += v * v.transpose() * 10f64.powf(rng.random_range(-8.0..0.0));
                }
                m
            } else {
                // Random rotation of eigenvalues with a nearly coinciding pair (either the two
                // largest, a disc-shaped patch, or the two smallest, a thick line).
                let q = Vector3::from_fn(|_, _| gauss.sample(&mut rng)).normalize();
                let rotation = nalgebra::Rotation3::new(q * rng.random_range(0.0..3.0)).into_inner();
                let close = 10f64.powf(rng.random_range(-12.0..-2.0));
                let far = 10f64.powf(rng.random_range(-6.0..0.0));
                let values = if trial % 4 == 1 {
                    [1.0, 1.0 - close, far]
                } else {
                    [1.0, far * (1.0 + close), far]
                };
                rotation * Matrix3::from_diagonal(&Vector3::from(values)) * rotation.transpose()
            };
            let a = [0, 1, 2].map(|r| [0, 1, 2].map(|c| m[(r, c)]));
            let eig = SymmetricEigen::new(m);
            let mut order = [0, 1, 2];
            order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
            let [lo, mid, hi] = order.map(|i| eig.eigenvalues[i]);
            let reference = eig.eigenvectors.column(order[0]);
            let reference = [reference[0], reference[1], reference[2]];
            let Some(got) = smallest_eigenvector(&a) else {
                assert!(
                    mid < 1e-9 * hi,
                    "trial {trial}: rejected as a line, eigenvalues {lo} {mid} {hi}"
                );
                continue;
            };
            // An eigenvector's direction error is about rounding / eigen-gap.
            let tolerance = 1e-12 * hi / (mid - lo);
            let c = cross(&got, &reference);
            let sine = dot(&c, &c).sqrt();
            assert!(
                sine < tolerance.max(1e-9),
                "trial {trial}: sin {sine}, gap {}",
                (mid - lo) / hi
            );
        }
    }

    #[test]
    fn smallest_eigenvector_on_exact_cases() {
        let diag = [[3.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]];
        let n = smallest_eigenvector(&diag).unwrap();
        assert!((n[1].abs() - 1.0).abs() < 1e-15, "{n:?}");
        assert_eq!(
            smallest_eigenvector(&[[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]),
            None
        );
        assert_eq!(smallest_eigenvector(&[[0.0; 3]; 3]), None);
        // Rank one: a line.
        let line = [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [3.0, 6.0, 9.0]];
        assert_eq!(smallest_eigenvector(&line), None);
    }
}
