//! sie's FPFH against Open3D's `compute_fpfh_feature` on the same points and normals
//! (tests/data/fpfh_open3d.txt, written by scripts/fpfh_fixture.py with open3d 0.20.0).

use sie::features::{FPFH_BINS, fpfh};
use sie::nn::NearestNeighbours;
use sie::parallel::Workers;

/// The fixture's search: Open3D's hybrid radius 0.25, at most 100 neighbours.
const RADIUS: f64 = 0.25;
const MAX_NEIGHBOURS: usize = 100;

#[test]
fn fpfh_agrees_with_open3d_on_the_same_points_and_normals() {
    let text = include_str!("data/fpfh_open3d.txt");
    let rows: Vec<Vec<f64>> = text
        .lines()
        .filter(|line| !line.starts_with('#'))
        .map(|line| {
            line.split_whitespace()
                .map(|v| v.parse().expect("number"))
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 440);
    let points: Vec<[f64; 3]> = rows.iter().map(|r| [r[0], r[1], r[2]]).collect();
    let normals: Vec<[f64; 3]> = rows.iter().map(|r| [r[3], r[4], r[5]]).collect();
    let index = NearestNeighbours::new(&points).unwrap();
    let ours = fpfh(
        &points,
        &normals,
        &index,
        RADIUS,
        MAX_NEIGHBOURS,
        &Workers::new(2).unwrap(),
    );
    // Every bin to 1e-9 of Open3D's (values 0 to 200): the same neighbours, angles and bins.
    let mut worst = (0.0f64, 0, 0);
    for (i, (row, feature)) in rows.iter().zip(&ours).enumerate() {
        for b in 0..FPFH_BINS {
            let difference = (row[6 + b] - feature[b]).abs();
            if difference > worst.0 {
                worst = (difference, i, b);
            }
        }
    }
    assert!(
        worst.0 <= 1e-9,
        "largest difference {} at point {} bin {}",
        worst.0,
        worst.1,
        worst.2
    );
}
