//! The `sie` binary end to end: real scan pairs with ground truth, every output, bad input.
#![cfg(feature = "cli")]
mod common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{data_dir, pose_error};
use nalgebra::{Matrix4, Rotation3, Vector3};
use serde_json::Value;
use sie::geometry::{make_rigid, transform_point};
use sie::io::{read_cloud, read_transform};

/// bun0 → bun4 from the Stanford bun.conf poses, as listed in pcl-test-bunny/README.md
/// (p_bun4 = T · p_bun0, the direction sie reports).
const BUNNY_TRUTH: &str = "\
 0.826351  0.004137 -0.563141  0.036838
-0.0106    0.99991  -0.00821  -0.000257
 0.563056  0.012754  0.82632   0.038321
";

fn sie(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sie"))
        .args(args)
        .output()
        .expect("run the sie binary")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A fresh scratch folder per test, removed when the test ends.
struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

fn scratch(test: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("sie-cli-{}-{test}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

fn arg(path: &Path) -> &str {
    path.to_str().expect("UTF-8 temp path")
}

fn json(output: &Output) -> Value {
    serde_json::from_slice(&output.stdout).unwrap_or_else(|e| {
        panic!(
            "stdout is not JSON ({e}): {}\nstderr: {}",
            text(&output.stdout),
            text(&output.stderr)
        )
    })
}

fn json_transform(report: &Value) -> Matrix4<f64> {
    let rows = report["transform"].as_array().expect("transform rows");
    assert_eq!(rows.len(), 4);
    Matrix4::from_fn(|r, c| rows[r][c].as_f64().expect("number"))
}

/// The 16 numbers of the plain-text transform (stdout or `-o`).
fn text_transform(text: &str) -> Matrix4<f64> {
    let values: Vec<f64> = text
        .split_whitespace()
        .map(|v| v.parse().expect("number"))
        .collect();
    assert_eq!(values.len(), 16, "{text}");
    Matrix4::from_row_slice(&values)
}

struct Bunny {
    source: PathBuf,
    target: PathBuf,
    truth: PathBuf,
}

fn bunny(dir: &Path) -> Option<Bunny> {
    let data = data_dir()?.join("pcl-test-bunny");
    let truth = dir.join("bunny_truth.txt");
    fs::write(&truth, BUNNY_TRUTH).unwrap();
    Some(Bunny {
        source: data.join("bun0.pcd"),
        target: data.join("bun4.pcd"),
        truth,
    })
}

#[test]
fn bunny_point_to_plane_from_identity_meets_the_tolerance() {
    let dir = scratch("bunny");
    let Some(b) = bunny(&dir) else { return };
    let written = dir.join("T.txt");
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--metric",
        "point-to-plane",
        "--ground-truth",
        arg(&b.truth),
        "--json",
        "-o",
        arg(&written),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let report = json(&output);
    let error = &report["ground_truth"];
    let (rotation, translation) = (
        error["rotation_error_deg"].as_f64().unwrap(),
        error["translation_error"].as_f64().unwrap(),
    );
    println!("bunny: {rotation:.3} deg, {:.2} mm", translation * 1e3);
    assert!(
        rotation < 1.0 && translation < 0.005,
        "{rotation} deg, {translation} m"
    );
    assert_eq!(report["stop_reason"], "converged");
    assert_eq!(report["converged"], true);
    assert_eq!(report["source"]["points"], 397);
    assert_eq!(report["target"]["points"], 361);
    for key in ["sigma", "beta"] {
        assert!(report[key][0].as_f64().unwrap() > 0.0, "{key}");
    }
    for key in [
        "iterations",
        "penalty",
        "noise_shape",
        "inlier_fraction",
        "rmse",
        "seconds",
    ] {
        assert!(report[key].as_f64().unwrap() > 0.0, "{key}");
    }
    // The JSON error is the error of the JSON transform, and `-o` holds that transform.
    let transform = json_transform(&report);
    // The ground truth is made exactly rigid before it is compared with.
    let truth = make_rigid(&read_transform(&b.truth).unwrap(), "truth")
        .unwrap()
        .transform;
    let (rotation_again, translation_again) = pose_error(&transform, &truth);
    assert!((rotation_again - rotation).abs() < 1e-9 && (translation_again - translation).abs() < 1e-12);
    let from_file = text_transform(&fs::read_to_string(&written).unwrap());
    assert!((from_file - transform).abs().max() < 1e-8);
}

#[test]
fn lidar_pair_from_identity_meets_the_tolerance() {
    let Some(data) = data_dir() else { return };
    let folder = data.join("small_gicp-data");
    let output = sie(&[
        "register",
        arg(&folder.join("source.ply")),
        arg(&folder.join("target.ply")),
        "--ground-truth",
        arg(&folder.join("T_target_source.txt")),
        "--json",
        "-q",
    ]);
    let report = json(&output);
    let rotation = report["ground_truth"]["rotation_error_deg"].as_f64().unwrap();
    let translation = report["ground_truth"]["translation_error"].as_f64().unwrap();
    println!(
        "LiDAR: {rotation:.3} deg, {:.1} mm, {} after {} iterations, {:.2} s",
        translation * 1e3,
        report["stop_reason"],
        report["iterations"],
        report["seconds"].as_f64().unwrap()
    );
    assert!(
        rotation < 0.5 && translation < 0.05,
        "{rotation} deg, {translation} m"
    );
    // Converged (0; 3 when the verdict is not good) or stopped at the iteration limit (1);
    // never degenerate or an error.
    let code = output.status.code();
    assert!(
        matches!(code, Some(0 | 1 | 3)),
        "{code:?}: {}",
        text(&output.stderr)
    );
    assert_ne!(report["stop_reason"], "degenerate");
    assert_eq!(
        code == Some(3),
        report["converged"] == true && report["quality"]["verdict"] != "good",
        "{}",
        report["quality"]
    );
    assert_eq!(report["source"]["points"], 69792);
    assert!(output.stderr.is_empty(), "-q: {}", text(&output.stderr));
}

#[test]
fn text_mode_prints_the_transform_on_stdout_and_a_summary_on_stderr() {
    let dir = scratch("text");
    let Some(b) = bunny(&dir) else { return };
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--ground-truth",
        arg(&b.truth),
    ]);
    assert_eq!(output.status.code(), Some(0));
    let transform = text_transform(&text(&output.stdout));
    assert_eq!(transform.row(3), Matrix4::<f64>::identity().row(3));
    let (rotation, _) = pose_error(&transform, &read_transform(&b.truth).unwrap());
    assert!(rotation < 1.0);
    let summary = text(&output.stderr);
    for expected in [
        "397 points",
        "361 points",
        "converged after",
        "sigma",
        "inlier fraction",
        "RMSE",
        "verdict  good",
        "rotation error",
    ] {
        assert!(summary.contains(expected), "{expected:?} missing from\n{summary}");
    }
    assert!(summary.lines().count() <= 12, "{summary}");
}

#[test]
fn trace_prints_one_row_per_iteration() {
    let dir = scratch("trace");
    let Some(b) = bunny(&dir) else { return };
    let output = sie(&["register", arg(&b.source), arg(&b.target), "--trace", "-q"]);
    assert_eq!(output.status.code(), Some(0));
    let stderr = text(&output.stderr);
    let mut lines = stderr.lines();
    let header = lines.next().unwrap();
    for column in ["sigma", "beta", "k", "inliers"] {
        assert!(header.split_whitespace().any(|c| c == column), "{header}");
    }
    let rows: Vec<&str> = lines.collect();
    assert!(rows.len() > 5);
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(
            row.split_whitespace().next(),
            Some((i + 1).to_string().as_str()),
            "{row}"
        );
    }
    // The same run in JSON carries the same number of trace rows.
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--trace",
        "--json",
        "-q",
    ]);
    let report = json(&output);
    let trace = report["trace"].as_array().unwrap();
    assert_eq!(trace.len(), rows.len());
    assert_eq!(report["iterations"].as_u64().unwrap() as usize, rows.len());
    // Each row carries the transform the update reached. With the automatic starts the rows are
    // every start's updates in order; the result is the last update of the start that won.
    assert!(
        trace.iter().any(|row| row["transform"] == report["transform"]),
        "the result is none of the {} updates",
        trace.len()
    );
    // From the initial guess alone the last row is the result.
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--starts",
        "initial-guess",
        "--trace",
        "--json",
        "-q",
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let report = json(&output);
    assert_eq!(report["search"]["starts_run"], 1);
    let trace = report["trace"].as_array().unwrap();
    assert_eq!(report["iterations"].as_u64().unwrap() as usize, trace.len());
    let last = trace.last().unwrap();
    assert_eq!(last["transform"], report["transform"]);
    // One meaning of "inlier fraction": the converged run's last update and the summary agree.
    let (progress, summary) = (
        last["inlier_fraction"].as_f64().unwrap(),
        report["inlier_fraction"].as_f64().unwrap(),
    );
    assert!((progress - summary).abs() < 0.01, "{progress} vs {summary}");
}

/// Width and height from a PNG's IHDR chunk.
fn png_size(bytes: &[u8]) -> (u32, u32) {
    assert!(bytes.len() > 24 && bytes.starts_with(b"\x89PNG\r\n\x1a\n") && &bytes[12..16] == b"IHDR");
    let number = |at: usize| u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap());
    (number(16), number(20))
}

#[test]
fn plot_writes_a_png_and_an_svg() {
    let dir = scratch("plot");
    let Some(b) = bunny(&dir) else { return };
    let png = dir.join("fig.png");
    let svg = dir.join("fig.svg");
    for path in [&png, &svg] {
        let output = sie(&[
            "register",
            arg(&b.source),
            arg(&b.target),
            "--plot",
            arg(path),
            "-q",
        ]);
        assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    }
    let bytes = fs::read(&png).unwrap();
    assert_eq!(png_size(&bytes), (1000, 610));
    // Bars, curves, legend and labels: far more than a blank image compresses to (~5 kB).
    assert!(bytes.len() > 20_000, "{} bytes", bytes.len());
    let svg = fs::read_to_string(&svg).unwrap();
    assert!(svg.starts_with("<svg"));
    for label in [
        "residuals per bin",
        "P(inlier | r)",
        "fitted inlier model G",
        "point-to-plane residual",
    ] {
        assert!(svg.contains(label), "{label:?} missing from the SVG");
    }
}

#[test]
fn aligned_cloud_is_the_source_moved_by_the_result() {
    let dir = scratch("aligned");
    let Some(b) = bunny(&dir) else { return };
    let aligned = dir.join("aligned.xyz");
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--aligned",
        arg(&aligned),
        "-q",
    ]);
    assert_eq!(output.status.code(), Some(0));
    let transform = text_transform(&text(&output.stdout));
    let source = read_cloud(&b.source).unwrap().points;
    let moved = read_cloud(&aligned).unwrap().points;
    assert_eq!(moved.len(), source.len());
    for (p, q) in source.iter().zip(&moved) {
        let expected = transform_point(&transform, p);
        // stdout has 9 decimals; the file was written from the full-precision transform.
        assert!(
            (0..3).all(|k| (expected[k] - q[k]).abs() < 1e-8),
            "{expected:?} {q:?}"
        );
    }

    // .pcd: float32 x y z, as PCL writes and reads them (pcl::PointXYZ matches only float
    // fields); binary unless --aligned-ascii. CI also loads it with PCL (examples-cpp).
    for (extra, data_line) in [(None, "DATA binary"), (Some("--aligned-ascii"), "DATA ascii")] {
        let pcd = dir.join("aligned.pcd");
        let mut args = vec![
            "register",
            arg(&b.source),
            arg(&b.target),
            "--aligned",
            arg(&pcd),
            "-q",
        ];
        args.extend(extra);
        let output = sie(&args);
        assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
        let bytes = fs::read(&pcd).unwrap();
        let header = text(&bytes[..bytes.len().min(300)]);
        // bun0.pcd has normals: they are written too, rotated.
        for line in ["FIELDS x y z normal_x", "SIZE 4 4 4 4", "TYPE F F F F", data_line] {
            assert!(header.contains(line), "{line:?} missing: {header}");
        }
        let moved = read_cloud(&pcd).unwrap().points;
        assert_eq!(moved.len(), source.len());
        for (p, q) in source.iter().zip(&moved) {
            let expected = transform_point(&transform, p).map(|v| f64::from(v as f32));
            assert!(
                (0..3).all(|k| (expected[k] - q[k]).abs() < 1e-7),
                "{expected:?} {q:?}"
            );
        }
    }
}

#[test]
fn init_pose_is_rz_ry_rx_like_the_same_matrix_from_a_file() {
    let dir = scratch("init");
    let Some(b) = bunny(&dir) else { return };
    let (tx, ty, tz, roll, pitch, yaw) = (0.03, -0.002, 0.04, 0.01, -0.55, 0.02);
    let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), roll);
    let mut init = rotation.to_homogeneous();
    init.fixed_view_mut::<3, 1>(0, 3)
        .copy_from(&Vector3::new(tx, ty, tz));
    let init_file = dir.join("init.txt");
    let rows: Vec<String> = (0..4)
        .map(|r| {
            (0..4)
                .map(|c| format!("{:e}", init[(r, c)]))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect();
    fs::write(&init_file, rows.join("\n")).unwrap();

    let pose = [tx, ty, tz, roll, pitch, yaw].map(|v| v.to_string());
    let mut with_pose = vec![
        "register",
        arg(&b.source),
        arg(&b.target),
        "--json",
        "-q",
        "--init-pose",
    ];
    with_pose.extend(pose.iter().map(String::as_str));
    let from_pose = json(&sie(&with_pose));
    let from_file = json(&sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--json",
        "-q",
        "--init",
        arg(&init_file),
    ]));
    let difference = (json_transform(&from_pose) - json_transform(&from_file))
        .abs()
        .max();
    assert!(difference < 1e-9, "{difference}");
    // Started 2° from the truth, it ends within the tolerance too.
    let (rotation_error, _) = pose_error(&json_transform(&from_pose), &read_transform(&b.truth).unwrap());
    assert!(rotation_error < 1.0, "{rotation_error}");
}

#[test]
fn iteration_limit_exits_1_and_still_writes_everything() {
    let dir = scratch("limit");
    let Some(b) = bunny(&dir) else { return };
    let written = dir.join("T.txt");
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--max-iterations",
        "3",
        "--starts",
        "initial-guess",
        "--json",
        "-o",
        arg(&written),
    ]);
    assert_eq!(output.status.code(), Some(1));
    let report = json(&output);
    assert_eq!(report["stop_reason"], "iteration_limit");
    assert_eq!(report["converged"], false);
    // One start: the cap is the run's update count.
    assert_eq!(report["iterations"], 3);
    assert_eq!(report["search"]["starts_run"], 1);
    assert!(fs::metadata(&written).unwrap().len() > 0);
    assert!(text(&output.stderr).contains("NOT converged"));
}

#[test]
fn baseline_costs_and_options_reach_the_core() {
    let dir = scratch("options");
    let Some(b) = bunny(&dir) else { return };
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--cost",
        "cauchy",
        "--cost-param",
        "0.002",
        "--metric",
        "point-to-point",
        "--noise",
        "quadratic-depth",
        "--max-correspondences",
        "200",
        "--threads",
        "1",
        "--json",
        "-q",
    ]);
    assert!(
        matches!(output.status.code(), Some(0 | 1)),
        "{}",
        text(&output.stderr)
    );
    let report = json(&output);
    assert_eq!(report["cost"], "cauchy");
    assert_eq!(report["cost_parameter"], 0.002);
    assert_eq!(report["metric"], "point-to-point");
    // A baseline fits no SIE model: σ reports the given scale, β is empty.
    assert_eq!(report["beta"].as_array().unwrap().len(), 0);
    // Its verdict is reported but never sets the exit code (3 is SIE's).
    assert!(report["quality"]["verdict"].is_string());
    assert_eq!(report["search"]["starts_run"], 1);
}

/// A PCD header for float x y z.
fn pcd_header(points: usize, data: &str) -> String {
    format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n"
    )
}

fn float_bytes(values: impl Iterator<Item = f64>) -> Vec<u8> {
    values.flat_map(|v| (v as f32).to_le_bytes()).collect()
}

/// The same bunny pair written as binary PCD, binary_compressed PCD and ascii PLY registers to
/// the same tolerance as the ascii PCD originals.
#[test]
fn pcd_binary_compressed_and_ply_ascii_files_register_alike() {
    let dir = scratch("formats");
    let Some(b) = bunny(&dir) else { return };
    let source = read_cloud(&b.source).unwrap().points;
    let target = read_cloud(&b.target).unwrap().points;

    let mut binary = pcd_header(source.len(), "binary").into_bytes();
    binary.extend(float_bytes(source.iter().flatten().copied()));
    let binary_pcd = dir.join("bun0_binary.pcd");
    fs::write(&binary_pcd, binary).unwrap();

    // binary_compressed stores the columns one after another, LZF-compressed; literal-only LZF
    // (a control byte n < 32 announces n + 1 literal bytes) is valid and enough here.
    let columns = float_bytes((0..3).flat_map(|axis| source.iter().map(move |p| p[axis])));
    let mut lzf = Vec::new();
    for chunk in columns.chunks(32) {
        lzf.push((chunk.len() - 1) as u8);
        lzf.extend_from_slice(chunk);
    }
    let mut compressed = pcd_header(source.len(), "binary_compressed").into_bytes();
    compressed.extend((lzf.len() as u32).to_le_bytes());
    compressed.extend((columns.len() as u32).to_le_bytes());
    compressed.extend(lzf);
    let compressed_pcd = dir.join("bun0_compressed.pcd");
    fs::write(&compressed_pcd, compressed).unwrap();

    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        target.len()
    );
    for p in &target {
        ply.push_str(&format!("{} {} {}\n", p[0], p[1], p[2]));
    }
    let ascii_ply = dir.join("bun4_ascii.ply");
    fs::write(&ascii_ply, ply).unwrap();

    let truth = read_transform(&b.truth).unwrap();
    for source_file in [&binary_pcd, &compressed_pcd] {
        let output = sie(&["register", arg(source_file), arg(&ascii_ply), "--json", "-q"]);
        assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
        let report = json(&output);
        assert_eq!(report["source"]["points"], 397);
        assert_eq!(report["target"]["points"], 361);
        let (rotation, translation) = pose_error(&json_transform(&report), &truth);
        assert!(
            rotation < 1.0 && translation < 0.005,
            "{source_file:?}: {rotation} deg, {translation} m"
        );
    }
}

/// Writes the synthetic room's two scans as .xyz files; returns their paths and the truth.
fn room_files(dir: &Path, points: usize) -> (PathBuf, PathBuf, PathBuf) {
    let scene = sie::synthetic::room_scene(points, 0.01, 7);
    let (source, target, truth) = (
        dir.join("room_source.xyz"),
        dir.join("room_target.xyz"),
        dir.join("truth.txt"),
    );
    sie::io::write_cloud_xyz(&source, &scene.source).unwrap();
    sie::io::write_cloud_xyz(&target, &scene.target).unwrap();
    let rows = (0..4)
        .map(|r| {
            (0..4)
                .map(|c| format!("{:.12}", scene.t_target_source[(r, c)]))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect::<Vec<_>>()
        .join("\n");
    fs::write(&truth, rows).unwrap();
    (source, target, truth)
}

/// `count` points uniform in the cube [-1, 1]³ from a fixed linear congruential generator.
fn uniform_cube(count: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut state = seed.wrapping_mul(2862933555777941757).wrapping_add(3037000493);
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / 9007199254740992.0 * 2.0 - 1.0
    };
    (0..count).map(|_| [next(), next(), next()]).collect()
}

fn quality_fields_are_finite(report: &Value) {
    let quality = &report["quality"];
    for key in ["significance", "conditioning"] {
        let value = quality[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key}: {quality}"));
        assert!(value.is_finite() && value >= 0.0, "{key}: {quality}");
    }
    assert!(quality["conditioning"].as_f64().unwrap() <= 1.0);
    // margin is null exactly when no start ended elsewhere.
    let runner_up = report["search"]["runner_up_significance"].as_f64().unwrap();
    assert_eq!(quality["margin"].is_null(), runner_up == 0.0, "{report:#}");
    let search = &report["search"];
    let (run, agreeing) = (
        search["starts_run"].as_u64().unwrap(),
        search["agreeing_starts"].as_u64().unwrap(),
    );
    assert!(run >= 1 && (1..=run).contains(&agreeing), "{search}");
}

/// The synthetic room (the demo's scene: 1 cm noise, partial overlap, 3 % outliers, 7° and
/// 0.2 m from the identity): registered right, and the evidence says so: exit 0.
#[test]
fn a_well_supported_registration_is_good_and_exits_0() {
    let dir = scratch("verdict-good");
    let (source, target, truth) = room_files(&dir, 4000);
    let output = sie(&[
        "register",
        arg(&source),
        arg(&target),
        "--ground-truth",
        arg(&truth),
        "--json",
    ]);
    let stderr = text(&output.stderr);
    assert_eq!(output.status.code(), Some(0), "{stderr}");
    let report = json(&output);
    let (rotation, translation) = (
        report["ground_truth"]["rotation_error_deg"].as_f64().unwrap(),
        report["ground_truth"]["translation_error"].as_f64().unwrap(),
    );
    assert!(
        rotation < 0.5 && translation < 0.01,
        "{rotation} deg, {translation}"
    );
    quality_fields_are_finite(&report);
    let quality = &report["quality"];
    assert_eq!(quality["verdict"], "good", "{quality}");
    assert!(quality["significance"].as_f64().unwrap() > 100.0, "{quality}");
    assert!(quality["conditioning"].as_f64().unwrap() >= 1e-3, "{quality}");
    let ratio = quality["sigma_to_spacing"].as_f64().unwrap();
    assert!(ratio > 0.0 && ratio <= 1.0, "{quality}");
    assert!(quality["margin"].is_null() || quality["margin"].as_f64().unwrap() >= 2.0);
    let search = &report["search"];
    assert!(
        ["initial_guess", "narrow_beta", "scale_free_lead"].contains(&search["start"].as_str().unwrap()),
        "{search}"
    );
    assert_eq!(search["hypotheses"], 0);
    // The summary says it in one line.
    let verdict_lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("verdict")).collect();
    assert_eq!(verdict_lines.len(), 1, "{stderr}");
    assert!(
        verdict_lines[0].starts_with("verdict  good (significance"),
        "{stderr}"
    );
}

/// Two clouds of independent uniform noise: SIE converges somewhere, but no inlier cluster
/// stands out from chance. Exit 3 (converged, verdict not good), with one start or several.
#[test]
fn a_registration_onto_pure_noise_is_unsupported_and_exits_3() {
    let dir = scratch("verdict-noise");
    let (source, target) = (dir.join("a.xyz"), dir.join("b.xyz"));
    sie::io::write_cloud_xyz(&source, &uniform_cube(3000, 1)).unwrap();
    sie::io::write_cloud_xyz(&target, &uniform_cube(3000, 2)).unwrap();
    for starts in ["automatic", "initial-guess"] {
        let written = dir.join("T.txt");
        let output = sie(&[
            "register",
            arg(&source),
            arg(&target),
            "--starts",
            starts,
            "--json",
            "-o",
            arg(&written),
        ]);
        let stderr = text(&output.stderr);
        let report = json(&output);
        assert_eq!(report["stop_reason"], "converged", "{starts}: {stderr}");
        assert_eq!(output.status.code(), Some(3), "{starts}: {stderr}");
        quality_fields_are_finite(&report);
        assert_eq!(
            report["quality"]["verdict"], "unsupported",
            "{starts}: {}",
            report["quality"]
        );
        assert_eq!(report["quality"]["significance"], 0.0);
        // Every output is still written.
        assert!(fs::metadata(&written).unwrap().len() > 0);
        assert!(
            stderr.contains("verdict  UNSUPPORTED: no inlier cluster stands out from chance"),
            "{stderr}"
        );
        if starts == "initial-guess" {
            assert_eq!(report["search"]["starts_run"], 1);
        }
    }
}

/// Two scans of one flat patch, shifted within its plane: nothing in the data fixes the shift,
/// so whatever pose the run ends at must not be called good. Exit 3 when it converged, 1 when
/// it stopped at the iteration limit.
#[test]
fn a_planar_patch_is_not_good() {
    let dir = scratch("verdict-plane");
    let flat = |seed, shift: f64| -> Vec<[f64; 3]> {
        uniform_cube(3000, seed)
            .into_iter()
            .map(|[x, y, z]| [x + shift, y, 0.002 * z])
            .collect()
    };
    let (source, target) = (dir.join("a.xyz"), dir.join("b.xyz"));
    sie::io::write_cloud_xyz(&source, &flat(3, 0.0)).unwrap();
    sie::io::write_cloud_xyz(&target, &flat(4, 0.05)).unwrap();
    let output = sie(&[
        "register",
        arg(&source),
        arg(&target),
        "--metric",
        "point-to-point",
        "--json",
        "-q",
    ]);
    let report = json(&output);
    quality_fields_are_finite(&report);
    let verdict = report["quality"]["verdict"].as_str().unwrap();
    assert!(
        ["doubtful", "unsupported"].contains(&verdict),
        "{:#}",
        report["quality"]
    );
    let expected = if report["converged"] == true { 3 } else { 1 };
    assert_eq!(output.status.code(), Some(expected), "{}", text(&output.stderr));
}

#[test]
fn demo_registers_the_synthetic_room() {
    let output = sie(&["demo", "--points", "3000"]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    let sie_row = stdout
        .lines()
        .find(|l| l.starts_with("SIE (no parameter)"))
        .unwrap_or_else(|| panic!("no SIE row in\n{stdout}"));
    let numbers: Vec<f64> = sie_row
        .split_whitespace()
        .filter_map(|v| v.parse().ok())
        .collect();
    let (rotation_deg, translation_mm) = (numbers[0], numbers[1]);
    assert!(rotation_deg < 0.5 && translation_mm < 10.0, "{sie_row}");
    assert!(sie_row.contains("converged"));
}

/// Each bad input: exit code 2, stdout empty, exactly one stderr line `sie: <file>: <reason>`.
#[test]
fn bad_files_give_one_line_and_exit_code_2() {
    let dir = scratch("bad");
    let good = dir.join("good.xyz");
    fs::write(&good, "0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 0\n1 0 1\n0 1 1\n1 1 1\n").unwrap();
    let mut truncated_binary_pcd = pcd_header(10, "binary").into_bytes();
    truncated_binary_pcd.extend_from_slice(&[0u8; 20]);
    let truncated_binary_ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n\
        property float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0\0\0\0\0"
        .to_vec();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("truncated.pcd", truncated_binary_pcd, "truncated"),
        ("truncated.ply", truncated_binary_ply, "truncated"),
        // Points and lines count from 1 in every message: the missing third point is point 3.
        ("short.pcd", format!("{}1 2 3\n4 5 6\n", pcd_header(3, "ascii")).into_bytes(), "point 3 of 3"),
        ("fields.pcd", format!("{}1 2 3\n4 5\n", pcd_header(2, "ascii")).into_bytes(), "line has 2 tokens"),
        ("fields.xyz", b"1 2 3\n4 5\n".to_vec(), "line 2: expected 3 numbers"),
        ("nan.xyz", b"0 0 0\n1 0 0\nnan 5 6\n0 1 0\n0 0 1\n1 1 0\n".to_vec(), "--skip-invalid"),
        ("nan.pcd", format!("{}1 2 3\n4 nan 6\n", pcd_header(2, "ascii")).into_bytes(), "non-finite"),
        ("empty.xyz", Vec::new(), "no points"),
        ("empty.pcd", pcd_header(0, "ascii").into_bytes(), "no points"),
        ("empty.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec(), "no points"),
        ("cloud.obj", b"v 1 2 3\n".to_vec(), "unknown point-cloud extension"),
        ("more.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 0\n".to_vec(), "2 more lines"),
        ("key.pcd", format!("{}0 0 0\n1 0 0\n0 1 0\n", pcd_header(3, "ascii").replace("WIDTH", "WIDTH 3\nſIZE 4 4 4\nWIDTH")).into_bytes(), "not ASCII"),
    ];
    let mut runs: Vec<(String, Vec<&str>, String)> = Vec::new();
    for (name, bytes, expected) in &cases {
        fs::write(dir.join(name), bytes).unwrap();
        runs.push((name.to_string(), vec![], expected.to_string()));
    }
    runs.push(("missing.pcd".into(), vec![], "cannot read file".into()));
    for (name, extra, expected) in &runs {
        let bad = dir.join(name);
        // As source and as target.
        for pair in [[arg(&bad), arg(&good)], [arg(&good), arg(&bad)]] {
            let mut args = vec!["register", pair[0], pair[1]];
            args.extend(extra);
            let output = sie(&args);
            let stderr = text(&output.stderr);
            assert_eq!(output.status.code(), Some(2), "{name}: {stderr}");
            assert!(output.stdout.is_empty(), "{name}: {}", text(&output.stdout));
            assert_eq!(stderr.lines().count(), 1, "{name}: {stderr}");
            assert!(
                stderr.starts_with("sie: ")
                    && stderr.contains(name.as_str())
                    && stderr.contains(expected.as_str()),
                "{name}: {stderr}"
            );
        }
    }
    // The hint works: the NaN point is dropped and counted.
    let output = sie(&[
        "register",
        arg(&dir.join("nan.xyz")),
        arg(&good),
        "--skip-invalid",
        "--json",
        "-q",
    ]);
    assert!(
        matches!(output.status.code(), Some(0 | 1)),
        "{}",
        text(&output.stderr)
    );
    assert_eq!(json(&output)["source"]["skipped_non_finite"], 1);
    // Depth-sensor style invalid points at 0 0 0 are dropped on request and counted.
    let with_origin = dir.join("origin.xyz");
    fs::write(
        &with_origin,
        "0 0 0\n1 0 0\n0 0 0\n0 1 0\n0 0 1\n1 1 0\n1 0 1\n0 1 1\n1 1 1\n",
    )
    .unwrap();
    let output = sie(&[
        "register",
        arg(&with_origin),
        arg(&good),
        "--skip-origin",
        "--json",
        "-q",
    ]);
    assert!(
        matches!(output.status.code(), Some(0 | 1)),
        "{}",
        text(&output.stderr)
    );
    let report = json(&output);
    assert_eq!(
        (
            report["source"]["skipped_origin"].as_u64(),
            report["target"]["skipped_origin"].as_u64()
        ),
        (Some(2), Some(1))
    );
}

/// `--file-normals` keeps the library's rule for given normals: a normal that is neither of unit
/// length nor 0 0 0 is bad input, one line naming the file and the normal, exit code 2.
#[test]
fn file_normals_that_are_not_unit_vectors_give_one_line_and_exit_code_2() {
    let dir = scratch("normals");
    let good = dir.join("good.xyz");
    fs::write(&good, "0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 0\n1 0 1\n0 1 1\n1 1 1\n").unwrap();
    let with_normals = |fourth_normal: &str| {
        let mut ply = "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\n\
            property float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n"
            .to_string();
        for (i, point) in [
            "0 0 0", "1 0 0", "0 1 0", "0 0 1", "1 1 0", "1 0 1", "0 1 1", "1 1 1",
        ]
        .iter()
        .enumerate()
        {
            let normal = if i == 3 { fourth_normal } else { "0 0 1" };
            ply.push_str(&format!("{point} {normal}\n"));
        }
        ply
    };
    let bad = dir.join("normals.ply");
    fs::write(&bad, with_normals("0 0 0.5")).unwrap();
    let output = sie(&["register", arg(&good), arg(&bad), "--file-normals"]);
    let stderr = text(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(output.stdout.is_empty(), "{}", text(&output.stdout));
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("sie: ")
            && stderr.contains("normals.ply")
            && stderr.contains("target normals[3] has length 0.5")
            && stderr.contains("unit vectors"),
        "{stderr}"
    );
    // 0 0 0 is "no normal" and passes; so do unit normals.
    fs::write(&bad, with_normals("0 0 0")).unwrap();
    let output = sie(&["register", arg(&good), arg(&bad), "--file-normals", "-q"]);
    assert!(
        matches!(output.status.code(), Some(0 | 1 | 3)),
        "{}",
        text(&output.stderr)
    );
}

/// A PCD file holding more points than its header declares: the declared points are read (as
/// PCL does) and a warning says what was left, on stderr even with -q and in the JSON report.
#[test]
fn pcd_holding_more_points_than_declared_is_read_with_a_warning() {
    let dir = scratch("undeclared");
    let mut contents = pcd_header(8, "ascii");
    for i in 0..10 {
        contents.push_str(&format!("{} {} {}\n", i % 2, i / 2 % 2, (i * 7) % 5));
    }
    let file = dir.join("more.pcd");
    fs::write(&file, contents).unwrap();
    let output = sie(&["register", arg(&file), arg(&file), "--json", "-q"]);
    let stderr = text(&output.stderr);
    assert!(matches!(output.status.code(), Some(0 | 1)), "{stderr}");
    assert!(
        stderr.contains("sie: warning:") && stderr.contains("more.pcd") && stderr.contains("10 points"),
        "{stderr}"
    );
    let report = json(&output);
    assert_eq!(report["source"]["points"], 8);
    let warnings = report["source"]["warnings"].as_array().unwrap();
    assert!(
        warnings.len() == 1 && warnings[0].as_str().unwrap().contains("declares 8"),
        "{warnings:?}"
    );
    assert_eq!(report["target"]["warnings"].as_array().unwrap().len(), 1);
}

/// Ground truths are published rounded (3DMatch's gt.log, GeoTransformer's gt.npy, PCL's
/// office matrix: orthonormal to 5e-5–7e-5). `--init` refused them (exit 2, "is the matrix
/// column-major?", which they are not) while `--ground-truth` took them as they were. Both
/// now accept up to 1e-3, make them exactly rigid and say so; the column-major hint comes only
/// when the transpose is valid.
#[test]
fn rounded_transform_files_are_accepted_and_made_rigid() {
    let dir = scratch("rounded");
    let cloud = dir.join("cloud.xyz");
    let points: String = (0..600)
        .map(|i| {
            let f = i as f64;
            format!(
                "{} {} {}\n",
                (f * 0.37).sin(),
                (f * 0.91).cos() * 0.8,
                (f * 0.13).sin() * 0.5 + 0.001 * f
            )
        })
        .collect();
    fs::write(&cloud, points).unwrap();
    let truth = Rotation3::from_euler_angles(0.02, -0.03, 0.05);
    let matrix = |rows: [[f64; 4]; 3], digits: i32| -> String {
        let scale = 10f64.powi(digits);
        rows.iter()
            .map(|row| row.map(|v| format!("{}", (v * scale).round() / scale)).join(" ") + "\n")
            .collect()
    };
    let r = truth.matrix();
    let rows = [0, 1, 2].map(|i| [r[(i, 0)], r[(i, 1)], r[(i, 2)], [0.01, -0.02, 0.005][i]]);
    let rounded = dir.join("rounded.txt");
    fs::write(&rounded, matrix(rows, 4)).unwrap();
    let c = arg(&cloud);
    let output = sie(&[
        "register",
        c,
        c,
        "--init",
        arg(&rounded),
        "--ground-truth",
        arg(&rounded),
        "--json",
    ]);
    let stderr = text(&output.stderr);
    assert!(matches!(output.status.code(), Some(0 | 1)), "{stderr}");
    assert!(
        stderr.contains("note: the --init rotation was rounded")
            && stderr.contains("note: the --ground-truth"),
        "{stderr}"
    );
    let report = json(&output);
    for key in ["init_correction", "ground_truth_correction"] {
        let correction = report[key].as_f64().unwrap();
        assert!(correction > 1e-6 && correction < 1e-4, "{key}: {correction}");
    }
    // Without the options the fields are null.
    let report = json(&sie(&["register", c, c, "--json", "-q"]));
    assert!(report["init_correction"].is_null() && report["ground_truth_correction"].is_null());

    // More than rounding: refused, and transposing would not help, so no column-major hint.
    let mut skewed_rows = rows;
    skewed_rows[0][1] += 3e-3;
    let skewed = dir.join("skewed.txt");
    fs::write(&skewed, matrix(skewed_rows, 6)).unwrap();
    // A rigid transform written column-major: the hint is right there.
    let full = |rows: [[f64; 4]; 3]| {
        let mut all = rows.to_vec();
        all.push([0.0, 0.0, 0.0, 1.0]);
        all
    };
    let transposed: String = (0..4)
        .map(|col| {
            (0..4)
                .map(|row| format!("{}", full(rows)[row][col]))
                .collect::<Vec<_>>()
                .join(" ")
                + "\n"
        })
        .collect();
    let column_major = dir.join("column_major.txt");
    fs::write(&column_major, transposed).unwrap();
    for option in ["--init", "--ground-truth"] {
        for (file, expected, hint) in [
            (&skewed, "not orthonormal", false),
            (&column_major, "last row", true),
        ] {
            let output = sie(&["register", c, c, option, arg(file)]);
            let stderr = text(&output.stderr);
            assert_eq!(output.status.code(), Some(2), "{stderr}");
            assert!(stderr.contains(expected) && stderr.contains(option), "{stderr}");
            assert_eq!(stderr.contains("column-major"), hint, "{stderr}");
        }
    }
}

/// Runs the `sie` binary with its address space capped at `limit` bytes.
fn sie_with_memory_limit(args: &[&str], limit: u64) -> Output {
    use std::os::unix::process::CommandExt;
    let mut command = Command::new(env!("CARGO_BIN_EXE_sie"));
    command.args(args);
    // SAFETY: between fork and exec only the async-signal-safe setrlimit is called.
    unsafe {
        command.pre_exec(move || {
            let cap = libc::rlimit {
                rlim_cur: limit as libc::rlim_t,
                rlim_max: limit as libc::rlim_t,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &cap) == 0 {
                Ok(())
            } else {
                Err(std::io::Error::last_os_error())
            }
        });
    }
    command.output().expect("run the sie binary")
}

/// A valid 8 MB binary_compressed PCD of 58 M points that decompresses to 696 MB, read with
/// 1 GiB of address space: exit 2 and one line, nothing decompressed. Before: "memory
/// allocation of 696000000 bytes failed", SIGABRT (exit 134).
#[test]
fn a_compressed_pcd_too_large_for_memory_exits_2() {
    let dir = scratch("lzf-bomb");
    let points = 58_000_000usize;
    let uncompressed = 12 * points;
    // LZF: one literal zero byte, then back references of 264 bytes at distance 1.
    let mut lzf = vec![0u8, 0];
    let mut produced = 1;
    while produced < uncompressed {
        let take = (uncompressed - produced).min(264);
        if take >= 9 {
            lzf.extend([0xe0, (take - 9) as u8, 0]);
        } else if take >= 3 {
            lzf.extend([((take - 2) << 5) as u8, 0]);
        } else {
            lzf.push((take - 1) as u8);
            lzf.extend(std::iter::repeat_n(0u8, take));
        }
        produced += take;
    }
    let mut bytes = pcd_header(points, "binary_compressed").into_bytes();
    bytes.extend((lzf.len() as u32).to_le_bytes());
    bytes.extend((uncompressed as u32).to_le_bytes());
    bytes.extend(lzf);
    let file = dir.join("bomb.pcd");
    fs::write(&file, bytes).unwrap();
    let output = sie_with_memory_limit(&["register", arg(&file), arg(&file)], 1 << 30);
    let stderr = text(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("bomb.pcd") && stderr.contains("out of memory") && stderr.contains("58000000 points"),
        "{stderr}"
    );
}

/// Two clouds that are read fine but whose registration does not fit the address space: exit 2
/// before the registration starts. Before: SIGABRT part-way through.
#[test]
fn a_registration_too_large_for_memory_exits_2() {
    let dir = scratch("big-pair");
    let points = 4_000_000usize;
    let mut bytes = pcd_header(points, "binary").into_bytes();
    bytes.extend(float_bytes((0..points).flat_map(|i| {
        let f = i as f64;
        [
            (f * 0.618).sin() * 5.0,
            (f * 0.377).cos() * 5.0,
            (i % 1000) as f64 * 0.003,
        ]
    })));
    let file = dir.join("big.pcd");
    fs::write(&file, bytes).unwrap();
    let output = sie_with_memory_limit(&["register", arg(&file), arg(&file), "-q"], 1 << 30);
    let stderr = text(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("cannot register") && stderr.contains(": out of memory") && stderr.contains("GiB"),
        "{stderr}"
    );
}

#[test]
fn bad_options_give_one_line_and_exit_code_2() {
    let dir = scratch("options-bad");
    let cloud = dir.join("cloud.xyz");
    fs::write(&cloud, "0 0 0\n1 0 0\n0 1 0\n0 0 1\n").unwrap();
    let not_rigid = dir.join("scaled.txt");
    fs::write(&not_rigid, "2 0 0 0\n0 1 0 0\n0 0 1 0\n").unwrap();
    let c = arg(&cloud);
    let cases: [(Vec<&str>, &str); 9] = [
        (vec!["--cost", "cauchy"], "needs --cost-param"),
        (vec!["--cost-param", "1"], "takes no --cost-param"),
        (vec!["--plot", "fig.jpg"], ".png or .svg"),
        (vec!["--plot", "fig.png", "--cost", "l2"], "fits none"),
        (vec!["--aligned", "out.ply"], ".pcd, .xyz or .txt"),
        (vec!["-o", "/no/such/folder/T.txt"], "does not exist"),
        (
            vec!["--init", arg(&not_rigid)],
            "(--init): the rotation part is not orthonormal",
        ),
        // PCL users' habit: answered, not hinted towards the sampling cap.
        (
            vec!["--max-correspondence-distance", "0.05"],
            "no correspondence distance gate",
        ),
        (vec!["--max-distance=1"], "no correspondence distance gate"),
    ];
    for (extra, expected) in cases {
        let mut args = vec!["register", c, c];
        args.extend(&extra);
        let output = sie(&args);
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{extra:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{extra:?}: {stderr}");
        assert!(
            stderr.starts_with("sie: ") && stderr.contains(expected),
            "{extra:?}: {stderr}"
        );
    }
    // clap's own usage errors use the same code.
    let output = sie(&["register", c, c, "--init-pose", "1", "2", "3"]);
    assert_eq!(output.status.code(), Some(2));
    let output = sie(&["register", c, c, "--aligned-ascii"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output.stderr).contains("--aligned <FILE>"));
    let help = text(&sie(&["register", "--help"]).stdout);
    assert!(help.contains("Exit codes") && help.contains("Rz(YAW)"), "{help}");
}
