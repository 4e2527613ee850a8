//! The `sie` binary's quality verdict: good, doubtful or unsupported, and exit codes 0 and 3.
#![cfg(feature = "cli")]
mod common;

use std::fs;
use std::path::{Path, PathBuf};

use common::cli::{arg, json, scratch, sie, text};
use serde_json::Value;

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

/// The room written with every point twice (as PCL's room scans store theirs) gives the
/// transform and the verdict it gives written once, exit 0, and the report counts the
/// repeats: each location counted once.
#[test]
fn a_room_stored_twice_is_good_like_stored_once_and_its_repeats_are_counted() {
    let dir = scratch("verdict-twice");
    let (source, target, _) = room_files(&dir, 3000);
    let once = sie(&["register", arg(&source), arg(&target), "--json", "-q"]);
    assert_eq!(once.status.code(), Some(0), "{}", text(&once.stderr));
    let twice_files: Vec<PathBuf> = [&source, &target]
        .iter()
        .map(|path| {
            let contents = fs::read_to_string(path).unwrap();
            let doubled = dir.join(format!("twice_{}", path.file_name().unwrap().to_string_lossy()));
            fs::write(&doubled, format!("{contents}{contents}")).unwrap();
            doubled
        })
        .collect();
    let twice = sie(&[
        "register",
        arg(&twice_files[0]),
        arg(&twice_files[1]),
        "--json",
        "-q",
    ]);
    assert_eq!(twice.status.code(), Some(0), "{}", text(&twice.stderr));
    let (once, twice) = (json(&once), json(&twice));
    assert_eq!(twice["transform"], once["transform"]);
    assert_eq!(twice["quality"]["verdict"], "good");
    assert_eq!(
        twice["quality"]["sigma_to_spacing"],
        once["quality"]["sigma_to_spacing"]
    );
    for cloud in ["source", "target"] {
        assert_eq!(once[cloud]["repeated"], 0, "{cloud}");
        assert_eq!(twice[cloud]["repeated"], once[cloud]["points"], "{cloud}");
        assert_eq!(
            twice[cloud]["points"],
            2 * once[cloud]["points"].as_u64().unwrap(),
            "{cloud}"
        );
    }
}
