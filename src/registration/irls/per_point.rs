//! A run's per-point results (P(I|r) and the match of every source point) computed only for
//! the run that is kept, and rebuilt rather than kept while later starts run.

use nalgebra::Matrix4;

use super::normalised;
use super::weighting::Weighting;
use crate::registration::problem::Problem;
use crate::registration::result::RegistrationResult;

/// A run's final per-row probabilities, not yet spread over the source points: a result
/// that is discarded (a start that does not win, a lead) never allocates its 16 bytes a
/// source point, and one that is kept allocates them after the result it replaces is freed.
pub(crate) struct PendingPerPoint {
    pub(super) row_probabilities: Vec<f64>,
    pub(super) model: FinalModel,
}

/// What a run's per-point results are computed from: its final noise model and transform.
/// Kept instead of the results themselves (16 bytes a source point) while later starts run.
pub(crate) struct FinalModel {
    pub(super) weighting: Weighting,
    pub(super) transform: Matrix4<f64>,
}

impl FinalModel {
    /// The run's final evaluation again: the problem's rows at the final transform and their
    /// probabilities under the final model. The same bits as the first time: matching is
    /// exact (a cached match is reused only when no other target can have come nearer),
    /// normals and noise scales are fixed per point, and the model is not refitted.
    pub(crate) fn evaluate_again(mut self, problem: &mut dyn Problem) -> PendingPerPoint {
        let cols = problem.cols();
        problem.evaluate_all(&self.transform);
        let mut buffer = Vec::new();
        let normalised = normalised(problem.rows(), cols, &mut buffer);
        let mut row_probabilities = Vec::new();
        self.weighting
            .final_probabilities(normalised, cols, &mut row_probabilities);
        PendingPerPoint {
            row_probabilities,
            model: self,
        }
    }
}

impl PendingPerPoint {
    /// Fills `result.probabilities` and `result.correspondences`; returns the model they
    /// came from. The problem's rows must still be the run's final evaluation; they stay.
    pub(crate) fn spread(self, problem: &dyn Problem, result: &mut RegistrationResult) -> FinalModel {
        let rows = problem.rows();
        self.fill(&rows.source, &rows.target, problem.source_count(), result)
    }

    /// [`PendingPerPoint::spread`] for rows that are read for the last time: the problem's
    /// rows are taken (empty until its next linearise or evaluation) and their residuals
    /// freed first, so that the per-point results need no more memory than the final
    /// evaluation did (at 10 M points, 76 MiB less at the registration's peak).
    pub(crate) fn spread_last(
        self,
        problem: &mut dyn Problem,
        result: &mut RegistrationResult,
    ) -> FinalModel {
        let source_count = problem.source_count();
        let (source, target) = problem.take_row_indices();
        self.fill(&source, &target, source_count, result)
    }

    /// Row `i`'s probability and target go to source point `source[i]`; one per-point vector
    /// at a time, the row probabilities freed before the second.
    fn fill(
        self,
        source: &[u32],
        target: &[u32],
        source_count: usize,
        result: &mut RegistrationResult,
    ) -> FinalModel {
        assert!(
            source.len() == self.row_probabilities.len() && target.len() == source.len(),
            "per-point results spread from rows other than the final evaluation's"
        );
        let mut probabilities = vec![0.0; source_count];
        for (&s, &p) in source.iter().zip(&self.row_probabilities) {
            probabilities[s as usize] = p;
        }
        drop(self.row_probabilities);
        let mut correspondences = vec![-1i64; source_count];
        for (&s, &t) in source.iter().zip(target) {
            correspondences[s as usize] = i64::from(t);
        }
        result.probabilities = probabilities;
        result.correspondences = correspondences;
        self.model
    }
}
