//! The `sie` binary end to end: real scan pairs with ground truth, every output, the demo.
//! Bad input is in cli_errors.rs, the quality verdict in cli_verdicts.rs.
#![cfg(feature = "cli")]
mod common;

use std::fs;

use common::cli::{
    arg, bunny, float_bytes, json, json_transform, pcd_header, scratch, sie, text, text_transform,
};
use common::{data_dir, pose_error};
use nalgebra::{Matrix4, Rotation3, Vector3};
use sie::geometry::{make_rigid, transform_point};
use sie::io::{read_cloud, read_transform};

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
    // From the initial guess alone every start ends at the result (the run travelled, so it ran
    // again from its result and stayed; a rival may run after it and end there too).
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
    // A rival (a quarter turn of the travelled result) may run after it and end there too.
    let starts = report["search"]["starts_run"].as_u64().unwrap();
    assert!(starts >= 2, "{starts} starts");
    assert_eq!(report["search"]["agreeing_starts"].as_u64().unwrap(), starts);
    let trace = report["trace"].as_array().unwrap();
    assert_eq!(report["iterations"].as_u64().unwrap() as usize, trace.len());
    let kept = trace
        .iter()
        .find(|row| row["transform"] == report["transform"])
        .expect("the result is one of the updates");
    // One meaning of "inlier fraction": the converged run's last update and the summary agree.
    let (progress, summary) = (
        kept["inlier_fraction"].as_f64().unwrap(),
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

/// The numbers of the array `key` of a JSON document, in order, parsed exactly from its text.
fn exact_numbers(json: &str, key: &str) -> Vec<f64> {
    let start = json
        .find(&format!("\"{key}\": ["))
        .unwrap_or_else(|| panic!("no {key} in {json}"));
    let array = &json[start + key.len() + 4..];
    let mut depth = 0;
    let end = array
        .char_indices()
        .find(|&(_, c)| {
            match c {
                '[' => depth += 1,
                ']' => depth -= 1,
                _ => {}
            }
            depth == 0
        })
        .expect("a closed array")
        .0;
    array[..end]
        .split(|c: char| c == '[' || c == ']' || c == ',' || c.is_whitespace())
        .filter(|token| !token.is_empty())
        .map(|token| token.parse().expect("a number"))
        .collect()
}

/// `--json` reports the pose's covariance and information as 6 rows of 6 numbers, with the
/// convention, and they are the library's for the same files and settings, bit for bit.
#[test]
fn json_reports_the_pose_covariance_and_information_of_the_library() {
    let dir = scratch("covariance");
    let scene = sie::synthetic::room_scene(1500, 0.01, 5);
    let mut files = Vec::new();
    for (name, points) in [("source.pcd", &scene.source), ("target.pcd", &scene.target)] {
        let mut bytes = pcd_header(points.len(), "binary").into_bytes();
        bytes.extend(float_bytes(points.iter().flatten().copied()));
        let path = dir.join(name);
        fs::write(&path, bytes).unwrap();
        files.push(path);
    }
    for metric in [sie::Metric::PointToPlane, sie::Metric::PointToPoint] {
        let metric_arg = match metric {
            sie::Metric::PointToPlane => "point-to-plane",
            sie::Metric::PointToPoint => "point-to-point",
        };
        let output = sie(&[
            "register",
            arg(&files[0]),
            arg(&files[1]),
            "--metric",
            metric_arg,
            "--json",
            "-q",
        ]);
        assert!(
            matches!(output.status.code(), Some(0 | 3)),
            "{}",
            text(&output.stderr)
        );
        let report = json(&output);
        let matrix = |key: &str| {
            let rows = report[key]
                .as_array()
                .unwrap_or_else(|| panic!("{key}: {report}"));
            assert_eq!(rows.len(), 6, "{key}");
            for row in rows {
                assert_eq!(row.as_array().expect("a row").len(), 6, "{key}");
            }
            nalgebra::Matrix6::from_fn(|r, c| rows[r][c].as_f64().expect("a number"))
        };
        let (covariance, information) = (matrix("covariance"), matrix("information"));
        let convention = report["pose_perturbation"].as_str().expect("the convention");
        for words in ["left", "rotation vector", "rotation first", "target frame"] {
            assert!(convention.contains(words), "{convention}");
        }

        let config = sie::RegistrationConfig {
            metric,
            ..sie::RegistrationConfig::default()
        };
        let source = read_cloud(&files[0]).unwrap().points;
        let target = read_cloud(&files[1]).unwrap().points;
        let library =
            sie::register_clouds(&source, &target, None, None, &config, sie::Hooks::default()).unwrap();
        // Bit for bit, read from the text (serde_json's default parser may be a few units in
        // the last place off).
        let stdout = text(&output.stdout);
        assert_eq!(
            exact_numbers(&stdout, "transform"),
            library.transform.transpose().as_slice(),
            "{metric_arg}"
        );
        for (name, want) in [
            ("covariance", library.uncertainty.covariance),
            ("information", library.uncertainty.information),
        ] {
            assert_eq!(
                exact_numbers(&stdout, name),
                want.transpose().as_slice(),
                "{metric_arg} {name}"
            );
        }
        assert!(
            (covariance * information - nalgebra::Matrix6::identity())
                .abs()
                .max()
                < 1e-9,
            "{metric_arg}"
        );
    }
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

/// `--starts global`: the bunny pair with no guess, from a descriptor match, GOOD; 20 points are
/// refused with the reason.
#[test]
fn global_starts_need_no_guess_and_refuse_what_they_cannot_describe() {
    let dir = scratch("global_starts");
    let Some(b) = bunny(&dir) else { return };
    let output = sie(&[
        "register",
        arg(&b.source),
        arg(&b.target),
        "--starts",
        "global",
        "--ground-truth",
        arg(&b.truth),
        "--json",
        "-q",
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let report = json(&output);
    let rotation = report["ground_truth"]["rotation_error_deg"].as_f64().unwrap();
    let translation = report["ground_truth"]["translation_error"].as_f64().unwrap();
    assert!(
        rotation < 1.0 && translation < 0.005,
        "{rotation} deg, {translation} m"
    );
    assert_eq!(report["search"]["start"], "feature_match");
    assert!(report["search"]["hypotheses"].as_u64().unwrap() > 0);
    assert_eq!(report["quality"]["verdict"], "good");
    let few = dir.join("few.xyz");
    let lines: String = (0..20)
        .map(|k| {
            format!(
                "{} {} {}\n",
                (k as f64).sin(),
                (k as f64 * 0.7).cos(),
                k as f64 * 0.1
            )
        })
        .collect();
    fs::write(&few, lines).unwrap();
    let output = sie(&["register", arg(&few), arg(&few), "--starts", "global"]);
    assert_ne!(output.status.code(), Some(0));
    assert!(
        text(&output.stderr).contains("keypoints"),
        "{}",
        text(&output.stderr)
    );
}

/// `sie odometry` over room frames written as .xyz, with a repeat, a frame of missing returns
/// only and a missing file among them: one KITTI line a frame (the set-aside ones hold the prediction), each good
/// frame's pose on the truth, exit 3 because frames were set aside; 0 when none is.
#[test]
fn odometry_prints_a_pose_a_frame_and_sets_bad_frames_aside() {
    let dir = scratch("odometry");
    let trajectory = sie::synthetic::room_trajectory(40, 3_000, 0.01, 7);
    let mut paths = Vec::new();
    for (i, frame) in trajectory.frames.iter().take(5).enumerate() {
        let path = dir.join(format!("{i}.xyz"));
        let lines: Vec<String> = frame
            .iter()
            .map(|p| format!("{} {} {}", p[0], p[1], p[2]))
            .collect();
        fs::write(&path, lines.join("\n")).unwrap();
        paths.push(path);
    }
    // Missing returns only, as a driver writes them: nothing usable once they are dropped.
    let empty = dir.join("no-returns.xyz");
    fs::write(&empty, "0 0 0\nnan nan nan\n0 0 0\n0 0 0\n").unwrap();
    let missing = dir.join("missing.xyz");
    let poses_file = dir.join("poses.txt");
    // (file, the true frame it is if good)
    let sent = [
        (&paths[0], Some(0)),
        (&paths[1], Some(1)),
        (&paths[1], None),
        (&empty, None),
        (&paths[3], Some(3)),
        (&missing, None),
        (&paths[4], Some(4)),
    ];
    let mut args = vec!["odometry", "--threads", "2", "-o", arg(&poses_file)];
    args.extend(sent.iter().map(|(path, _)| arg(path)));
    let output = sie(&args);
    let stderr = text(&output.stderr);
    assert_eq!(output.status.code(), Some(3), "{stderr}");
    for words in [
        "first",
        "accepted",
        "the last accepted frame again",
        "refused",
        "unreadable",
        "3 set aside",
    ] {
        assert!(stderr.contains(words), "{words:?} not in {stderr}");
    }
    let stdout = text(&output.stdout);
    assert_eq!(fs::read_to_string(&poses_file).unwrap(), stdout);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), sent.len(), "{stdout}");
    let world = trajectory.poses[0].try_inverse().unwrap();
    for ((_, truth), line) in sent.iter().zip(&lines) {
        let values: Vec<f64> = line.split_whitespace().map(|v| v.parse().unwrap()).collect();
        assert_eq!(values.len(), 12, "{line}");
        let Some(i) = truth else { continue };
        let mut pose = Matrix4::identity();
        for (k, v) in values.iter().enumerate() {
            pose[(k / 4, k % 4)] = *v;
        }
        let (degrees, metres) = pose_error(&pose, &(world * trajectory.poses[*i]));
        assert!(
            degrees < 0.1 && metres < 0.005,
            "frame {i}: {degrees:.3}° / {metres:.4} m"
        );
    }
    let clean = sie(&["odometry", "-q", arg(&paths[0]), arg(&paths[1]), arg(&paths[2])]);
    assert_eq!(clean.status.code(), Some(0), "{}", text(&clean.stderr));
    assert!(clean.stderr.is_empty(), "{}", text(&clean.stderr));
}
