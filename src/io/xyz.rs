//! Plain text: XYZ clouds (one point per line) and rigid transforms (16 or 12 numbers).
use std::io::Write;
use std::path::Path;

use nalgebra::Matrix4;

use super::cloud::{RawCloud, ensure_memory, write_text};
use crate::point::Point;

/// Writes one `x y z` line per point (shortest text that reads back to the same f64).
pub fn write_cloud_xyz(path: &Path, points: &[Point]) -> Result<(), String> {
    write_text(path, |out| {
        for p in points {
            writeln!(out, "{} {} {}", p[0], p[1], p[2])?;
        }
        Ok(())
    })
}

/// Tokens of one text line: `#` comment removed, separated by whitespace and/or commas.
fn text_tokens(line: &str) -> impl Iterator<Item = &str> {
    let content = line.split('#').next().unwrap_or("");
    content
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
}

pub(super) fn parse_xyz(bytes: &[u8]) -> Result<RawCloud, String> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = bytes[..e.valid_up_to()].iter().filter(|&&b| b == b'\n').count() + 1;
        format!("line {line}: not UTF-8 text")
    })?;
    // A point takes at least six bytes ("1 2 3\n") and the Vec may double past the count:
    // room for a third of the bytes in points is asked for up front.
    ensure_memory(
        (bytes.len() as u64 / 3).saturating_mul(size_of::<Point>() as u64),
        "reading the points",
    )?;
    let mut points = Vec::new();
    let mut seen_data_line = false;
    for (line_index, line) in text.lines().enumerate() {
        let tokens: Vec<&str> = text_tokens(line).take(3).collect();
        if tokens.is_empty() {
            continue;
        }
        let numbers: Vec<f64> = tokens.iter().filter_map(|t| t.parse().ok()).collect();
        if !seen_data_line && numbers.is_empty() {
            seen_data_line = true; // a column header such as "x y z"
            continue;
        }
        seen_data_line = true;
        if numbers.len() < 3 {
            let shown: String = line.trim().chars().take(60).collect();
            return Err(format!(
                "line {}: expected 3 numbers, found {shown:?}",
                line_index + 1
            ));
        }
        points.push([numbers[0], numbers[1], numbers[2]]);
    }
    Ok(RawCloud {
        points,
        normals: None,
        warnings: Vec::new(),
    })
}

pub(super) fn parse_transform(text: &str) -> Result<Matrix4<f64>, String> {
    let mut values = Vec::with_capacity(16);
    for token in text.lines().flat_map(text_tokens) {
        let value: f64 = token.parse().map_err(|_| format!("{token:?} is not a number"))?;
        if !value.is_finite() {
            return Err(format!("non-finite entry {token:?}"));
        }
        values.push(value);
    }
    match values.len() {
        12 => values.extend([0.0, 0.0, 0.0, 1.0]),
        16 => {}
        n => return Err(format!("expected 16 numbers (4×4) or 12 (3×4), found {n}")),
    }
    let mut matrix = Matrix4::from_row_slice(&values);
    if !crate::geometry::homogeneous_last_row(&matrix) {
        // The same message as everywhere, with the column-major hint when it applies.
        return Err(crate::geometry::check_rigid(&matrix, "the matrix")
            .err()
            .unwrap_or_else(|| "the last row must be 0 0 0 1 for a rigid transform".into()));
    }
    // Printed rounding (e.g. 0.99999999999999978 from an inverted matrix) is removed.
    matrix.set_row(3, &nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0));
    Ok(matrix)
}

#[cfg(test)]
mod tests {
    use std::fs;

    use super::*;
    use crate::io::read_transform;
    use crate::io::samples::{temp_path, write_temp};
    use crate::point::NonFinite;

    #[test]
    fn reads_xyz_text() {
        let text = "# exported\nX,Y,Z\n1, 2, 3, 99\n\n  4\t5 6 # note\n7,8,9\n";
        let cloud = parse_xyz(text.as_bytes())
            .unwrap()
            .finish(NonFinite::Reject)
            .unwrap();
        assert_eq!(
            cloud.points,
            vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
        );
        let err = parse_xyz(b"1 2 3\n4 5\n").err().unwrap();
        assert!(err.contains("line 2"), "{err}");
        let err = parse_xyz(b"1 2 3\nx y z\n").err().unwrap();
        assert!(err.contains("line 2"), "{err}");
    }

    #[test]
    fn transform_files() {
        let m = parse_transform("# T\n1 0 0 0.5\n0 1 0 -1\n0 0 1 2\n0 0 0 1\n").unwrap();
        assert_eq!(m[(0, 3)], 0.5);
        assert_eq!(m[(1, 3)], -1.0);
        let m34 = parse_transform("1,0,0,0.5, 0,1,0,-1, 0,0,1,2").unwrap();
        assert_eq!(m, m34);
        assert!(parse_transform("1 0 0 0").unwrap_err().contains("found 4"));
        assert!(
            parse_transform("1 0 0 0 0 1 0 0 0 0 1 0 0 0 2 1")
                .unwrap_err()
                .contains("last row")
        );
        assert!(
            parse_transform("1 0 0 0 0 1 0 0 0 0 1 nan")
                .unwrap_err()
                .contains("non-finite")
        );
        assert!(
            parse_transform("1 0 0 0 0 1 0 0 0 0 1 zero")
                .unwrap_err()
                .contains("\"zero\"")
        );
        let path = write_temp("t.txt", b"1 0 0 1\n0 1 0 2\n0 0 1 3\n");
        assert_eq!(read_transform(&path).unwrap()[(2, 3)], 3.0);
        fs::remove_file(&path).unwrap();
        assert!(
            read_transform(&temp_path("absent.txt"))
                .unwrap_err()
                .contains("absent.txt")
        );
    }
}
