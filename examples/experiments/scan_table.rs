//! Part `scans`: every method on the real scan pairs, from the identity and perturbed starts.
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use sie::{Hooks, Starts, register_clouds};

use crate::options::Options;
use crate::progress::Progress;
use crate::report::{table, verdict_line, write_csv};
use crate::scans::{self, PairCase, ScanRun};
use crate::simulation::VerdictTally;

pub fn scan_table(options: &Options) -> Result<String, String> {
    let (cases, left_out) = load_cases(options)?;
    let runs = run_jobs(options, &cases, None);
    scan_csv(&options.out.join("scans.csv"), &cases, &runs)?;
    Ok(scan_report(&cases, &runs, &left_out))
}

/// Part `scans-one-start`: SIE alone on the same pairs and starts, one start run
/// (`Starts::InitialGuess`, as the PCL adapter and odometry run it), judged like the table.
pub fn one_start_table(options: &Options) -> Result<String, String> {
    let (cases, _) = load_cases(options)?;
    let runs = run_jobs(options, &cases, Some(Starts::InitialGuess));
    scan_csv(&options.out.join("scans-one-start.csv"), &cases, &runs)?;
    Ok(one_start_report(&cases, &runs))
}

fn load_cases(options: &Options) -> Result<(Vec<PairCase>, Vec<scans::LeftOut>), String> {
    eprintln!("[scans] loading {}", options.data.display());
    let (mut cases, left_out) = scans::bunny_pairs(&options.data)?;
    cases.push(scans::lidar_pair(&options.data)?);
    cases.push(scans::room_pair(&options.data)?);
    cases.extend(scans::depth_pairs(&options.data)?);
    Ok((cases, left_out))
}

/// Every case × start × method (only SIE when `one_start` is given, run with those starts).
fn run_jobs(options: &Options, cases: &[PairCase], one_start: Option<Starts>) -> Vec<ScanRun> {
    let wanted = |key: &str| match one_start {
        Some(_) => key == "sie",
        None => options.method.as_deref().is_none_or(|k| k == key),
    };
    // The large LiDAR jobs go first so the two workers finish together.
    let mut jobs = Vec::new();
    let mut starts = Vec::new();
    for (c, case) in cases.iter().enumerate() {
        let case_starts = case.starts(c as u64);
        for (s, _) in case_starts.iter().enumerate() {
            for (m, method) in case.methods().iter().enumerate() {
                if wanted(method.key) {
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
                    let run = run_scan(&cases[c], c, &starts[c][s], m, one_start);
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
    runs
}

fn run_scan(
    case: &PairCase,
    index: usize,
    start: &(String, nalgebra::Matrix4<f64>),
    method: usize,
    one_start: Option<Starts>,
) -> ScanRun {
    let methods = case.methods();
    let mut config = methods[method].config.clone();
    if let Some(starts) = one_start {
        config.starts = starts;
    }
    let began = Instant::now();
    let result = register_clouds(
        &case.source,
        &case.target,
        None,
        Some(&start.1),
        &config,
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

/// The one-start table: SIE's outcomes and verdicts per data set, and every wrong run it called
/// GOOD.
fn one_start_report(cases: &[PairCase], runs: &[ScanRun]) -> String {
    let mut names: Vec<&str> = Vec::new();
    for case in cases {
        if !names.contains(&case.settings.name) {
            names.push(case.settings.name);
        }
    }
    let mut rows = Vec::new();
    let mut all = VerdictTally::default();
    for name in &names {
        let mut tally = VerdictTally::default();
        let set: Vec<&ScanRun> = runs
            .iter()
            .filter(|r| cases[r.case].settings.name == *name)
            .collect();
        for r in &set {
            tally.add(r.success, r.far_off, r.called_good);
        }
        all.merge(&tally);
        rows.push(vec![
            name.to_string(),
            format!("{}/{}", set.iter().filter(|r| r.success).count(), set.len()),
            tally.right_good.to_string(),
            tally.right_not_good.to_string(),
            tally.wrong_good.to_string(),
            tally.wrong_not_good.to_string(),
        ]);
    }
    let mut out = String::from(
        "SIE alone, `Starts::InitialGuess` (the paper's run from the guess, run once more from its result when it ended \
         more than 10σ from the guess beyond a local correction, then only its half and quarter turns and period shifts are tried, and a narrow β₀ from the guess when that far result is not GOOD), on the pairs and starts \
         of the table above.\n\n",
    );
    out.push_str(&table(
        &[
            "data set",
            "successes",
            "right, GOOD",
            "right, not GOOD",
            "wrong, GOOD (false good)",
            "wrong, not GOOD",
        ]
        .map(String::from),
        &rows,
    ));
    out.push('\n');
    out.push_str(&verdict_line("the real scans from one start", &all));
    let false_good: Vec<String> = runs
        .iter()
        .filter(|r| r.called_good && !r.success)
        .map(|r| {
            let case = &cases[r.case];
            format!(
                "{} {} [{}]: {:.2}° / {:.3} m, conditioning {:.3}, margin {:.2}",
                case.settings.name,
                case.label(),
                r.start,
                r.rotation_degrees,
                r.translation,
                r.quality.conditioning,
                r.quality.margin
            )
        })
        .collect();
    if !false_good.is_empty() {
        out.push_str(&format!("\nWrong and GOOD: {}.\n", false_good.join("; ")));
    }
    out.push_str("\nCSV (every run): `results/scans-one-start.csv`.\n");
    out
}
