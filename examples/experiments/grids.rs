//! Parts `grid`, `beyond` and `appendix`: grids of simulation cells, their CSV files, tables
//! and figures.
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::options::Options;
use crate::progress::Progress;
use crate::report::{cell_text, file_name, sci, table, verdict_line, write_csv};
use crate::simulation::{
    Cell, CellStats, Method, Motion, NOISE_SIGMA, Noise, OUTLIER_LEVELS, STEPS, VerdictTally,
    appendix_methods, grid_cells, paper_methods, run_cell,
};
use crate::{beyond, plots};

/// Aggregates of one grid: cells in `grid_cells` order, one `CellStats` per method.
struct GridResult {
    cells: Vec<Cell>,
    stats: Vec<Vec<CellStats>>,
}

fn run_grid(name: &str, noise: Noise, methods: &[Method], options: &Options) -> GridResult {
    let cells = grid_cells(noise);
    let progress = Progress::new(name, cells.len());
    let mut stats = Vec::new();
    for cell in &cells {
        let label = format!(
            "{} outliers, {} {}",
            cell.outliers,
            cell.motion.name(),
            cell.motion.label(cell.step)
        );
        let finished = AtomicUsize::new(0);
        let tick = || {
            let n = finished.fetch_add(1, Ordering::Relaxed) + 1;
            progress.tick(&label, n, options.instances);
        };
        let cell_stats = run_cell(cell, methods, options.instances, options.threads, &tick);
        let summary: Vec<String> = methods
            .iter()
            .zip(&cell_stats)
            .take(3)
            .map(|(m, s)| format!("{} {}/{}", m.label, s.failures, s.instances))
            .collect();
        progress.step(&format!("{label}: failures {}", summary.join(", ")));
        stats.push(cell_stats);
    }
    GridResult { cells, stats }
}

fn grid_csv(path: &Path, grid: &GridResult, methods: &[Method]) -> Result<(), String> {
    let mut rows = Vec::new();
    for (cell, stats) in grid.cells.iter().zip(&grid.stats) {
        for (method, s) in methods.iter().zip(stats) {
            rows.push(vec![
                cell.noise.name().to_string(),
                cell.outliers.to_string(),
                cell.motion.name().to_string(),
                format!("{:.6}", cell.motion.magnitude(cell.step)),
                method.key.to_string(),
                s.instances.to_string(),
                s.failures.to_string(),
                format!("{:.4e}", s.mean_error),
                format!("{:.4e}", s.max_error),
                s.not_converged.to_string(),
                format!("{:.1}", s.mean_iterations),
                format!("{:.3}", s.seconds),
            ]);
        }
    }
    write_csv(
        path,
        &[
            "noise",
            "outliers",
            "motion",
            "magnitude",
            "method",
            "instances",
            "failures",
            "mean_error_non_failures",
            "max_error_non_failures",
            "not_converged",
            "mean_iterations",
            "cpu_seconds",
        ],
        &rows,
    )
}

/// One table per outlier level and motion: methods × T0 steps.
fn grid_tables(grid: &GridResult, methods: &[Method]) -> String {
    let mut out = String::new();
    for outliers in OUTLIER_LEVELS {
        for motion in [Motion::Translation, Motion::Rotation] {
            let columns: Vec<usize> = (0..grid.cells.len())
                .filter(|&i| grid.cells[i].outliers == outliers && grid.cells[i].motion == motion)
                .collect();
            let mut header = vec![format!("{outliers} outliers, {}", motion.name())];
            header.extend(columns.iter().map(|&i| motion.label(grid.cells[i].step)));
            let rows: Vec<Vec<String>> = methods
                .iter()
                .enumerate()
                .map(|(m, method)| {
                    let mut row = vec![method.label.to_string()];
                    row.extend(columns.iter().map(|&i| cell_text(&grid.stats[i][m])));
                    row
                })
                .collect();
            out.push_str(&table(&header, &rows));
            out.push('\n');
        }
    }
    out
}

/// Per method and outlier level: failure rate over the translation cells, the rotation cells
/// up to π/2 and beyond, and the mean error over every non-failure of the level.
fn grid_summary(grid: &GridResult, methods: &[Method]) -> String {
    let mut header = vec!["method".to_string()];
    for outliers in OUTLIER_LEVELS {
        header.extend([
            format!("{outliers}: fail t ≤ 1"),
            format!("{outliers}: fail r ≤ π/2"),
            format!("{outliers}: fail r > π/2"),
            format!("{outliers}: mean error"),
        ]);
    }
    let half = (STEPS - 1) / 2;
    let rows: Vec<Vec<String>> = methods
        .iter()
        .enumerate()
        .map(|(m, method)| {
            let mut row = vec![method.label.to_string()];
            for outliers in OUTLIER_LEVELS {
                let pick = |keep: &dyn Fn(&Cell) -> bool| {
                    let (mut failures, mut instances, mut error_sum, mut good) = (0, 0, 0.0, 0usize);
                    for (cell, stats) in grid.cells.iter().zip(&grid.stats) {
                        if cell.outliers == outliers && keep(cell) {
                            let s = &stats[m];
                            failures += s.failures;
                            instances += s.instances;
                            let n = s.instances - s.failures;
                            if n > 0 {
                                error_sum += s.mean_error * n as f64;
                                good += n;
                            }
                        }
                    }
                    (failures, instances, error_sum, good)
                };
                let percent = |(f, n, _, _): (usize, usize, f64, usize)| {
                    format!("{:.1} %", 100.0 * f as f64 / n as f64)
                };
                row.push(percent(pick(&|c| c.motion == Motion::Translation)));
                row.push(percent(pick(&|c| c.motion == Motion::Rotation && c.step <= half)));
                row.push(percent(pick(&|c| c.motion == Motion::Rotation && c.step > half)));
                let (_, _, sum, good) = pick(&|_| true);
                row.push(if good > 0 {
                    sci(sum / good as f64)
                } else {
                    "–".into()
                });
            }
            row
        })
        .collect();
    table(&header, &rows)
}

/// Failure-ratio and mean-error figures of a grid, laid out like the paper's (rows:
/// translation, rotation; columns: outlier levels). Mean errors are left out where more than
/// half the instances failed, as in the paper.
fn grid_figures(
    grid: &GridResult,
    methods: &[Method],
    stem: &str,
    title: &str,
    options: &Options,
) -> Result<Vec<String>, String> {
    let mut failure_panels = Vec::new();
    let mut error_panels = Vec::new();
    for motion in [Motion::Translation, Motion::Rotation] {
        for outliers in OUTLIER_LEVELS {
            let indices: Vec<usize> = (0..grid.cells.len())
                .filter(|&i| grid.cells[i].outliers == outliers && grid.cells[i].motion == motion)
                .collect();
            let x_label = match motion {
                Motion::Translation => "initial translation along x",
                Motion::Rotation => "initial rotation about x (rad)",
            };
            let x_max = motion.magnitude(STEPS - 1);
            let make = |value: &dyn Fn(&CellStats) -> f64| -> Vec<plots::Series> {
                methods
                    .iter()
                    .enumerate()
                    .map(|(m, method)| plots::Series {
                        label: method.label.to_string(),
                        colour: plots::PALETTE[m % plots::PALETTE.len()],
                        points: indices
                            .iter()
                            .map(|&i| {
                                (
                                    grid.cells[i].motion.magnitude(grid.cells[i].step),
                                    value(&grid.stats[i][m]),
                                )
                            })
                            .collect(),
                    })
                    .collect()
            };
            let title = format!("1000 inliers, {outliers} outliers: {}", motion.name());
            failure_panels.push(plots::Panel {
                title: title.clone(),
                x_label: x_label.into(),
                x_range: (0.0, x_max),
                series: make(&|s| s.failure_rate()),
            });
            error_panels.push(plots::Panel {
                title,
                x_label: x_label.into(),
                x_range: (0.0, x_max),
                series: make(&|s| {
                    if s.failure_rate() > 0.5 {
                        f64::NAN
                    } else {
                        s.mean_error
                    }
                }),
            });
        }
    }
    let failures = options.figures.join(format!("{stem}-failures.svg"));
    let errors = options.figures.join(format!("{stem}-errors.svg"));
    plots::panel_grid(
        &failures,
        &format!("{title}: failure ratio (error > 0.01)"),
        3,
        &failure_panels,
        "failure ratio",
        plots::YAxis::Ratio,
    )?;
    plots::panel_grid(
        &errors,
        &format!("{title}: mean error of non-failures (shown where ≤ 50 % fail)"),
        3,
        &error_panels,
        "mean error",
        plots::YAxis::Log(1e-14, 1e-2),
    )?;
    Ok(vec![file_name(&failures), file_name(&errors)])
}

pub fn grid(options: &Options) -> Result<String, String> {
    let methods = paper_methods(NOISE_SIGMA);
    let result = run_grid("grid", Noise::Gaussian, &methods, options);
    grid_csv(&options.out.join("grid.csv"), &result, &methods)?;
    let figures = grid_figures(&result, &methods, "grid", "Simulation grid (§6)", options)?;
    let mut section = String::new();
    section.push_str("#### Summary per outlier level\n\n");
    section.push_str(&grid_summary(&result, &methods));
    section.push_str("\n#### Figures\n\n");
    for f in &figures {
        section.push_str(&format!("![{f}](figures/{f})\n\n"));
    }
    section.push_str("#### Every cell: failures (%) · mean error of the non-failures\n\n");
    section.push_str(&grid_tables(&result, &methods));
    let mut tally = VerdictTally::default();
    for cell in &result.stats {
        tally.merge(&cell[0].verdicts);
    }
    section.push('\n');
    section.push_str(&verdict_line("every instance of the grid", &tally));
    section.push_str("\nCSV: `results/grid.csv`.\n");
    Ok(section)
}

/// The "beyond the grid" table: every method on each family of `beyond::families()`.
pub fn beyond_grid(options: &Options) -> Result<String, String> {
    let methods = paper_methods(NOISE_SIGMA);
    let families = beyond::families();
    let progress = Progress::new("beyond", families.len());
    let mut header = vec!["family".to_string()];
    header.extend(methods.iter().map(|m| m.label.to_string()));
    let mut rows = Vec::new();
    let mut csv = Vec::new();
    let mut tally = VerdictTally::default();
    for family in &families {
        let label = family.label();
        let finished = AtomicUsize::new(0);
        let tick = || {
            let n = finished.fetch_add(1, Ordering::Relaxed) + 1;
            progress.tick(&label, n, options.instances);
        };
        let stats = beyond::run_family(family, &methods, options.instances, options.threads, &tick);
        tally.merge(&stats[0].verdicts);
        let mut row = vec![label.clone()];
        row.extend(stats.iter().map(cell_text));
        rows.push(row);
        for (method, s) in methods.iter().zip(&stats) {
            csv.push(vec![
                label.clone(),
                method.key.to_string(),
                s.instances.to_string(),
                s.failures.to_string(),
                format!("{:.4e}", s.mean_error),
                format!("{:.4e}", s.max_error),
                s.not_converged.to_string(),
                format!("{:.1}", s.mean_iterations),
                format!("{:.3}", s.seconds),
            ]);
        }
        progress.step(&format!(
            "{label}: failures SIE {}/{}, Cauchy {}/{}",
            stats[0].failures, stats[0].instances, stats[7].failures, stats[7].instances
        ));
    }
    write_csv(
        &options.out.join("beyond.csv"),
        &[
            "family",
            "method",
            "instances",
            "failures",
            "mean_error_non_failures",
            "max_error_non_failures",
            "not_converged",
            "mean_iterations",
            "cpu_seconds",
        ],
        &csv,
    )?;
    let mut section = String::from(
        "Failures (%) · mean error of the non-failures, per family (rows) and method (columns); \
         the same protocol, error and baseline scales as the grid.\n\n",
    );
    section.push_str(&table(&header, &rows));
    section.push('\n');
    section.push_str(&verdict_line("every instance of these families", &tally));
    section.push_str("\nCSV: `results/beyond.csv`.\n");
    Ok(section)
}

pub fn appendix(options: &Options) -> Result<String, String> {
    let methods = appendix_methods();
    let mut section = String::new();
    let mut csv_rows = Vec::new();
    for noise in [Noise::Laplacian, Noise::Gaussian] {
        let result = run_grid(&format!("appendix {}", noise.name()), noise, &methods, options);
        let path = options.out.join(format!("appendix-{}.csv", noise.name()));
        grid_csv(&path, &result, &methods)?;
        csv_rows.push(format!("`results/appendix-{}.csv`", noise.name()));
        let title = match noise {
            Noise::Laplacian => "Appendix, Laplacian noise",
            Noise::Gaussian => "Appendix, Gaussian noise",
        };
        let figures = grid_figures(
            &result,
            &methods,
            &format!("appendix-{}", noise.name()),
            title,
            options,
        )?;
        let metric = match noise {
            Noise::Laplacian => "mean-absolute-error above T_MLE (the Σ‖r‖ minimiser)",
            Noise::Gaussian => "RMS error above T_MLE (least squares)",
        };
        section.push_str(&format!("#### {title} (error: {metric})\n\n"));
        section.push_str(&grid_summary(&result, &methods));
        section.push('\n');
        for f in &figures {
            section.push_str(&format!("![{f}](figures/{f})\n\n"));
        }
        section.push_str("Every cell: failures (%) · mean error of the non-failures\n\n");
        section.push_str(&grid_tables(&result, &methods));
    }
    section.push_str(&format!("CSV: {}.\n", csv_rows.join(", ")));
    Ok(section)
}
