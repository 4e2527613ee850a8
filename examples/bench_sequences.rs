//! Odometry benchmark: sie over frame sequences, frame to previous frame and frame to a growing
//! map, the targets prepared once (`PreparedTarget`). Prints frames per second and drift (the
//! relative pose error of each frame's motion, and the absolute trajectory error: the RMS
//! distance of each estimated position from the true one, every trajectory starting at the
//! true first pose, without alignment) as CSV rows, in the same format as
//! bench/sequences.py prints for small_gicp and KISS-ICP on the same frames (bench/sequences.sh
//! runs all of them and the report). sie runs cold, warm-started, through `Odometry`, and cold
//! on each frame thinned to the map's voxels (the speed and drift that thinning buys).
//!
//! ```text
//! bench_sequences write DIR [FRAMES] [N,N,...]   synthetic room trajectories (default 100 frames
//!                                                 of 10000 and 50000 points), a depth camera on
//!                                                 the same loop (noise growing as depth²),
//!                                                 FRAMES sweeps of the simulated 64-beam LiDAR
//!                                                 driving through a street
//!                                                 (`sie::synthetic::lidar`, about 100 000 points
//!                                                 each; the story takes 300), still and with
//!                                                 motion distortion, and, if SIE_DATA_DIR has
//!                                                 them, the Kinect frames and the LiDAR pair, as
//!                                                 DIR/<name>/
//! bench_sequences run DIR [THREADS,...]          CSV on stdout (default 1,2 threads)
//! bench_sequences quick                          a 12-frame 2000-point trajectory, written to a
//!                                                 temporary folder and run once (CI)
//! ```
//!
//! A sequence folder holds `NNNN.f32` (float32 x y z per point, little-endian), `poses.txt` (one
//! row-major T_world_sensor per line, 16 numbers), `voxel.txt` (the map's voxel size, m) and,
//! for a depth camera's frames, `noise.txt` reading `quadratic-depth` (sie registers them with
//! `NoiseModel::QuadraticDepth`; the peers have no such setting). The LiDAR streets' folders
//! also hold their sweeps as `pcd/NNNN.pcd` (binary PCD, missing returns at 0 0 0 as drivers
//! write them) and `poses_kitti.txt` (KITTI format: the top 3 rows of each T_world_sensor, 12
//! numbers a line), for any other program to read the same frames.
use std::borrow::Cow;
use std::collections::HashSet;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[path = "common/slambook.rs"]
mod slambook;

use nalgebra::Matrix4;
use sie::geometry::{rotation_angle, rotation_part, transform_point, translation_part};
use sie::synthetic::lidar::{Scanner, drive};
use sie::synthetic::{DepthCamera, depth_camera_trajectory, room_trajectory};
use sie::{
    FrameStatus, Hooks, NoiseModel, Odometry, Point, PrepareOptions, PreparedTarget, RegistrationConfig,
    WarmStart, register_clouds_to,
};
use slambook::{KinectFrames, read_kinect_frames};

/// The map gets a keyframe every this many frames; its prepared target serves the frames between.
const KEYFRAME_INTERVAL: usize = 5;
/// Range noise of the synthetic scanner (m).
const RANGE_NOISE: f64 = 0.01;

pub const HEADER: &str = "library,method,sequence,points,frames,threads,mode,seconds,fps,rpe_t_rmse_mm,rpe_r_rmse_deg,rpe_t_max_mm,ate_t_rmse_mm,note";

pub struct Sequence {
    name: String,
    frames: Vec<Vec<Point>>,
    poses: Vec<Matrix4<f64>>,
    voxel: f64,
    /// How sie normalises the residuals (the peers have no such setting).
    noise: NoiseModel,
}

/// A sequence's `noise.txt` for [`NoiseModel::QuadraticDepth`] (absent: constant noise).
const QUADRATIC_DEPTH: &str = "quadratic-depth";

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("write") => {
            let dir = PathBuf::from(args.get(1).ok_or("write needs DIR")?);
            let frames = args
                .get(2)
                .map_or(Ok(100), |a| a.parse::<usize>().map_err(|e| e.to_string()))?;
            let sizes = parse_list(args.get(3).map_or("10000,50000", String::as_str))?;
            write_sequences(&dir, frames, &sizes)
        }
        Some("run") => {
            let dir = PathBuf::from(args.get(1).ok_or("run needs DIR")?);
            let threads = parse_list(args.get(2).map_or("1,2", String::as_str))?;
            println!("{HEADER}");
            for sequence in read_sequences(&dir)? {
                for &t in &threads {
                    for mode in [Mode::PreviousFrame, Mode::Map] {
                        for start in [Start::Cold, Start::Warm] {
                            println!("{}", run(&sequence, mode, t, start, Source::Whole)?.csv());
                        }
                        println!(
                            "{}",
                            run(&sequence, mode, t, Start::Cold, Source::MapVoxels)?.csv()
                        );
                    }
                    println!("{}", run_odometry(&sequence, t)?.csv());
                }
            }
            Ok(())
        }
        Some("quick") => {
            let dir = std::env::temp_dir().join(format!("sie-bench-sequences-{}", std::process::id()));
            write_synthetic(&dir, 12, 2_000)?;
            println!("{HEADER}");
            let result = (|| {
                for sequence in read_sequences(&dir)? {
                    let rows = [
                        run(&sequence, Mode::PreviousFrame, 1, Start::Cold, Source::Whole)?,
                        run(&sequence, Mode::Map, 1, Start::Warm, Source::Whole)?,
                        run(&sequence, Mode::Map, 1, Start::Cold, Source::MapVoxels)?,
                        run_odometry(&sequence, 1)?,
                    ];
                    for row in rows {
                        println!("{}", row.csv());
                        // A sanity bound, not a benchmark: odometry on clean synthetic frames.
                        if !(row.rpe_t_rmse_mm < 50.0 && row.rpe_r_rmse_deg < 1.0) {
                            return Err(format!("implausible drift: {}", row.csv()));
                        }
                    }
                }
                Ok(())
            })();
            fs::remove_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
            result
        }
        _ => Err("usage: bench_sequences write DIR [FRAMES] [N,...] | run DIR [THREADS,...] | quick".into()),
    }
}

fn parse_list(text: &str) -> Result<Vec<usize>, String> {
    text.split(',')
        .map(|v| v.trim().parse::<usize>().map_err(|e| format!("{v:?}: {e}")))
        .collect()
}

#[derive(Clone, Copy, PartialEq)]
pub enum Mode {
    /// Frame i onto frame i − 1 (prepared once, as the next frame's target).
    PreviousFrame,
    /// Frame i onto a voxel map of keyframes in the world frame.
    Map,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::PreviousFrame => "frame-to-frame",
            Mode::Map => "frame-to-map",
        }
    }
}

/// Which of a frame's points are registered.
#[derive(Clone, Copy, PartialEq)]
pub enum Source {
    /// Every point of the frame (the library's use as documented).
    Whole,
    /// One point per voxel of the map's size (the first in it, in the sensor's frame), thinned
    /// in the timed loop: what KISS-ICP does to each frame, for the speed and drift it buys.
    MapVoxels,
}

impl Source {
    fn points(self, frame: &[Point], voxel: f64) -> Cow<'_, [Point]> {
        match self {
            Source::Whole => Cow::Borrowed(frame),
            Source::MapVoxels => {
                let mut occupied = HashSet::with_capacity(frame.len());
                frame
                    .iter()
                    .filter(|p| occupied.insert(voxel_of(p, voxel)))
                    .copied()
                    .collect()
            }
        }
    }
}

/// Whether each registration starts from the previous one's noise model.
#[derive(Clone, Copy, PartialEq)]
pub enum Start {
    /// Every frame registered as a single pair (the library's defaults).
    Cold,
    /// `RegistrationConfig::warm_start` from the previous frame's result.
    Warm,
    /// The library's `Odometry` (cold, frame to the last accepted frame, bad frames set aside).
    Odometry,
}

pub struct Row {
    sequence: String,
    start: Start,
    source: Source,
    points: usize,
    frames: usize,
    threads: usize,
    mode: Mode,
    seconds: f64,
    pub rpe_t_rmse_mm: f64,
    pub rpe_r_rmse_deg: f64,
    pub rpe_t_max_mm: f64,
    pub ate_t_rmse_mm: f64,
    pub note: String,
}

impl Row {
    pub fn csv(&self) -> String {
        // Frames registered: all but the first.
        let registered = self.frames.saturating_sub(1) as f64;
        format!(
            "sie,SIE point-to-plane{}{},{},{},{},{},{},{:.4},{:.2},{:.3},{:.4},{:.3},{:.3},{}",
            match self.start {
                Start::Cold => "",
                Start::Warm => " warm start",
                Start::Odometry => " (sie::Odometry)",
            },
            match self.source {
                Source::Whole => "",
                Source::MapVoxels => " on the map's voxels",
            },
            self.sequence,
            self.points,
            self.frames,
            self.threads,
            self.mode.name(),
            self.seconds,
            registered / self.seconds,
            self.rpe_t_rmse_mm,
            self.rpe_r_rmse_deg,
            self.rpe_t_max_mm,
            self.ate_t_rmse_mm,
            self.note
        )
    }
}

/// Runs odometry over the sequence from the true first pose with a constant-velocity guess.
pub fn run(
    sequence: &Sequence,
    mode: Mode,
    threads: usize,
    start: Start,
    source: Source,
) -> Result<Row, String> {
    let mut config = RegistrationConfig {
        threads,
        noise: sequence.noise,
        ..RegistrationConfig::default()
    };
    let options = PrepareOptions::from_config(&config);
    let frames = &sequence.frames;
    let mut estimates = vec![sequence.poses[0]];
    let mut velocity = Matrix4::identity(); // last frame-to-frame motion
    let mut iterations = 0u64;
    let mut starts = 0u64;
    let mut registered_points = 0usize;
    let started = Instant::now();
    let mut map = VoxelMap::new(sequence.voxel);
    let mut target = match mode {
        Mode::PreviousFrame => PreparedTarget::new(&frames[0], None, &options),
        Mode::Map => {
            map.insert(&frames[0], &sequence.poses[0]);
            PreparedTarget::new(&map.points, None, &options)
        }
    }
    .map_err(|e| e.to_string())?;
    for i in 1..frames.len() {
        let previous = estimates[i - 1];
        let points = source.points(&frames[i], sequence.voxel);
        registered_points += points.len();
        let pose = match mode {
            Mode::PreviousFrame => {
                let result = register_clouds_to(&points, &target, Some(&velocity), &config, Hooks::default())
                    .map_err(|e| format!("frame {i}: {e}"))?;
                iterations += u64::from(result.iterations);
                starts += u64::from(result.search.starts_run);
                if start == Start::Warm {
                    config.warm_start = WarmStart::of(&result);
                }
                target = PreparedTarget::new(&frames[i], None, &options).map_err(|e| e.to_string())?;
                previous * result.transform
            }
            Mode::Map => {
                let guess = previous * velocity;
                let result = register_clouds_to(&points, &target, Some(&guess), &config, Hooks::default())
                    .map_err(|e| format!("frame {i}: {e}"))?;
                iterations += u64::from(result.iterations);
                starts += u64::from(result.search.starts_run);
                if start == Start::Warm {
                    config.warm_start = WarmStart::of(&result);
                }
                if i % KEYFRAME_INTERVAL == 0 {
                    map.insert(&frames[i], &result.transform);
                    target = PreparedTarget::new(&map.points, None, &options).map_err(|e| e.to_string())?;
                }
                result.transform
            }
        };
        velocity = sie::geometry::orthonormalised(&(previous.try_inverse().ok_or("singular pose")? * pose));
        estimates.push(pose);
    }
    let seconds = started.elapsed().as_secs_f64();
    let (rpe_t_rmse_mm, rpe_r_rmse_deg, rpe_t_max_mm) = relative_pose_errors(&sequence.poses, &estimates);
    let ate_t_rmse_mm = absolute_trajectory_error(&sequence.poses, &estimates);
    let registered = frames.len().saturating_sub(1).max(1) as u64;
    let mut note = format!(
        "{:.1} iterations/frame; {:.2} starts/frame",
        iterations as f64 / registered as f64,
        starts as f64 / registered as f64
    );
    if source == Source::MapVoxels {
        note += &format!(
            "; {} points/frame registered (one per {} m voxel)",
            registered_points / registered as usize,
            sequence.voxel
        );
    }
    if mode == Mode::Map {
        note += &format!(
            "; map {} points at {} m voxels; keyframe every {KEYFRAME_INTERVAL}",
            map.points.len(),
            sequence.voxel
        );
    }
    Ok(Row {
        sequence: sequence.name.clone(),
        start,
        source,
        points: frames.iter().map(Vec::len).sum::<usize>() / frames.len(),
        frames: frames.len(),
        threads,
        mode,
        seconds,
        rpe_t_rmse_mm,
        rpe_r_rmse_deg,
        rpe_t_max_mm,
        ate_t_rmse_mm,
        note,
    })
}

/// Frame to frame with the library's `Odometry`: a frame it sets aside (not GOOD, refused) takes
/// the constant-velocity prediction as its estimate, and the note counts such frames.
fn run_odometry(sequence: &Sequence, threads: usize) -> Result<Row, String> {
    let config = RegistrationConfig {
        threads,
        noise: sequence.noise,
        ..Odometry::sensor_config()
    };
    let mut odometry = Odometry::new(config).map_err(|e| e.to_string())?;
    let frames = &sequence.frames;
    let (mut iterations, mut starts, mut set_aside, mut loose) = (0u64, 0u64, Vec::new(), 0usize);
    let world = sequence.poses[0];
    let mut estimates = Vec::with_capacity(frames.len());
    let started = Instant::now();
    for (i, frame) in frames.iter().enumerate() {
        let outcome = odometry.register_frame(frame, Hooks::default());
        if let Some(result) = &outcome.result {
            iterations += u64::from(result.iterations);
            starts += u64::from(result.search.starts_run);
        }
        match outcome.status {
            FrameStatus::First | FrameStatus::Accepted => {}
            FrameStatus::Loose => loose += 1,
            status => set_aside.push(format!("{i} {status:?}")),
        }
        let pose = outcome
            .pose
            .or(outcome.predicted_pose)
            .unwrap_or_else(|| odometry.pose());
        estimates.push(world * pose);
    }
    let seconds = started.elapsed().as_secs_f64();
    let (rpe_t_rmse_mm, rpe_r_rmse_deg, rpe_t_max_mm) = relative_pose_errors(&sequence.poses, &estimates);
    let ate_t_rmse_mm = absolute_trajectory_error(&sequence.poses, &estimates);
    let registered = frames.len().saturating_sub(1).max(1) as u64;
    let mut note = format!(
        "{:.1} iterations/frame; {:.2} starts/frame; {loose} frames loose; {} frames set aside",
        iterations as f64 / registered as f64,
        starts as f64 / registered as f64,
        set_aside.len()
    );
    if !set_aside.is_empty() {
        note += &format!(" ({})", set_aside.join(" "));
    }
    Ok(Row {
        sequence: sequence.name.clone(),
        start: Start::Odometry,
        source: Source::Whole,
        points: frames.iter().map(Vec::len).sum::<usize>() / frames.len(),
        frames: frames.len(),
        threads,
        mode: Mode::PreviousFrame,
        seconds,
        rpe_t_rmse_mm,
        rpe_r_rmse_deg,
        rpe_t_max_mm,
        ate_t_rmse_mm,
        note,
    })
}

/// RMS and max of each frame's relative pose error: E_i = (G_{i−1}⁻¹ G_i)⁻¹ (P_{i−1}⁻¹ P_i),
/// translation in mm, rotation in degrees (as the paper's TUM table, per frame).
fn relative_pose_errors(truth: &[Matrix4<f64>], estimate: &[Matrix4<f64>]) -> (f64, f64, f64) {
    let (mut t2, mut r2, mut t_max, mut n) = (0.0, 0.0, 0.0f64, 0.0);
    for i in 1..truth.len() {
        let true_motion = truth[i - 1].try_inverse().expect("rigid") * truth[i];
        let estimated_motion = estimate[i - 1].try_inverse().expect("rigid") * estimate[i];
        let error = true_motion.try_inverse().expect("rigid") * estimated_motion;
        let t = translation_part(&error).norm() * 1e3;
        let r = rotation_angle(&rotation_part(&error)).to_degrees();
        t2 += t * t;
        r2 += r * r;
        t_max = t_max.max(t);
        n += 1.0;
    }
    ((t2 / n).sqrt(), (r2 / n).sqrt(), t_max)
}

/// RMS distance (mm) of each estimated position from the true one. Every trajectory starts at
/// the true first pose, so no alignment is fitted: the error is the drift accumulated so far.
fn absolute_trajectory_error(truth: &[Matrix4<f64>], estimate: &[Matrix4<f64>]) -> f64 {
    let squared: f64 = truth
        .iter()
        .zip(estimate)
        .map(|(t, e)| ((translation_part(e) - translation_part(t)).norm() * 1e3).powi(2))
        .sum();
    (squared / truth.len().max(1) as f64).sqrt()
}

/// The voxel of size `voxel` holding `p` (integer cell coordinates).
fn voxel_of(p: &Point, voxel: f64) -> [i64; 3] {
    p.map(|c| (c / voxel).floor() as i64)
}

/// Keyframe points in the world frame, one per voxel (the first that fell into it).
struct VoxelMap {
    voxel: f64,
    occupied: HashSet<[i64; 3]>,
    points: Vec<Point>,
}

impl VoxelMap {
    fn new(voxel: f64) -> Self {
        VoxelMap {
            voxel,
            occupied: HashSet::new(),
            points: Vec::new(),
        }
    }

    fn insert(&mut self, frame: &[Point], pose: &Matrix4<f64>) {
        for p in frame {
            let w = transform_point(pose, p);
            if self.occupied.insert(voxel_of(&w, self.voxel)) {
                self.points.push(w);
            }
        }
    }
}

// ---- sequences on disk -------------------------------------------------------------------

fn write_sequences(dir: &Path, frames: usize, sizes: &[usize]) -> Result<(), String> {
    for &n in sizes {
        eprintln!("room trajectory: {frames} frames of {n} points");
        write_synthetic(dir, frames, n)?;
    }
    eprintln!("depth camera on the room's loop: {frames} frames");
    write_depth_camera(dir, frames)?;
    eprintln!("LiDAR street: {frames} sweeps of a 64-beam sensor, still and skewed by the motion");
    write_lidar_street(dir, frames, Sweep::Still)?;
    write_lidar_street(dir, frames, Sweep::Skewed)?;
    let data = std::env::var_os("SIE_DATA_DIR").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
        PathBuf::from,
    );
    let kinect = data.join("slambook-joinmap-rgbd");
    if kinect.is_dir() {
        eprintln!("Kinect frames from {}", kinect.display());
        write_sequence(dir, &kinect_sequence(&kinect)?)?;
    } else {
        eprintln!("skipped: {} not found (set SIE_DATA_DIR)", kinect.display());
    }
    let lidar = data.join("small_gicp-data");
    if lidar.is_dir() {
        eprintln!("LiDAR pair from {}", lidar.display());
        let target = sie::io::read_cloud(&lidar.join("target.ply"))?.points;
        let source = sie::io::read_cloud(&lidar.join("source.ply"))?.points;
        let t_target_source = sie::io::read_transform(&lidar.join("T_target_source.txt"))?;
        write_sequence(
            dir,
            &Sequence {
                name: "lidar-pair".into(),
                frames: vec![target, source],
                poses: vec![Matrix4::identity(), t_target_source],
                voxel: 0.25,
                noise: NoiseModel::Constant,
            },
        )?;
    }
    Ok(())
}

fn write_synthetic(dir: &Path, frames: usize, points: usize) -> Result<(), String> {
    let trajectory = room_trajectory(frames, points, RANGE_NOISE, 7);
    write_sequence(
        dir,
        &Sequence {
            name: format!("room-{points}"),
            frames: trajectory.frames,
            poses: trajectory.poses,
            voxel: 0.05,
            noise: NoiseModel::Constant,
        },
    )
}

/// Seed of the depth camera's noise.
const DEPTH_CAMERA_SEED: u64 = 7;

fn write_depth_camera(dir: &Path, frames: usize) -> Result<(), String> {
    let trajectory = depth_camera_trajectory(frames, &DepthCamera::kinect_like(), DEPTH_CAMERA_SEED);
    write_sequence(
        dir,
        &Sequence {
            name: "rgbd-room".into(),
            frames: trajectory.frames,
            poses: trajectory.poses,
            voxel: 0.02,
            noise: NoiseModel::QuadraticDepth,
        },
    )
}

/// How the LiDAR sweeps are taken.
#[derive(Clone, Copy, PartialEq)]
enum Sweep {
    /// Each from one pose (as de-skewed by a driver).
    Still,
    /// Each column from where the sensor is when it fires (motion distortion, not de-skewed).
    Skewed,
}

/// Seed of the simulated street and its range noise.
const STREET_SEED: u64 = 29;

fn write_lidar_street(dir: &Path, frames: usize, sweep: Sweep) -> Result<(), String> {
    let drive = drive(
        &Scanner::sixty_four_beams(),
        frames,
        STREET_SEED,
        sweep == Sweep::Skewed,
    );
    let sequence = Sequence {
        name: match sweep {
            Sweep::Still => "lidar-street",
            Sweep::Skewed => "lidar-street-skewed",
        }
        .into(),
        frames: drive.frames,
        poses: drive.poses.iter().map(|p| p.to_homogeneous()).collect(),
        voxel: 0.25,
        noise: NoiseModel::Constant,
    };
    write_sequence(dir, &sequence)?;
    let folder = dir.join(&sequence.name);
    let pcd = folder.join("pcd");
    fs::create_dir_all(&pcd).map_err(|e| format!("{}: {e}", pcd.display()))?;
    for (i, frame) in sequence.frames.iter().enumerate() {
        sie::io::write_cloud_pcd(
            &pcd.join(format!("{i:04}.pcd")),
            frame,
            None,
            sie::io::PcdEncoding::Binary,
        )?;
    }
    let kitti: String = sequence
        .poses
        .iter()
        .map(|t| {
            let rows: Vec<String> = (0..12).map(|k| format!("{:.9e}", t[(k / 4, k % 4)])).collect();
            rows.join(" ") + "\n"
        })
        .collect();
    let path = folder.join("poses_kitti.txt");
    fs::write(&path, kitti).map_err(|e| format!("{}: {e}", path.display()))
}

fn write_sequence(dir: &Path, sequence: &Sequence) -> Result<(), String> {
    let folder = dir.join(&sequence.name);
    fs::create_dir_all(&folder).map_err(|e| format!("{}: {e}", folder.display()))?;
    for (i, frame) in sequence.frames.iter().enumerate() {
        let bytes: Vec<u8> = frame
            .iter()
            .flat_map(|p| p.iter().flat_map(|&c| (c as f32).to_le_bytes()))
            .collect();
        let path = folder.join(format!("{i:04}.f32"));
        fs::write(&path, bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    let poses: String = sequence
        .poses
        .iter()
        .map(|t| {
            let row_major: Vec<String> = (0..16).map(|k| format!("{:.17e}", t[(k / 4, k % 4)])).collect();
            row_major.join(" ") + "\n"
        })
        .collect();
    let write = |name: &str, text: String| {
        fs::write(folder.join(name), text).map_err(|e| format!("{}/{name}: {e}", folder.display()))
    };
    write("poses.txt", poses)?;
    if sequence.noise == NoiseModel::QuadraticDepth {
        write("noise.txt", format!("{QUADRATIC_DEPTH}\n"))?;
    }
    write("voxel.txt", format!("{}\n", sequence.voxel))
}

fn read_sequences(dir: &Path) -> Result<Vec<Sequence>, String> {
    let mut folders: Vec<PathBuf> = fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|path| path.join("poses.txt").is_file())
        .collect();
    folders.sort();
    folders.iter().map(|folder| read_sequence(folder)).collect()
}

fn read_sequence(folder: &Path) -> Result<Sequence, String> {
    let read = |name: &str| {
        fs::read_to_string(folder.join(name)).map_err(|e| format!("{}/{name}: {e}", folder.display()))
    };
    let numbers = |line: &str| -> Result<Vec<f64>, String> {
        line.split_whitespace()
            .map(|v| v.parse::<f64>().map_err(|e| format!("{v:?}: {e}")))
            .collect()
    };
    let mut poses = Vec::new();
    for line in read("poses.txt")?.lines().filter(|l| !l.trim().is_empty()) {
        let values = numbers(line)?;
        if values.len() != 16 {
            return Err(format!("{}: a pose needs 16 numbers", folder.display()));
        }
        poses.push(Matrix4::from_row_slice(&values));
    }
    let voxel = numbers(&read("voxel.txt")?)?
        .first()
        .copied()
        .ok_or("voxel.txt is empty")?;
    let noise = match fs::read_to_string(folder.join("noise.txt")) {
        Err(_) => NoiseModel::Constant,
        Ok(text) if text.trim() == QUADRATIC_DEPTH => NoiseModel::QuadraticDepth,
        Ok(text) => {
            return Err(format!(
                "{}/noise.txt: unknown noise model {:?}",
                folder.display(),
                text.trim()
            ));
        }
    };
    let mut frames = Vec::with_capacity(poses.len());
    for i in 0..poses.len() {
        let path = folder.join(format!("{i:04}.f32"));
        let bytes = fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        let frame: Vec<Point> = bytes
            .chunks_exact(12)
            .map(|p| {
                std::array::from_fn(|d| {
                    f64::from(f32::from_le_bytes(p[4 * d..4 * d + 4].try_into().unwrap()))
                })
            })
            .collect();
        frames.push(frame);
    }
    let name = folder
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    Ok(Sequence {
        name,
        frames,
        poses,
        voxel,
        noise,
    })
}

/// The slambook Kinect frames 2..5 with their poses
/// (examples/common/slambook.rs).
pub fn kinect_sequence(folder: &Path) -> Result<Sequence, String> {
    let KinectFrames {
        mut frames,
        mut poses,
    } = read_kinect_frames(folder)?;
    // Frame 1 -> 2 is a large motion with little overlap (the data README: median NN distance
    // 21 cm at the true poses) on which every library fails; drift is measured on 2..5.
    let (frames, poses) = (frames.split_off(1), poses.split_off(1));
    Ok(Sequence {
        name: "kinect-slambook-2to5".into(),
        frames,
        poses,
        voxel: 0.02,
        noise: NoiseModel::Constant,
    })
}
