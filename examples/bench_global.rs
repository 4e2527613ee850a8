//! The global stage (`Starts::Global`, issue 31) on the shared real pairs (bunny scans, the
//! 3DLoMatch pair, the LiDAR pair, the slambook Kinect frames, the room scans) with no initial guess:
//! each pair as given and with the source turned 30°, 90° and 180° about fixed arbitrary axes
//! through its centroid (bench/global_peers.py runs the peers on the same cases). Prints a table: rotation and translation error against the ground
//! truth, success (2° and 2 % of the target's diagonal), verdict, time. A program, not a test.
//!
//! `cargo run --release --example bench_global -- [data dir] [threads] [pair name filter]`
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Matrix4, Rotation3, Translation3, Unit, Vector3};
use sie::geometry::{
    bounding_box_diagonal, centroid, rotation_angle, rotation_part, transform_point, translation_part,
};
use sie::io::{read_cloud, read_transform};
use sie::{Hooks, Point, RegistrationConfig, Starts, Verdict, register_clouds};

#[path = "common/slambook.rs"]
mod slambook;

/// The turns of the source about its centroid, and their axes (arbitrary, fixed so that
/// bench/global_peers.py turns the same way).
const TURNS: [(f64, [f64; 3]); 4] = [
    (0.0, [0.0, 0.0, 1.0]),
    (30.0, [0.3, -0.5, 0.8]),
    (90.0, [-0.7, 0.2, 0.6]),
    (180.0, [0.1, 0.9, -0.4]),
];

struct Pair {
    name: String,
    source: Vec<Point>,
    target: Vec<Point>,
    /// T_target_source.
    truth: Matrix4<f64>,
}

fn main() {
    let mut args = std::env::args().skip(1);
    let dir = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    let threads: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(0);
    let name_filter = args.next().unwrap_or_default();
    let pairs: Vec<Pair> = pairs(&dir)
        .into_iter()
        .filter(|pair| pair.name.contains(&name_filter))
        .collect();
    let config = RegistrationConfig {
        starts: Starts::Global,
        threads,
        ..RegistrationConfig::default()
    };
    println!(
        "| pair | turn | rot err [deg] | trans err [% diag] | success | verdict | starts run | time [s] |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let (mut successes, mut runs, mut wrong_good) = (0, 0, 0);
    for pair in &pairs {
        let diagonal = bounding_box_diagonal(&pair.target);
        for (degrees, axis) in TURNS {
            let axis = Unit::new_normalize(Vector3::from(axis));
            let c = Vector3::from(centroid(&pair.source));
            let turn = Translation3::from(c).to_homogeneous()
                * Rotation3::from_axis_angle(&axis, degrees.to_radians()).to_homogeneous()
                * Translation3::from(-c).to_homogeneous();
            let turned: Vec<Point> = pair.source.iter().map(|p| transform_point(&turn, p)).collect();
            let truth = pair.truth * turn.try_inverse().unwrap();
            let started = Instant::now();
            let outcome = register_clouds(&turned, &pair.target, None, None, &config, Hooks::default());
            let seconds = started.elapsed().as_secs_f64();
            runs += 1;
            match outcome {
                Ok(result) => {
                    let difference = truth.try_inverse().unwrap() * result.transform;
                    let rotation = rotation_angle(&rotation_part(&difference)).to_degrees();
                    let translation = translation_part(&difference).norm() / diagonal;
                    let success = rotation < 2.0 && translation < 0.02;
                    successes += usize::from(success);
                    wrong_good += usize::from(!success && result.quality.verdict == Verdict::Good);
                    println!(
                        "| {} | {degrees}° | {rotation:.2} | {:.2} | {} | {:?} | {} | {seconds:.2} |",
                        pair.name,
                        100.0 * translation,
                        if success { "yes" } else { "no" },
                        result.quality.verdict,
                        result.search.starts_run
                    );
                }
                Err(error) => println!(
                    "| {} | {degrees}° | - | - | no | error: {error} | - | {seconds:.2} |",
                    pair.name
                ),
            }
        }
    }
    println!(
        "\n{successes} of {runs} within 2° and 2 % of the diagonal; wrong poses called GOOD: {wrong_good}"
    );
}

fn pairs(dir: &Path) -> Vec<Pair> {
    let read = |path: &str| read_cloud(&dir.join(path)).expect("cloud").points;
    let mut pairs = Vec::new();
    let bunny_pose = |scan: &str| {
        let conf = std::fs::read_to_string(dir.join("stanford-bunny-scans/bun.conf")).expect("bun.conf");
        let line = conf
            .lines()
            .find(|l| l.starts_with("bmesh") && l.contains(&format!("{scan}.ply")))
            .expect("scan");
        let v: Vec<f64> = line
            .split_whitespace()
            .skip(2)
            .map(|x| x.parse().unwrap())
            .collect();
        let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(v[6], v[3], v[4], v[5]));
        let mut pose = q.to_rotation_matrix().inverse().to_homogeneous();
        pose.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&Vector3::new(v[0], v[1], v[2]));
        pose
    };
    for (source, target) in [
        ("bun045", "bun000"),
        ("bun315", "bun000"),
        ("bun090", "bun045"),
        ("bun270", "bun315"),
    ] {
        pairs.push(Pair {
            name: format!("bunny {source} -> {target}"),
            source: read(&format!("stanford-bunny-scans/{source}.ply")),
            target: read(&format!("stanford-bunny-scans/{target}.ply")),
            truth: bunny_pose(target).try_inverse().unwrap() * bunny_pose(source),
        });
    }
    pairs.push(Pair {
        name: "3DLoMatch redkitchen 34 -> 21".into(),
        source: read("predator-3dlomatch-redkitchen/cloud_bin_34.xyz"),
        target: read("predator-3dlomatch-redkitchen/cloud_bin_21.xyz"),
        truth: read_transform(&dir.join("predator-3dlomatch-redkitchen/gt_34_to_21.txt")).expect("gt"),
    });
    pairs.push(Pair {
        name: "LiDAR small_gicp".into(),
        source: read("small_gicp-data/source.ply"),
        target: read("small_gicp-data/target.ply"),
        truth: read_transform(&dir.join("small_gicp-data/T_target_source.txt")).expect("gt"),
    });
    // Consecutive Kinect frames, each into the one before (frame 2 into 1: a large motion with
    // little overlap, the data README).
    let kinect = slambook::read_kinect_frames(&dir.join("slambook-joinmap-rgbd")).expect("Kinect frames");
    for i in 1..kinect.frames.len() {
        pairs.push(Pair {
            name: format!("Kinect frame {} -> {}", i + 1, i),
            source: kinect.frames[i].clone(),
            target: kinect.frames[i - 1].clone(),
            truth: kinect.poses[i - 1].try_inverse().unwrap() * kinect.poses[i],
        });
    }
    // No exact truth: the default registration from the tutorial's odometry guess (README).
    let source = read("pcl-data-room-scans/room_scan2.pcd");
    let target = read("pcl-data-room-scans/room_scan1.pcd");
    let guess = Translation3::new(1.79387, 0.720047, 0.0).to_homogeneous()
        * Rotation3::from_axis_angle(&Vector3::z_axis(), ROOM_ODOMETRY_YAW).to_homogeneous();
    let reference = register_clouds(
        &source,
        &target,
        None,
        Some(&guess),
        &RegistrationConfig::default(),
        Hooks::default(),
    )
    .expect("room reference");
    println!(
        "room reference from the tutorial guess: {:?}, {:.2}° from the guess\n",
        reference.quality.verdict,
        rotation_angle(&rotation_part(
            &(guess.try_inverse().unwrap() * reference.transform)
        ))
        .to_degrees()
    );
    pairs.push(Pair {
        name: "PCL room scan2 -> scan1".into(),
        source,
        target,
        truth: reference.transform,
    });
    pairs
}

/// The PCL tutorial's odometry yaw (rad) of room_scan2 into room_scan1 (the folder's README).
#[expect(
    clippy::approx_constant,
    reason = "the tutorial's yaw, which happens to be near ln 2"
)]
const ROOM_ODOMETRY_YAW: f64 = 0.6931;
