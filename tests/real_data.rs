//! ICP on real scans with ground truth (see each folder's README for the direction).
#![cfg(feature = "io")]
mod common;

use common::{data_dir, icp, pose_error};
use nalgebra::Matrix4;
use sie::io::{read_cloud, read_transform};
use sie::{CostFunction, Metric, RegistrationConfig, StopReason};

/// bun000 → bun045 from the Stanford bun.conf poses (the README's preferred ground truth;
/// PCL's bun0_to_bun4 matrix is a y-only simplification 0.78° away).
fn bunny_truth() -> Matrix4<f64> {
    Matrix4::new(
        0.826351, 0.004137, -0.563141, 0.036838, //
        -0.0106, 0.99991, -0.00821, -0.000257, //
        0.563056, 0.012754, 0.82632, 0.038321, //
        0.0, 0.0, 0.0, 1.0,
    )
}

#[test]
fn bunny_bun0_to_bun4_point_to_plane_from_identity() {
    let Some(dir) = data_dir() else { return };
    let source = read_cloud(&dir.join("pcl-test-bunny/bun0.pcd")).unwrap().points;
    let target = read_cloud(&dir.join("pcl-test-bunny/bun4.pcd")).unwrap().points;
    let config = RegistrationConfig::default();
    assert_eq!(config.metric, Metric::PointToPlane);
    let sie = icp(&source, &target, &config);
    let (rot, trans) = pose_error(&sie.transform, &bunny_truth());
    println!(
        "SIE point-to-plane: {rot:.3} deg, {:.2} mm, {:?}, {} iterations",
        trans * 1e3,
        sie.stop_reason,
        sie.iterations
    );
    assert_eq!(sie.stop_reason, StopReason::Converged);
    assert!(rot < 1.0 && trans < 0.005, "{rot} deg {trans} m");

    // Plain least squares, point-to-point, stops in the local optimum PCL's ICP also finds.
    let l2 = RegistrationConfig {
        cost: CostFunction::L2,
        metric: Metric::PointToPoint,
        ..RegistrationConfig::default()
    };
    let baseline = icp(&source, &target, &l2);
    let (rot_l2, _) = pose_error(&baseline.transform, &bunny_truth());
    println!("L2 point-to-point: {rot_l2:.3} deg");
    assert!(
        rot_l2 > 3.0,
        "the baseline should be visibly worse here ({rot_l2} deg)"
    );
}

#[test]
fn lidar_pair_point_to_plane_from_identity() {
    let Some(dir) = data_dir() else { return };
    let folder = dir.join("small_gicp-data");
    let source = read_cloud(&folder.join("source.ply")).unwrap().points;
    let target = read_cloud(&folder.join("target.ply")).unwrap().points;
    let truth = read_transform(&folder.join("T_target_source.txt")).unwrap();
    let result = icp(&source, &target, &RegistrationConfig::default());
    let (rot, trans) = pose_error(&result.transform, &truth);
    println!(
        "SIE point-to-plane: {rot:.3} deg, {:.1} mm, {:?}, {} iterations, sigma {:.4} m, inliers {:.2}",
        trans * 1e3,
        result.stop_reason,
        result.iterations,
        result.sigma[0],
        result.inlier_fraction
    );
    assert!(rot < 0.5 && trans < 0.05, "{rot} deg {trans} m");
    assert_ne!(result.stop_reason, StopReason::Degenerate);
}
