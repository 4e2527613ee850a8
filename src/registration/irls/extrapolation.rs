//! Extrapolation of the final round's updates (project issue 30, "Anderson acceleration of the
//! ICP fixed point"; the one-step form, Aitken's Δ²). Near its end ICP converges linearly: each
//! update repeats the last one's direction, shortened by a ratio r close to 1 where the surfaces
//! fix some direction weakly, and such a run creeps in steps too small to stop on until its
//! update cap (docs/performance.md, "Final-round extrapolation"). The remaining steps sum to
//! r / (1 − r) times the last one, so the pose jumps there and IRLS goes on from the jump: a
//! wrong jump is undone by the next update, since the model's width bounds it.

use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};

use crate::geometry::{from_parts, orthonormalised, rotation_part, translation_part};
use crate::registration::problem::Problem;

/// Two updates repeat a direction when the first and second together moved the rows by at
/// least this fraction of the sum of their lengths (1: exactly collinear); the jump grows from
/// nothing at [`BENT`] to its full length here, so that it changes smoothly with the updates
/// (a rounding difference in them must not decide between a jump and none).
const COLLINEAR: f64 = 0.95;
/// See [`COLLINEAR`].
const BENT: f64 = 0.9;
/// The jump adds r / (1 − r) times the last update up to this ratio of successive update
/// lengths (99 times), and tapers to nothing at r = 1 (updates that do not shrink).
const MAX_RATIO: f64 = 0.99;

/// The last two poses of plain updates in a run's final round.
#[derive(Default)]
pub(super) struct Extrapolation {
    before: Option<Matrix4<f64>>,
    last: Option<Matrix4<f64>>,
}

impl Extrapolation {
    /// After the plain update `from` → `to` of the final round: `to` moved on by the steps that
    /// remain when the last two updates and this one shrink geometrically along one direction,
    /// at most `width` (the model's σ+β, normalised) further; `to` itself otherwise.
    pub(super) fn next(
        &mut self,
        problem: &dyn Problem,
        from: &Matrix4<f64>,
        to: &Matrix4<f64>,
        width: f64,
    ) -> Matrix4<f64> {
        let earlier = match (self.before, self.last) {
            (Some(before), Some(last)) if last == *from => Some(before),
            _ => None,
        };
        self.before = Some(*from);
        self.last = Some(*to);
        let Some(earlier) = earlier else {
            return *to;
        };
        let first = problem.displacement(&earlier, from);
        let second = problem.displacement(from, to);
        let both = problem.displacement(&earlier, to);
        let ratio = second / first;
        let straightness = ((both / (first + second) - BENT) / (COLLINEAR - BENT)).clamp(0.0, 1.0);
        let remaining = if ratio < MAX_RATIO {
            ratio / (1.0 - ratio)
        } else {
            // From MAX_RATIO / (1 − MAX_RATIO) at MAX_RATIO down to 0 at 1.
            (MAX_RATIO / (1.0 - MAX_RATIO)) * ((1.0 - ratio) / (1.0 - MAX_RATIO)).max(0.0)
        };
        let factor = (straightness * remaining).min(width / second);
        if !(first > 0.0 && second > 0.0 && factor.is_finite() && factor > 0.0) {
            return *to;
        }
        let Some(inverse) = from.try_inverse() else {
            return *to;
        };
        let extrapolated = orthonormalised(&(power(&(to * inverse), factor) * to));
        if !extrapolated.iter().all(|v| v.is_finite()) {
            return *to;
        }
        // The next extrapolation needs two plain updates from here.
        self.before = None;
        self.last = Some(extrapolated);
        extrapolated
    }
}

/// The rigid motion `step` raised to the power `exponent`: the same screw motion, its angle
/// and its advance along the axis times `exponent` (exp(exponent · log(step)) on SE(3)), so
/// that the jump does not depend on the frame the poses are written in.
fn power(step: &Matrix4<f64>, exponent: f64) -> Matrix4<f64> {
    let omega = rotation_vector(&rotation_part(step));
    // t = V(ω)·u, and the power moves by V(exponent·ω)·exponent·u.
    let advance = match left_jacobian(&omega).try_inverse() {
        Some(inverse) => inverse * translation_part(step),
        None => return *step,
    };
    let scaled = exponent * omega;
    from_parts(
        Rotation3::from_scaled_axis(scaled).matrix(),
        &(left_jacobian(&scaled) * (exponent * advance)),
    )
}

/// The rotation vector (axis times angle) of a rotation matrix, through its quaternion:
/// accurate for the small turns of a final round (an angle from the trace's arccosine keeps
/// only about 1e-8 rad).
fn rotation_vector(rotation: &Matrix3<f64>) -> Vector3<f64> {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*rotation));
    let (w, v) = (q.scalar(), q.vector().into_owned());
    let (w, v) = if w < 0.0 { (-w, -v) } else { (w, v) };
    let sine = v.norm();
    if sine == 0.0 {
        return Vector3::zeros();
    }
    v * (2.0 * sine.atan2(w) / sine)
}

/// V(ω) = I + (1 − cos θ)/θ² [ω]ₓ + (θ − sin θ)/θ³ [ω]ₓ², θ = |ω| (series below 1e-4 rad).
fn left_jacobian(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta_squared = omega.norm_squared();
    let cross = omega.cross_matrix();
    let (a, b) = if theta_squared < 1e-8 {
        (0.5 - theta_squared / 24.0, 1.0 / 6.0 - theta_squared / 120.0)
    } else {
        let theta = theta_squared.sqrt();
        (
            (1.0 - theta.cos()) / theta_squared,
            (theta - theta.sin()) / (theta_squared * theta),
        )
    };
    Matrix3::identity() + a * cross + b * cross * cross
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A screw motion raised to 2 is the motion twice, to 1 itself, to ½ its square root, and
    /// the power does not depend on the frame: conjugating the step conjugates its power.
    #[test]
    fn powers_of_a_rigid_motion_compose_and_follow_the_frame() {
        let step = from_parts(
            Rotation3::from_euler_angles(0.3, -0.2, 0.5).matrix(),
            &Vector3::new(1.0, -2.0, 0.5),
        );
        let close = |a: &Matrix4<f64>, b: &Matrix4<f64>| (a - b).amax() < 1e-12;
        assert!(close(&power(&step, 1.0), &step));
        assert!(close(&power(&step, 2.0), &(step * step)));
        let half = power(&step, 0.5);
        assert!(close(&(half * half), &step));
        let frame = from_parts(
            Rotation3::from_euler_angles(-0.4, 0.1, 1.2).matrix(),
            &Vector3::new(5.0, 3.0, -7.0),
        );
        let moved = frame * step * frame.try_inverse().unwrap();
        let expected = frame * power(&step, 7.5) * frame.try_inverse().unwrap();
        assert!(close(&power(&moved, 7.5), &expected));
        // A tiny turn (the series branch) still composes.
        let tiny = from_parts(
            Rotation3::from_euler_angles(1e-6, 2e-6, -1e-6).matrix(),
            &Vector3::new(1e-5, 0.0, 2e-5),
        );
        assert!(close(&power(&tiny, 3.0), &(tiny * tiny * tiny)));
    }
}
