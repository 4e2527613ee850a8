//! Poses a scene whose sides look alike explains nearly as well as the result (project issue
//! 29). Seen from inside, a room's walls, floor and ceiling meet at corners that look alike: a
//! scan turned a quarter turn about the vertical lies on the previous one with most of its
//! points on walls, GOOD on its own evidence, and a single start has nothing to compare that
//! with. The turn that would undo it is about no point of the result's inliers (it is about
//! the sensors, metres from them), so the rivals are re-centred instead: the result's rotation
//! turned a quarter turn either way about each principal axis of its inliers, with the
//! translation that puts the source's centroid on the target's. Two scans of one place from
//! nearby hold much the same surfaces, so at the right rotation their centroids nearly meet
//! (10–20 cm in a 6 × 4 m room, where the turn about the inliers is 1.5–2.5 m off). The half
//! turns' screens and count judge them (`half_turns`).

use nalgebra::{Matrix3, Matrix4, Vector3};

use crate::Point;
use crate::geometry::{from_parts, principal_axes, rotation_part};

/// A result is challenged by its quarter turns only when it moved the source points (RMS) by
/// more than this fraction of the target's spread (RMS distance from its centroid) from the
/// caller's guess. A quarter turn moves points by about √2 times their distance from its axis,
/// so a result a quarter turn from the truth lies about a spread from any guess near the truth
/// (the room's wrong results: 0.62–1.08 of it); a sequence's constant-velocity guess mostly
/// ends well within it, and those frames pay nothing.
pub(crate) const QUARTER_TURN_REACH: f64 = 0.25;

/// The rotation of `transform` turned a quarter turn either way about each principal axis of
/// `inliers` (target frame), each with the translation that moves the centroid of the source
/// points `source_centroid` (source frame) onto `target_centroid`.
pub(super) fn quarter_turns(
    inliers: &[Point],
    transform: &Matrix4<f64>,
    source_centroid: Vector3<f64>,
    target_centroid: Vector3<f64>,
) -> Vec<Matrix4<f64>> {
    let (_, axes) = principal_axes(inliers);
    let rotation = rotation_part(transform);
    axes.column_iter()
        .flat_map(|axis| {
            let outer = axis * axis.transpose();
            let cross = axis.cross_matrix();
            // Rodrigues at ±90°: R = e·eᵀ ± [e]ₓ.
            [outer + cross, outer - cross]
        })
        .map(|turn: Matrix3<f64>| {
            let turned = turn * rotation;
            from_parts(&turned, &(target_centroid - turned * source_centroid))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform_point;
    use nalgebra::Rotation3;

    /// Each rival of a turned and shifted pose is a rotation, a quarter turn (trace 1) away
    /// from the pose's own about one of the points' principal axes, and puts the source
    /// centroid on the target's.
    #[test]
    fn quarter_turns_are_quarter_turns_about_the_axes_that_match_the_centroids() {
        let box_points: Vec<Point> = (0..8)
            .map(|i| {
                let s = |bit: usize, half: f64| if i >> bit & 1 == 1 { half } else { -half };
                [3.0 + s(0, 2.0), s(1, 1.0), 1.0 + s(2, 0.5)]
            })
            .collect();
        let pose = Rotation3::from_euler_angles(0.1, -0.2, 0.7).to_homogeneous()
            * nalgebra::Translation3::new(0.5, -1.0, 2.0).to_homogeneous();
        let (source_centroid, target_centroid) = (Vector3::new(1.0, 2.0, 3.0), Vector3::new(-1.0, 0.5, 0.0));
        let rivals = quarter_turns(&box_points, &pose, source_centroid, target_centroid);
        assert_eq!(rivals.len(), 6);
        let rotation = rotation_part(&pose);
        for rival in &rivals {
            let turned = rotation_part(rival);
            assert!((turned.determinant() - 1.0).abs() < 1e-12);
            let turn = turned * rotation.transpose();
            assert!((turn.trace() - 1.0).abs() < 1e-12, "a quarter turn has trace 1");
            let axis = Rotation3::from_matrix_unchecked(turn).axis().unwrap();
            // The box's principal axes are x, y and z.
            assert!(axis.iter().any(|c| (c.abs() - 1.0).abs() < 1e-9), "{axis:?}");
            let moved = Vector3::from(transform_point(rival, &source_centroid.into()));
            assert!((moved - target_centroid).norm() < 1e-12);
        }
    }
}
