//! Point-cloud and transform files for the CLI and the data-driven tests (feature `io`).
//!
//! Readers: PCD via `pcd-rs` (ascii, binary, binary_compressed; VERSION 0.5–0.7), PLY via
//! `ply-rs` (ascii, binary little/big endian), and plain XYZ text. Every error is one line
//! naming the file; malformed input is an error, never a panic (the two crates panic or
//! allocate without bound on a few malformed headers, which are checked here first).
//!
//! Writers: PCD (float32, as PCL stores clouds) and XYZ text; [`write_cloud`] picks one by
//! extension.
mod cloud;
mod pcd;
mod ply;
#[cfg(test)]
mod samples;
mod xyz;

use std::fmt::Display;
use std::fs;
use std::path::Path;

use nalgebra::Matrix4;

use crate::point::{NonFinite, Point};
pub use cloud::CloudFile;
use cloud::RawCloud;
use pcd::parse_pcd;
pub use pcd::{PcdEncoding, write_cloud_pcd};
use ply::parse_ply;
pub use xyz::write_cloud_xyz;
use xyz::{parse_transform, parse_xyz};

/// Reads a `.pcd`, `.ply`, `.xyz` or `.txt` cloud; non-finite coordinates are an error.
pub fn read_cloud(path: &Path) -> Result<CloudFile, String> {
    read_cloud_with(path, NonFinite::Reject)
}

/// A point-cloud file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CloudFormat {
    /// PCL's `.pcd`: ascii, binary or binary_compressed.
    Pcd,
    /// `.ply`: ascii or binary (either endianness).
    Ply,
    /// Plain text: one point per line, the first three numbers separated by whitespace and/or
    /// commas (further columns ignored), `#` starts a comment; a first line without any number
    /// (a column header) is skipped.
    Xyz,
}

impl CloudFormat {
    /// The format for a file extension (case-insensitive): pcd, ply, xyz or txt.
    pub fn from_extension(extension: &str) -> Option<Self> {
        match extension.to_ascii_lowercase().as_str() {
            "pcd" => Some(CloudFormat::Pcd),
            "ply" => Some(CloudFormat::Ply),
            "xyz" | "txt" => Some(CloudFormat::Xyz),
            _ => None,
        }
    }

    /// The format a path's extension names (see [`CloudFormat::from_extension`]).
    pub fn from_path(path: &Path) -> Option<Self> {
        Self::from_extension(path.extension().and_then(|e| e.to_str()).unwrap_or(""))
    }

    /// Whether [`write_cloud`] writes this format: PCD and XYZ text are written, PLY is only
    /// read.
    pub fn is_writable(self) -> bool {
        matches!(self, CloudFormat::Pcd | CloudFormat::Xyz)
    }
}

/// Reads a cloud, choosing the format by extension (case-insensitive; see [`CloudFormat`]).
pub fn read_cloud_with(path: &Path, non_finite: NonFinite) -> Result<CloudFile, String> {
    let fail = |message: &dyn Display| format!("{}: {}", path.display(), one_line(message));
    let Some(format) = CloudFormat::from_path(path) else {
        return Err(fail(&format_args!(
            "unknown point-cloud extension {:?} (expected .pcd, .ply, .xyz or .txt)",
            lowercase_extension(path)
        )));
    };
    let bytes = fs::read(path).map_err(|e| fail(&format_args!("cannot read file: {e}")))?;
    parse_cloud(&bytes, format, non_finite).map_err(|e| fail(&e))
}

/// Parses a cloud held in memory. Malformed input is an error (one line), never a panic.
pub fn parse_cloud(bytes: &[u8], format: CloudFormat, non_finite: NonFinite) -> Result<CloudFile, String> {
    let parse: ParseFn = match format {
        CloudFormat::Pcd => parse_pcd,
        CloudFormat::Ply => parse_ply,
        CloudFormat::Xyz => parse_xyz,
    };
    parse(bytes)
        .and_then(|raw| raw.finish(non_finite))
        .map_err(|e| one_line(&e))
}

/// Reads a rigid transform: 16 numbers (4×4, row-major) or 12 (the top 3×4 rows), separated
/// by whitespace and/or commas, `#` comments allowed. A 4×4 must end in the row 0 0 0 1. The
/// rotation block is returned as written: [`crate::geometry::make_rigid`] checks it (published
/// matrices are rounded) and makes it exact.
pub fn read_transform(path: &Path) -> Result<Matrix4<f64>, String> {
    let fail = |message: &dyn Display| format!("{}: {}", path.display(), one_line(message));
    let text = fs::read_to_string(path).map_err(|e| fail(&format_args!("cannot read file: {e}")))?;
    parse_transform(&text).map_err(|e| fail(&e))
}

/// Writes a cloud in the format its extension names (see [`CloudFormat`]): a PCD with the
/// normals when given ([`write_cloud_pcd`], stored as `encoding` says), or XYZ text
/// ([`write_cloud_xyz`], which has no place for normals). A format that is not
/// [writable](CloudFormat::is_writable) is an error.
pub fn write_cloud(
    path: &Path,
    points: &[Point],
    normals: Option<&[Point]>,
    encoding: PcdEncoding,
) -> Result<(), String> {
    match CloudFormat::from_path(path) {
        Some(CloudFormat::Pcd) => write_cloud_pcd(path, points, normals, encoding),
        Some(CloudFormat::Xyz) => write_cloud_xyz(path, points),
        Some(CloudFormat::Ply) | None => Err(format!(
            "{}: cannot write {:?} point clouds (.pcd, .xyz or .txt can be written)",
            path.display(),
            lowercase_extension(path)
        )),
    }
}

/// The extension as messages show it: lower case, empty when there is none.
fn lowercase_extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// Library messages (ply-rs in particular) span lines; callers expect one.
fn one_line(message: &dyn Display) -> String {
    message
        .to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

type ParseFn = fn(&[u8]) -> Result<RawCloud, String>;

#[cfg(test)]
mod tests {
    use super::samples::{
        PCD_ASCII, PLY_ASCII, SAMPLE, pcd_binary, pcd_compressed, ply_binary, temp_path, write_temp,
    };
    use super::*;
    use rand::rngs::Xoshiro256PlusPlus;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn non_finite_points_are_rejected_or_skipped() {
        let text = "1 2 3\n4 nan 6\n7 8 9\ninf 0 0\n";
        let path = write_temp("nonfinite.xyz", text.as_bytes());
        let err = read_cloud(&path).err().unwrap();
        // Counted from 1, like the lines of the file: the second point (on line 2).
        assert!(
            err.contains("point 2 of 4 ") && err.contains("nonfinite.xyz"),
            "{err}"
        );
        let cloud = read_cloud_with(&path, NonFinite::Skip).unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [7.0, 8.0, 9.0]]);
        assert_eq!(cloud.skipped_non_finite, 2);
        fs::write(&path, "nan 0 0\n").unwrap();
        let err = read_cloud_with(&path, NonFinite::Skip).err().unwrap();
        assert!(err.contains("all 1 points"), "{err}");
        fs::remove_file(&path).unwrap();
    }

    #[test]
    fn skip_keeps_normals_aligned() {
        let pcd = PCD_ASCII.replace("4 5 6 0 1 0", "4 nan 6 0 1 0");
        let cloud = parse_pcd(pcd.as_bytes())
            .unwrap()
            .finish(NonFinite::Skip)
            .unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [7.0, 8.0, 9.0]]);
        assert_eq!(cloud.normals.unwrap(), vec![[0.0, 0.0, 1.0], [0.0; 3]]);
    }

    #[test]
    fn errors_name_the_file_on_one_line() {
        let missing = temp_path("missing.pcd");
        let err = read_cloud(&missing).err().unwrap();
        assert!(
            err.starts_with(&missing.display().to_string()) && err.contains("cannot read"),
            "{err}"
        );
        let err = read_cloud(Path::new("cloud.obj")).err().unwrap();
        assert!(
            err.starts_with("cloud.obj:") && err.contains("unknown point-cloud extension"),
            "{err}"
        );
        let cases: [(&str, &[u8], &str); 6] = [
            ("empty.xyz", b"# nothing\n", "no points"),
            ("noxyz.pcd", b"VERSION 0.7\nFIELDS a b\nSIZE 4 4\nTYPE F F\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n", "no x, y, z"),
            ("fields.pcd", b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3\n1 2\n", "point 2 of 2"),
            ("noxyz.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float u\nend_header\n1\n", "no scalar x, y, z"),
            ("garbage.ply", b"\x00\x01garbage\n", "PLY header"),
            ("truncated.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0", "truncated"),
        ];
        for (name, bytes, expected) in cases {
            let path = write_temp(name, bytes);
            let err = read_cloud(&path)
                .err()
                .unwrap_or_else(|| panic!("{name} was accepted"));
            assert!(err.contains(name) && err.contains(expected), "{name}: {err}");
            assert!(!err.contains('\n'), "{name}: multi-line error {err:?}");
            fs::remove_file(&path).unwrap();
        }
    }

    /// Every truncation and many random corruptions of valid files give Ok or Err, not a panic.
    #[test]
    fn malformed_input_never_panics() {
        let samples: Vec<(ParseFn, Vec<u8>)> = vec![
            (parse_pcd, PCD_ASCII.as_bytes().to_vec()),
            (parse_pcd, pcd_binary(&SAMPLE)),
            (parse_pcd, pcd_compressed(&SAMPLE)),
            (parse_ply, ply_binary(&SAMPLE)),
            (parse_ply, PLY_ASCII.as_bytes().to_vec()),
            (parse_xyz, b"1 2 3\n4,5,6\n".to_vec()),
        ];
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let replacements = [b'0', b'9', b'\n', b' ', b'-', 0, 0xff, b'x', b'.', b'_'];
        for (parse, bytes) in &samples {
            for len in 0..bytes.len() {
                let _ = parse(&bytes[..len]);
            }
            for _ in 0..3000 {
                let mut corrupt = bytes.clone();
                for _ in 0..rng.random_range(1..4) {
                    let at = rng.random_range(0..corrupt.len());
                    corrupt[at] = replacements[rng.random_range(0..replacements.len())];
                }
                let _ = parse(&corrupt);
            }
            // Whole-header number blow-ups.
            let text = String::from_utf8_lossy(bytes).to_string();
            for (from, to) in [
                ("3", "99999999999999999999999"),
                ("1", "18446744073709551615"),
                ("4", "0"),
            ] {
                let _ = parse(text.replacen(from, to, 1).as_bytes());
            }
        }
        assert!(
            parse_ply(b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\nend_header\n")
                .is_err()
        );
        assert!(parse_ply(b"ply\nformat ascii 1.0\nelement vertex 1000000000000\nend_header\n").is_err());
    }

    #[test]
    fn write_cloud_picks_the_writer_by_extension() {
        let normals = [[0.0, 0.0, 1.0]; 3];
        // The samples are float32 values: the PCD holds them exactly.
        for (name, normals_read) in [("picked.PCD", Some(normals.to_vec())), ("picked.txt", None)] {
            let path = temp_path(name);
            write_cloud(&path, &SAMPLE, Some(&normals), PcdEncoding::Ascii).unwrap();
            let cloud = read_cloud(&path).unwrap();
            assert_eq!((cloud.points, cloud.normals), (SAMPLE.to_vec(), normals_read));
            fs::remove_file(&path).unwrap();
        }
        for name in ["refused.ply", "refused"] {
            let path = temp_path(name);
            let error = write_cloud(&path, &SAMPLE, None, PcdEncoding::Binary).unwrap_err();
            assert!(error.contains(".pcd, .xyz or .txt can be written"), "{error}");
            assert!(!path.exists());
        }
        assert_eq!(
            CloudFormat::from_path(Path::new("a/b.Ply")),
            Some(CloudFormat::Ply)
        );
        assert_eq!(CloudFormat::from_path(Path::new("a/b")), None);
        assert!(CloudFormat::Pcd.is_writable() && CloudFormat::Xyz.is_writable());
        assert!(!CloudFormat::Ply.is_writable());
    }

    #[test]
    fn writers_round_trip_exactly() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
        let points: Vec<Point> = (0..200)
            .map(|_| [0, 1, 2].map(|_| rng.random_range(-1e3..1e3) * rng.random::<f64>()))
            .collect();
        let normals: Vec<Point> = points.iter().map(|p| [p[1], -p[0], 1e-9 * p[2]]).collect();

        let xyz = temp_path("round.xyz");
        write_cloud_xyz(&xyz, &points).unwrap();
        assert_eq!(read_cloud(&xyz).unwrap().points, points);

        // PCD holds float32, as PCL does: exact for values that are float32 already.
        let as_f32 = |values: &[Point]| -> Vec<Point> {
            values.iter().map(|p| p.map(|v| f64::from(v as f32))).collect()
        };
        let pcd = temp_path("round.pcd");
        for encoding in [PcdEncoding::Binary, PcdEncoding::Ascii] {
            write_cloud_pcd(&pcd, &points, Some(&normals), encoding).unwrap();
            let cloud = read_cloud(&pcd).unwrap();
            assert_eq!(
                (cloud.points, cloud.normals),
                (as_f32(&points), Some(as_f32(&normals)))
            );
            write_cloud_pcd(&pcd, &points, None, encoding).unwrap();
            assert_eq!(read_cloud(&pcd).unwrap().normals, None);
            let text = fs::read(&pcd).unwrap();
            let header = String::from_utf8_lossy(&text[..200]);
            assert!(header.contains("SIZE 4 4 4\nTYPE F F F\n"), "{header}");
        }
        let bytes = fs::read(&pcd).unwrap();
        assert!(String::from_utf8_lossy(&bytes).contains("DATA ascii\n"));
        write_cloud_pcd(&pcd, &points, None, PcdEncoding::Binary).unwrap();
        let bytes = fs::read(&pcd).unwrap();
        let data = bytes.windows(12).position(|w| w == b"DATA binary\n").unwrap() + 12;
        assert_eq!(bytes.len() - data, points.len() * 12);
        assert_eq!(
            f32::from_le_bytes(bytes[data..data + 4].try_into().unwrap()),
            points[0][0] as f32
        );
        assert!(write_cloud_pcd(&pcd, &points, Some(&points[..3]), PcdEncoding::Binary).is_err());
        let huge = [[1e39, 0.0, 0.0]];
        let error = write_cloud_pcd(&pcd, &huge, None, PcdEncoding::Binary).unwrap_err();
        assert!(error.contains("float32"), "{error}");
        for path in [xyz, pcd] {
            fs::remove_file(path).unwrap();
        }
        let unwritable = temp_path("no-such-dir").join("x.xyz");
        assert!(
            write_cloud_xyz(&unwritable, &points)
                .unwrap_err()
                .contains("cannot write")
        );
    }
}
