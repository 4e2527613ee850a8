//! The two registration problems the IRLS driver solves: fixed correspondences and ICP.
//! Each produces residual rows at a transform and solves the weighted step; buffers are reused
//! across iterations (no per-correspondence allocation per iteration).
use std::time::Instant;

use nalgebra::Matrix4;
use rand::SeedableRng;

use super::target::{NO_MATCH, PreparedTarget, sort_along_curve};
use super::{Metric, RegistrationConfig};
use crate::geometry::{
    Point, Solve, length, point_to_plane_step_by, splitmix64, transform_point, weighted_rigid_fit,
    weighted_rigid_fit_by,
};
use crate::median::median;
use crate::noise::combine;
use crate::parallel::Workers;

/// The noise scale F of each row (§4.4).
#[derive(Clone, Debug, Default)]
pub enum RowScales {
    /// Every F is 1 (constant noise, ICP's default): 8 bytes a row not stored, and the
    /// residuals are their own normalised values (no copy).
    #[default]
    Unit,
    PerRow(Vec<f64>),
}

impl RowScales {
    /// F of `row`.
    pub fn get(&self, row: usize) -> f64 {
        match self {
            RowScales::Unit => 1.0,
            RowScales::PerRow(scales) => scales[row],
        }
    }

    /// The scales row by row; `None` when every F is 1.
    pub fn per_row(&self) -> Option<&[f64]> {
        match self {
            RowScales::Unit => None,
            RowScales::PerRow(scales) => Some(scales),
        }
    }

    /// The median F (1 when every F is 1 or there are no rows).
    pub fn median(&self) -> f64 {
        match self.per_row() {
            Some(scales) => median(&mut scales.to_vec()).unwrap_or(1.0),
            None => 1.0,
        }
    }

    fn push(&mut self, scale: f64) {
        if let RowScales::PerRow(scales) = self {
            scales.push(scale);
        }
    }

    fn clear(&mut self) {
        if let RowScales::PerRow(scales) = self {
            scales.clear();
        }
    }

    fn reserve_exact(&mut self, rows: usize) {
        if let RowScales::PerRow(scales) = self {
            scales.reserve_exact(rows);
        }
    }
}

/// Residual rows of one iteration.
#[derive(Default)]
pub struct Rows {
    /// Number of rows.
    count: usize,
    /// Source point of each row; empty for the rows of an ICP update, which the solver reads
    /// through its pass (8 bytes a row less at the registration's peak).
    pub source: Vec<u32>,
    /// Matched target point of each row; empty where `source` is.
    pub target: Vec<u32>,
    /// Residuals, rows × cols, input units.
    pub residual: Vec<f64>,
    /// Noise scale F of each row (§4.4).
    pub scale: RowScales,
    /// Source points this pass looked at; the rows are those of them that found a residual
    /// (matched and, point-to-plane, with a target normal). Inlier fractions divide by it.
    pub considered: usize,
}

impl Rows {
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    fn clear(&mut self) {
        self.count = 0;
        self.source.clear();
        self.target.clear();
        self.residual.clear();
        self.scale.clear();
        self.considered = 0;
    }

    /// Room for `rows` rows of `cols` residuals, exactly: grown by doubling, the rows of 10 M
    /// points would hold room for 16.7 M (160 MiB more). Without `indexed`, the room of
    /// `source` and `target` is freed.
    fn reserve_exact(&mut self, rows: usize, cols: usize, indexed: bool) {
        if indexed {
            self.source.reserve_exact(rows);
            self.target.reserve_exact(rows);
        } else {
            self.source = Vec::new();
            self.target = Vec::new();
        }
        self.residual.reserve_exact(rows * cols);
        self.scale.reserve_exact(rows);
    }
}

pub trait Problem {
    /// Residual dimensions m.
    fn cols(&self) -> usize;
    /// Whether the pairs change with the transform (ICP re-matches; given correspondences do
    /// not).
    fn rematches(&self) -> bool;
    fn source_count(&self) -> usize;
    /// At most [`PROBE_POINTS`] source points, evenly strided in the caller's order: where
    /// two transforms are compared (`moved_apart`).
    fn probe_points(&self) -> &[Point];
    /// Typical coordinate magnitude of the source points, the median of max |x|, |y|, |z|
    /// (sets the arithmetic's resolution; a garbage point far out does not).
    fn coordinate_magnitude(&self) -> f64;
    /// Centre of the source points (where update sizes are measured): the per-axis median,
    /// which a far-off garbage point does not move.
    fn source_anchor(&self) -> Point;
    /// (Re)matches at `transform` and fills the rows used for fitting.
    fn linearise(&mut self, transform: &Matrix4<f64>) -> &Rows;
    /// The rows of the last `linearise`.
    fn rows(&self) -> &Rows;
    /// Weighted least-squares step from `transform` with one weight per row.
    fn solve(&mut self, transform: &Matrix4<f64>, weights: &[f64]) -> Option<Solve>;
    /// RMS over the rows of ‖(new − old)·a_i‖ / F_i: how far the update moved the data,
    /// in the normalised units σ is measured in.
    fn displacement(&self, old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64;
    /// Rows for every source point (no sampling) at `transform`, for the reported results.
    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows;
    /// The last rows' source and target indices, for their last reader. ICP takes them and
    /// frees the rows (empty until the next linearise or evaluation); fixed correspondences,
    /// whose rows are built once and reused, give copies.
    fn take_row_indices(&mut self) -> (Vec<u32>, Vec<u32>) {
        let rows = self.rows();
        (rows.source.clone(), rows.target.clone())
    }
    /// Told before each `linearise` whether β is being annealed: ICP then matches only a
    /// coarse subset of large samples. No-op by default.
    fn set_annealing(&mut self, _annealing: bool) {}
    /// Seconds spent so far building the index and estimating normals (ICP only; normals are
    /// estimated as matching reaches them, so the second value grows).
    fn setup_seconds(&self) -> (f64, f64) {
        (0.0, 0.0)
    }
}

fn noise_scale(source_sigma: &Option<Vec<f64>>, target_sigma: &Option<Vec<f64>>, s: usize, t: usize) -> f64 {
    match (source_sigma, target_sigma) {
        (Some(a), Some(b)) => combine(a[s], b[t]),
        _ => 1.0,
    }
}

/// RMS over the rows of ‖(new − old)·a_i‖ / F_i, from each row's source point a_i =
/// `source(i)` (i < `count`) and scale F_i.
fn rms_displacement(
    count: usize,
    source: impl Fn(usize) -> Point,
    scales: &RowScales,
    old: &Matrix4<f64>,
    new: &Matrix4<f64>,
) -> f64 {
    if count == 0 {
        return 0.0;
    }
    let difference = new - old;
    let sum: f64 = (0..count)
        .map(|i| {
            let f = scales.get(i);
            let d = transform_point(&difference, &source(i));
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) / (f * f)
        })
        .filter(|v| v.is_finite())
        .sum();
    (sum / count as f64).sqrt()
}

/// How many source points [`Problem::probe_points`] holds at most.
pub const PROBE_POINTS: usize = 1024;

/// Every `len.div_ceil(PROBE_POINTS)`-th point, from the first.
fn probe_points_of(points: &[Point]) -> Vec<Point> {
    let step = points.len().div_ceil(PROBE_POINTS).max(1);
    points.iter().step_by(step).copied().collect()
}

/// Median over the points of their largest coordinate magnitude.
fn typical_magnitude(points: &[Point]) -> f64 {
    let mut magnitudes: Vec<f64> = points
        .iter()
        .map(|p| p.iter().fold(0.0f64, |m, v| m.max(v.abs())))
        .collect();
    median(&mut magnitudes).unwrap_or(0.0)
}

/// Matched pairs: source[i] ↔ target[i], residual T·a_i − b_i (the paper's simulation, §6).
pub struct CorrespondenceProblem<'a> {
    source: &'a [Point],
    probe: Vec<Point>,
    pairs: Vec<(Point, Point)>,
    rows: Rows,
}

impl<'a> CorrespondenceProblem<'a> {
    pub fn new(
        source: &'a [Point],
        target: &'a [Point],
        source_sigma: Option<Vec<f64>>,
        target_sigma: Option<Vec<f64>>,
    ) -> Self {
        let n = source.len();
        let rows = Rows {
            count: n,
            source: (0..n as u32).collect(),
            target: (0..n as u32).collect(),
            residual: vec![0.0; 3 * n],
            scale: RowScales::PerRow(
                (0..n)
                    .map(|i| noise_scale(&source_sigma, &target_sigma, i, i))
                    .collect(),
            ),
            considered: n,
        };
        CorrespondenceProblem {
            source,
            probe: probe_points_of(source),
            pairs: source.iter().copied().zip(target.iter().copied()).collect(),
            rows,
        }
    }
}

impl Problem for CorrespondenceProblem<'_> {
    fn rematches(&self) -> bool {
        false
    }

    fn cols(&self) -> usize {
        3
    }

    fn source_count(&self) -> usize {
        self.source.len()
    }

    fn probe_points(&self) -> &[Point] {
        &self.probe
    }

    fn coordinate_magnitude(&self) -> f64 {
        typical_magnitude(self.source)
    }

    fn source_anchor(&self) -> Point {
        crate::geometry::median_point(self.source)
    }

    fn linearise(&mut self, transform: &Matrix4<f64>) -> &Rows {
        for ((a, b), r) in self.pairs.iter().zip(self.rows.residual.chunks_exact_mut(3)) {
            let p = transform_point(transform, a);
            r.copy_from_slice(&[p[0] - b[0], p[1] - b[1], p[2] - b[2]]);
        }
        &self.rows
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    fn solve(&mut self, _transform: &Matrix4<f64>, weights: &[f64]) -> Option<Solve> {
        weighted_rigid_fit(&self.pairs, weights)
    }

    fn displacement(&self, old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64 {
        rms_displacement(self.source.len(), |i| self.source[i], &self.rows.scale, old, new)
    }

    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.linearise(transform)
    }
}

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
struct Match {
    /// Nearest target at the last query.
    nearest: u32,
    /// `history` index of the transform of the last query (NEVER_QUERIED: none).
    queried_at: u16,
    /// d₂ − d₁ at the last query, rounded down.
    margin: Margin,
}

/// The history is cleared (every cached query dropped) when it reaches this many transforms.
const NEVER_QUERIED: u16 = u16::MAX;

/// A non-negative distance in 16 bits: the upper half of its f32 (8 bits of mantissa, the
/// full exponent range), rounded towards zero, so never above the distance it stands for and
/// the skip test stays exact. Within 0.8 % below: a few more queries, no other change.
#[derive(Clone, Copy)]
struct Margin(u16);

impl Margin {
    /// "Query again".
    const ZERO: Margin = Margin(0);

    /// The largest margin at most `distance` (≥ 0; ∞ and values beyond f32 give f32::MAX's).
    fn at_most(distance: f64) -> Margin {
        let narrowed = if distance.is_finite() {
            // Rounded to nearest, so possibly up by 6e-8 relative: callers leave room for it.
            (distance as f32).clamp(0.0, f32::MAX)
        } else {
            f32::MAX
        };
        Margin((narrowed.to_bits() >> 16) as u16)
    }

    fn get(self) -> f64 {
        f64::from(f32::from_bits(u32::from(self.0) << 16))
    }
}

/// While β is annealed the fit needs the basin, not the last digit: at most this many source
/// points are matched then (σ/√5000 is far below any β level, and the histogram still has
/// 125 bins of 40 samples), all of them afterwards. Fewer than 20 000 costs no accuracy and
/// saves about 30 % (see docs/performance.md, "Design measurements behind the code").
const COARSE_POINTS: usize = 5_000;

/// Every ⌈len / limit⌉-th index of `sample` on average, picked by a hash of the index (curve
/// order kept): about `limit` of them, or none when `sample` has at most `limit`.
fn hashed_subset(sample: &[u32], limit: usize, seed: u64) -> Vec<u32> {
    if sample.len() <= limit {
        return Vec::new();
    }
    let factor = sample.len().div_ceil(limit) as u64;
    sample
        .iter()
        .copied()
        .filter(|&i| splitmix64(u64::from(i) ^ seed) % factor == 0)
        .collect()
}

/// The verdict's evidence (the residuals at the initial guess and at the result displaced along
/// each axis, `Evidence`) is a mean over residuals: about this many source points give it. On
/// 5 000 its passes (three displaced ones, which also reach targets without normals) were 24 %
/// of a warm odometry frame at 10 k points (perf). From 5 000 to 1 000, the significance of the
/// real-scan SIE runs moved by 0.2 % (median; 10–90 %: −2.4 % to +2.7 %) and no success or
/// verdict changed there, on the paper's grid or on the families beyond it (2026-12-01).
const EVIDENCE_POINTS: usize = 1_000;

/// What the driver's next runs on a [`CloudProblem`] are for.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum RunKind {
    /// A lead run (its end is only a start for SIE): every update on the coarse subset.
    Lead,
    /// A registration: the coarse subset only while β is annealed.
    Registration,
}

/// Why the source is matched: for an IRLS step (the sample or its coarse subset, with the
/// solver's per-row terms), for the final evaluation (every source point, not solved), or for
/// the evidence a result is judged by (see [`CloudProblem::evaluate_evidence`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Purpose {
    Solve,
    Evaluate,
    Evidence,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Which {
    Sample,
    Coarse,
    Evidence,
    Everything,
}

/// Source points matched together, in curve order, with their cached queries.
#[derive(Default)]
struct Pass {
    order: Vec<u32>,
    /// `source[order[k]]`: a copy in pass order, so each iteration reads the points
    /// sequentially instead of once per cache line at random (1 M points: 24 MB).
    points: Vec<Point>,
    /// Allocated at the pass's first matching: the everything pass of a sampled source is
    /// built while the caller's source still exists, and its 8 bytes a point would otherwise
    /// add to that moment's peak (at 10 M points, the registration's peak).
    matches: Vec<Match>,
}

impl Pass {
    fn new(source: &[Point], order: Vec<u32>) -> Self {
        let points = order.iter().map(|&i| source[i as usize]).collect();
        Pass {
            order,
            points,
            matches: Vec::new(),
        }
    }
}

impl Match {
    const EMPTY: Match = Match {
        nearest: NO_MATCH,
        queried_at: NEVER_QUERIED,
        margin: Margin::ZERO,
    };
}

/// ICP: nearest-neighbour correspondences onto a prepared target (kd-tree and normals shared,
/// see `PreparedTarget`); this part is per registration.
pub struct CloudProblem<'a> {
    /// Source points (kept ones); the problem holds them only in pass order, so a caller that
    /// owns its copy can drop it once the problem is built.
    source_count: usize,
    /// See [`Problem::probe_points`].
    probe: Vec<Point>,
    /// See [`Problem::coordinate_magnitude`] and [`Problem::source_anchor`]; computed once.
    magnitude: f64,
    anchor: Point,
    target: &'a PreparedTarget,
    metric: Metric,
    /// Source points matched in each iteration (all, or a fixed random subset), in
    /// space-filling-curve order: consecutive queries then visit the same tree nodes, which
    /// keeps them in cache (random order is several times slower on large clouds).
    sample: Pass,
    /// A fixed subset of `sample` (at most COARSE_POINTS) used while β is annealed; empty
    /// when the sample is small enough.
    coarse: Pass,
    /// A fixed subset of `sample` (about EVIDENCE_POINTS) for the verdict's evidence; empty
    /// when the sample is small enough.
    evidence: Pass,
    use_coarse: bool,
    /// A lead run (its end is only a start for SIE): every update on the coarse subset.
    lead_only: bool,
    /// Every source point, for the final evaluation when `sample` is a subset (empty
    /// otherwise).
    everything: Pass,
    source_sigma: Option<Vec<f64>>,
    /// Per kept target point, in the caller's order.
    target_sigma: Option<Vec<f64>>,
    workers: Workers,
    /// Transforms at which queries were made (see `Match`).
    history: Vec<Matrix4<f64>>,
    /// Per `history` entry, this iteration's transform minus that one (reused buffer).
    moves: Vec<Matrix4<f64>>,
    /// Median d₂ − d₁ of the first pass (∞ before it): a point whose last update moved it by
    /// at least half of this will most likely fail the skip test again next time.
    typical_margin: f64,
    rows: Rows,
    /// Per row of the last solvable pass: its index in that pass, from which the solver and the
    /// update size read the source point, the moved point, the matched target and its normal
    /// (4 bytes a row instead of copies: 96 bytes a row for point-to-plane).
    row_pass: Vec<u32>,
    /// The pass `row_pass` indexes, and the transform it was matched at.
    solved_pass: Which,
    linearised: Matrix4<f64>,
    /// Seconds this registration spent building the target (0 for a target prepared before).
    index_seconds: f64,
    normals_seconds: f64,
}

impl<'a> CloudProblem<'a> {
    /// `index_seconds`: what preparing `target` cost, when this registration prepared it.
    pub fn new(
        source: &[Point],
        target: &'a PreparedTarget,
        source_sigma: Option<Vec<f64>>,
        target_sigma: Option<Vec<f64>>,
        config: &RegistrationConfig,
        workers: Workers,
        index_seconds: f64,
    ) -> Result<Self, String> {
        if source.len() >= NO_MATCH as usize {
            return Err(format!(
                "source has {} points; at most {} are supported",
                source.len(),
                NO_MATCH - 1
            ));
        }
        let normals_seconds = match config.metric {
            Metric::PointToPlane => target.prepare_normal_estimation(&workers),
            Metric::PointToPoint => 0.0,
        };
        let mut sample = sample_indices(source.len(), config.max_correspondences, config.seed);
        sort_along_curve(source, &mut sample);
        let coarse = hashed_subset(&sample, COARSE_POINTS, config.seed);
        let evidence = hashed_subset(&sample, EVIDENCE_POINTS, config.seed);
        // Built now rather than at the first final evaluation, so the problem needs no source
        // afterwards; it is there at the registration's peak either way.
        let everything = if sample.len() < source.len() {
            let mut everything: Vec<u32> = (0..source.len() as u32).collect();
            sort_along_curve(source, &mut everything);
            Pass::new(source, everything)
        } else {
            Pass::default()
        };
        // As `noise_scale`: F is 1 unless both clouds have per-point sigmas.
        let scale = match (&source_sigma, &target_sigma) {
            (Some(_), Some(_)) => RowScales::PerRow(Vec::new()),
            _ => RowScales::Unit,
        };
        Ok(CloudProblem {
            source_count: source.len(),
            probe: probe_points_of(source),
            magnitude: typical_magnitude(source),
            anchor: crate::geometry::median_point(source),
            target,
            metric: config.metric,
            sample: Pass::new(source, sample),
            coarse: Pass::new(source, coarse),
            evidence: Pass::new(source, evidence),
            use_coarse: false,
            lead_only: false,
            everything,
            source_sigma,
            target_sigma,
            workers,
            history: Vec::new(),
            moves: Vec::new(),
            typical_margin: f64::INFINITY,
            rows: Rows {
                scale,
                ..Rows::default()
            },
            row_pass: Vec::new(),
            solved_pass: Which::Sample,
            linearised: Matrix4::identity(),
            index_seconds,
            normals_seconds,
        })
    }

    /// The pass `purpose` matches: for a step the sample (or its coarse subset while β is
    /// annealed), for the final evaluation every source point, for evidence the evidence subset
    /// (the sample when that is small enough).
    fn pass_for(&mut self, purpose: Purpose) -> Which {
        match purpose {
            Purpose::Evaluate if self.sample.order.len() < self.source_count => Which::Everything,
            Purpose::Solve if self.use_coarse && !self.coarse.order.is_empty() => Which::Coarse,
            Purpose::Evidence if !self.evidence.order.is_empty() => Which::Evidence,
            _ => Which::Sample,
        }
    }

    /// Matches the pass `purpose` asks for at `transform` and fills the rows.
    fn match_and_fill(&mut self, transform: &Matrix4<f64>, purpose: Purpose) {
        let which = self.pass_for(purpose);
        if self.history.len() >= NEVER_QUERIED as usize {
            self.history.clear();
            for pass in [
                &mut self.sample,
                &mut self.coarse,
                &mut self.evidence,
                &mut self.everything,
            ] {
                pass.matches.fill(Match::EMPTY);
            }
        }
        let generation = self.history.len() as u16;
        // How far each earlier query transform is from this one, applied to a point.
        let mut moves = std::mem::take(&mut self.moves);
        moves.clear();
        moves.extend(self.history.iter().map(|old| transform - old));
        self.history.push(*transform);
        let mut pass = std::mem::take(self.pass_mut(which));
        if pass.matches.is_empty() {
            pass.matches.resize(pass.order.len(), Match::EMPTY);
            self.share_queries_into(which, &mut pass);
        }
        self.match_pass(transform, &mut pass, &moves, generation);
        self.moves = moves;
        if self.typical_margin == f64::INFINITY {
            let mut margins: Vec<f64> = pass.matches.iter().map(|m| m.margin.get()).collect();
            if let Some(typical) = median(&mut margins) {
                self.typical_margin = typical;
            }
        }
        self.estimate_missing_normals(&pass);
        self.fill_rows(&pass, transform, purpose);
        if purpose == Purpose::Solve {
            self.solved_pass = which;
            self.linearised = *transform;
        }
        *self.pass_mut(which) = pass;
    }

    /// A pass matched for the first time starts from the queries the other passes already
    /// made for the same source points (the coarse subset's, when the final round first
    /// matches the sample; the evidence subset's, when the first update matches the coarse
    /// subset at the same initial guess). The history is shared, so each copied query keeps its
    /// exact skip test: the matches are the same as from fresh queries, only cheaper.
    fn share_queries_into(&self, which: Which, pass: &mut Pass) {
        // The sample is the parent: coarse and evidence are subsequences of it (same order).
        if which == Which::Everything {
            return;
        }
        let parent = if which == Which::Sample {
            &pass.order
        } else {
            &self.sample.order
        };
        let others: Vec<&Pass> = [Which::Sample, Which::Coarse, Which::Evidence]
            .into_iter()
            .filter(|&w| w != which)
            .map(|w| self.pass(w))
            .filter(|p| !p.matches.is_empty())
            .collect();
        if others.is_empty() {
            return;
        }
        let mut next_in_other = vec![0usize; others.len()];
        let mut next_in_pass = 0usize;
        for &point in parent {
            let in_pass = pass.order.get(next_in_pass) == Some(&point);
            for (other, next) in others.iter().zip(next_in_other.iter_mut()) {
                if other.order.get(*next) != Some(&point) {
                    continue;
                }
                let cached = other.matches[*next];
                *next += 1;
                if !in_pass || cached.queried_at == NEVER_QUERIED {
                    continue;
                }
                let slot = &mut pass.matches[next_in_pass];
                // The later query has the smaller moves since, hence the likelier skip.
                if slot.queried_at == NEVER_QUERIED || cached.queried_at > slot.queried_at {
                    *slot = cached;
                }
            }
            if in_pass {
                next_in_pass += 1;
            }
        }
    }

    fn pass(&self, which: Which) -> &Pass {
        match which {
            Which::Sample => &self.sample,
            Which::Coarse => &self.coarse,
            Which::Evidence => &self.evidence,
            Which::Everything => &self.everything,
        }
    }

    fn pass_mut(&mut self, which: Which) -> &mut Pass {
        match which {
            Which::Sample => &mut self.sample,
            Which::Coarse => &mut self.coarse,
            Which::Evidence => &mut self.evidence,
            Which::Everything => &mut self.everything,
        }
    }

    /// Estimates the normals of the targets this pass matched that have none yet.
    fn estimate_missing_normals(&mut self, pass: &Pass) {
        if self.metric != Metric::PointToPlane {
            return;
        }
        let started = Instant::now();
        self.target
            .ensure_normals(pass.matches.iter().map(|m| m.nearest), &self.workers);
        self.normals_seconds += started.elapsed().as_secs_f64();
    }

    fn match_pass(&self, transform: &Matrix4<f64>, pass: &mut Pass, moves: &[Matrix4<f64>], generation: u16) {
        let (points, index) = (&pass.points, self.target.index());
        let (last_move, typical_margin) = (moves.last(), self.typical_margin);
        self.workers
            .for_each_chunk_of(MATCH_CHUNK, &mut pass.matches, |start, chunk| {
                let mut previous: Option<(&Point, Match)> = None;
                for (k, slot) in chunk.iter_mut().enumerate() {
                    let a = &points[start + k];
                    // A copy of the previous point (depth frames: a third of them at 0 0 0, next
                    // to each other in curve order) has the same history, so the same match.
                    if let Some((_, matched)) = previous.filter(|(p, _)| *p == a) {
                        *slot = matched;
                        continue;
                    }
                    let unchanged = slot.queried_at != NEVER_QUERIED
                        && 2.0 * length(&transform_point(&moves[slot.queried_at as usize], a))
                            < slot.margin.get();
                    if !unchanged {
                        let point = transform_point(transform, a);
                        slot.queried_at = generation;
                        // Early on, updates move points by more than the typical gap, so a
                        // cached margin would not be used: the cheaper nearest-only query
                        // (about half the cost) is then enough, and margin 0 means "query again".
                        let moving_fast =
                            last_move.is_some_and(|m| 2.0 * length(&transform_point(m, a)) >= typical_margin);
                        if moving_fast {
                            slot.nearest = index.nearest_one(&point).0 as u32;
                            slot.margin = Margin::ZERO;
                        } else {
                            let (nearest, first, second) = index.nearest_two(&point);
                            slot.nearest = nearest as u32;
                            // Less a relative 1e-6: covers the rounding of the distances and of
                            // the conversion to f32 (at most 6e-8 relative).
                            slot.margin = Margin::at_most((second - first) * (1.0 - 1e-6));
                        }
                    }
                    previous = Some((a, *slot));
                }
            });
    }

    /// The rows of the matched pairs: for [`Purpose::Solve`] with each row's index in the pass
    /// (`row_pass`, from which the solver reads its points), otherwise with the points' indices
    /// (the caller's).
    fn fill_rows(&mut self, pass: &Pass, transform: &Matrix4<f64>, purpose: Purpose) {
        let target = self.target;
        let normals = target.normals();
        let plane = self.metric == Metric::PointToPlane;
        let solve = purpose == Purpose::Solve;
        let rows = &mut self.rows;
        rows.clear();
        rows.considered = pass.order.len();
        rows.reserve_exact(pass.order.len(), if plane { 1 } else { 3 }, !solve);
        self.row_pass.clear();
        if solve {
            self.row_pass.reserve_exact(pass.order.len());
        } else {
            self.row_pass = Vec::new();
        }
        for (k, m) in pass.matches.iter().enumerate() {
            if m.nearest == NO_MATCH {
                continue;
            }
            let t = m.nearest as usize;
            let normal = if plane { normals.get(t) } else { [0.0; 3] };
            // A target point without a normal (degenerate neighbourhood) gives no plane.
            if plane && normal == [0.0; 3] {
                continue;
            }
            let (s, original_t) = (pass.order[k] as usize, target.order()[t] as usize);
            let q = target.points()[t];
            let moved = transform_point(transform, &pass.points[k]);
            let d = [moved[0] - q[0], moved[1] - q[1], moved[2] - q[2]];
            rows.count += 1;
            if solve {
                self.row_pass.push(k as u32);
            } else {
                rows.source.push(s as u32);
                rows.target.push(original_t as u32);
            }
            if plane {
                let n = normal;
                rows.residual.push(n[0] * d[0] + n[1] * d[1] + n[2] * d[2]);
            } else {
                rows.residual.extend_from_slice(&d);
            }
            rows.scale
                .push(noise_scale(&self.source_sigma, &self.target_sigma, s, original_t));
        }
    }
}

/// Source points per thread's work item when matching: the matches do not depend on it, and
/// the 5 000-point coarse passes then split evenly over two threads (20 pieces, not 4 of 1 024
/// and one of 904). Room 10 k, 2 threads, two alternating rounds against 1 024: +2-3 %
/// frames/s warm, 10 k pair matching 14.9 -> 13.8 ms.
const MATCH_CHUNK: usize = 256;

/// A fixed, sorted random subset of `limit` source indices (all when `limit` is 0 or ≥ n), so
/// every iteration sees the same correspondences' sources.
fn sample_indices(n: usize, limit: usize, seed: u64) -> Vec<u32> {
    if limit == 0 || limit >= n {
        return (0..n as u32).collect();
    }
    let mut rng = rand::rngs::Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut chosen: Vec<u32> = rand::seq::index::sample(&mut rng, n, limit)
        .into_iter()
        .map(|i| i as u32)
        .collect();
    chosen.sort_unstable();
    chosen
}

impl CloudProblem<'_> {
    /// Runs until the next call as a lead (see `lead_only`) or as a registration.
    pub fn set_run_kind(&mut self, kind: RunKind) {
        self.lead_only = kind == RunKind::Lead;
    }

    /// Rows of the evidence subset at `transform`: about EVIDENCE_POINTS source points,
    /// hash-chosen (the sample when it is no larger). The spreads a verdict compares against
    /// are means over residuals and enter the significance through a logarithm. Matching every
    /// source point for them took 46 % of the sequence benchmark's time at 10 k points (perf),
    /// 5 000 of them still a quarter. Leaves the other passes' cached queries alone.
    pub fn evaluate_evidence(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.match_and_fill(transform, Purpose::Evidence);
        &self.rows
    }

    /// See [`PreparedTarget::spread`].
    pub fn target_spread(&self) -> f64 {
        self.target.spread()
    }

    /// See [`PreparedTarget::spacing`].
    pub fn target_spacing(&self) -> f64 {
        self.target.spacing()
    }
}

impl Problem for CloudProblem<'_> {
    fn rematches(&self) -> bool {
        true
    }

    fn cols(&self) -> usize {
        match self.metric {
            Metric::PointToPoint => 3,
            Metric::PointToPlane => 1,
        }
    }

    fn source_count(&self) -> usize {
        self.source_count
    }

    fn probe_points(&self) -> &[Point] {
        &self.probe
    }

    fn coordinate_magnitude(&self) -> f64 {
        self.magnitude
    }

    fn source_anchor(&self) -> Point {
        self.anchor
    }

    fn linearise(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.match_and_fill(transform, Purpose::Solve);
        &self.rows
    }

    fn rows(&self) -> &Rows {
        &self.rows
    }

    fn solve(&mut self, transform: &Matrix4<f64>, weights: &[f64]) -> Option<Solve> {
        let (pass, rows, target) = (self.pass(self.solved_pass), &self.row_pass, self.target);
        let matched = |i: usize| pass.matches[rows[i] as usize].nearest as usize;
        match self.metric {
            Metric::PointToPoint => weighted_rigid_fit_by(
                rows.len(),
                |i| (pass.points[rows[i] as usize], target.points()[matched(i)]),
                weights,
            ),
            Metric::PointToPlane => {
                let normals = target.normals();
                point_to_plane_step_by(
                    transform,
                    rows.len(),
                    |i| transform_point(&self.linearised, &pass.points[rows[i] as usize]),
                    |i| {
                        let t = matched(i);
                        (target.points()[t], normals.get(t))
                    },
                    weights,
                )
            }
        }
    }

    fn displacement(&self, old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64 {
        let (pass, rows) = (self.pass(self.solved_pass), &self.row_pass);
        rms_displacement(
            rows.len(),
            |i| pass.points[rows[i] as usize],
            &self.rows.scale,
            old,
            new,
        )
    }

    fn take_row_indices(&mut self) -> (Vec<u32>, Vec<u32>) {
        let rows = &mut self.rows;
        let indices = (std::mem::take(&mut rows.source), std::mem::take(&mut rows.target));
        rows.clear();
        rows.residual = Vec::new();
        rows.scale = match &rows.scale {
            RowScales::Unit => RowScales::Unit,
            RowScales::PerRow(_) => RowScales::PerRow(Vec::new()),
        };
        indices
    }

    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.match_and_fill(transform, Purpose::Evaluate);
        &self.rows
    }

    fn set_annealing(&mut self, annealing: bool) {
        self.use_coarse = annealing || self.lead_only;
    }

    fn setup_seconds(&self) -> (f64, f64) {
        (self.index_seconds, self.normals_seconds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampling_is_deterministic_sorted_and_bounded() {
        let a = sample_indices(1000, 100, 42);
        assert_eq!(a, sample_indices(1000, 100, 42));
        assert_eq!(a.len(), 100);
        assert!(a.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(sample_indices(10, 0, 1).len(), 10);
        assert_eq!(sample_indices(10, 50, 1).len(), 10);
    }

    /// Sources, targets, residual bits and the count considered.
    type Snapshot = (Vec<u32>, Vec<u32>, Vec<u64>, usize);

    fn snapshot(rows: &Rows) -> Snapshot {
        let bits = rows.residual.iter().map(|r| r.to_bits()).collect();
        (rows.source.clone(), rows.target.clone(), bits, rows.considered)
    }

    fn room_problem_rows(points: usize, check: impl FnOnce(&mut CloudProblem<'_>)) {
        let scene = crate::synthetic::room_scene(points, 0.01, 5);
        let config = RegistrationConfig::default();
        let options = crate::PrepareOptions::from_config(&config);
        let target = PreparedTarget::new(&scene.target, None, &options).unwrap();
        let workers = Workers::new(1).unwrap();
        let mut problem =
            CloudProblem::new(&scene.source, &target, None, None, &config, workers, 0.0).unwrap();
        check(&mut problem);
    }

    /// The verdict's evidence is matched on about EVIDENCE_POINTS source points (every point of
    /// a smaller cloud), and matching it leaves the full evaluation's pass in place: its rows at
    /// the same transform come out bit for bit as before (they would not if the evidence pass
    /// were stored back into the sample's or everything's slot).
    #[test]
    fn evidence_uses_its_subset_and_leaves_the_evaluation_alone() {
        let shifted = |x: f64| {
            let mut t = Matrix4::identity();
            t[(0, 3)] = x;
            t
        };
        room_problem_rows(12_000, |problem| {
            let before = snapshot(problem.evaluate_all(&shifted(0.01)));
            assert!(
                before.3 == 12_000 && before.0.len() > 10_000,
                "{}",
                before.0.len()
            );
            let subset: std::collections::HashSet<u32> = problem.evidence.order.iter().copied().collect();
            // A hash picks every 12th on average: 1 000 give or take its noise.
            assert!(
                subset.len() <= EVIDENCE_POINTS * 11 / 10 && subset.len() > EVIDENCE_POINTS / 2,
                "{}",
                subset.len()
            );
            for x in [0.2, -0.1] {
                let evidence = problem.evaluate_evidence(&shifted(x));
                assert_eq!(evidence.considered, subset.len());
                assert!(evidence.len() > subset.len() / 2);
                assert!(evidence.source.iter().all(|s| subset.contains(s)));
            }
            assert_eq!(snapshot(problem.evaluate_all(&shifted(0.01))), before);
        });
        room_problem_rows(EVIDENCE_POINTS, |problem| {
            let all = snapshot(problem.evaluate_all(&shifted(0.05)));
            assert_eq!(snapshot(problem.evaluate_evidence(&shifted(0.05))), all);
            assert_eq!(all.3, EVIDENCE_POINTS);
        });
    }

    /// A pass matched for the first time reuses the queries the other passes made for the same
    /// points (evidence → coarse at the initial guess, coarse → sample when the final round
    /// begins): most of them are not queried again, and the rows come out bit for bit as from
    /// fresh queries, at the same transform and after a small move.
    #[test]
    fn a_new_pass_reuses_the_other_passes_queries_exactly() {
        let moved = |x: f64| {
            let mut t = Matrix4::identity();
            t[(0, 3)] = x;
            t[(1, 3)] = -0.5 * x;
            t
        };
        let (guess, step) = (moved(0.01), moved(0.010_002));
        let (mut fresh_coarse, mut fresh_sample) = (None, None);
        room_problem_rows(12_000, |problem| {
            problem.set_annealing(true);
            fresh_coarse = Some(snapshot(problem.linearise(&guess)));
        });
        room_problem_rows(12_000, |problem| {
            fresh_sample = Some(snapshot(problem.evaluate_all(&step)))
        });
        let (fresh_coarse, fresh_sample) = (fresh_coarse.unwrap(), fresh_sample.unwrap());
        room_problem_rows(12_000, |problem| {
            problem.evaluate_evidence(&guess);
            problem.set_annealing(true);
            assert_eq!(snapshot(problem.linearise(&guess)), fresh_coarse);
            // Evidence points sit in the coarse subset too (hashes of 1 in 12 and 1 in 3 of
            // the same sample): their queries at this transform were kept.
            let kept = problem
                .coarse
                .matches
                .iter()
                .filter(|m| m.queried_at == 0)
                .count();
            let shared = problem
                .evidence
                .order
                .iter()
                .filter(|i| problem.coarse.order.contains(i))
                .count();
            assert!(shared > 500 && kept >= shared * 9 / 10, "{kept} of {shared}");
            problem.set_annealing(false);
            assert_eq!(snapshot(problem.evaluate_all(&step)), fresh_sample);
            let generation = (problem.history.len() - 1) as u16;
            let requeried = problem
                .sample
                .matches
                .iter()
                .filter(|m| m.queried_at == generation)
                .count();
            let coarse = problem.coarse.order.len();
            assert!(
                requeried <= problem.sample.order.len() - coarse * 9 / 10,
                "{requeried} of {} queried again ({coarse} coarse)",
                problem.sample.order.len()
            );
        });
    }
}
