//! A cloud as read, and what every reader and writer shares: the parsed points before the
//! non-finite policy, the memory a file's counts need, the normal fields' names, text output.

use std::fs;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::geometry::{first_non_finite, is_finite};
use crate::point::{NonFinite, Point};

/// A cloud read from a file.
#[derive(Clone, Debug, PartialEq)]
pub struct CloudFile {
    /// Coordinates in the file's units (read as f64).
    pub points: Vec<Point>,
    /// From `normal_x/normal_y/normal_z` or `nx/ny/nz` fields when the file has them; a
    /// non-finite normal becomes `[0, 0, 0]` ("no normal", as `estimate_normals` gives).
    pub normals: Option<Vec<Point>>,
    /// Points dropped for a non-finite coordinate (only with [`NonFinite::Skip`]).
    pub skipped_non_finite: usize,
    /// What the reader noticed but could read past, one line each: a PCD file holding more
    /// points than its header declares (read as declared, as PCL does, and said here).
    pub warnings: Vec<String>,
}

/// Writes a text file through a buffer; the error names the file.
pub(super) fn write_text(
    path: &Path,
    body: impl FnOnce(&mut BufWriter<fs::File>) -> std::io::Result<()>,
) -> Result<(), String> {
    let result = fs::File::create(path).and_then(|file| {
        let mut out = BufWriter::new(file);
        body(&mut out)?;
        out.flush()
    });
    result.map_err(|e| format!("{}: cannot write file: {e}", path.display()))
}

/// Points and optional normals as parsed, before the non-finite policy.
pub(super) struct RawCloud {
    pub(super) points: Vec<Point>,
    pub(super) normals: Option<Vec<Point>>,
    pub(super) warnings: Vec<String>,
}

impl RawCloud {
    pub(super) fn finish(self, non_finite: NonFinite) -> Result<CloudFile, String> {
        let RawCloud {
            mut points,
            mut normals,
            warnings,
        } = self;
        if points.is_empty() {
            return Err("the cloud has no points".into());
        }
        if let Some(normals) = normals.as_mut() {
            for n in normals.iter_mut().filter(|n| !is_finite(n)) {
                *n = [0.0; 3];
            }
        }
        let total = points.len();
        let Some(first_bad) = first_non_finite(&points) else {
            return Ok(CloudFile {
                points,
                normals,
                skipped_non_finite: 0,
                warnings,
            });
        };
        if non_finite == NonFinite::Reject {
            let p = points[first_bad];
            return Err(format!(
                "point {} of {total} has a non-finite coordinate ({}, {}, {}); \
                 invalid points can be skipped instead (NonFinite::Skip)",
                first_bad + 1,
                p[0],
                p[1],
                p[2]
            ));
        }
        // In place: no second copy of a cloud that may fill memory.
        if let Some(normals) = normals.as_mut() {
            let mut finite = points.iter().map(is_finite);
            normals.retain(|_| finite.next().unwrap_or(false));
        }
        points.retain(is_finite);
        if points.is_empty() {
            return Err(format!("all {total} points have a non-finite coordinate"));
        }
        Ok(CloudFile {
            skipped_non_finite: total - points.len(),
            points,
            normals,
            warnings,
        })
    }
}

/// Bytes per point of the cloud a reader builds: position and normal, and as much again for
/// the file crate's own per-point records while it reads.
pub(super) const READ_BYTES_PER_POINT: u64 = 4 * size_of::<Point>() as u64;

/// Asks for the memory a file's declared counts need before any of it is used.
pub(super) fn ensure_memory(bytes: u64, what: &str) -> Result<(), String> {
    let bytes = usize::try_from(bytes).unwrap_or(usize::MAX);
    crate::memory::ensure_available(bytes, what).map_err(|e| e.to_string())
}

/// Names under which a cloud's normal components appear.
pub(super) const NORMAL_FIELD_NAMES: [[&str; 3]; 2] =
    [["normal_x", "normal_y", "normal_z"], ["nx", "ny", "nz"]];

/// Room for `count` points, the memory asked for first.
pub(super) fn try_points(count: usize) -> Result<Vec<Point>, String> {
    crate::memory::try_vec(count, &format!("{count} points")).map_err(|e| e.to_string())
}
