//! Shared helpers for the data-driven tests.
#![allow(dead_code)]
use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use sie::geometry::{rotation_angle, rotation_part, translation_part};
use sie::{Hooks, Point, RegistrationConfig, RegistrationResult, register_clouds};

pub mod c_context;

// The `sie` binary's helpers: its tests only exist with the CLI.
#[cfg(feature = "cli")]
pub mod cli;

/// The real-scan folder: `$SIE_DATA_DIR`, by default `<crate>/../shared/data`. Returns `None`
/// (the caller skips) only outside CI; under CI (env `CI` set) a missing folder is a failure,
/// so a wrong path cannot turn these tests into no-ops.
pub fn data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("SIE_DATA_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "data folder {} not found under CI",
        dir.display()
    );
    eprintln!(
        "skipping: data folder {} not found (set SIE_DATA_DIR)",
        dir.display()
    );
    None
}

/// The small_gicp LiDAR pair (`small_gicp-data`): both scans as read, missing returns at 0 0 0
/// kept, and `T_target_source`.
#[cfg(feature = "io")]
pub struct LidarPair {
    pub source: Vec<Point>,
    pub target: Vec<Point>,
    pub truth: Matrix4<f64>,
}

#[cfg(feature = "io")]
impl LidarPair {
    /// Reads the pair from the data folder `dir`; panics when a file is missing or malformed.
    pub fn read(dir: &Path) -> Self {
        use sie::io::{read_cloud, read_transform};
        let folder = dir.join("small_gicp-data");
        LidarPair {
            source: read_cloud(&folder.join("source.ply")).unwrap().points,
            target: read_cloud(&folder.join("target.ply")).unwrap().points,
            truth: read_transform(&folder.join("T_target_source.txt")).unwrap(),
        }
    }
}

/// Rotation (degrees) and translation distance of `estimate` from `truth`.
pub fn pose_error(estimate: &Matrix4<f64>, truth: &Matrix4<f64>) -> (f64, f64) {
    let difference = truth.try_inverse().expect("rigid") * estimate;
    (
        rotation_angle(&rotation_part(&difference)).to_degrees(),
        translation_part(&difference).norm(),
    )
}

/// ICP of `source` onto `target` from the identity, normals estimated, no hooks; panics on an
/// error (the tests using it pass valid input).
pub fn icp(source: &[Point], target: &[Point], config: &RegistrationConfig) -> RegistrationResult {
    register_clouds(source, target, None, None, config, Hooks::default()).expect("registration")
}
