//! CSV files, Markdown tables and the generated sections of docs/results.md.
use std::fmt::Write as _;
use std::fs;
use std::path::Path;

use crate::simulation::{CellStats, VerdictTally};

/// A value for a table: scientific with two significant digits, "–" for none.
pub fn sci(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1e}")
    } else {
        "–".into()
    }
}

/// Writes rows of already formatted fields as CSV (fields never contain commas or quotes
/// except labels, which are quoted).
pub fn write_csv(path: &Path, header: &[&str], rows: &[Vec<String>]) -> Result<(), String> {
    let mut text = header.join(",");
    text.push('\n');
    for row in rows {
        let fields: Vec<String> = row
            .iter()
            .map(|f| {
                if f.contains([',', '"', ' ']) {
                    format!("\"{}\"", f.replace('"', "\"\""))
                } else {
                    f.clone()
                }
            })
            .collect();
        text.push_str(&fields.join(","));
        text.push('\n');
    }
    fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

/// A Markdown table.
pub fn table(header: &[String], rows: &[Vec<String>]) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "| {} |", header.join(" | "));
    let _ = writeln!(out, "|{}", "---|".repeat(header.len()));
    for row in rows {
        let _ = writeln!(out, "| {} |", row.join(" | "));
    }
    out
}

/// Replaces the text between `<!-- BEGIN name -->` and `<!-- END name -->` in the document
/// (the markers stay), so the hand-written parts of the document survive a rerun.
pub fn replace_section(doc: &Path, name: &str, content: &str) -> Result<(), String> {
    let text = fs::read_to_string(doc).map_err(|e| format!("{}: {e}", doc.display()))?;
    let begin = format!("<!-- BEGIN {name} -->");
    let end = format!("<!-- END {name} -->");
    let (Some(b), Some(e)) = (text.find(&begin), text.find(&end)) else {
        return Err(format!(
            "{}: no {begin} … {end} markers to fill in",
            doc.display()
        ));
    };
    if e < b {
        return Err(format!("{}: {end} comes before {begin}", doc.display()));
    }
    let mut updated = String::with_capacity(text.len() + content.len());
    updated.push_str(&text[..b + begin.len()]);
    updated.push('\n');
    updated.push_str(content.trim_end());
    updated.push('\n');
    updated.push_str(&text[e..]);
    fs::write(doc, updated).map_err(|e| format!("{}: {e}", doc.display()))
}

/// "12m 05s" style.
pub fn duration(seconds: f64) -> String {
    let s = seconds.round() as u64;
    if s >= 3600 {
        format!("{}h {:02}m {:02}s", s / 3600, s % 3600 / 60, s % 60)
    } else if s >= 60 {
        format!("{}m {:02}s", s / 60, s % 60)
    } else {
        format!("{seconds:.1} s")
    }
}

/// CPU model and core count of this machine, and the compiler, for the record.
pub fn machine() -> String {
    let cpu = fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let rustc = std::process::Command::new("rustc")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|| "rustc (unknown version)".into());
    format!("{cpu}, {cores} cores (shared with other work), {rustc}")
}

/// One line on how SIE's quality verdict matched its outcomes over `runs` runs.
pub fn verdict_line(what: &str, t: &VerdictTally) -> String {
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

/// Cell text: failure percentage and mean error of the non-failures.
pub fn cell_text(s: &CellStats) -> String {
    format!("{:.0} · {}", 100.0 * s.failure_rate(), sci(s.mean_error))
}

pub fn file_name(path: &Path) -> String {
    path.file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
}
