//! Shared helpers of the `sie` binary's tests (tests/cli*.rs): running it, scratch folders,
//! reading its JSON and text output, the bunny pair and synthetic PCD files.
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use nalgebra::Matrix4;
use serde_json::Value;

use super::data_dir;

/// bun0 → bun4 from the Stanford bun.conf poses, as listed in pcl-test-bunny/README.md
/// (p_bun4 = T · p_bun0, the direction sie reports).
pub const BUNNY_TRUTH: &str = "\
 0.826351  0.004137 -0.563141  0.036838
-0.0106    0.99991  -0.00821  -0.000257
 0.563056  0.012754  0.82632   0.038321
";

pub fn sie(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sie"))
        .args(args)
        .output()
        .expect("run the sie binary")
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A fresh scratch folder per test, removed when the test ends.
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

pub fn scratch(test: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("sie-cli-{}-{test}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

pub fn arg(path: &Path) -> &str {
    path.to_str().expect("UTF-8 temp path")
}

pub fn json(output: &Output) -> Value {
    serde_json::from_slice(&output.stdout).unwrap_or_else(|e| {
        panic!(
            "stdout is not JSON ({e}): {}\nstderr: {}",
            text(&output.stdout),
            text(&output.stderr)
        )
    })
}

pub fn json_transform(report: &Value) -> Matrix4<f64> {
    let rows = report["transform"].as_array().expect("transform rows");
    assert_eq!(rows.len(), 4);
    Matrix4::from_fn(|r, c| rows[r][c].as_f64().expect("number"))
}

/// The 16 numbers of the plain-text transform (stdout or `-o`).
pub fn text_transform(text: &str) -> Matrix4<f64> {
    let values: Vec<f64> = text
        .split_whitespace()
        .map(|v| v.parse().expect("number"))
        .collect();
    assert_eq!(values.len(), 16, "{text}");
    Matrix4::from_row_slice(&values)
}

pub struct Bunny {
    pub source: PathBuf,
    pub target: PathBuf,
    pub truth: PathBuf,
}

pub fn bunny(dir: &Path) -> Option<Bunny> {
    let data = data_dir()?.join("pcl-test-bunny");
    let truth = dir.join("bunny_truth.txt");
    fs::write(&truth, BUNNY_TRUTH).unwrap();
    Some(Bunny {
        source: data.join("bun0.pcd"),
        target: data.join("bun4.pcd"),
        truth,
    })
}

/// A PCD header for float x y z.
pub fn pcd_header(points: usize, data: &str) -> String {
    format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\nHEIGHT 1\n\
         VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n"
    )
}

pub fn float_bytes(values: impl Iterator<Item = f64>) -> Vec<u8> {
    values.flat_map(|v| (v as f32).to_le_bytes()).collect()
}
