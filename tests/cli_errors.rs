//! The `sie` binary on bad input: one line on stderr and exit code 2 (files, options, memory),
//! and input read with a warning or a note.
#![cfg(feature = "cli")]
mod common;

use std::fs;
use std::process::{Command, Output};

use common::cli::{arg, float_bytes, json, pcd_header, scratch, sie, text};
use nalgebra::Rotation3;

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
        // Both were read without a word (pcd-rs takes COUNT 0 as 1 and ignores WIDTH × HEIGHT).
        ("count0.pcd", format!("{}0 0 0\n1 0 0\n0 1 0\n", pcd_header(3, "ascii").replace("COUNT 1 1 1", "COUNT 1 0 1")).into_bytes(), "COUNT of field y is 0"),
        ("size.pcd", format!("{}0 0 0\n1 0 0\n0 1 0\n", pcd_header(3, "ascii").replace("HEIGHT 1", "HEIGHT 9223372036854775808")).into_bytes(), "WIDTH 3 × HEIGHT 9223372036854775808"),
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
    // Read and registered (8 points onto themselves show no surfaces: any verdict), not refused.
    assert!(matches!(output.status.code(), Some(0 | 1 | 3)), "{stderr}");
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
    // A bumpy surface: every direction is constrained, so the run can be GOOD (exit 0).
    let points: String = (0..600)
        .map(|i| {
            let (x, y) = ((i % 25) as f64 * 0.08 - 1.0, (i / 25) as f64 * 0.08 - 1.0);
            let z = 0.3 * (2.0 * x).sin() * (3.0 * y).cos() + 0.2 * x * x;
            format!("{x} {y} {z}\n")
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

/// `--threads -1` got clap's tip "to pass '-1' as a value, use '-- -1'", which suggests the
/// value would then be taken; it now says which values are allowed, like a wrong count does.
#[test]
fn a_negative_thread_count_says_which_counts_are_allowed() {
    let dir = scratch("threads-bad");
    let cloud = dir.join("cloud.xyz");
    fs::write(&cloud, "0 0 0\n1 0 0\n0 1 0\n0 0 1\n").unwrap();
    let c = arg(&cloud);
    for args in [
        vec!["register", c, c, "--threads", "-1"],
        vec!["register", c, c, "--threads=-1"],
        vec!["register", c, c, "--threads", "1.5"],
        vec!["demo", "--threads", "-1"],
    ] {
        let output = sie(&args);
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(output.stdout.is_empty(), "{args:?}");
        assert!(
            stderr.contains("--threads")
                && stderr.contains("0 (one per core) or a count of threads")
                && !stderr.contains("tip:"),
            "{args:?}: {stderr}"
        );
    }
}
