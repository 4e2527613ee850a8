//! The readers on the real clouds in the shared data folder (point counts from its READMEs).
//!
//! The folder is `$SIE_DATA_DIR`, by default `<crate>/../shared/data`; when it is missing the
//! tests print a note and pass (CI has it).
#![cfg(feature = "io")]

use std::path::{Path, PathBuf};

use sie::NonFinite;
use sie::io::{CloudFile, read_cloud, read_cloud_with, read_transform};

fn data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("SIE_DATA_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!(
            "skipping: data folder {} not found (set SIE_DATA_DIR)",
            dir.display()
        );
        None
    }
}

fn read(dir: &Path, file: &str) -> CloudFile {
    read_cloud(&dir.join(file)).unwrap_or_else(|e| panic!("{e}"))
}

fn assert_counts(dir: &Path, folder: &str, expected: &[(&str, usize)]) {
    for &(file, count) in expected {
        let cloud = read(dir, &format!("{folder}/{file}"));
        assert_eq!(cloud.points.len(), count, "{folder}/{file}");
        assert_eq!(cloud.skipped_non_finite, 0);
    }
}

#[test]
fn pcl_test_bunny() {
    let Some(dir) = data_dir() else { return };
    assert_counts(
        &dir,
        "pcl-test-bunny",
        // bun4 and the bun0x files have a `VERSION .5` header, which pcd-rs accepts.
        &[
            ("bun0.pcd", 397),
            ("bun4.pcd", 361),
            ("bunny.pcd", 397),
            ("bun01.pcd", 200),
            ("bun02.pcd", 217),
            ("bun03.pcd", 197),
        ],
    );
    let bun0 = read(&dir, "pcl-test-bunny/bun0.pcd");
    let normals = bun0.normals.as_ref().expect("bun0.pcd has normal_x/y/z");
    assert_eq!(normals.len(), 397);
    for n in normals {
        let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((norm - 1.0).abs() < 1e-5, "normal {n:?}");
    }
    // The first line of the file, read as the f32 its header declares.
    let first_line = ["0.0054215998", "0.11349", "0.040748999"].map(|t| t.parse::<f32>().unwrap() as f64);
    assert_eq!(bun0.points[0], first_line);
    // The README: bunny.pcd holds the same coordinates as bun0.pcd.
    let bunny = read(&dir, "pcl-test-bunny/bunny.pcd");
    assert!(bunny.normals.is_none());
    for (a, b) in bun0.points.iter().zip(&bunny.points) {
        assert!((0..3).all(|d| (a[d] - b[d]).abs() < 1e-7), "{a:?} vs {b:?}");
    }
}

#[test]
fn small_gicp_pair_and_transform() {
    let Some(dir) = data_dir() else { return };
    assert_counts(
        &dir,
        "small_gicp-data",
        &[("source.ply", 69792), ("target.ply", 69088)],
    );
    // Invalid LiDAR returns are stored as exact zeros; registration must not treat this stack
    // of identical points as structure.
    let source = read(&dir, "small_gicp-data/source.ply");
    assert_eq!(source.points.iter().filter(|p| **p == [0.0; 3]).count(), 5107);
    let t = read_transform(&dir.join("small_gicp-data/T_target_source.txt")).unwrap();
    assert_eq!(t[(0, 0)], 0.999925);
    assert_eq!(t[(0, 3)], 0.488882);
    assert_eq!(t[(1, 3)], 0.121214);
    assert_eq!(t[(2, 3)], -0.0253342);
    let rotation = t.fixed_view::<3, 3>(0, 0);
    let orthogonality = (rotation.transpose() * rotation - nalgebra::Matrix3::identity())
        .abs()
        .max();
    assert!(orthogonality < 1e-5, "{orthogonality}");
}

#[test]
fn stanford_scans_stop_before_range_grid() {
    let Some(dir) = data_dir() else { return };
    assert_counts(
        &dir,
        "stanford-bunny-scans",
        &[
            ("bun000.ply", 40256),
            ("bun045.ply", 40097),
            ("bun090.ply", 30379),
            ("bun180.ply", 40251),
            ("bun270.ply", 31701),
            ("bun315.ply", 35336),
            ("chin.ply", 37738),
            ("ear_back.ply", 32193),
            ("top2.ply", 38298),
            ("top3.ply", 36023),
        ],
    );
    // A bunny is about 0.15 m across.
    let scan = read(&dir, "stanford-bunny-scans/bun000.ply");
    for d in 0..3 {
        let (lo, hi) = scan
            .points
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), p| (lo.min(p[d]), hi.max(p[d])));
        assert!(hi - lo > 0.03 && hi - lo < 0.3, "axis {d}: {lo}..{hi}");
    }
}

#[test]
fn room_scans_binary_compressed() {
    let Some(dir) = data_dir() else { return };
    assert_counts(
        &dir,
        "pcl-data-room-scans",
        &[("room_scan1.pcd", 112586), ("room_scan2.pcd", 112624)],
    );
    let scan = read(&dir, "pcl-data-room-scans/room_scan1.pcd");
    let extent: Vec<f64> = (0..3)
        .map(|d| {
            let (lo, hi) = scan
                .points
                .iter()
                .fold((f64::MAX, f64::MIN), |(lo, hi), p| (lo.min(p[d]), hi.max(p[d])));
            hi - lo
        })
        .collect();
    // README: 29.2 × 14.5 × 3.1 m.
    for (got, want) in extent.iter().zip([29.2, 14.5, 3.1]) {
        assert!((got - want).abs() < 0.1, "extent {extent:?}");
    }
}

#[test]
fn truncated_real_files_are_errors() {
    let Some(dir) = data_dir() else { return };
    let out = std::env::temp_dir().join(format!("sie-io-data-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    for file in [
        "pcl-data-room-scans/room_scan1.pcd",
        "small_gicp-data/source.ply",
        "pcl-test-bunny/bun0.pcd",
    ] {
        let bytes = std::fs::read(dir.join(file)).unwrap();
        let name = Path::new(file).file_name().unwrap();
        // Not the last bytes: PCL pads binary_compressed files beyond the compressed block.
        for keep in [bytes.len() / 3, bytes.len() * 2 / 3] {
            let path = out.join(name);
            std::fs::write(&path, &bytes[..keep]).unwrap();
            let err = read_cloud_with(&path, NonFinite::Skip)
                .err()
                .unwrap_or_else(|| panic!("{file} cut at {keep}"));
            assert!(
                err.contains(&path.display().to_string()) && !err.contains('\n'),
                "{err}"
            );
        }
    }
    std::fs::remove_dir_all(&out).unwrap();
}
