//! Benchmark: two real Kinect depth frames (slambook-joinmap-rgbd, 640×480) whose invalid
//! pixels are 0 0 0 — 31–43 % of each frame, exact duplicates of one another — registered with
//! the invalid pixels kept and dropped (`skip_origin`), and n identical points alone. Prints
//! the time, the iterations and the error against the frames' poses (which are good to about a
//! centimetre, see the data README).
//!
//! ```text
//! cargo run --release --example depth_frames [-- --write DIR]
//! ```
//! `--write DIR` also writes the two frames (all pixels) as binary PCD files, to time the same
//! pair with an older `sie register` build.
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Matrix4, Quaternion, Translation3, UnitQuaternion};
use sie::geometry::{rotation_angle, rotation_part, translation_part};
use sie::{Hooks, Point, RegistrationConfig, register_clouds};

// Intrinsics from the data README.
const CX: f64 = 325.5;
const CY: f64 = 253.5;
const FX: f64 = 518.0;
const FY: f64 = 519.0;
const DEPTH_SCALE: f64 = 1000.0;

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let write_dir = args
        .iter()
        .position(|a| a == "--write")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from);
    let data = std::env::var_os("SIE_DATA_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"))
        .join("slambook-joinmap-rgbd");
    let poses = read_poses(&data.join("pose.txt"))?;
    println!(
        "| pair | invalid pixels | kept as | points (source + target) | seconds | iterations | rotation error (°) | translation error (mm) |"
    );
    println!("|---|---:|---|---:|---:|---:|---:|---:|");
    for (source_frame, target_frame) in [(3, 2), (4, 3), (5, 4)] {
        let source = back_project(&data.join(format!("depth/{source_frame}.pgm")))?;
        let target = back_project(&data.join(format!("depth/{target_frame}.pgm")))?;
        if let Some(dir) = &write_dir {
            fs::create_dir_all(dir).map_err(|e| e.to_string())?;
            for (frame, cloud) in [(source_frame, &source), (target_frame, &target)] {
                write_pcd(&dir.join(format!("frame{frame}.pcd")), cloud)?;
            }
        }
        let invalid = |cloud: &[Point]| cloud.iter().filter(|p| **p == [0.0; 3]).count();
        let truth = poses[target_frame - 1].try_inverse().ok_or("pose")? * poses[source_frame - 1];
        for skip_origin in [false, true] {
            let config = RegistrationConfig {
                skip_origin,
                ..RegistrationConfig::default()
            };
            let started = Instant::now();
            let result = register_clouds(&source, &target, None, None, &config, Hooks::default())
                .map_err(|e| e.to_string())?;
            let seconds = started.elapsed().as_secs_f64();
            if std::env::var_os("SIE_STAGES").is_some() {
                eprintln!("{:?}", result.times);
            }
            let difference = truth.try_inverse().ok_or("truth")? * result.transform;
            println!(
                "| {source_frame} → {target_frame} | {:.0} % + {:.0} % | {} | {} + {} | {seconds:.2} | {} | {:.2} | {:.1} |",
                100.0 * invalid(&source) as f64 / source.len() as f64,
                100.0 * invalid(&target) as f64 / target.len() as f64,
                if skip_origin {
                    "dropped (skip_origin)"
                } else {
                    "0 0 0 (duplicates)"
                },
                source.len(),
                target.len(),
                result.iterations,
                rotation_angle(&rotation_part(&difference)).to_degrees(),
                translation_part(&difference).norm() * 1e3,
            );
        }
    }
    println!();
    println!("| identical points per cloud | seconds (point-to-point, 1 thread) |");
    println!("|---:|---:|");
    for n in [20_000, 40_000, 80_000] {
        let same = vec![[0.5, -1.0, 2.0]; n];
        let config = RegistrationConfig {
            metric: sie::Metric::PointToPoint,
            threads: 1,
            ..RegistrationConfig::default()
        };
        let started = Instant::now();
        register_clouds(&same, &same, None, None, &config, Hooks::default()).map_err(|e| e.to_string())?;
        println!("| {n} | {:.3} |", started.elapsed().as_secs_f64());
    }
    Ok(())
}

/// All 640×480 pixels as points in the camera frame (metres); depth 0 (invalid) gives 0 0 0.
fn back_project(path: &Path) -> Result<Vec<Point>, String> {
    let bytes = fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    // P5 header: magic, width, height, maxval, then one whitespace byte.
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        while bytes.get(at).is_some_and(|b| b.is_ascii_whitespace()) {
            at += 1;
        }
        if bytes.get(at) == Some(&b'#') {
            while bytes.get(at).is_some_and(|&b| b != b'\n') {
                at += 1;
            }
            continue;
        }
        let start = at;
        while bytes.get(at).is_some_and(|b| !b.is_ascii_whitespace()) {
            at += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..at]).into_owned());
    }
    let parse = |s: &str| s.parse::<usize>().map_err(|e| format!("{}: {e}", path.display()));
    let (width, height) = (parse(&fields[1])?, parse(&fields[2])?);
    if fields[0] != "P5" || parse(&fields[3])? != 65535 {
        return Err(format!("{}: not a 16-bit binary PGM", path.display()));
    }
    let pixels = bytes.get(at + 1..).ok_or("no pixels")?;
    if pixels.len() < 2 * width * height {
        return Err(format!("{}: truncated", path.display()));
    }
    Ok((0..width * height)
        .map(|i| {
            let depth = f64::from(u16::from_be_bytes([pixels[2 * i], pixels[2 * i + 1]])) / DEPTH_SCALE;
            let (u, v) = ((i % width) as f64, (i / width) as f64);
            [(u - CX) * depth / FX, (v - CY) * depth / FY, depth]
        })
        .collect())
}

/// `tx ty tz qx qy qz qw` per line: T_world_camera.
fn read_poses(path: &Path) -> Result<Vec<Matrix4<f64>>, String> {
    let text = fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|line| {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|t| t.parse().map_err(|e| format!("{line}: {e}")))
                .collect::<Result<_, _>>()?;
            let rotation = UnitQuaternion::from_quaternion(Quaternion::new(v[6], v[3], v[4], v[5]));
            Ok(Translation3::new(v[0], v[1], v[2]).to_homogeneous() * rotation.to_homogeneous())
        })
        .collect()
}

fn write_pcd(path: &Path, points: &[Point]) -> Result<(), String> {
    let mut bytes = format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n",
        n = points.len()
    )
    .into_bytes();
    for p in points {
        for c in p {
            bytes.extend((*c as f32).to_le_bytes());
        }
    }
    fs::File::create(path)
        .and_then(|mut f| f.write_all(&bytes))
        .map_err(|e| format!("{}: {e}", path.display()))
}
