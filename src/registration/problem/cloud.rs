//! ICP: nearest-neighbour correspondences onto a prepared target (kd-tree and normals shared,
//! see `PreparedTarget`), matched in passes over subsets of the source with cached queries.

use std::collections::HashMap;
use std::time::Instant;

use nalgebra::Matrix4;
use rand::SeedableRng;

use super::matches::{Margin, Match, NEVER_QUERIED, Pass};
use super::{
    Problem, RowScales, Rows, StepPoints, noise_scale, probe_points_of, rms_displacement, typical_magnitude,
};
use crate::geometry::{
    PlaneConditioning, Solve, length, point_to_plane_step_by, splitmix64, transform_point,
    weighted_rigid_fit_by,
};
use crate::median::median;
use crate::parallel::Workers;
use crate::point::Point;
use crate::registration::config::{Metric, RegistrationConfig};
use crate::registration::covariance::{InformationSum, PoseUncertainty, RowWeight};
use crate::registration::degeneracy::{
    SurfacePair, SurfaceRow, surface_conditioning, surface_rows, surface_sample,
};
use crate::registration::result::StageTimes;
use crate::registration::target::{NO_MATCH, PreparedTarget, sort_along_curve};

/// While β is annealed the fit needs the basin, not the last digit: at most this many source
/// points are matched then (σ/√5000 is far below any β level, and the histogram still has
/// 125 bins of 40 samples), all of them afterwards (docs/performance.md, "Design measurements
/// behind the code", has what fewer or more cost).
const COARSE_POINTS: usize = 5_000;

/// After the annealing, while SIE still fits its final model, the updates steer towards the
/// optimum and the histogram needs σ, not every digit of the pose: at most this many source
/// points are matched then (σ/√20000 is below the final model's width by far), all of them once
/// the model is frozen or the subset is handed over (`irls::iterate`: a rank-deficient or a
/// long unsettled fit); docs/performance.md, issue 30, has what it saves on LiDAR frames.
const MEDIUM_POINTS: usize = 20_000;

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
/// each axis, `verdict::Evidence`) is a mean over residuals that enters the significance
/// through a logarithm: about this many source points give it as well as every point does, at
/// a fraction of the matching (docs/performance.md, item 14, has the measurements).
const EVIDENCE_POINTS: usize = 1_000;

/// Why the source is matched: for an IRLS step (the sample or its coarse subset, with the
/// solver's per-row terms), for the final evaluation (every source point, not solved), or for
/// the evidence a result is judged by (see [`CloudProblem::evaluate_evidence`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Purpose {
    Step(StepPoints),
    Evaluate,
    Evidence,
}

/// The passes of a cloud problem: the subsets of the source points matched together.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Subset {
    /// Every source point, or the caller's random sample of them (`max_correspondences`).
    Sample,
    /// At most COARSE_POINTS of the sample, for steps while searching.
    Coarse,
    /// At most MEDIUM_POINTS of the sample, for steps while the final model is fitted.
    Medium,
    /// About EVIDENCE_POINTS of the sample, for the verdict's evidence.
    Evidence,
    /// Every source point, for the final evaluation when the sample is smaller.
    Everything,
}

/// Seconds a registration spent on its target: building it (when this call prepared it), and
/// estimating normals (the scale up front, then each normal when matching first reaches its
/// point), with the part spent inside the steps' matching and the final evaluation.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SetupTime {
    index: f64,
    normals: f64,
    normals_in_steps: f64,
    normals_in_evaluation: f64,
}

impl SetupTime {
    /// Completes the stage times of a run that began at `before`: the index and the normals
    /// so far, and the normals its matching and evaluation reached moved out of those stages.
    pub(crate) fn complete(&self, before: &SetupTime, times: &mut StageTimes) {
        times.index = self.index;
        times.normals = self.normals;
        times.matching -= self.normals_in_steps - before.normals_in_steps;
        times.evaluation -= self.normals_in_evaluation - before.normals_in_evaluation;
    }
}

/// ICP: nearest-neighbour correspondences onto a prepared target (kd-tree and normals shared,
/// see `PreparedTarget`); this part is per registration.
pub(crate) struct CloudProblem<'a> {
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
    /// A fixed subset of `sample` (at most MEDIUM_POINTS) used while SIE fits its final model;
    /// empty when the sample is small enough.
    medium: Pass,
    /// A fixed subset of `sample` (about EVIDENCE_POINTS) for the verdict's evidence; empty
    /// when the sample is small enough.
    evidence: Pass,
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
    solved_pass: Subset,
    linearised: Matrix4<f64>,
    /// Seconds this registration spent on its target.
    setup: SetupTime,
    /// The rows the last `surface_conditioning` drew, with their targets' per-point normals (the
    /// pose's uncertainty uses them).
    surfaces: Vec<SurfaceRow>,
}

impl<'a> CloudProblem<'a> {
    /// `index_seconds`: what preparing `target` cost, when this registration prepared it.
    pub(crate) fn new(
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
        // Both metrics estimate the normals of a few thousand targets at each result (the
        // surfaces' conditioning, `degeneracy`): their scale is chosen now, before the
        // registration's peak; point-to-plane needs a normal per match besides.
        let scale_seconds = target.prepare_normal_scale(&workers)
            + match config.metric {
                Metric::PointToPlane => target.prepare_normal_estimation(&workers),
                Metric::PointToPoint => 0.0,
            };
        let mut sample = sample_indices(source.len(), config.max_correspondences, config.seed);
        sort_along_curve(source, &mut sample);
        // One seed for all subsets: with a medium factor dividing the coarse one, the coarse
        // points are medium points too and their queries carry over.
        let coarse = hashed_subset(&sample, COARSE_POINTS, config.seed);
        let medium = hashed_subset(&sample, MEDIUM_POINTS, config.seed);
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
            medium: Pass::new(source, medium),
            evidence: Pass::new(source, evidence),
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
            solved_pass: Subset::Sample,
            linearised: Matrix4::identity(),
            setup: SetupTime {
                index: index_seconds,
                normals: scale_seconds,
                ..SetupTime::default()
            },
            surfaces: Vec::new(),
        })
    }

    /// The pass `purpose` matches: for a step the sample (or its coarse subset while β is
    /// annealed, its medium subset while the final model is fitted), for the final evaluation
    /// every source point, for evidence the evidence subset (the sample when that is small
    /// enough).
    fn pass_for(&self, purpose: Purpose) -> Subset {
        match purpose {
            Purpose::Evaluate if self.sample.order.len() < self.source_count => Subset::Everything,
            Purpose::Step(StepPoints::Coarse) if !self.coarse.order.is_empty() => Subset::Coarse,
            Purpose::Step(StepPoints::Medium) if !self.medium.order.is_empty() => Subset::Medium,
            Purpose::Evidence | Purpose::Step(StepPoints::Evidence) if !self.evidence.order.is_empty() => {
                Subset::Evidence
            }
            _ => Subset::Sample,
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
                &mut self.medium,
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
        self.estimate_missing_normals(&pass, purpose);
        self.fill_rows(&pass, transform, purpose);
        if matches!(purpose, Purpose::Step(_)) {
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
    fn share_queries_into(&self, which: Subset, pass: &mut Pass) {
        // The sample is the parent: the other subsets are subsequences of it (same order).
        if which == Subset::Everything {
            return;
        }
        let parent = if which == Subset::Sample {
            &pass.order
        } else {
            &self.sample.order
        };
        let others: Vec<&Pass> = [Subset::Sample, Subset::Coarse, Subset::Medium, Subset::Evidence]
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

    fn pass(&self, which: Subset) -> &Pass {
        match which {
            Subset::Sample => &self.sample,
            Subset::Coarse => &self.coarse,
            Subset::Medium => &self.medium,
            Subset::Evidence => &self.evidence,
            Subset::Everything => &self.everything,
        }
    }

    fn pass_mut(&mut self, which: Subset) -> &mut Pass {
        match which {
            Subset::Sample => &mut self.sample,
            Subset::Coarse => &mut self.coarse,
            Subset::Medium => &mut self.medium,
            Subset::Evidence => &mut self.evidence,
            Subset::Everything => &mut self.everything,
        }
    }

    /// Estimates the normals of the targets this pass matched that have none yet.
    fn estimate_missing_normals(&mut self, pass: &Pass, purpose: Purpose) {
        if self.metric != Metric::PointToPlane {
            return;
        }
        let started = Instant::now();
        self.target
            .ensure_normals(pass.matches.iter().map(|m| m.nearest), &self.workers);
        let seconds = started.elapsed().as_secs_f64();
        self.setup.normals += seconds;
        match purpose {
            Purpose::Step(_) => self.setup.normals_in_steps += seconds,
            Purpose::Evaluate => self.setup.normals_in_evaluation += seconds,
            Purpose::Evidence => {}
        }
    }

    fn match_pass(&self, transform: &Matrix4<f64>, pass: &mut Pass, moves: &[Matrix4<f64>], generation: u16) {
        let (points, index) = (&pass.points, self.target.index());
        let (last_move, typical_margin) = (moves.last(), self.typical_margin);
        self.workers
            .for_each_chunk_of(MATCH_CHUNK, &mut pass.matches, |start, chunk| {
                for (k, slot) in chunk.iter_mut().enumerate() {
                    let a = &points[start + k];
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
                }
            });
    }

    /// The rows of the matched pairs: for [`Purpose::Step`] with each row's index in the pass
    /// (`row_pass`, from which the solver reads its points), otherwise with the points' indices
    /// (the caller's).
    fn fill_rows(&mut self, pass: &Pass, transform: &Matrix4<f64>, purpose: Purpose) {
        let target = self.target;
        let normals = target.normals();
        let plane = self.metric == Metric::PointToPlane;
        let solve = matches!(purpose, Purpose::Step(_));
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

/// One row of [`CloudProblem::evidence_matches`].
pub(crate) struct EvidenceMatch {
    /// The source point moved by the transform matched at.
    pub(crate) moved: Point,
    /// Its nearest target point.
    pub(crate) target: Point,
    /// The target point's unit normal; zero for point-to-point.
    pub(crate) normal: Point,
    /// The row's noise scale F (§4.4).
    pub(crate) scale: f64,
}

/// Residuals of source points within this many target spacings of each other lean on the
/// same target points and normals (10 neighbours span about two spacings): their errors are
/// taken as correlated in the pose's covariance.
const CORRELATED_SPACINGS: f64 = 4.0;

/// Source points per thread's work item when matching: the matches do not depend on it, and
/// the 5 000-point coarse passes then split evenly over two threads (20 pieces, not 4 of 1 024
/// and one of 904; docs/performance.md, item 19, has the gain).
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
    /// Seconds this registration has spent on its target so far.
    pub(crate) fn setup_time(&self) -> SetupTime {
        self.setup
    }

    /// Rows of the evidence subset at `transform`: about EVIDENCE_POINTS source points,
    /// hash-chosen (the sample when it is no larger). The spreads a verdict compares against
    /// are means over residuals and enter the significance through a logarithm, so a subset
    /// gives them, at a fraction of the matching a pass over every point would cost. Leaves
    /// the other passes' cached queries alone.
    pub(crate) fn evaluate_evidence(&mut self, transform: &Matrix4<f64>) -> &Rows {
        self.match_and_fill(transform, Purpose::Evidence);
        &self.rows
    }

    /// The evidence subset's source points moved by `transform` whose residual there lies
    /// within `radius_squared` (normalised, as `at_scale` counts): where a pose's inliers are,
    /// in the target frame. Leaves the problem's rows at the evidence subset's.
    pub(crate) fn evidence_points_within(
        &mut self,
        transform: &Matrix4<f64>,
        radius_squared: f64,
    ) -> Vec<Point> {
        self.match_and_fill(transform, Purpose::Evidence);
        let cols = self.cols();
        let pass = self.pass(self.pass_for(Purpose::Evidence));
        let rows = &self.rows;
        self.rows_of(pass)
            .zip(rows.residual.chunks_exact(cols).enumerate())
            .filter(|(_, (i, r))| {
                let f = rows.scale.get(*i);
                r.iter().map(|v| v * v).sum::<f64>() <= radius_squared * f * f
            })
            .map(|((k, _), _)| transform_point(transform, &pass.points[k]))
            .collect()
    }

    /// The evidence subset's rows at `transform` (which may scale as well as move) with what
    /// a fit of that transform needs of each: the moved source point, its matched target point,
    /// the target's normal and the row's noise scale F. Point-to-point's targets have no normals
    /// of their own: theirs are estimated into `own_normals` (curve-order target → normal), kept
    /// by the caller across calls and not in the target, whose later registrations must not see
    /// them. Leaves the problem's rows at the evidence subset's.
    pub(crate) fn evidence_matches(
        &mut self,
        transform: &Matrix4<f64>,
        own_normals: &mut HashMap<u32, Point>,
    ) -> Vec<EvidenceMatch> {
        self.match_and_fill(transform, Purpose::Evidence);
        let pass = self.pass(self.pass_for(Purpose::Evidence));
        let (plane, target) = (self.metric == Metric::PointToPlane, self.target);
        if !plane {
            let mut missing: Vec<u32> = self
                .rows_of(pass)
                .map(|(_, m)| m.nearest)
                .filter(|t| !own_normals.contains_key(t))
                .collect();
            missing.sort_unstable();
            missing.dedup();
            let found = target.normals_not_kept(&missing, &self.workers);
            own_normals.extend(missing.into_iter().zip(found));
        }
        self.rows_of(pass)
            .enumerate()
            .map(|(row, (k, m))| {
                let t = m.nearest as usize;
                EvidenceMatch {
                    moved: transform_point(transform, &pass.points[k]),
                    target: target.points()[t],
                    normal: if plane {
                        target.normals().get(t)
                    } else {
                        own_normals.get(&m.nearest).copied().unwrap_or([0.0; 3])
                    },
                    scale: self.rows.scale.get(row),
                }
            })
            .collect()
    }

    /// The pass's matches that gave a row, in row order (`fill_rows` skips the others), with
    /// their index in the pass.
    fn rows_of<'p>(&'p self, pass: &'p Pass) -> impl Iterator<Item = (usize, &'p Match)> {
        let (plane, normals) = (self.metric == Metric::PointToPlane, self.target.normals());
        pass.matches.iter().enumerate().filter(move |(_, m)| {
            m.nearest != NO_MATCH && !(plane && normals.get(m.nearest as usize) == [0.0; 3])
        })
    }

    /// See [`PreparedTarget::spread`].
    pub(crate) fn target_spread(&self) -> f64 {
        self.target.spread()
    }

    /// See [`PreparedTarget::spacing`].
    pub(crate) fn target_spacing(&self) -> f64 {
        self.target.spacing()
    }

    /// See [`PreparedTarget::centroid`].
    pub(crate) fn target_centroid(&self) -> Point {
        self.target.centroid()
    }
}

impl Problem for CloudProblem<'_> {
    fn rematches(&self) -> bool {
        true
    }

    fn steps_on_subset(&self, points: StepPoints) -> bool {
        self.pass_for(Purpose::Step(points)) != Subset::Sample
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

    fn linearise(&mut self, transform: &Matrix4<f64>, points: StepPoints) -> &Rows {
        self.match_and_fill(transform, Purpose::Step(points));
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

    /// Both metrics: point-to-point's solve does not see the surfaces, point-to-plane's sees
    /// them through per-point normals whose noise reads as constraint (`degeneracy`).
    fn surface_conditioning(
        &mut self,
        transform: &Matrix4<f64>,
        probabilities: &[f64],
    ) -> Option<PlaneConditioning> {
        let started = Instant::now();
        let pass = self.pass(self.pass_for(Purpose::Evaluate));
        let chosen = surface_rows(probabilities);
        // The final evaluation's rows are its pass's matches that gave one, in order (as
        // `fill_rows` skips them).
        let matched = self.rows_of(pass);
        let mut pairs = Vec::with_capacity(chosen.len());
        let mut wanted = chosen.iter().copied().peekable();
        for (row, (k, m)) in matched.enumerate() {
            let Some(&(next, weight)) = wanted.peek() else {
                break;
            };
            if row == next {
                pairs.push(SurfacePair {
                    moved: transform_point(transform, &pass.points[k]),
                    target: m.nearest,
                    weight,
                    row,
                });
                wanted.next();
            }
        }
        let (surfaces, rows) = surface_sample(&pairs, self.target, &self.workers);
        let conditioning = surface_conditioning(&surfaces);
        self.surfaces = rows;
        self.setup.normals += started.elapsed().as_secs_f64();
        Some(conditioning)
    }

    fn surface_rows(&self) -> &[SurfaceRow] {
        &self.surfaces
    }

    /// Visits the evaluation pass's matches in the order and with the filter of `fill_rows`,
    /// so row i is the i-th match visited. Rows are correlated by the cells of their targets;
    /// point-to-point's response to the pose comes from the surfaces' sample.
    fn pose_uncertainty(
        &self,
        transform: &Matrix4<f64>,
        probabilities: &[f64],
        weight: &RowWeight,
    ) -> PoseUncertainty {
        let pass = self.pass(self.pass_for(Purpose::Evaluate));
        let (target, rows) = (self.target, &self.rows);
        let normals = target.normals();
        let plane = self.metric == Metric::PointToPlane;
        // Point-to-point without a sample of the surfaces (a target with no plane anywhere)
        // responds as fixed correspondences would.
        let on_surfaces = !plane && self.surfaces.len() >= 6;
        let mut sum = InformationSum::about(
            transform_point(transform, &self.anchor),
            CORRELATED_SPACINGS * self.target.spacing(),
        );
        for (row, (k, m)) in self.rows_of(pass).enumerate().take(rows.len()) {
            let t = m.nearest as usize;
            let normal = if plane { normals.get(t) } else { [0.0; 3] };
            let p = transform_point(transform, &pass.points[k]);
            let (scale, probability) = (rows.scale.get(row), probabilities[row]);
            let key = Some(&target.points()[t]);
            if plane {
                sum.add_plane(&p, &normal, key, rows.residual[row], scale, probability, weight);
            } else {
                let residual = &rows.residual[3 * row..3 * row + 3];
                sum.add_point(
                    &p,
                    key,
                    residual,
                    scale,
                    probability,
                    (!on_surfaces).then_some(weight),
                );
            }
        }
        if on_surfaces {
            // Σ_i P_i·Jᵀn nᵀJ / F_i² over every row, from the sample drawn in proportion to P:
            // each draw stands for ΣP / Σw of the probability.
            let mass: f64 = probabilities.iter().filter(|p| **p > 0.0).sum();
            let draws: f64 = self.surfaces.iter().map(|s| s.weight).sum();
            for surface in &self.surfaces {
                let scale = rows.scale.get(surface.row);
                let factor = mass / draws * surface.weight / (scale * scale);
                sum.add_surface_response(&surface.moved, &surface.normal, factor);
            }
        }
        sum.finish(self.matching_response())
    }
}

/// The response factor s of the pose's uncertainty is not taken below this: a sample that
/// barely responds is not a surface the pose rests on.
const MIN_MATCHING_RESPONSE: f64 = 0.1;

/// Rows of the surfaces' sample matched again for s, at most: its standard error is then about
/// 0.02 where the targets' noise moves half the matches, far less where it moves few.
const MATCHING_RESPONSE_ROWS: usize = 1_024;

impl CloudProblem<'_> {
    /// s (`covariance`): how much of a move off its surface a point's residual keeps when it is
    /// matched again. Rows of the surfaces' sample are moved by ±h along their normals (h the
    /// spread of their residuals along them) and matched again; s = Σ w·nᵀ(Δp − Δq) / (2h·Σ w),
    /// where the target point found moves by Δq = q₊ − q₋ with the point when the targets'
    /// noise lets it choose one on the point's side. 1 without a sample.
    fn matching_response(&self) -> f64 {
        let (index, points) = (self.target.index(), self.target.points());
        let stride = self.surfaces.len().div_ceil(MATCHING_RESPONSE_ROWS).max(1);
        let rows = || self.surfaces.iter().step_by(stride);
        let along = |row: &SurfaceRow, p: &Point, q: &Point| {
            (0..3).map(|c| row.normal[c] * (p[c] - q[c])).sum::<f64>()
        };
        let draws: f64 = rows().map(|s| s.weight).sum();
        let spread = rows()
            .map(|s| s.weight * along(s, &s.moved, &points[s.target as usize]).powi(2))
            .sum::<f64>()
            / draws;
        let h = spread.sqrt();
        if !(h > 0.0 && h.is_finite()) {
            return 1.0;
        }
        let mut response = 0.0;
        for surface in rows() {
            let shifted = |sign: f64| -> Point {
                std::array::from_fn(|c| surface.moved[c] + sign * h * surface.normal[c])
            };
            let (up, down) = (shifted(1.0), shifted(-1.0));
            let (above, below) = (index.nearest_one(&up).0, index.nearest_one(&down).0);
            let change = along(surface, &up, &points[above]) - along(surface, &down, &points[below]);
            response += surface.weight * change / (2.0 * h);
        }
        (response / draws).clamp(MIN_MATCHING_RESPONSE, 1.0)
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
        let options = crate::registration::target::PrepareOptions::from_config(&config);
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
            fresh_coarse = Some(snapshot(problem.linearise(&guess, StepPoints::Coarse)));
        });
        room_problem_rows(12_000, |problem| {
            fresh_sample = Some(snapshot(problem.evaluate_all(&step)))
        });
        let (fresh_coarse, fresh_sample) = (fresh_coarse.unwrap(), fresh_sample.unwrap());
        room_problem_rows(12_000, |problem| {
            problem.evaluate_evidence(&guess);
            assert_eq!(
                snapshot(problem.linearise(&guess, StepPoints::Coarse)),
                fresh_coarse
            );
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
