//! Reproduces the paper's experiments (docs/results.md): the simulation grid of §6, the
//! appendix (Laplacian / Gaussian noise, SIE with p = 2, 1 and estimated) and a real-scan table
//! in place of the TUM table; writes CSV files, SVG figures and the generated sections of
//! docs/results.md.
//!
//! ```text
//! cargo run --release --example experiments -- [PART ...] [OPTIONS]
//!   PART        grid | appendix | scans | figures | all (default: all), or variants
//!               (SIE settings on the hard cells, not part of all)
//!   --instances N   instances per simulation cell (default 100, the paper's)
//!   --threads N     worker threads (default: all cores)
//!   --out DIR       CSV folder (default results)
//!   --figures DIR   SVG folder (default docs/figures)
//!   --doc FILE      document whose generated sections are filled in (default docs/results.md;
//!                   "-" leaves it alone)
//!   --data DIR      real scans (default $SIE_DATA_DIR or ../shared/data)
//!   --method KEY    scans: run only this method (its CSV key, e.g. sie), to check a change
//! ```
//! Every random draw is seeded, so a rerun gives the same numbers (timings aside).
#[path = "experiments/beyond.rs"]
mod beyond;
#[path = "experiments/plots.rs"]
mod plots;
#[path = "experiments/report.rs"]
mod report;
#[path = "experiments/scans.rs"]
mod scans;
#[path = "experiments/simulation.rs"]
mod simulation;
#[path = "experiments/variants.rs"]
mod variants;

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use report::{duration, replace_section, sci, table, write_csv};
use scans::{PairCase, ScanRun};
use sie::{GammaRule, Hooks, register_clouds, register_correspondences};
use simulation::{
    Cell, CellStats, Method, Motion, NOISE_SIGMA, Noise, OUTLIER_LEVELS, STEPS, VerdictTally,
    appendix_methods, grid_cells, instance, instance_seed, paper_methods, run_cell,
};

struct Options {
    parts: Vec<String>,
    instances: usize,
    threads: usize,
    out: PathBuf,
    figures: PathBuf,
    doc: Option<PathBuf>,
    data: PathBuf,
    /// Scans: only the method with this CSV key.
    method: Option<String>,
    /// The command line, recorded in the document.
    command: String,
}

fn parse_options() -> Result<Options, String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut options = Options {
        parts: Vec::new(),
        instances: 100,
        threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        out: PathBuf::from("results"),
        figures: PathBuf::from("docs/figures"),
        doc: Some(PathBuf::from("docs/results.md")),
        data: std::env::var_os("SIE_DATA_DIR").map_or_else(|| PathBuf::from("../shared/data"), PathBuf::from),
        method: None,
        command: format!(
            "cargo run --release --example experiments --{}",
            args.iter().map(|a| format!(" {a}")).collect::<String>()
        ),
    };
    let mut it = args.into_iter();
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or_else(|| format!("{name} needs a value"));
        match arg.as_str() {
            "--instances" => {
                options.instances = value("--instances")?
                    .parse()
                    .map_err(|_| "--instances takes a positive integer".to_string())?
            }
            "--threads" => {
                options.threads = value("--threads")?
                    .parse()
                    .map_err(|_| "--threads takes a positive integer".to_string())?
            }
            "--out" => options.out = value("--out")?.into(),
            "--figures" => options.figures = value("--figures")?.into(),
            "--doc" => {
                let v = value("--doc")?;
                options.doc = (v != "-").then(|| v.into());
            }
            "--data" => options.data = value("--data")?.into(),
            "--method" => options.method = Some(value("--method")?),
            "grid" | "beyond" | "appendix" | "scans" | "figures" | "variants" => options.parts.push(arg),
            "all" => options
                .parts
                .extend(["grid", "beyond", "appendix", "scans", "figures"].map(String::from)),
            "-h" | "--help" => {
                println!(
                    "{}",
                    include_str!("experiments.rs")
                        .lines()
                        .take(18)
                        .map(|l| l.trim_start_matches("//!"))
                        .collect::<Vec<_>>()
                        .join("\n")
                );
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument {other:?} (try --help)")),
        }
    }
    if options.parts.is_empty() {
        options
            .parts
            .extend(["grid", "beyond", "appendix", "scans", "figures"].map(String::from));
    }
    if options.instances == 0 || options.threads == 0 {
        return Err("--instances and --threads must be >= 1".into());
    }
    Ok(options)
}

fn main() {
    let options = match parse_options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("experiments: {e}");
            std::process::exit(2);
        }
    };
    if let Err(e) = run(&options) {
        eprintln!("experiments: {e}");
        std::process::exit(1);
    }
}

fn run(options: &Options) -> Result<(), String> {
    for dir in [&options.out, &options.figures] {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let machine = report::machine();
    eprintln!("machine: {machine}");
    for part in &options.parts {
        let start = Instant::now();
        let section = match part.as_str() {
            "grid" => grid(options)?,
            "beyond" => beyond_grid(options)?,
            "appendix" => appendix(options)?,
            "scans" => scan_table(options)?,
            "figures" => figure_one(options)?,
            "variants" => variants(options)?,
            _ => unreachable!("parsed above"),
        };
        let wall = start.elapsed().as_secs_f64();
        eprintln!("[{part}] done in {}", duration(wall));
        if let Some(doc) = &options.doc {
            let provenance = format!(
                "_Generated by `{}` (part `{part}`, {} worker threads) on {machine}; wall time {}._\n\n",
                options.command,
                options.threads,
                duration(wall)
            );
            replace_section(doc, part, &(provenance + &section))?;
        }
    }
    Ok(())
}

/// Progress on stderr: one line per finished unit, and a live counter on a terminal.
struct Progress {
    what: String,
    total: usize,
    done: AtomicUsize,
    start: Instant,
    live: bool,
    /// Serialises the stderr lines of several workers.
    lock: Mutex<()>,
}

impl Progress {
    fn new(what: &str, total: usize) -> Self {
        Progress {
            what: what.into(),
            total,
            done: AtomicUsize::new(0),
            start: Instant::now(),
            live: std::io::stderr().is_terminal(),
            lock: Mutex::new(()),
        }
    }

    /// One more unit done; `note` is printed with the count, elapsed time and ETA.
    fn step(&self, note: &str) {
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        let elapsed = self.start.elapsed().as_secs_f64();
        let eta = elapsed / done as f64 * (self.total - done) as f64;
        let _guard = self.lock.lock();
        eprintln!(
            "[{}] {done}/{} {note} — elapsed {}, ETA {}",
            self.what,
            self.total,
            duration(elapsed),
            duration(eta)
        );
    }

    fn tick(&self, note: &str, done: usize, total: usize) {
        if self.live {
            let _guard = self.lock.lock();
            eprint!("\r[{}] {note}: {done}/{total} instances   \r", self.what);
        }
    }
}

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

/// Cell text: failure percentage and mean error of the non-failures.
/// One line on how SIE's quality verdict matched its outcomes over `runs` runs.
fn verdict_line(what: &str, t: &VerdictTally) -> String {
    let right = t.right_good + t.right_not_good;
    let wrong = t.wrong_good + t.wrong_not_good;
    let rate = |n: usize, of: usize| {
        if of == 0 {
            "–".to_string()
        } else {
            format!("{:.1} %", 100.0 * n as f64 / of as f64)
        }
    };
    format!(
        "SIE's quality verdict on {what}: {right} right runs, {} called GOOD, {} not (false \"bad\": {}); \
         {wrong} wrong runs, {} called GOOD (false \"good\": {}), {} of them more than 5× the failure bound off.\n",
        t.right_good,
        t.right_not_good,
        rate(t.right_not_good, right),
        t.wrong_good,
        rate(t.wrong_good, wrong),
        t.far_wrong_good
    )
}

fn cell_text(s: &CellStats) -> String {
    format!("{:.0} · {}", 100.0 * s.failure_rate(), sci(s.mean_error))
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

fn file_name(path: &Path) -> String {
    path.file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
}

fn grid(options: &Options) -> Result<String, String> {
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
fn beyond_grid(options: &Options) -> Result<String, String> {
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

fn appendix(options: &Options) -> Result<String, String> {
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

fn scan_table(options: &Options) -> Result<String, String> {
    eprintln!("[scans] loading {}", options.data.display());
    let (mut cases, left_out) = scans::bunny_pairs(&options.data)?;
    cases.push(scans::lidar_pair(&options.data)?);
    cases.push(scans::room_pair(&options.data)?);
    cases.extend(scans::depth_pairs(&options.data)?);
    // Jobs: every case × start × method; the large LiDAR jobs go first so the two workers
    // finish together.
    let mut jobs = Vec::new();
    let mut starts = Vec::new();
    for (c, case) in cases.iter().enumerate() {
        let case_starts = case.starts(c as u64);
        for (s, _) in case_starts.iter().enumerate() {
            for (m, method) in case.methods().iter().enumerate() {
                if options.method.as_deref().is_none_or(|key| key == method.key) {
                    jobs.push((c, s, m));
                }
            }
        }
        starts.push(case_starts);
    }
    jobs.sort_by_key(|&(c, _, _)| {
        std::cmp::Reverse(cases[c].source.len().max(cases[c].target.len()) > 50_000)
    });
    let progress = Progress::new("scans", jobs.len());
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<ScanRun>> = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..options.threads {
            scope.spawn(|| {
                loop {
                    let j = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&(c, s, m)) = jobs.get(j) else { break };
                    let run = run_scan(&cases[c], c, &starts[c][s], m);
                    let note = format!(
                        "{} {} [{}] {}: {:.3}° / {:.4} m",
                        cases[c].settings.name,
                        cases[c].label(),
                        run.start,
                        cases[c].methods()[m].label,
                        run.rotation_degrees,
                        run.translation
                    );
                    results.lock().expect("no worker panicked").push(run);
                    progress.step(&note);
                }
            });
        }
    });
    let mut runs = results.into_inner().expect("no worker panicked");
    runs.sort_by_key(|r| (r.case, r.start.clone(), r.method));
    scan_csv(&options.out.join("scans.csv"), &cases, &runs)?;
    Ok(scan_report(&cases, &runs, &left_out))
}

fn run_scan(
    case: &PairCase,
    index: usize,
    start: &(String, nalgebra::Matrix4<f64>),
    method: usize,
) -> ScanRun {
    let methods = case.methods();
    let config = &methods[method].config;
    let began = Instant::now();
    let result = register_clouds(
        &case.source,
        &case.target,
        None,
        Some(&start.1),
        config,
        Hooks::default(),
    )
    .expect("scan input is valid");
    let errors = case.errors(&result.transform);
    ScanRun {
        case: index,
        start: start.0.clone(),
        method,
        rotation_degrees: errors.0,
        translation: errors.1,
        success: case.success(errors),
        far_off: case.far_off(errors),
        called_good: result.quality.verdict == sie::Verdict::Good,
        converged: result.converged,
        iterations: result.iterations,
        seconds: began.elapsed().as_secs_f64(),
        sigma: result.sigma.first().copied().unwrap_or(f64::NAN),
        quality: result.quality,
    }
}

fn scan_csv(path: &Path, cases: &[PairCase], runs: &[ScanRun]) -> Result<(), String> {
    let rows: Vec<Vec<String>> = runs
        .iter()
        .map(|r| {
            let case = &cases[r.case];
            vec![
                case.settings.name.to_string(),
                case.source_name.clone(),
                case.target_name.clone(),
                r.start.clone(),
                case.methods()[r.method].key.to_string(),
                format!("{:.5}", r.rotation_degrees),
                format!("{:.6}", r.translation),
                (r.success as u8).to_string(),
                (r.converged as u8).to_string(),
                r.iterations.to_string(),
                format!("{:.3}", r.seconds),
                format!("{:.6e}", r.sigma),
                format!("{:?}", r.quality.verdict),
                format!("{:.4e}", r.quality.significance),
                format!("{:.4e}", r.quality.conditioning),
                format!("{:.4e}", r.quality.sigma_to_spacing),
                format!("{:.4e}", r.quality.margin),
            ]
        })
        .collect();
    write_csv(
        path,
        &[
            "dataset",
            "source",
            "target",
            "start",
            "method",
            "rotation_error_deg",
            "translation_error_m",
            "success",
            "converged",
            "iterations",
            "seconds",
            "sigma_or_scale",
            "verdict",
            "significance",
            "conditioning",
            "sigma_to_spacing",
            "margin",
        ],
        &rows,
    )
}

fn median(mut values: Vec<f64>) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

fn scan_report(cases: &[PairCase], runs: &[ScanRun], left_out: &[scans::LeftOut]) -> String {
    let methods = cases[0].methods();
    let mut out = String::new();
    // Settings per data set.
    out.push_str("#### Data sets and the baselines' scale\n\n");
    let mut seen = Vec::new();
    let mut rows = Vec::new();
    for case in cases {
        let s = &case.settings;
        if seen.contains(&s.name) {
            continue;
        }
        seen.push(s.name);
        rows.push(vec![
            s.name.to_string(),
            format!("{} m", s.sigma),
            s.sigma_reason.to_string(),
            format!("{:?}", s.noise),
            if s.max_correspondences == 0 {
                "all".into()
            } else {
                s.max_correspondences.to_string()
            },
            format!("{}°, {} m", s.perturbation_degrees, s.perturbation_translation),
            format!("< {}° and < {} m", s.success_degrees, s.success_translation),
        ]);
    }
    out.push_str(&table(
        &[
            "data set",
            "σ for baselines",
            "why",
            "noise scaling",
            "matches / iteration",
            "perturbation",
            "success",
        ]
        .map(String::from),
        &rows,
    ));
    out.push_str(
        "\nEvery case is point-to-plane ICP (target normals from 10-neighbour PCA), at most 200 updates.\n\n",
    );

    let mut header = vec!["data set".to_string(), "pair (overlap)".to_string()];
    header.extend(methods.iter().map(|m| m.label.to_string()));
    // Identity starts.
    let mut identity_rows = Vec::new();
    let mut perturbed_rows = Vec::new();
    for (c, case) in cases.iter().enumerate() {
        let unit = case.settings.unit;
        let pair = format!("{} ({:.0} %)", case.label(), 100.0 * case.overlap);
        let mut identity = vec![case.settings.name.to_string(), pair.clone()];
        let mut perturbed = identity.clone();
        for m in 0..methods.len() {
            let of: Vec<&ScanRun> = runs.iter().filter(|r| r.case == c && r.method == m).collect();
            let cell = |r: &&ScanRun| {
                let mark = if r.success { "" } else { " ✗" };
                format!(
                    "{:.2}° / {:.1} {}{mark}",
                    r.rotation_degrees,
                    r.translation / unit.1,
                    unit.0
                )
            };
            identity.push(of.iter().find(|r| r.start == "identity").map_or("–".into(), cell));
            let moved: Vec<&&ScanRun> = of.iter().filter(|r| r.start != "identity").collect();
            let ok = moved.iter().filter(|r| r.success).count();
            perturbed.push(format!(
                "{ok}/{} · {:.2}° / {:.1} {}",
                moved.len(),
                median(moved.iter().map(|r| r.rotation_degrees).collect()),
                median(moved.iter().map(|r| r.translation).collect()) / unit.1,
                unit.0
            ));
        }
        identity_rows.push(identity);
        perturbed_rows.push(perturbed);
    }
    out.push_str("#### From the identity: rotation / translation error against the ground truth (✗ = not within the success bounds)\n\n");
    out.push_str(&table(&header, &identity_rows));
    out.push_str(&format!(
        "\n#### From {} perturbed starts: successes · median rotation / translation error\n\n",
        scans::PERTURBED_STARTS
    ));
    out.push_str(&table(&header, &perturbed_rows));
    // Success counts per method over everything.
    let mut totals = vec!["all cases".to_string(), "successes".to_string()];
    for m in 0..methods.len() {
        let of: Vec<&ScanRun> = runs.iter().filter(|r| r.method == m).collect();
        totals.push(format!(
            "{}/{}",
            of.iter().filter(|r| r.success).count(),
            of.len()
        ));
    }
    out.push_str(&table(&header, &[totals]));
    // Successes per data set, and how SIE's verdict matched its outcomes there.
    let mut names: Vec<&str> = Vec::new();
    for case in cases {
        if !names.contains(&case.settings.name) {
            names.push(case.settings.name);
        }
    }
    let mut success_header = vec!["data set".to_string()];
    success_header.extend(methods.iter().map(|m| m.label.to_string()));
    let mut success_rows = Vec::new();
    let mut verdict_rows = Vec::new();
    let mut all = VerdictTally::default();
    for name in &names {
        let of_set = |m: usize| -> Vec<&ScanRun> {
            runs.iter()
                .filter(|r| r.method == m && cases[r.case].settings.name == *name)
                .collect()
        };
        let mut row = vec![name.to_string()];
        for m in 0..methods.len() {
            let set = of_set(m);
            row.push(format!(
                "{}/{}",
                set.iter().filter(|r| r.success).count(),
                set.len()
            ));
        }
        success_rows.push(row);
        let mut tally = VerdictTally::default();
        for r in of_set(0) {
            tally.add(r.success, r.far_off, r.called_good);
        }
        all.merge(&tally);
        verdict_rows.push(vec![
            name.to_string(),
            tally.right_good.to_string(),
            tally.right_not_good.to_string(),
            tally.wrong_good.to_string(),
            tally.far_wrong_good.to_string(),
            tally.wrong_not_good.to_string(),
        ]);
    }
    out.push_str("\n#### Successes per data set (both starts)\n\n");
    out.push_str(&table(&success_header, &success_rows));
    out.push_str("\n#### SIE's quality verdict against the outcome\n\n");
    out.push_str(&table(
        &[
            "data set",
            "right, GOOD",
            "right, not GOOD (false bad)",
            "wrong, GOOD (false good)",
            "of those > 5× the bound off",
            "wrong, not GOOD",
        ]
        .map(String::from),
        &verdict_rows,
    ));
    out.push('\n');
    out.push_str(&verdict_line("the real scans", &all));
    if !left_out.is_empty() {
        let list: Vec<String> = left_out
            .iter()
            .map(|(p, o)| format!("{p} ({:.0} %)", 100.0 * o))
            .collect();
        out.push_str(&format!(
            "\nStanford pairs left out for overlap below {:.0} % (share of source points within {} mm of the target at the ground truth): {}.\n",
            100.0 * scans::MIN_OVERLAP,
            scans::OVERLAP_DISTANCE * 1000.0,
            list.join(", ")
        ));
    }
    out.push_str("\nCSV (every run, with iterations, time and SIE's σ): `results/scans.csv`.\n");
    out
}

/// Fig. 1 (right): the last histogram, fitted model and P(inlier | r) of one simulation
/// registration and one real-scan registration.
fn figure_one(options: &Options) -> Result<String, String> {
    let mut section = String::new();
    let t0 = Motion::Translation.initial_transform(5);
    // Instance 1 is typical; instance 0 is the one instance of the 1000-outlier set where σ
    // settles at about half the truth (see the grid's max errors), drawn to show why.
    for (index, stem, what) in [
        (1, "fig1-simulation", "typical instance"),
        (0, "fig1-simulation-low-sigma", "the instance whose σ settles low"),
    ] {
        let data = instance(
            Noise::Gaussian,
            1000,
            &t0,
            instance_seed(Noise::Gaussian, 1000, index),
        );
        let reference = simulation::Reference::new(&data, Noise::Gaussian.metric());
        let config = paper_methods(NOISE_SIGMA).remove(0).config;
        let result = register_correspondences(&data.source, &data.target, None, &config, Hooks::default())
            .map_err(|e| e.to_string())?;
        let path = options.figures.join(format!("{stem}.svg"));
        plots::histogram_figure(
            &path,
            &format!("SIE, 1000 inliers + 1000 outliers, T0 = 0.5 along x, {what}: last iteration"),
            "|r| per axis, pooled over x, y, z",
            &result.histograms[0],
        )?;
        section.push_str(&format!(
            "![{stem}](figures/{})\n\nSimulation instance {index} (1000 inliers, 1000 outliers, T0 = 0.5 along x), {what}: σ = {:.4} (true 0.01), inlier fraction {:.3} (true 0.500), error above T_MLE {:.1e}, {} updates.\n\n",
            file_name(&path),
            result.sigma[0],
            result.inlier_fraction,
            reference.error(&result.transform),
            result.iterations
        ));
    }
    let (cases, _) = scans::bunny_pairs(&options.data)?;
    let case = cases
        .iter()
        .find(|c| c.source_name == "bun045" && c.target_name == "bun000")
        .ok_or("bun045 → bun000 is not among the overlapping pairs")?;
    let config = case.methods().remove(0).config;
    let result = register_clouds(&case.source, &case.target, None, None, &config, Hooks::default())
        .map_err(|e| e.to_string())?;
    let errors = case.errors(&result.transform);
    let path = options.figures.join("fig1-bunny.svg");
    plots::histogram_figure(
        &path,
        "SIE, Stanford bun045 → bun000 from the identity: last iteration",
        "|point-to-plane residual| (m)",
        &result.histograms[0],
    )?;
    section.push_str(&format!(
        "![fig1-bunny](figures/{})\n\nbun045 → bun000 from the identity (34° apart): σ = {:.2e} m, inlier fraction {:.3}, error {:.3}° / {:.2} mm, {} updates.\n",
        file_name(&path),
        result.sigma[0],
        result.inlier_fraction,
        errors.0,
        errors.1 * 1000.0,
        result.iterations
    ));
    Ok(section)
}

/// SIE settings compared on the cells where the default fails (10 000 outliers, rotations
/// around π/2) and on cells it passes, to see whether a change helps and what it costs: two
/// library settings, and the annealing change of `variants.rs` next to the same minimal driver
/// without it.
fn variants(options: &Options) -> Result<String, String> {
    let base = paper_methods(NOISE_SIGMA).remove(0);
    let variant = |key: &'static str, label: &'static str, change: &dyn Fn(&mut sie::RegistrationConfig)| {
        let mut m = base.clone();
        m.key = key;
        m.label = label;
        change(&mut m.config);
        m
    };
    let methods = vec![
        variant("default", "library SIE (γ from P(I), β × 0.5)", &|_| {}),
        variant("gamma_one", "library, γ = 1", &|c| c.sie.gamma = GammaRule::One),
        variant("shrink_0.8", "library, β × 0.8", &|c| c.beta_shrink = 0.8),
    ];
    let custom: [(&str, bool); 2] = [
        ("minimal driver", false),
        ("minimal driver + hold σ jumps above σ+β", true),
    ];
    let mut cells = Vec::new();
    for step in [5, 6, 7] {
        cells.push(Cell {
            noise: Noise::Gaussian,
            outliers: 10_000,
            motion: Motion::Rotation,
            step,
        });
    }
    cells.push(Cell {
        noise: Noise::Gaussian,
        outliers: 10_000,
        motion: Motion::Translation,
        step: 10,
    });
    cells.push(Cell {
        noise: Noise::Gaussian,
        outliers: 1000,
        motion: Motion::Rotation,
        step: 10,
    });
    cells.push(Cell {
        noise: Noise::Gaussian,
        outliers: 100,
        motion: Motion::Translation,
        step: 10,
    });
    let progress = Progress::new("variants", cells.len());
    let mut rows: Vec<Vec<String>> = methods.iter().map(|m| vec![m.label.to_string()]).collect();
    rows.extend(custom.iter().map(|(label, _)| vec![label.to_string()]));
    for cell in &cells {
        let mut texts: Vec<String> = run_cell(cell, &methods, options.instances, options.threads, &|| {})
            .iter()
            .map(cell_text)
            .collect();
        for (_, hold) in custom {
            let stats = run_custom(cell, options.instances, options.threads, &|data| {
                variants::register(data, hold)
            });
            texts.push(cell_text(&stats));
        }
        progress.step(&format!(
            "{} outliers {} {}: {}",
            cell.outliers,
            cell.motion.name(),
            cell.motion.label(cell.step),
            texts.join(" | ")
        ));
        for (row, text) in rows.iter_mut().zip(texts) {
            row.push(text);
        }
    }
    let mut header = vec!["SIE setting".to_string()];
    header.extend(
        cells
            .iter()
            .map(|c| format!("{}, {} {}", c.outliers, c.motion.name(), c.motion.label(c.step))),
    );
    Ok(format!(
        "Failures (%) · mean error of the non-failures, {} instances per cell (the first {} of the grid's).\n\n{}",
        options.instances,
        options.instances,
        table(&header, &rows)
    ))
}

/// `register` on the first `instances` instances of `cell`, on `threads` threads.
fn run_custom(
    cell: &Cell,
    instances: usize,
    threads: usize,
    register: &(dyn Fn(&sie::synthetic::Correspondences) -> nalgebra::Matrix4<f64> + Sync),
) -> CellStats {
    let t0 = cell.motion.initial_transform(cell.step);
    let next = AtomicUsize::new(0);
    let trials = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    if index >= instances {
                        break;
                    }
                    let data = instance(
                        cell.noise,
                        cell.outliers,
                        &t0,
                        instance_seed(cell.noise, cell.outliers, index),
                    );
                    let reference = simulation::Reference::new(&data, cell.noise.metric());
                    let began = Instant::now();
                    let t = register(&data);
                    let trial = simulation::Trial {
                        error: reference.error(&t),
                        called_good: false,
                        converged: true,
                        iterations: 0,
                        seconds: began.elapsed().as_secs_f64(),
                    };
                    trials.lock().expect("no worker panicked").push(trial);
                }
            });
        }
    });
    CellStats::from_trials(&trials.into_inner().expect("no worker panicked"))
}
