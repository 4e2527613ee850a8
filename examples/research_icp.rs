//! Scratch: SIE on the real-scan pairs, variants.
#[allow(dead_code)]
#[path = "experiments/scans.rs"]
mod scans;
#[allow(dead_code)]
#[path = "experiments/simulation.rs"]
mod simulation;

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use sie::{Hooks, register_clouds};

fn main() {
    let data = std::path::PathBuf::from(std::env::var("SIE_DATA_DIR").unwrap_or("../shared/data".into()));
    let filter = std::env::args().nth(1).unwrap_or_default();
    let (mut cases, _) = scans::bunny_pairs(&data).unwrap();
    cases.push(scans::lidar_pair(&data).unwrap());
    cases.push(scans::room_pair(&data).unwrap());
    cases.extend(scans::depth_pairs(&data).unwrap());
    let mut jobs = vec![];
    for (c, case) in cases.iter().enumerate() {
        if !filter.is_empty() && !format!("{} {}", case.settings.name, case.label()).contains(&filter) {
            continue;
        }
        for (s, start) in case.starts(c as u64).into_iter().enumerate() {
            if let Ok(only) = std::env::var("START") {
                if only.parse::<usize>().unwrap() != s {
                    continue;
                }
            }
            jobs.push((c, s, start));
        }
    }
    let next = AtomicUsize::new(0);
    let out = Mutex::new(vec![]);
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let j = next.fetch_add(1, Ordering::Relaxed);
                let Some((c, s, start)) = jobs.get(j) else { break };
                let case = &cases[*c];
                let mut config = case.methods()[0].config.clone();
                let trace = std::env::var("TRACE").is_ok();
                config.record_trace = trace;
                let t = std::time::Instant::now();
                let r = register_clouds(&case.source, &case.target, None, Some(&start.1), &config, Hooks::default()).unwrap();
                let e = case.errors(&r.transform);
                if trace {
                    let _guard = out.lock().unwrap();
                    for t in &r.trace {
                        println!("  it {:3} ann {} σ {:.2e} β {:.2e} k {:.1} P {:.3} rms {:.2e} dθ {:.3} dt {:.2e}", t.iteration, t.annealing as u8, t.sigma, t.beta, t.penalty, t.inlier_fraction, t.rmse, t.rotation_change.to_degrees(), t.translation_change);
                    }
                }
                let ok = case.success(e);
                out.lock().unwrap().push((*c, *s, ok, e, r.sigma[0], r.inlier_fraction, r.iterations, t.elapsed().as_secs_f64(), r.search.significance, r.search.start, r.search.agreeing_starts, r.search.runner_up_significance));
            });
        }
    });
    let mut out = out.into_inner().unwrap();
    out.sort_by_key(|o| (o.0, o.1));
    let mut per: std::collections::BTreeMap<String, (usize, usize)> = Default::default();
    for (c, s, ok, e, sigma, frac, it, secs, sig, kind, agree, runner) in &out {
        let case = &cases[*c];
        let e2 = per.entry(case.settings.name.to_string()).or_default();
        e2.0 += *ok as usize;
        e2.1 += 1;
        println!(
            "{:30} {:28} start {s} {} {:7.2}° {:8.4} m  σ {sigma:.2e} P {frac:.3} it {it} {secs:.2}s sig {sig:.1} {kind:?} agree {agree} runner {runner:.1}",
            case.settings.name,
            case.label(),
            if *ok { "ok  " } else { "FAIL" },
            e.0,
            e.1
        );
    }
    for (k, v) in per {
        println!("{k:40} {}/{}", v.0, v.1);
    }
}
