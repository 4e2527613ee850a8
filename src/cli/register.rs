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
    CloudReport, GroundTruthError, JsonReport, POSE_PERTURBATION, SummaryContext, TraceRow, format_transform,
    json_stop_reason, matrix6_rows, pose_error, quality_report, search_row, significant, summary,
    transform_rows,
};
use super::{CliError, exit};

pub fn run(args: &RegisterArgs) -> Result<u8, CliError> {
    let config = args.config()?;
    check_outputs(args, &config)?;
    // The live table would interleave with nothing useful in JSON mode; there the trace goes
    // into the report.
    let mut progress = Progress::new(args.trace && !args.json, args.quiet, config.max_iterations);
    let inputs = read_inputs(args, &mut progress)?;
    let registered = register_with_progress(args, &config, &inputs, &mut progress)?;
    // Files first, so a failed write is the last thing the user reads; the result is printed
    // either way.
    let written = write_outputs(args, &config, &inputs, &registered);
    print_report(args, &config, &inputs, &registered, &written)?;
    written.report_failures()?;
    Ok(exit_code(&config, &registered.result))
}

/// What the command reads before registering.
struct Inputs {
    /// `--init` or `--init-pose`.
    init: Option<Rigid>,
    /// `--ground-truth`.
    truth: Option<Rigid>,
    source: CloudFile,
    target: CloudFile,
    /// The target file's normals, taken from it with `--file-normals`; else estimated.
    target_normals: Option<Vec<Point>>,
    /// Time spent reading the two clouds.
    read_seconds: f64,
}

/// A finished registration and its time (reading excluded).
struct Registered {
    result: RegistrationResult,
    seconds: f64,
}

/// The outputs written, and the messages of those that could not be.
#[derive(Default)]
struct WrittenFiles {
    paths: Vec<String>,
    errors: Vec<String>,
}

impl WrittenFiles {
    fn record(&mut self, path: &Path, outcome: Result<(), String>) {
        match outcome {
            Ok(()) => self.paths.push(path.display().to_string()),
            Err(message) => self.errors.push(message),
        }
    }

    /// Every failed write: the others on stderr, then the first as the command's error.
    fn report_failures(&self) -> Result<(), CliError> {
        let Some(first) = self.errors.first() else {
            return Ok(());
        };
        for message in &self.errors[1..] {
            eprintln!("sie: {message}");
        }
        Err(CliError::new(first))
    }
}

/// Reads the guesses (noting any visible rounding) and the two clouds (saying what the files
/// hold beyond what they declare).
fn read_inputs(args: &RegisterArgs, progress: &mut Progress) -> Result<Inputs, CliError> {
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

    let read_start = Instant::now();
    let policy = if args.skip_invalid {
        NonFinite::Skip
    } else {
        NonFinite::Reject
    };
    progress.note(&format!("reading {}", args.source.display()));
    let source = read_cloud_with(&args.source, policy).map_err(input_error)?;
    progress.note(&format!("reading {}", args.target.display()));
    let mut target = read_cloud_with(&args.target, policy).map_err(input_error)?;
    // Data the files hold beyond what they declare is said even with -q: it was not read.
    for (path, cloud) in [(&args.source, &source), (&args.target, &target)] {
        for warning in &cloud.warnings {
            eprintln!("sie: warning: {}: {warning}", path.display());
        }
    }
    let target_normals = if args.file_normals {
        let normals = target.normals.take().ok_or_else(|| {
            CliError::new(format!(
                "{}: --file-normals, but the file has no normal_x/y/z or nx/ny/nz fields",
                args.target.display()
            ))
        })?;
        Some(normals)
    } else {
        None
    };
    Ok(Inputs {
        init,
        truth,
        source,
        target,
        target_normals,
        read_seconds: read_start.elapsed().as_secs_f64(),
    })
}

/// Registers the source onto the target, with the live progress on stderr; Ctrl-C stops it
/// after the current iteration.
fn register_with_progress(
    args: &RegisterArgs,
    config: &RegistrationConfig,
    inputs: &Inputs,
    progress: &mut Progress,
) -> Result<Registered, CliError> {
    install_interrupt_handler();
    progress.note(match (config.metric, &inputs.target_normals) {
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
            &inputs.source.points,
            &inputs.target.points,
            inputs.target_normals.as_deref(),
            inputs.init.as_ref().map(|rigid| &rigid.transform),
            config,
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
    Ok(Registered {
        result,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// Writes the requested files (`-o`, `--aligned`, `--plot`); a failed one does not stop the
/// others.
fn write_outputs(
    args: &RegisterArgs,
    config: &RegistrationConfig,
    inputs: &Inputs,
    registered: &Registered,
) -> WrittenFiles {
    let result = &registered.result;
    let mut written = WrittenFiles::default();
    if let Some(path) = &args.output {
        let outcome = fs::write(path, format_transform(&result.transform, ""))
            .map_err(|e| format!("{}: cannot write: {e}", path.display()));
        written.record(path, outcome);
    }
    if let Some(path) = &args.aligned {
        let encoding = if args.aligned_ascii {
            PcdEncoding::Ascii
        } else {
            PcdEncoding::Binary
        };
        written.record(
            path,
            write_aligned(path, &inputs.source, &result.transform, encoding),
        );
    }
    if let Some(path) = &args.plot {
        let text = plot_text(args, config, result);
        let plot_text = PlotText {
            title: &text.title,
            x_label: &text.x_label,
            panel_captions: text.panel_captions,
        };
        written.record(path, write_plot(path, &result.histograms, &plot_text));
    }
    written
}

/// The result on stdout (the transform, or the JSON report with `--json`) and, unless `-q`,
/// the summary on stderr.
fn print_report(
    args: &RegisterArgs,
    config: &RegistrationConfig,
    inputs: &Inputs,
    registered: &Registered,
    written: &WrittenFiles,
) -> Result<(), CliError> {
    let Registered { result, seconds } = registered;
    let ground_truth = inputs.truth.map(|t| {
        let (rotation_error_deg, translation_error) = pose_error(&result.transform, &t.transform);
        GroundTruthError {
            rotation_error_deg,
            translation_error,
        }
    });
    let source_report = cloud_report(&args.source, &inputs.source, config.skip_origin);
    let target_report = cloud_report(&args.target, &inputs.target, config.skip_origin);
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
            seconds: *seconds,
            read_seconds: inputs.read_seconds,
            ground_truth,
            init_correction: inputs.init.map(|rigid| rigid.correction),
            ground_truth_correction: inputs.truth.map(|rigid| rigid.correction),
            quality: quality_report(result),
            search: search_row(result),
            covariance: matrix6_rows(&result.uncertainty.covariance),
            information: matrix6_rows(&result.uncertainty.information),
            pose_perturbation: POSE_PERTURBATION,
            trace: result.trace.iter().map(TraceRow::from).collect(),
        };
        let json = serde_json::to_string_pretty(&report).map_err(CliError::new)?;
        println!("{json}");
    } else {
        print!("{}", format_transform(&result.transform, ""));
    }
    if !args.quiet {
        let context = SummaryContext {
            source: &source_report,
            target: &target_report,
            method: method_description(args, config),
            target_note: match (config.metric, &inputs.target_normals) {
                (Metric::PointToPoint, _) => "point-to-point".into(),
                (Metric::PointToPlane, Some(_)) => "normals from the file".into(),
                (Metric::PointToPlane, None) => {
                    format!("normals from {} neighbours", config.normal_neighbours)
                }
            },
            units: units(config),
            seconds: *seconds,
            read_seconds: inputs.read_seconds,
            ground_truth,
            judged: config.cost == CostFunction::Sie,
            written: written.paths.clone(),
        };
        eprint!("{}", summary(result, &context));
    }
    Ok(())
}

/// The exit code for a registration that ran to its end (see [`exit`]).
fn exit_code(config: &RegistrationConfig, result: &RegistrationResult) -> u8 {
    match result.stop_reason {
        // The verdict judges SIE's fitted noise model; a baseline cost has none (L2) or the
        // caller's scale, so its verdict does not set the exit code.
        StopReason::Converged if config.cost != CostFunction::Sie => exit::CONVERGED,
        StopReason::Converged if result.quality.verdict == Verdict::Good => exit::CONVERGED,
        StopReason::Converged => exit::NOT_GOOD,
        StopReason::IterationLimit | StopReason::Degenerate => exit::NOT_CONVERGED,
        StopReason::Cancelled => exit::CANCELLED,
    }
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
        repeated: repeated_points(&cloud.points, skip_origin),
        warnings: cloud.warnings.clone(),
    }
}

/// Kept points (finite, and not 0 0 0 under `--skip-origin`) that repeat an earlier one
/// exactly (−0.0 equals 0.0), as the registration groups them.
fn repeated_points(points: &[Point], skip_origin: bool) -> usize {
    let kept = points
        .iter()
        .filter(|p| p.iter().all(|c| c.is_finite()) && !(skip_origin && **p == [0.0; 3]));
    let mut seen = std::collections::HashSet::with_capacity(points.len());
    kept.filter(|p| !seen.insert(p.map(|c| (c + 0.0).to_bits())))
        .count()
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
        match config.sie.noise_shape {
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

/// The `--plot` figure's text, owned ([`PlotText`] borrows it).
struct PlotCaptions {
    title: String,
    x_label: String,
    panel_captions: Vec<String>,
}

/// Title, x-axis label and per-panel captions of the `--plot` figure.
fn plot_text(args: &RegisterArgs, config: &RegistrationConfig, result: &RegistrationResult) -> PlotCaptions {
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
    PlotCaptions {
        title,
        x_label,
        panel_captions: captions,
    }
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
