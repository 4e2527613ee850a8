//! The two registration problems the IRLS loop solves: fixed correspondences (`pairs`) and
//! ICP (`cloud`, with its cached matches in `matches`). Each produces residual rows at a
//! transform and solves the weighted step; buffers are reused across iterations (no
//! per-correspondence allocation per iteration).

mod cloud;
mod matches;
mod pairs;

use nalgebra::Matrix4;

use crate::geometry::{PlaneConditioning, Solve, transform_point};
use crate::median::median;
use crate::noise::combine;
use crate::point::Point;
use crate::registration::covariance::{PoseUncertainty, RowWeight};
use crate::registration::degeneracy::SurfaceRow;
pub(crate) use cloud::{CloudProblem, EvidenceMatch};
pub(crate) use pairs::CorrespondenceProblem;

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

/// Which source points an IRLS step matches (ICP; fixed pairs always use all of theirs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum StepPoints {
    /// A fixed coarse subset of the sample: the basin, not the last digit.
    Coarse,
    /// A fixed medium subset of the sample: the final model's fit, before the last digits.
    Medium,
    /// Every sampled source point.
    Sample,
    /// The verdict's evidence subset (ICP; about EVIDENCE_POINTS of the sample): where a rival
    /// leads, judged on the same points.
    Evidence,
}

/// What the IRLS loop needs of a registration problem.
pub(crate) trait Problem {
    /// Residual dimensions m.
    fn cols(&self) -> usize;
    /// Whether the pairs change with the transform (ICP re-matches; given correspondences do
    /// not).
    fn rematches(&self) -> bool;
    /// Whether a step on `points` matches fewer source points than the sample (ICP with a
    /// sample larger than that subset).
    fn steps_on_subset(&self, points: StepPoints) -> bool;
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
    /// (Re)matches `points` at `transform` and fills the rows used for fitting.
    fn linearise(&mut self, transform: &Matrix4<f64>, points: StepPoints) -> &Rows;
    /// The rows of the last `linearise`.
    fn rows(&self) -> &Rows;
    /// Weighted least-squares step from `transform` with one weight per row.
    fn solve(&mut self, transform: &Matrix4<f64>, weights: &[f64]) -> Option<Solve>;
    /// RMS over the rows of ‖(new − old)·a_i‖ / F_i: how far the update moved the data,
    /// in the normalised units σ is measured in.
    fn displacement(&self, old: &Matrix4<f64>, new: &Matrix4<f64>) -> f64;
    /// Rows for every source point (no sampling) at `transform`, for the reported results.
    fn evaluate_all(&mut self, transform: &Matrix4<f64>) -> &Rows;
    /// How well the surfaces under the last `evaluate_all` (at `transform`, with its rows'
    /// inlier `probabilities`) fix the pose, for a problem whose solve's conditioning misses
    /// sliding along them (ICP, see `registration::degeneracy`); `None` when the solve's
    /// conditioning says all there is (fixed correspondences: no surfaces).
    fn surface_conditioning(
        &mut self,
        _transform: &Matrix4<f64>,
        _probabilities: &[f64],
    ) -> Option<PlaneConditioning> {
        None
    }
    /// The surface sample the last `surface_conditioning` drew (inliers with their targets'
    /// normals, moved into the target frame); empty without surfaces.
    fn surface_rows(&self) -> &[SurfaceRow] {
        &[]
    }
    /// The pose's uncertainty at `transform` from the rows of the last `evaluate_all` there,
    /// one inlier probability per row, and the final model's `weight` (`covariance`); ICP's
    /// after its `surface_conditioning` there.
    fn pose_uncertainty(
        &self,
        transform: &Matrix4<f64>,
        probabilities: &[f64],
        weight: &RowWeight,
    ) -> PoseUncertainty;
    /// The last rows' source and target indices, for their last reader. ICP takes them and
    /// frees the rows (empty until the next linearise or evaluation); fixed correspondences,
    /// whose rows are built once and reused, give copies.
    fn take_row_indices(&mut self) -> (Vec<u32>, Vec<u32>) {
        let rows = self.rows();
        (rows.source.clone(), rows.target.clone())
    }
}

/// F of a row from its points' σ (§4.4), 1 unless both clouds have them.
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

/// RMS distance between where two transforms put `probe` (a problem's probe points), in input
/// units.
pub(crate) fn moved_apart(probe: &[Point], a: &Matrix4<f64>, b: &Matrix4<f64>) -> f64 {
    let difference = a - b;
    let (sum, count) = probe.iter().fold((0.0, 0usize), |(sum, n), p| {
        let d = transform_point(&difference, p);
        (sum + d[0] * d[0] + d[1] * d[1] + d[2] * d[2], n + 1)
    });
    if count == 0 {
        0.0
    } else {
        (sum / count as f64).sqrt()
    }
}
