//! Whether a source scaled against its target explains the data better than the rigid result
//! (project issue 29). A source a few per cent too large or small has no rigid answer, but ICP
//! still finds one: it aligns one part of the scene (a corner, whose planes a scaling about
//! their common point leaves in place) to the noise and leaves the rest as outliers, so the
//! result looks as clean as a right one with partial overlap. What tells them apart is the
//! rest: under a scaled fit it joins the inliers, under a rigid one nothing does.
//!
//! The check fits a similarity (rotation, translation and one scale) from the rigid result,
//! with SIE's annealing: Gaussian weights of a scale β that starts at the RMS residual (every
//! row has a say, so the far parts pull the scale) and shrinks to the result's fitted σ (only
//! the inliers are left to hold it). The scaled source is a rival when its inliers stand out
//! `MIN_SCALED_RATIO` times as much as those of the rigid result refitted alike: the
//! scale-free significance of the point-to-plane residuals of both on the evidence subset, in
//! both metrics (point-to-point's residuals are mostly the sampling's offsets along the
//! surfaces, which no scale removes).

use std::collections::HashMap;

use nalgebra::{Matrix4, Rotation3, SMatrix, SVector, Vector3};

use crate::point::Point;
use crate::registration::problem::{CloudProblem, EvidenceMatch, Problem};
use crate::registration::result::ScaledSource;
use crate::registration::significance::{Background, BinnedSignificance};
use crate::registration::verdict::{Evidence, MIN_SCALED_RATIO};

/// A similarity fitted where the rigid result holds only part of the data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct ScaledFit {
    /// The scale of the source against the target (1: none).
    pub(crate) scale: f64,
    /// The scale-free significance of the scaled fit's rows on the evidence subset …
    pub(crate) significance: f64,
    /// … and of the rigid result refitted to the same residuals.
    pub(crate) rigid_significance: f64,
}

impl ScaledFit {
    /// The rival the verdict counts: this fit when it stands out `MIN_SCALED_RATIO` times as
    /// much as the rigid result.
    pub(crate) fn rival(&self) -> Option<ScaledSource> {
        let ratio = self.significance / self.rigid_significance;
        (ratio >= MIN_SCALED_RATIO).then_some(ScaledSource {
            scale: self.scale,
            significance_ratio: ratio,
        })
    }
}

/// β shrinks by this factor per level, as SIE's schedule does.
const BETA_FACTOR: f64 = 0.7;
/// Updates per β level (each matches the evidence subset again).
const UPDATES_PER_LEVEL: usize = 2;
/// Updates at the final β (the result's σ).
const FINAL_UPDATES: usize = 4;
/// At most this many β levels (a spread 10⁷ times σ takes 45).
const MAX_LEVELS: usize = 48;
/// One update changes the scale by at most this fraction: the far parts pull it in steps.
const MAX_SCALE_STEP: f64 = 0.02;
/// Fewer evidence rows than this hold no scale.
const MIN_ROWS: usize = 30;

/// Fits a similarity from `rigid` (the best result, fitted σ `sigma` in normalised units) on the
/// evidence subset; `None` when there are too few rows or the fit breaks down. Leaves the
/// problem's rows at the evidence subset's.
pub(crate) fn fit_scaled(
    problem: &mut CloudProblem<'_>,
    evidence: &Evidence,
    rigid: &Matrix4<f64>,
    sigma: f64,
    inlier_fraction: f64,
) -> Option<ScaledFit> {
    let cols = problem.cols();
    // Point-to-point's targets' normals, estimated as its matches reach them.
    let mut own_normals = HashMap::new();
    let start = problem.evidence_matches(rigid, &mut own_normals);
    if start.len() < MIN_ROWS || sigma.is_nan() || sigma <= 0.0 {
        return None;
    }
    // The rigid fit judged alike: refitted to the same residuals with the same weights at σ
    // (point-to-point's result is the optimum of other residuals; a scaled fit measured against
    // it would win by the change of residual alone).
    let mut refit = *rigid;
    for _ in 0..FINAL_UPDATES {
        let matches = problem.evidence_matches(&refit, &mut own_normals);
        refit = update(&matches, sigma, Freedom::Rigid)? * refit;
    }
    let rigid_significance =
        plane_significance(&problem.evidence_matches(&refit, &mut own_normals), evidence);
    // β₀ per residual component of the problem's metric, as SIE's is (point-to-point: the plane
    // residuals' mean square over three components; the measured schedule).
    let rms = (start.iter().map(squared_residual).sum::<f64>() / (start.len() * cols) as f64).sqrt();
    let centre = centroid(&start);
    let mut best: Option<ScaledFit> = None;
    let initial_scales = if inlier_fraction < FEW_INLIERS {
        &INITIAL_SCALES[..]
    } else {
        &INITIAL_SCALES[..1]
    };
    let schedule = Schedule {
        first_beta: rms.max(sigma),
        last_beta: sigma,
    };
    for &initial_scale in initial_scales {
        let from = scaled_about(&centre, initial_scale) * rigid;
        let Some(fit) = anneal(problem, evidence, from, &schedule, &mut own_normals) else {
            continue;
        };
        if best.is_none_or(|b| fit.significance > b.significance) {
            best = Some(ScaledFit {
                rigid_significance,
                ..fit
            });
        }
    }
    best
}

/// The scales the annealed fits start from (about the evidence rows' centroid): a scaling of
/// 10 % moves a far part of a scene out of reach of the wide first levels that start at 1 …
const INITIAL_SCALES: [f64; 3] = [1.0, 1.1, 1.0 / 1.1];
/// … when the rigid result holds less than this fraction of the points (a corner of a room
/// scaled by 0.9: 16–51 %). One that holds more leaves no far part that large a scale would
/// move away, and the fit from 1 reaches the scale.
const FEW_INLIERS: f64 = 0.6;

/// The centroid of the moved points.
fn centroid(matches: &[EvidenceMatch]) -> Vector3<f64> {
    matches
        .iter()
        .map(|m| Vector3::from(m.moved))
        .sum::<Vector3<f64>>()
        / matches.len().max(1) as f64
}

/// β of the annealed fits: from `first_beta` down to `last_beta` (the result's σ).
struct Schedule {
    first_beta: f64,
    last_beta: f64,
}

/// The map scaling points by `scale` about `centre`.
fn scaled_about(centre: &Vector3<f64>, scale: f64) -> Matrix4<f64> {
    let mut map = Matrix4::identity();
    map.fixed_view_mut::<3, 3>(0, 0).scale_mut(scale);
    map.fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&(centre - scale * centre));
    map
}

/// One annealed similarity fit from `start` (its scale-free significance left 0 for the rigid
/// one: the caller's).
fn anneal(
    problem: &mut CloudProblem<'_>,
    evidence: &Evidence,
    start: Matrix4<f64>,
    schedule: &Schedule,
    own_normals: &mut HashMap<u32, Point>,
) -> Option<ScaledFit> {
    let (mut beta, sigma) = (schedule.first_beta, schedule.last_beta);
    let mut similarity = start;
    let mut levels = 0;
    loop {
        let last = beta <= sigma || levels >= MAX_LEVELS;
        let updates = if last { FINAL_UPDATES } else { UPDATES_PER_LEVEL };
        for _ in 0..updates {
            let matches = problem.evidence_matches(&similarity, own_normals);
            similarity = update(&matches, beta, Freedom::Similarity)? * similarity;
        }
        if last {
            break;
        }
        beta = (beta * BETA_FACTOR).max(sigma);
        levels += 1;
    }
    let scale = similarity.fixed_view::<3, 3>(0, 0).determinant().cbrt();
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let matches = problem.evidence_matches(&similarity, own_normals);
    Some(ScaledFit {
        scale,
        significance: plane_significance(&matches, evidence),
        rigid_significance: 0.0,
    })
}

/// The scale-free significance of the matches' point-to-plane residuals (those whose target has
/// a normal) against the evidence's background per residual component: in both metrics, since a
/// point-to-point residual is mostly the sampling's offset along the surface, which no scale
/// removes.
fn plane_significance(matches: &[EvidenceMatch], evidence: &Evidence) -> f64 {
    let background = evidence.background();
    let per_component = Background {
        spread_squared: background.spread_squared / background.dims.max(1) as f64,
        dims: 1,
    };
    BinnedSignificance::new(per_component)
        .evaluate(
            matches
                .iter()
                .filter(|m| m.normal != [0.0; 3])
                .map(squared_residual),
        )
        .significance
}

/// ‖r‖² / F² of one match: point-to-plane where its target has a normal (in both metrics),
/// point-to-point where it has none.
fn squared_residual(m: &EvidenceMatch) -> f64 {
    let d = Vector3::from(m.moved) - Vector3::from(m.target);
    let r2 = if m.normal != [0.0; 3] {
        Vector3::from(m.normal).dot(&d).powi(2)
    } else {
        d.norm_squared()
    };
    r2 / (m.scale * m.scale)
}

/// Gaussian weight of a match at scale β (normalised units).
fn weight(m: &EvidenceMatch, beta: f64) -> f64 {
    (-0.5 * squared_residual(m) / (beta * beta)).exp()
}

/// The weighted centroid of the moved points (weights at β), `None` when no row has weight.
fn weighted_centroid(matches: &[EvidenceMatch], beta: f64) -> Option<(Vector3<f64>, f64)> {
    let (mut sum, mut total) = (Vector3::zeros(), 0.0);
    for m in matches {
        let w = weight(m, beta);
        sum += w * Vector3::from(m.moved);
        total += w;
    }
    (total > 0.0).then(|| (sum / total, total))
}

/// What an update may change.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Freedom {
    /// Rotation and translation.
    Rigid,
    /// Rotation, translation and scale.
    Similarity,
}

/// One weighted Gauss-Newton update about the inliers' centroid c: a point x moves to
/// c + e^λ·R(ω)·(x − c) + v (λ = 0 for a rigid update); returned as that map.
fn update(matches: &[EvidenceMatch], beta: f64, freedom: Freedom) -> Option<Matrix4<f64>> {
    let (centre, _) = weighted_centroid(matches, beta)?;
    let mut normal = SMatrix::<f64, 7, 7>::zeros();
    let mut rhs = SVector::<f64, 7>::zeros();
    let mut add = |jacobian: SVector<f64, 7>, residual: f64, w: f64| {
        normal += w * jacobian * jacobian.transpose();
        rhs -= w * residual * jacobian;
    };
    for m in matches {
        let w = weight(m, beta);
        if w < 1e-12 {
            continue;
        }
        let x = Vector3::from(m.moved) - centre;
        let d = Vector3::from(m.moved) - Vector3::from(m.target);
        let f = m.scale;
        if m.normal != [0.0; 3] {
            let n = Vector3::from(m.normal);
            let jr = x.cross(&n);
            let jacobian =
                SVector::<f64, 7>::from_column_slice(&[jr.x, jr.y, jr.z, n.x, n.y, n.z, n.dot(&x)]);
            add(jacobian / f, n.dot(&d) / f, w);
        } else {
            for axis in 0..3 {
                // ∂x_axis / ∂(ω, v, λ): (ω × x)_axis, e_axis, x_axis.
                let e = Vector3::ith(axis, 1.0);
                let jr = x.cross(&e);
                let mut jacobian = SVector::<f64, 7>::zeros();
                jacobian.fixed_rows_mut::<3>(0).copy_from(&jr);
                jacobian[3 + axis] = 1.0;
                jacobian[6] = x[axis];
                add(jacobian / f, d[axis] / f, w);
            }
        }
    }
    if freedom == Freedom::Rigid {
        for i in 0..7 {
            normal[(6, i)] = 0.0;
            normal[(i, 6)] = 0.0;
        }
        normal[(6, 6)] = 1.0;
        rhs[6] = 0.0;
    }
    // A tiny ridge keeps a direction the weighted rows leave free (a plane's slide) at zero.
    let ridge = 1e-9 * (0..7).map(|i| normal[(i, i)]).fold(0.0, f64::max);
    for i in 0..7 {
        normal[(i, i)] += ridge;
    }
    let step = normal.cholesky()?.solve(&rhs);
    if !step.iter().all(|v| v.is_finite()) {
        return None;
    }
    let omega = Vector3::new(step[0], step[1], step[2]);
    let shift = Vector3::new(step[3], step[4], step[5]);
    let log_scale = step[6].clamp(-MAX_SCALE_STEP, MAX_SCALE_STEP);
    let linear = Rotation3::new(omega).into_inner() * log_scale.exp();
    let mut map = Matrix4::identity();
    map.fixed_view_mut::<3, 3>(0, 0).copy_from(&linear);
    map.fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&(centre + shift - linear * centre));
    Some(map)
}
