//! A target cloud prepared once for many registrations: sorted along a space-filling curve,
//! indexed by a kd-tree, with its normals (given, or estimated on demand and kept).
//!
//! Immutable from the outside and `Send + Sync`: share one behind an `Arc` between threads and
//! register many sources against it at once (odometry onto the previous frame, scan-to-map).
//! Estimated normals are filled lazily by whichever registration first matches a target point
//! and kept for the later ones; two threads that race on the same point compute the same bits,
//! so results never depend on who got there first.
use std::collections::HashMap;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::Instant;

use super::config::{RegistrationConfig, require_normal_neighbours};
use super::input::{Selection, Skip, require_finite, require_points, require_unit_normals};
use super::units::Units;
use crate::error::Error;
use crate::geometry::is_finite;
use crate::median::median;
use crate::memory::{self, MemoryError, try_vec};
use crate::nn::NearestNeighbours;
use crate::normals::NormalScale;
use crate::parallel::Workers;
use crate::point::{NonFinite, Point};

/// Indices are u32 with u32::MAX reserved for "no match".
pub(crate) const NO_MATCH: u32 = u32::MAX;

/// Normals `estimate_all_normals` estimates at a time (52 bytes each while it runs; the fixed
/// part of `memory::target_normals_bytes`).
const NORMALS_BLOCK: usize = 1 << 16;

/// Surface normals a target keeps, at most (33 bytes a slot in a table of up to 2^17 slots:
/// about 4.3 MB): many times one surface sample (`degeneracy::SURFACE_PAIRS`), so the runs of
/// one registration and the next registrations onto the same target find theirs, and a small
/// bound whatever the target's size.
const SURFACE_NORMALS_KEPT: usize = 1 << 16;

/// How a target is prepared.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PrepareOptions {
    /// Neighbours for PCA normals when none are given (as `RegistrationConfig::normal_neighbours`;
    /// a registration whose config asks for another count is refused).
    pub normal_neighbours: usize,
    /// Target points with a NaN or infinite coordinate: refused, or dropped (correspondences
    /// still name the caller's indices; a non-finite given normal then counts as "no normal").
    pub non_finite: NonFinite,
    /// Drop target points at exactly 0 0 0 (depth sensors' invalid pixels).
    pub skip_origin: bool,
}

impl Default for PrepareOptions {
    fn default() -> Self {
        PrepareOptions {
            normal_neighbours: RegistrationConfig::default().normal_neighbours,
            non_finite: NonFinite::Reject,
            skip_origin: false,
        }
    }
}

impl PrepareOptions {
    /// The options `register_clouds` prepares its target with under `config`.
    pub fn from_config(config: &RegistrationConfig) -> Self {
        PrepareOptions {
            normal_neighbours: config.normal_neighbours,
            non_finite: config.non_finite,
            skip_origin: config.skip_origin,
        }
    }
}

/// A target cloud ready for `register_clouds_to`. See the module documentation.
pub struct PreparedTarget {
    /// The (kept) target points in curve order; the kd-tree's indices refer to this copy, so the
    /// targets consecutive queries find, and their normals, are neighbours in memory.
    points: Vec<Point>,
    /// `points[t]` is kept point `order[t]` (kept points are numbered in the caller's order).
    order: Vec<u32>,
    /// The caller's index of each kept point when points were dropped (non-finite, the
    /// origin) or merged (exact copies: each location is kept once, as its first copy).
    kept: Option<Vec<u32>>,
    /// Points the caller gave, dropped ones included.
    given_count: usize,
    index: NearestNeighbours,
    normals: TargetNormals,
    /// Where estimated normals take their neighbours from (`NormalScale::choose`), chosen by
    /// the first registration that needs normals: point-to-plane's own, or the surface
    /// conditioning of any ICP result (`registration::degeneracy`).
    normal_scale: OnceLock<NormalScale>,
    /// The options' count, before capping at the cloud size (what configs are compared with).
    normal_neighbours: usize,
    index_seconds: f64,
    /// The units `points` are held in (the caller's unless they were beyond the safe range).
    units: Units,
    /// [`PreparedTarget::centroid`] with [`PreparedTarget::spread`], and
    /// [`PreparedTarget::spacing`], once asked for.
    moments: OnceLock<(Point, f64)>,
    spacing: OnceLock<f64>,
    /// Surface normals estimated so far (`surface_and_point_normals`): every run's final
    /// evaluation draws its surface sample from much the same inliers.
    surface_normals: Mutex<SurfaceNormals>,
}

/// Surface normals by curve-order target, for one neighbour count.
#[derive(Default)]
struct SurfaceNormals {
    neighbours: usize,
    by_target: HashMap<u32, Point>,
}

enum TargetNormals {
    /// The caller's normals in curve order; `[0, 0, 0]` = no normal. `any`: some is non-zero.
    Given { normals: Vec<Point>, any: bool },
    /// Estimated by k-NN PCA, set up by the first point-to-plane registration.
    Estimated(Box<OnceLock<EstimatedNormals>>),
}

/// A view of a target's normals (see `PreparedTarget::normals`).
pub(crate) enum Normals<'a> {
    /// Not set up (point-to-point so far): every normal reads `[0, 0, 0]`.
    None,
    Given(&'a [Point]),
    Estimated(&'a EstimatedNormals),
}

impl Normals<'_> {
    /// The normal of curve-order target `t` (`[0, 0, 0]`: none, or not estimated yet).
    pub(crate) fn get(&self, t: usize) -> Point {
        match self {
            Normals::None => [0.0; 3],
            Normals::Given(normals) => normals[t],
            Normals::Estimated(estimated) => estimated.get(t).unwrap_or([0.0; 3]),
        }
    }
}

/// Normals filled as registrations reach their points. Components are stored as f32 bits in
/// atomics so that concurrent registrations can fill them without locks: 12 bytes a target
/// point (f64 with a flag took 25; at 10 M points that is 124 MiB). A plane's orientation to
/// 6e-8 rad is far below any scan's noise. The x component is written last (release) and
/// read first (acquire); [`UNKNOWN`] there marks a normal not estimated yet.
pub(crate) struct EstimatedNormals {
    values: Vec<[AtomicU32; 3]>,
}

/// The x component's bits before the normal is estimated: a NaN no estimate stores (a normal
/// that is not finite is stored as 0 0 0, "no normal").
const UNKNOWN: u32 = u32::MAX;

impl EstimatedNormals {
    fn new(count: usize) -> Self {
        EstimatedNormals {
            values: (0..count)
                .map(|_| [AtomicU32::new(UNKNOWN), AtomicU32::new(0), AtomicU32::new(0)])
                .collect(),
        }
    }

    /// The normal of curve-order target `t`, `None` when not estimated yet.
    fn get(&self, t: usize) -> Option<Point> {
        let [x, y, z] = &self.values[t];
        let x = x.load(Ordering::Acquire);
        (x != UNKNOWN).then(|| {
            [x, y.load(Ordering::Relaxed), z.load(Ordering::Relaxed)].map(|c| f64::from(f32::from_bits(c)))
        })
    }

    fn is_known(&self, t: usize) -> bool {
        self.values[t][0].load(Ordering::Acquire) != UNKNOWN
    }

    /// Stores the normal of `t`; racing writers store the same bits.
    fn set(&self, t: usize, normal: Point) {
        let stored = stored_bits(&normal);
        let [x, y, z] = &self.values[t];
        y.store(stored[1], Ordering::Relaxed);
        z.store(stored[2], Ordering::Relaxed);
        x.store(stored[0], Ordering::Release);
    }
}

/// The bits [`EstimatedNormals`] keeps of a normal: f32 components, 0 0 0 for one that is not
/// finite.
fn stored_bits(normal: &Point) -> [u32; 3] {
    if is_finite(normal) {
        normal.map(|c| (c as f32).to_bits())
    } else {
        [0.0f32.to_bits(); 3]
    }
}

/// A normal as [`EstimatedNormals`] gives it back once stored.
fn as_stored(normal: &Point) -> Point {
    stored_bits(normal).map(|c| f64::from(f32::from_bits(c)))
}

impl PreparedTarget {
    /// Sorts `target` along a space-filling curve and builds its kd-tree. `normals` (one unit
    /// vector per point, `[0, 0, 0]` for none) are used by point-to-plane; without them, normals
    /// are estimated from `normal_neighbours` neighbours when a registration first needs them.
    ///
    /// Errors: fewer than 3 (finite) points, a non-finite coordinate or normal (unless
    /// [`NonFinite::Skip`]), a normal count that differs from the point count, a finite normal
    /// that is neither of unit length (within [`NORMAL_LENGTH_TOLERANCE`](crate::NORMAL_LENGTH_TOLERANCE)) nor 0 0 0, a bad
    /// `normal_neighbours`, more than u32::MAX − 1 points; not enough memory for the
    /// preparation ([`Error::OutOfMemory`], asked for before it starts).
    pub fn new(target: &[Point], normals: Option<&[Point]>, options: &PrepareOptions) -> Result<Self, Error> {
        Self::build(target, normals, options, true)
    }

    /// [`PreparedTarget::new`] for `register_clouds`, whose up-front memory check covers the
    /// preparation already.
    pub(crate) fn new_within_checked_memory(
        target: &[Point],
        normals: Option<&[Point]>,
        options: &PrepareOptions,
    ) -> Result<Self, Error> {
        Self::build(target, normals, options, false)
    }

    fn build(
        target: &[Point],
        normals: Option<&[Point]>,
        options: &PrepareOptions,
        check_memory: bool,
    ) -> Result<Self, Error> {
        require_normal_neighbours(options.normal_neighbours)?;
        if let Some(normals) = normals {
            if normals.len() != target.len() {
                return Err(Error::InvalidArgument(format!(
                    "target has {} points but {} normals",
                    target.len(),
                    normals.len()
                )));
            }
            require_unit_normals("target normals", normals)?;
        }
        if check_memory {
            // Asked for up front: the kd-tree (and the unit conversion) allocate infallibly, so a
            // memory limit is an error here, not an abort part-way.
            memory::ensure_available(
                memory::prepared_target_bytes(target.len(), normals.is_some()),
                "preparing this target",
            )?;
        }
        let skip = Skip {
            non_finite: options.non_finite,
            origin: options.skip_origin,
        };
        // Refused with the caller's index, before any point is dropped or merged.
        if skip.non_finite == NonFinite::Reject {
            require_finite("target", target)?;
        }
        // Each distinct location once (see `Selection`): normals from distinct neighbours, the
        // spacing that of distinct locations, one match per location.
        let selection = Selection::of(target, skip, "target")?;
        require_points(
            "target",
            selection.as_ref().map_or(target.len(), Selection::kept_points),
            3,
        )?;
        let kept = selection.map(Selection::into_first);
        let pick = |points: &[Point], what: &str| -> Result<Vec<Point>, MemoryError> {
            let mut picked = try_vec(kept.as_ref().map_or(points.len(), Vec::len), what)?;
            match &kept {
                Some(kept) => picked.extend(kept.iter().map(|&i| points[i as usize])),
                None => picked.extend_from_slice(points),
            }
            Ok(picked)
        };
        // Copies only when points are dropped or merged.
        let kept_points = match kept {
            Some(_) => Some(pick(target, "the target's kept points")?),
            None => None,
        };
        let points = kept_points.as_deref().unwrap_or(target);
        let kept_normals: Option<Vec<Point>> = match (normals, options.non_finite) {
            (Some(normals), NonFinite::Skip) => {
                let mut picked = pick(normals, "the target's kept normals")?;
                for n in picked.iter_mut().filter(|n| !is_finite(n)) {
                    *n = [0.0; 3];
                }
                Some(picked)
            }
            (Some(normals), NonFinite::Reject) => {
                require_finite("target normals", normals)?;
                // Merged copies keep their first copy's normal, as they keep its point.
                match kept {
                    Some(_) => Some(pick(normals, "the target's kept normals")?),
                    None => None,
                }
            }
            (None, _) => None,
        };
        let normals = kept_normals.as_deref().or(normals);
        if points.len() >= NO_MATCH as usize {
            return Err(Error::InvalidArgument(format!(
                "target has {} points; at most {} are supported",
                points.len(),
                NO_MATCH - 1
            )));
        }
        // Coordinates beyond the safe range are held in units where they are not (the results
        // are converted back by the registration).
        let units = Units::of_lengths(&[], points);
        let normalised = (!units.is_identity()).then(|| units.points(points));
        let points = normalised.as_deref().unwrap_or(points);
        let started = Instant::now();
        let mut order: Vec<u32> = try_vec(points.len(), "the target's curve order")?;
        order.extend(0..points.len() as u32);
        try_sort_along_curve(points, &mut order)?;
        let in_order = |values: &[Point], what: &str| -> Result<Vec<Point>, MemoryError> {
            let mut sorted = try_vec(order.len(), what)?;
            sorted.extend(order.iter().map(|&i| values[i as usize]));
            Ok(sorted)
        };
        let sorted = in_order(points, "the target points in curve order")?;
        let normals = match normals {
            Some(given) => {
                let normals = in_order(given, "the target normals in curve order")?;
                let any = normals.iter().any(|n| *n != [0.0; 3]);
                TargetNormals::Given { normals, any }
            }
            None => TargetNormals::Estimated(Box::default()),
        };
        // The copies in the caller's order are not needed once sorted: freed before the tree.
        drop((kept_points, kept_normals, normalised));
        // Distinct as given; a change of units (rounded) may make some coincide again.
        let index = if units.is_identity() {
            NearestNeighbours::of_distinct(&sorted)?
        } else {
            NearestNeighbours::new(&sorted)?
        };
        let index_seconds = started.elapsed().as_secs_f64();
        Ok(PreparedTarget {
            points: sorted,
            order,
            kept,
            given_count: target.len(),
            index,
            normals,
            normal_scale: OnceLock::new(),
            normal_neighbours: options.normal_neighbours,
            index_seconds,
            units,
            moments: OnceLock::new(),
            spacing: OnceLock::new(),
            surface_normals: Mutex::default(),
        })
    }

    /// Points the caller gave (dropped non-finite ones included).
    pub fn len(&self) -> usize {
        self.given_count
    }

    /// Whether the caller gave no point.
    pub fn is_empty(&self) -> bool {
        self.given_count == 0
    }

    /// Points indexed: the distinct locations among the kept points (the finite ones when
    /// non-finite points were skipped); a location the caller gave several times is one point.
    pub fn indexed_len(&self) -> usize {
        self.points.len()
    }

    /// Whether the caller gave normals.
    pub fn has_given_normals(&self) -> bool {
        matches!(self.normals, TargetNormals::Given { .. })
    }

    /// The neighbour count estimated normals use (`PrepareOptions::normal_neighbours`).
    pub fn normal_neighbours(&self) -> usize {
        self.normal_neighbours
    }

    /// Seconds spent sorting and building the kd-tree.
    pub fn index_seconds(&self) -> f64 {
        self.index_seconds
    }

    /// Estimates every normal not estimated yet (point-to-plane without given normals), on
    /// `threads` threads (0 = one per core), so that no later registration pays for them:
    /// e.g. for a map prepared in the background. Registrations otherwise estimate the normals
    /// they reach, which is less work when they reach only part of the target. Returns the
    /// seconds spent. Results are the same either way, bit for bit.
    ///
    /// Errors: more than 1024 threads ([`Error::InvalidArgument`]); not enough memory for the
    /// normals ([`Error::OutOfMemory`], asked for before any is estimated; the target is
    /// unchanged and stays usable).
    pub fn estimate_all_normals(&self, threads: usize) -> Result<f64, Error> {
        let workers = Workers::new(threads).map_err(Error::InvalidArgument)?;
        let started = Instant::now();
        if let TargetNormals::Estimated(cell) = &self.normals {
            let n = self.points.len();
            // Asked for up front: the normals and the scale's thinned copies and kd-trees are
            // allocated infallibly. Once set up, only a block's working memory is left to need.
            let needing = if cell.get().is_some() { 0 } else { n };
            memory::ensure_available(
                memory::target_normals_bytes(needing),
                "estimating this target's normals",
            )?;
            // In blocks, so that the working memory is a block's, not the target's.
            for start in (0..n).step_by(NORMALS_BLOCK) {
                let end = n.min(start + NORMALS_BLOCK);
                self.ensure_normals(start as u32..end as u32, &workers);
            }
        }
        Ok(started.elapsed().as_secs_f64())
    }

    /// The caller's (kept) points in the caller's order, for per-point noise callbacks.
    pub(crate) fn points_in_caller_order(&self) -> Vec<Point> {
        let mut points = vec![[0.0; 3]; self.points.len()];
        for (t, &k) in self.order.iter().enumerate() {
            points[k as usize] = self.units.point_out(&self.points[t]);
        }
        points
    }

    /// RMS distance of the target points from their centroid (over at most 1024 evenly
    /// strided points), in the units the points are held in. Computed once per target.
    pub(crate) fn spread(&self) -> f64 {
        self.moments().1
    }

    /// Centroid of the target points (over the same points as [`PreparedTarget::spread`]).
    pub(crate) fn centroid(&self) -> Point {
        self.moments().0
    }

    fn moments(&self) -> (Point, f64) {
        *self.moments.get_or_init(|| {
            let sample: Vec<Point> = self.points.iter().step_by(self.stride()).copied().collect();
            let n = sample.len().max(1) as f64;
            let centre: Point = std::array::from_fn(|axis| sample.iter().map(|p| p[axis]).sum::<f64>() / n);
            let sum: f64 = sample
                .iter()
                .map(|p| (0..3).map(|a| (p[a] - centre[a]).powi(2)).sum::<f64>())
                .sum();
            (centre, (sum / n).sqrt())
        })
    }

    /// Median distance from a target point to its nearest other target point (over at most
    /// 1024 evenly strided points), in the units the points are held in. Computed once per
    /// target (a map or the previous frame is judged against by many registrations).
    pub(crate) fn spacing(&self) -> f64 {
        *self.spacing.get_or_init(|| {
            let mut gaps: Vec<f64> = self
                .points
                .iter()
                .step_by(self.stride())
                .map(|p| self.index.nearest_two(p).2)
                .filter(|d| d.is_finite())
                .collect();
            median(&mut gaps).unwrap_or(0.0)
        })
    }

    /// The step that visits at most 1024 of the points.
    fn stride(&self) -> usize {
        self.points.len().div_ceil(1024).max(1)
    }

    /// The units the points are held in.
    pub(crate) fn units(&self) -> Units {
        self.units
    }

    pub(crate) fn points(&self) -> &[Point] {
        &self.points
    }

    pub(crate) fn order(&self) -> &[u32] {
        &self.order
    }

    pub(crate) fn kept(&self) -> Option<&[u32]> {
        self.kept.as_deref()
    }

    pub(crate) fn index(&self) -> &NearestNeighbours {
        &self.index
    }

    /// Given normals that are all zero (point-to-plane has nothing to work with).
    pub(crate) fn given_normals_all_zero(&self) -> bool {
        matches!(self.normals, TargetNormals::Given { any: false, .. })
    }

    /// The neighbourhood scale of estimated normals, chosen now if no registration has yet.
    fn normal_scale(&self, workers: &Workers) -> &NormalScale {
        self.normal_scale.get_or_init(|| {
            let k = self.normal_neighbours.min(self.points.len());
            NormalScale::choose(&self.points, Some(&self.order), &self.index, k, workers)
        })
    }

    /// Chooses the neighbourhood scale of estimated normals if no registration has yet;
    /// returns the seconds this call spent on it.
    pub(crate) fn prepare_normal_scale(&self, workers: &Workers) -> f64 {
        let started = Instant::now();
        self.normal_scale(workers);
        started.elapsed().as_secs_f64()
    }

    /// Sets up normal estimation (chooses the neighbourhood scale, makes room for the normals)
    /// if no registration has yet; returns the seconds this call spent on it.
    pub(crate) fn prepare_normal_estimation(&self, workers: &Workers) -> f64 {
        let started = Instant::now();
        if let TargetNormals::Estimated(cell) = &self.normals {
            self.normal_scale(workers);
            cell.get_or_init(|| EstimatedNormals::new(self.points.len()));
        }
        started.elapsed().as_secs_f64()
    }

    /// Estimates the normals of `targets` (curve-order indices, repeats allowed) that are not
    /// known yet. Needs `prepare_normal_estimation` first; a no-op for given normals.
    pub(crate) fn ensure_normals(&self, targets: impl Iterator<Item = u32>, workers: &Workers) {
        self.prepare_normal_estimation(workers);
        let TargetNormals::Estimated(cell) = &self.normals else {
            return;
        };
        let (Some(estimated), Some(scale)) = (cell.get(), self.normal_scale.get()) else {
            return;
        };
        let mut missing: Vec<u32> = targets
            .filter(|&t| t != NO_MATCH && !estimated.is_known(t as usize))
            .collect();
        if missing.is_empty() {
            return;
        }
        // Curve order: neighbouring queries visit the same tree nodes.
        missing.sort_unstable();
        missing.dedup();
        let queries: Vec<Point> = missing.iter().map(|&t| self.points[t as usize]).collect();
        let k = self.normal_neighbours.min(self.points.len());
        let found = scale.normals_at(&self.points, &self.index, &queries, k, workers);
        for (&t, n) in missing.iter().zip(found) {
            estimated.set(t as usize, n);
        }
    }

    /// Normals at the curve-order targets `targets` from their `normal_neighbours` nearest
    /// points, at the scale estimated normals use, not kept: for a point-to-point registration's
    /// checks, which must leave a shared target's normals as its registrations found them.
    pub(crate) fn normals_not_kept(&self, targets: &[u32], workers: &Workers) -> Vec<Point> {
        let queries: Vec<Point> = targets.iter().map(|&t| self.points[t as usize]).collect();
        let k = self.normal_neighbours.min(self.points.len());
        self.normal_scale(workers)
            .normals_at(&self.points, &self.index, &queries, k, workers)
    }

    /// Normals at the curve-order targets `targets`, at the scale estimated normals use (given
    /// normals or not), not kept. First from their `neighbours` nearest points: with more
    /// neighbours than `normal_neighbours`, a view of the surfaces in which the points' noise
    /// hardly tilts a normal, `[0, 0, 0]` where the neighbourhood is no plane (an edge, a
    /// corner: `NormalScale::planar_normals_at`). Second, the per-point normals point-to-plane
    /// uses: given, estimated, or estimated now from the `normal_neighbours` nearest by the same
    /// search and to the same precision as stored ones, so that a shared target's stored
    /// normals and a fresh target's give the same bits (a nearest-k search may keep other
    /// points among ties at its k-th distance for another k).
    pub(crate) fn surface_and_point_normals(
        &self,
        targets: &[u32],
        neighbours: usize,
        workers: &Workers,
    ) -> (Vec<Point>, Vec<Point>) {
        let surface = self.surface_normals(targets, neighbours, workers);
        let known = self.normals();
        let stored = |t: u32| match &known {
            Normals::None => None,
            Normals::Given(normals) => Some(normals[t as usize]),
            Normals::Estimated(estimated) => estimated.get(t as usize),
        };
        // Read once: another registration sharing the target may store normals meanwhile.
        let point: Vec<Option<Point>> = targets.iter().map(|&t| stored(t)).collect();
        let missing: Vec<u32> = targets
            .iter()
            .zip(&point)
            .filter(|(_, normal)| normal.is_none())
            .map(|(&t, _)| t)
            .collect();
        let mut estimated = self
            .normals_not_kept(&missing, workers)
            .into_iter()
            .map(|normal| as_stored(&normal));
        let point = point
            .into_iter()
            .map(|normal| normal.or_else(|| estimated.next()).unwrap_or([0.0; 3]))
            .collect();
        (surface, point)
    }

    /// `NormalScale::planar_normals_at` the curve-order targets `targets`, each estimated once:
    /// the same bits as estimated anew (each normal depends on its point alone).
    fn surface_normals(&self, targets: &[u32], neighbours: usize, workers: &Workers) -> Vec<Point> {
        // The map only ever holds whole normals: a panic elsewhere leaves it usable.
        let kept = || {
            self.surface_normals
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner())
        };
        let known: Vec<Option<Point>> = {
            let kept = kept();
            let same_count = kept.neighbours == neighbours;
            targets
                .iter()
                .map(|t| kept.by_target.get(t).copied().filter(|_| same_count))
                .collect()
        };
        let mut missing: Vec<u32> = targets
            .iter()
            .zip(&known)
            .filter(|(_, normal)| normal.is_none())
            .map(|(&t, _)| t)
            .collect();
        missing.sort_unstable();
        missing.dedup();
        let queries: Vec<Point> = missing.iter().map(|&t| self.points[t as usize]).collect();
        let found = self.normal_scale(workers).planar_normals_at(
            &self.points,
            &self.index,
            &queries,
            neighbours,
            workers,
        );
        let surface = targets
            .iter()
            .zip(known)
            .map(|(t, normal)| normal.unwrap_or_else(|| found[missing.binary_search(t).unwrap_or(0)]))
            .collect();
        let mut kept = kept();
        if kept.neighbours != neighbours || kept.by_target.len() + missing.len() > SURFACE_NORMALS_KEPT {
            kept.by_target.clear();
            kept.neighbours = neighbours;
        }
        kept.by_target.extend(missing.into_iter().zip(found));
        surface
    }

    /// The normal of curve-order target `t`: given, or estimated (`[0, 0, 0]`: none, or not
    /// estimated yet, or point-to-point).
    #[cfg(test)]
    pub(crate) fn normal(&self, t: usize) -> Point {
        self.normals().get(t)
    }

    /// The normals as they are now, for many look-ups.
    pub(crate) fn normals(&self) -> Normals<'_> {
        match &self.normals {
            TargetNormals::Given { normals, .. } => Normals::Given(normals),
            TargetNormals::Estimated(cell) => match cell.get() {
                Some(estimated) => Normals::Estimated(estimated),
                None => Normals::None,
            },
        }
    }
}

/// Reorders `indices` along a Morton (Z-order) curve over the points' bounding box (21 bits
/// per axis); ties keep index order, so the result is deterministic.
pub(crate) fn sort_along_curve(points: &[Point], indices: &mut [u32]) {
    sort_with(points, indices, Vec::with_capacity(indices.len()));
}

/// [`sort_along_curve`] with its working memory (16 bytes an index) allocated fallibly.
fn try_sort_along_curve(points: &[Point], indices: &mut [u32]) -> Result<(), MemoryError> {
    let keyed = try_vec(indices.len(), "sorting the target along its curve")?;
    sort_with(points, indices, keyed);
    Ok(())
}

/// [`sort_along_curve`] in `keyed`, an empty buffer with room for every index.
fn sort_with(points: &[Point], indices: &mut [u32], mut keyed: Vec<(u64, u32)>) {
    let (mut low, mut high) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for &i in indices.iter() {
        for axis in 0..3 {
            low[axis] = low[axis].min(points[i as usize][axis]);
            high[axis] = high[axis].max(points[i as usize][axis]);
        }
    }
    const CELLS: f64 = ((1u32 << 21) - 1) as f64;
    let scale: [f64; 3] = std::array::from_fn(|axis| {
        let extent = high[axis] - low[axis];
        if extent > 0.0 { CELLS / extent } else { 0.0 }
    });
    let key = |i: u32| -> u64 {
        let p = points[i as usize];
        (0..3).fold(0, |code, axis| {
            let cell = ((p[axis] - low[axis]) * scale[axis]).clamp(0.0, CELLS) as u64;
            code | (spread_bits(cell) << axis)
        })
    };
    // Keys made unique by the index: an unstable sort gives the one order, and sorting 16-byte
    // pairs needs less memory than a cached-key sort (24 bytes a point; 240 MB at 10 M).
    keyed.extend(indices.iter().map(|&i| (key(i), i)));
    keyed.sort_unstable();
    for (slot, (_, i)) in indices.iter_mut().zip(keyed) {
        *slot = i;
    }
}

/// Spreads the low 21 bits of `v` so that bit b moves to bit 3b.
fn spread_bits(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_bits_interleaves() {
        assert_eq!(spread_bits(0b1), 0b1);
        assert_eq!(spread_bits(0b11), 0b1001);
        assert_eq!(spread_bits(0b101), 0b1_000_001);
        assert_eq!(spread_bits(0x1f_ffff), 0x1249_2492_4924_9249);
    }

    #[test]
    fn curve_order_is_a_permutation_that_groups_nearby_points() {
        // Two far-apart clusters, interleaved in index order: the curve puts each together.
        let points: Vec<Point> = (0..100)
            .map(|i| {
                let base = if i % 2 == 0 { 0.0 } else { 100.0 };
                [base + (i / 2) as f64 * 1e-3, base, base]
            })
            .collect();
        let mut order: Vec<u32> = (0..100).collect();
        sort_along_curve(&points, &mut order);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..100).collect::<Vec<u32>>());
        let switches = order.windows(2).filter(|w| w[0] % 2 != w[1] % 2).count();
        assert_eq!(switches, 1, "{order:?}");
    }

    #[test]
    fn prepared_target_is_send_and_sync() {
        fn shareable<T: Send + Sync>() {}
        shareable::<PreparedTarget>();
    }

    #[test]
    fn lazy_normals_equal_normals_estimated_all_at_once() {
        let scene = crate::synthetic::room_scene(3_000, 0.01, 3);
        let lazy = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
        let eager = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
        eager.estimate_all_normals(2).unwrap();
        let workers = Workers::new(1).unwrap();
        // Lazy: every third point, then the rest in reverse, in small batches.
        let n = lazy.indexed_len() as u32;
        lazy.ensure_normals((0..n).step_by(3), &workers);
        for start in (0..n).rev().step_by(500) {
            lazy.ensure_normals(start.saturating_sub(500)..=start, &workers);
        }
        let estimated = (0..n as usize).filter(|&t| eager.normal(t) != [0.0; 3]).count();
        assert!(estimated > n as usize * 9 / 10, "{estimated} of {n}");
        for t in 0..n as usize {
            assert_eq!(
                lazy.normal(t).map(f64::to_bits),
                eager.normal(t).map(f64::to_bits),
                "target {t}"
            );
        }
    }

    /// All normals at once in blocks (a target of more than one block) against one batch of
    /// every point, as registrations estimate them: the same bits.
    #[test]
    fn normals_estimated_in_blocks_equal_one_batch() {
        let scene = crate::synthetic::room_scene(NORMALS_BLOCK + 5_000, 0.01, 5);
        let batch = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
        let blocks = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
        let n = batch.indexed_len();
        assert!(n > NORMALS_BLOCK, "{n} points: one block");
        batch.ensure_normals(0..n as u32, &Workers::new(2).unwrap());
        blocks.estimate_all_normals(2).unwrap();
        for t in 0..n {
            assert_eq!(
                blocks.normal(t).map(f64::to_bits),
                batch.normal(t).map(f64::to_bits),
                "target {t}"
            );
        }
    }

    /// Surface normals served from the target's map: the same bits as estimated anew on a
    /// fresh target, for samples with repeats, samples that overlap earlier ones, and a
    /// change of neighbour count (which must not serve the other count's normals).
    #[test]
    fn kept_surface_normals_equal_fresh_ones() {
        let scene = crate::synthetic::room_scene(3_000, 0.01, 6);
        let shared = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
        let workers = Workers::new(2).unwrap();
        let n = shared.indexed_len() as u32;
        let fresh = |targets: &[u32], neighbours: usize| {
            let target = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
            let queries: Vec<Point> = targets.iter().map(|&t| target.points[t as usize]).collect();
            target.normal_scale(&workers).planar_normals_at(
                &target.points,
                &target.index,
                &queries,
                neighbours,
                &workers,
            )
        };
        let bits =
            |normals: Vec<Point>| -> Vec<[u64; 3]> { normals.iter().map(|n| n.map(f64::to_bits)).collect() };
        let first: Vec<u32> = (0..n).step_by(7).chain((0..n).step_by(14)).collect();
        let overlapping: Vec<u32> = (0..n).step_by(5).collect();
        for (targets, neighbours) in [(&first, 50), (&overlapping, 50), (&overlapping, 30), (&first, 50)] {
            let kept = shared.surface_normals(targets, neighbours, &workers);
            let planar = kept.iter().filter(|n| **n != [0.0; 3]).count();
            assert!(planar > targets.len() / 4, "{planar} of {}", targets.len());
            assert_eq!(
                bits(kept),
                bits(fresh(targets, neighbours)),
                "{neighbours} neighbours"
            );
        }
    }

    /// Spacing and spread against brute force over the same strided points (every third of
    /// 3 000 points: the stride that visits at most 1024).
    #[test]
    fn spacing_and_spread_match_brute_force() {
        let scene = crate::synthetic::room_scene(3_000, 0.01, 4);
        let target = PreparedTarget::new(&scene.target, None, &PrepareOptions::default()).unwrap();
        let points = target.points();
        let probes: Vec<&Point> = points.iter().step_by(3).collect();
        let distance = |a: &Point, b: &Point| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt();
        let mut gaps: Vec<f64> = probes
            .iter()
            .map(|p| {
                points
                    .iter()
                    .filter(|q| !std::ptr::eq(*p, *q))
                    .map(|q| distance(p, q))
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        let median = median(&mut gaps).unwrap();
        assert_eq!(target.spacing(), median);
        assert_eq!(target.spacing(), median, "kept");
        let n = probes.len() as f64;
        let centre: Point = std::array::from_fn(|a| probes.iter().map(|p| p[a]).sum::<f64>() / n);
        let rms = (probes.iter().map(|p| distance(p, &centre).powi(2)).sum::<f64>() / n).sqrt();
        assert!(
            (target.spread() - rms).abs() <= 1e-12 * rms,
            "{} vs {rms}",
            target.spread()
        );
    }

    #[test]
    fn bad_targets_are_refused_with_a_reason() {
        let options = PrepareOptions::default();
        let two = [[0.0; 3], [1.0, 0.0, 0.0]];
        assert!(matches!(
            PreparedTarget::new(&two, None, &options),
            Err(Error::TooFewPoints(_))
        ));
        let nan = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [f64::NAN, 0.0, 0.0]];
        assert!(matches!(
            PreparedTarget::new(&nan, None, &options),
            Err(Error::NonFinite(_))
        ));
        let skipping = PrepareOptions {
            non_finite: NonFinite::Skip,
            ..options.clone()
        };
        let prepared = PreparedTarget::new(&nan, None, &skipping).unwrap();
        assert_eq!((prepared.len(), prepared.indexed_len()), (4, 3));
        assert_eq!(prepared.kept(), Some(&[0, 1, 2][..]));
        let err = PreparedTarget::new(&nan[..3], Some(&two), &options)
            .err()
            .unwrap();
        assert!(err.to_string().contains("3 points but 2 normals"), "{err}");
        let few_neighbours = PrepareOptions {
            normal_neighbours: 2,
            ..options
        };
        assert!(matches!(
            PreparedTarget::new(&nan[..3], None, &few_neighbours),
            Err(Error::InvalidArgument(_))
        ));
    }
}
