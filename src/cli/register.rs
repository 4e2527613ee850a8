//! `sie register SOURCE TARGET`: read two clouds, register, report.
//!
//! stdout carries the result only (the 4×4 transform, or the JSON report with `--json`), so it
//! can be redirected to a file and read back with `--init`; progress, the `--trace` table and
//! the summary go to stderr.
use std::fs;
use std::path::Path;
use std::time::Instant;

use nalgebra::Matrix4;
use sie::geometry::{NOTABLE_CORRECTION, Rigid, make_rigid, rotation_part, transform_point, vector};
use sie::io::{CloudFile, CloudFormat, PcdEncoding, read_cloud_with, read_transform, write_cloud};
use sie::{
    CostFunction, HistogramMode, Hooks, Metric, NoiseModel, NoiseShape, NonFinite, Point, RegistrationConfig,
    RegistrationResult, StopReason, TraceEntry, Verdict, register_clouds,
};

use super::args::{RegisterArgs, pose_matrix};
use super::plot::{PlotFormat, PlotText, write_plot};
use super::progress::{InterruptScope, Progress, install_interrupt_handler};
use super::report::{
    CloudReport, GroundTruthError, JsonReport, SummaryContext, TraceRow, format_transform, json_stop_reason,
    pose_error, quality_report, search_row, significant, summary, transform_rows,
};
use super::{CliError, exit};

pub fn run(args: &RegisterArgs) -> Result<u8, CliError> {
    let config = args.config()?;
    check_outputs(args, &config)?;
    let init = match (&args.init, &args.init_pose) {
        (Some(path), _) => Some(rigid_file(path, "--init")?),
        (None, Some(values)) => Some(Rigid {
            transform: pose_matrix(values)?,
            correction: 0.0,
        }),
        (None, None) => None,
    };
    let truth = match &args.ground_truth {
        Some(path) => Some(rigid_file(path, "--ground-truth")?),
        None => None,
    };
    if !args.quiet {
        for (rigid, option) in [(&init, "--init"), (&truth, "--ground-truth")] {
            if let Some(rigid) = rigid.as_ref().filter(|r| r.correction > NOTABLE_CORRECTION) {
                eprintln!(
                    "sie: note: the {option} rotation was rounded (an entry changed by {:.1e} to make it \
                     exactly rigid)",
                    rigid.correction
                );
            }
        }
    }

    // The live table would interleave with nothing useful in JSON mode; there the trace goes
    // into the report.
    let mut progress = Progress::new(args.trace && !args.json, args.quiet, config.max_iterations);
    let read_start = Instant::now();
    let policy = if args.skip_invalid {
        NonFinite::Skip
    } else {
        NonFinite::Reject
    };
    progress.note(&format!("reading {}", args.source.display()));
    let source = read_cloud_with(&args.source, policy).map_err(input_error)?;
    progress.note(&format!("reading {}", args.target.display()));
    let target = read_cloud_with(&args.target, policy).map_err(input_error)?;
    // Data the files hold beyond what they declare is said even with -q: it was not read.
    for (path, cloud) in [(&args.source, &source), (&args.target, &target)] {
        for warning in &cloud.warnings {
            eprintln!("sie: warning: {}: {warning}", path.display());
        }
    }
    let target_normals = if args.file_normals {
        let normals = target.normals.as_deref().ok_or_else(|| {
            CliError::new(format!(
                "{}: --file-normals, but the file has no normal_x/y/z or nx/ny/nz fields",
                args.target.display()
            ))
        })?;
        Some(normals)
    } else {
        None
    };
    let read_seconds = read_start.elapsed().as_secs_f64();

    install_interrupt_handler();
    progress.note(match (config.metric, target_normals) {
        (Metric::PointToPlane, None) => "estimating target normals",
        _ => "registering",
    });
    let started = Instant::now();
    let outcome = {
        let _interruptible = InterruptScope::enter();
        let mut observer = |entry: &TraceEntry| progress.on_iteration(entry);
        let hooks = Hooks {
            noise: None,
            observer: Some(&mut observer),
        };
        register_clouds(
            &source.points,
            &target.points,
            target_normals,
            init.as_ref().map(|rigid| &rigid.transform),
            &config,
            hooks,
        )
    };
    progress.finish();
    // The library checks the input (unit normals, the memory it needs) and names what is wrong;
    // the files say where.
    let result = outcome.map_err(|e| {
        CliError::new(format!(
            "cannot register {} onto {}: {e}",
            args.source.display(),
            args.target.display()
        ))
    })?;
    let seconds = started.elapsed().as_secs_f64();

    let ground_truth = truth.map(|t| {
        let (rotation_error_deg, translation_error) = pose_error(&result.transform, &t.transform);
        GroundTruthError {
            rotation_error_deg,
            translation_error,
        }
    });
    let source_report = cloud_report(&args.source, &source, config.skip_origin);
    let target_report = cloud_report(&args.target, &target, config.skip_origin);
    let transform_text = format_transform(&result.transform, "");

    // Files first, so a failed write is the last thing the user reads; the result is printed
    // either way.
    let mut written = Vec::new();
    let mut write_errors = Vec::new();
    let mut record = |path: &Path, outcome: Result<(), String>| match outcome {
        Ok(()) => written.push(path.display().to_string()),
        Err(message) => write_errors.push(message),
    };
    if let Some(path) = &args.output {
        let outcome =
            fs::write(path, &transform_text).map_err(|e| format!("{}: cannot write: {e}", path.display()));
        record(path, outcome);
    }
    if let Some(path) = &args.aligned {
        let encoding = if args.aligned_ascii {
            PcdEncoding::Ascii
        } else {
            PcdEncoding::Binary
        };
        record(path, write_aligned(path, &source, &result.transform, encoding));
    }
    if let Some(path) = &args.plot {
        let text = plot_text(args, &config, &result);
        let plot_text = PlotText {
            title: &text.0,
            x_label: &text.1,
            panel_captions: text.2,
        };
        record(path, write_plot(path, &result.histograms, &plot_text));
    }

    if args.json {
        let report = JsonReport {
            source: &source_report,
            target: &target_report,
            cost: args.cost.name(),
            cost_parameter: (!matches!(config.cost, CostFunction::Sie | CostFunction::L2))
                .then(|| config.cost.parameter()),
            metric: metric_name(config.metric),
            transform: transform_rows(&result.transform),
            stop_reason: json_stop_reason(result.stop_reason),
            converged: result.converged,
            iterations: result.iterations,
            sigma: result.sigma.clone(),
            beta: result.beta.clone(),
            penalty: result.penalty,
            noise_shape: result.noise_shape,
            inlier_fraction: result.inlier_fraction,
            rmse: result.rmse,
            seconds,
            read_seconds,
            ground_truth,
            init_correction: init.map(|rigid| rigid.correction),
            ground_truth_correction: truth.map(|rigid| rigid.correction),
            quality: quality_report(&result),
            search: search_row(&result),
            trace: result.trace.iter().map(TraceRow::from).collect(),
        };
        let json = serde_json::to_string_pretty(&report).map_err(CliError::new)?;
        println!("{json}");
    } else {
        print!("{transform_text}");
    }
    if !args.quiet {
        let context = SummaryContext {
            source: &source_report,
            target: &target_report,
            method: method_description(args, &config),
            target_note: match (config.metric, target_normals) {
                (Metric::PointToPoint, _) => "point-to-point".into(),
                (Metric::PointToPlane, Some(_)) => "normals from the file".into(),
                (Metric::PointToPlane, None) => {
                    format!("normals from {} neighbours", config.normal_neighbours)
                }
            },
            units: units(&config),
            seconds,
            read_seconds,
            ground_truth,
            judged: config.cost == CostFunction::Sie,
            written,
        };
        eprint!("{}", summary(&result, &context));
    }
    if let Some(first) = write_errors.first() {
        for message in &write_errors[1..] {
            eprintln!("sie: {message}");
        }
        return Err(CliError::new(first));
    }
    Ok(match result.stop_reason {
        // The verdict judges SIE's fitted noise model; a baseline cost has none (L2) or the
        // caller's scale, so its verdict does not set the exit code.
        StopReason::Converged if config.cost != CostFunction::Sie => exit::CONVERGED,
        StopReason::Converged if result.quality.verdict == Verdict::Good => exit::CONVERGED,
        StopReason::Converged => exit::NOT_GOOD,
        StopReason::IterationLimit | StopReason::Degenerate => exit::NOT_CONVERGED,
        StopReason::Cancelled => exit::CANCELLED,
    })
}

/// Rejects output requests that cannot succeed before spending time on the registration.
fn check_outputs(args: &RegisterArgs, config: &RegistrationConfig) -> Result<(), CliError> {
    if let Some(path) = &args.plot {
        PlotFormat::of(path).map_err(CliError::new)?;
        if config.cost != CostFunction::Sie {
            return Err(CliError::new(format!(
                "--plot draws SIE's fitted histogram; --cost {} fits none",
                args.cost.name()
            )));
        }
    }
    if let Some(path) = args.aligned.as_deref() {
        if !CloudFormat::from_path(path).is_some_and(CloudFormat::is_writable) {
            let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("");
            return Err(CliError::new(format!(
                "{}: --aligned writes .pcd, .xyz or .txt, not {:?}",
                path.display(),
                extension.to_ascii_lowercase()
            )));
        }
    }
    for path in [&args.output, &args.aligned, &args.plot].into_iter().flatten() {
        let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
        if let Some(parent) = parent.filter(|p| !p.is_dir()) {
            return Err(CliError::new(format!(
                "{}: cannot write: folder {} does not exist",
                path.display(),
                parent.display()
            )));
        }
    }
    Ok(())
}

/// A transform file made exactly rigid: rotation blocks within 1e-3 of orthonormal are
/// accepted (published ground truths are rounded to ~5e-5), anything else is an error naming
/// the file and the option.
fn rigid_file(path: &Path, option: &str) -> Result<Rigid, CliError> {
    let matrix = read_transform(path).map_err(|e| CliError::new(format!("{option}: {e}")))?;
    make_rigid(&matrix, &format!("{} ({option})", path.display())).map_err(CliError::new)
}

/// A reader error as one line, in this tool's terms: the library's hint names its API, and a
/// short binary payload surfaces as a bare I/O message.
fn input_error(message: String) -> CliError {
    CliError::new(
        message
            .replace("(NonFinite::Skip)", "with --skip-invalid")
            .replace(
                "I/O error: failed to fill whole buffer",
                "the file ends early (truncated)",
            ),
    )
}

fn cloud_report(path: &Path, cloud: &CloudFile, skip_origin: bool) -> CloudReport {
    CloudReport {
        path: path.display().to_string(),
        points: cloud.points.len(),
        skipped_non_finite: cloud.skipped_non_finite,
        skipped_origin: match skip_origin {
            true => cloud.points.iter().filter(|p| **p == [0.0; 3]).count(),
            false => 0,
        },
        warnings: cloud.warnings.clone(),
    }
}

fn metric_name(metric: Metric) -> &'static str {
    match metric {
        Metric::PointToPlane => "point-to-plane",
        Metric::PointToPoint => "point-to-point",
    }
}

/// Unit of SIE's σ and of the histogram axis.
fn units(config: &RegistrationConfig) -> &'static str {
    match config.noise {
        NoiseModel::Constant => "input units",
        NoiseModel::QuadraticDepth => "noise-normalised units",
    }
}

fn method_description(args: &RegisterArgs, config: &RegistrationConfig) -> String {
    let cost = match config.cost {
        CostFunction::Sie => "SIE".to_string(),
        CostFunction::L2 => "L2".to_string(),
        other => format!("{} {}", args.cost.name(), significant(other.parameter())),
    };
    let mut parts = vec![cost, metric_name(config.metric).to_string()];
    parts.push(match config.noise {
        NoiseModel::Constant => "constant noise".into(),
        NoiseModel::QuadraticDepth => "noise ∝ depth²".into(),
    });
    if config.cost == CostFunction::Sie {
        match config.sie.shape_exponent {
            NoiseShape::Fixed(2.0) => {}
            NoiseShape::Fixed(p) => parts.push(format!("noise shape p = {p}")),
            NoiseShape::Estimated => parts.push("noise shape estimated".into()),
        }
        if config.sie.histogram == HistogramMode::PerColumn {
            parts.push("one histogram per component".into());
        }
    }
    if config.max_correspondences > 0 {
        parts.push(format!(
            "at most {} matches per iteration",
            config.max_correspondences
        ));
    }
    parts.join(", ")
}

/// Title, x-axis label and per-panel captions of the `--plot` figure.
fn plot_text(
    args: &RegisterArgs,
    config: &RegistrationConfig,
    result: &RegistrationResult,
) -> (String, String, Vec<String>) {
    let file_name = |p: &Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| p.display().to_string())
    };
    let title = format!(
        "{} onto {}: residuals at the result ({}, {} iterations, inlier fraction {:.2})",
        file_name(&args.source),
        file_name(&args.target),
        metric_name(config.metric),
        result.iterations,
        result.inlier_fraction
    );
    let pooled = config.sie.histogram == HistogramMode::Pooled;
    let quantity = match (config.metric, pooled) {
        (Metric::PointToPlane, true) => "|point-to-plane residual|",
        (Metric::PointToPlane, false) => "point-to-plane residual",
        (Metric::PointToPoint, true) => "|residual component| (x, y and z pooled)",
        (Metric::PointToPoint, false) => "residual component",
    };
    let x_label = format!("{quantity} ({})", units(config));
    let captions = if result.histograms.len() > 1 {
        ["x", "y", "z"]
            .iter()
            .take(result.histograms.len())
            .map(|axis| format!("component {axis}"))
            .collect()
    } else {
        Vec::new()
    };
    (title, x_label, captions)
}

/// Writes the source cloud moved into the target frame, normals rotated along.
fn write_aligned(
    path: &Path,
    source: &CloudFile,
    t: &Matrix4<f64>,
    encoding: PcdEncoding,
) -> Result<(), String> {
    let points: Vec<Point> = source.points.iter().map(|p| transform_point(t, p)).collect();
    let rotation = rotation_part(t);
    let normals: Option<Vec<Point>> = source.normals.as_ref().map(|normals| {
        normals
            .iter()
            .map(|n| {
                let r = rotation * vector(n);
                [r.x, r.y, r.z]
            })
            .collect()
    });
    write_cloud(path, &points, normals.as_deref(), encoding)
}
