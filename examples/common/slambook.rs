//! The slambook Kinect frames (`slambook-joinmap-rgbd`, five 640×480 depth images and their
//! camera poses), back-projected with the data README's intrinsics. One reader for the programs
//! that use them (`experiments`' scan table, `bench_sequences`, `bench_global`).
use std::fs;
use std::path::Path;

use nalgebra::{Matrix4, Quaternion, Translation3, UnitQuaternion};
use sie::Point;

/// Intrinsics and depth scale from the data README (joinMap.cpp).
const FX: f64 = 518.0;
const FY: f64 = 519.0;
const CX: f64 = 325.5;
const CY: f64 = 253.5;
const DEPTH_SCALE: f64 = 1000.0;
/// Every 4th pixel in both directions: about 13 000 points a frame, what every program reads.
const STRIDE: usize = 4;

/// The frames in file order (`depth/1.pgm` first) and their camera poses.
pub struct KinectFrames {
    /// Every [`STRIDE`]-th pixel with a depth, in the camera frame (metres).
    pub frames: Vec<Vec<Point>>,
    /// T_world_camera of each frame (`pose.txt`: `p_world = R(q)·p_cam + t`).
    pub poses: Vec<Matrix4<f64>>,
}

/// Reads `pose.txt` and one `depth/N.pgm` per pose, keeping every [`STRIDE`]-th pixel in both
/// directions (0 = no depth, left out).
pub fn read_kinect_frames(folder: &Path) -> Result<KinectFrames, String> {
    let text = fs::read_to_string(folder.join("pose.txt")).map_err(|e| format!("pose.txt: {e}"))?;
    let mut poses = Vec::new();
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|f| f.parse::<f64>().map_err(|e| format!("pose.txt: {line}: {e}")))
            .collect::<Result<_, _>>()?;
        if v.len() != 7 {
            return Err(format!("pose.txt: expected tx ty tz qx qy qz qw, got {line}"));
        }
        let q = UnitQuaternion::from_quaternion(Quaternion::new(v[6], v[3], v[4], v[5]));
        poses.push((Translation3::new(v[0], v[1], v[2]) * q).to_homogeneous());
    }
    let frames = (1..=poses.len())
        .map(|i| {
            let path = folder.join("depth").join(format!("{i}.pgm"));
            let bytes = fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
            let image = parse_pgm16(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
            Ok(back_project(&image))
        })
        .collect::<Result<_, String>>()?;
    Ok(KinectFrames { frames, poses })
}

fn back_project(image: &Gray16) -> Vec<Point> {
    let mut points = Vec::new();
    for v in (0..image.height).step_by(STRIDE) {
        for u in (0..image.width).step_by(STRIDE) {
            let d = image.pixels[v * image.width + u];
            if d != 0 {
                let z = f64::from(d) / DEPTH_SCALE;
                points.push([(u as f64 - CX) * z / FX, (v as f64 - CY) * z / FY, z]);
            }
        }
    }
    points
}

/// A 16-bit grey image.
struct Gray16 {
    width: usize,
    height: usize,
    pixels: Vec<u16>,
}

/// Binary PGM (P5) with maxval > 255: two big-endian bytes per pixel (Netpbm spec). A header
/// of four whitespace-separated tokens (comments from `#` to the end of a line), then one
/// whitespace byte, then the raster. Written here rather than pulling in an image crate for
/// 25 lines; 8-bit PGM is not needed by any data set.
fn parse_pgm16(bytes: &[u8]) -> Result<Gray16, String> {
    let mut pos = 0;
    let mut tokens = Vec::new();
    while tokens.len() < 4 {
        while pos < bytes.len() && (bytes[pos].is_ascii_whitespace() || bytes[pos] == b'#') {
            if bytes[pos] == b'#' {
                while pos < bytes.len() && bytes[pos] != b'\n' {
                    pos += 1;
                }
            } else {
                pos += 1;
            }
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if start == pos {
            return Err("truncated PGM header".into());
        }
        tokens.push(String::from_utf8_lossy(&bytes[start..pos]).into_owned());
    }
    if tokens[0] != "P5" {
        return Err(format!("not a binary PGM (magic {:?})", tokens[0]));
    }
    let number = |t: &str| {
        t.parse::<usize>()
            .map_err(|_| format!("bad PGM header value {t:?}"))
    };
    let (width, height, maxval) = (number(&tokens[1])?, number(&tokens[2])?, number(&tokens[3])?);
    if !(256..=65535).contains(&maxval) {
        return Err(format!(
            "expected a 16-bit PGM (maxval 256..65535), got maxval {maxval}"
        ));
    }
    pos += 1; // the single whitespace byte after maxval
    let needed = width * height * 2;
    let raster = bytes.get(pos..pos + needed).ok_or_else(|| {
        format!(
            "raster has {} bytes, {width}×{height} needs {needed}",
            bytes.len().saturating_sub(pos)
        )
    })?;
    let pixels = raster
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    Ok(Gray16 {
        width,
        height,
        pixels,
    })
}
