//! Point-cloud and transform files for the CLI and the data-driven tests (feature `io`).
//!
//! Readers: PCD via `pcd-rs` (ascii, binary, binary_compressed; VERSION 0.5–0.7), PLY via
//! `ply-rs` (ascii, binary little/big endian), and plain XYZ text. Every error is one line
//! naming the file; malformed input is an error, never a panic (the two crates panic or
//! allocate without bound on a few malformed headers, which are checked here first).
use std::fmt::Display;
use std::fs;
use std::io::{BufWriter, Write};
use std::path::Path;

use nalgebra::Matrix4;
use pcd_rs::{DynReader, DynRecord, Field};
use ply_rs::parser::Parser;
use ply_rs::ply::{ElementDef, Encoding, Property, PropertyAccess, PropertyType, ScalarType};

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
}

/// Reads a cloud, choosing the format by extension (case-insensitive; see [`CloudFormat`]).
pub fn read_cloud_with(path: &Path, non_finite: NonFinite) -> Result<CloudFile, String> {
    let fail = |message: &dyn Display| format!("{}: {}", path.display(), one_line(message));
    let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    let Some(format) = CloudFormat::from_extension(extension) else {
        return Err(fail(&format_args!(
            "unknown point-cloud extension {:?} (expected .pcd, .ply, .xyz or .txt)",
            extension.to_ascii_lowercase()
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

/// Writes one `x y z` line per point (shortest text that reads back to the same f64).
pub fn write_cloud_xyz(path: &Path, points: &[Point]) -> Result<(), String> {
    write_text(path, |out| {
        for p in points {
            writeln!(out, "{} {} {}", p[0], p[1], p[2])?;
        }
        Ok(())
    })
}

/// How [`write_cloud_pcd`] stores the points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PcdEncoding {
    /// `DATA binary`: little-endian float32 records (PCL's default for saved clouds; compact
    /// and exact for float32).
    Binary,
    /// `DATA ascii`: one line per point, each float32 value printed so it reads back exactly.
    Ascii,
}

/// Writes a PCD v0.7 with float32 `x y z` and, when given, `normal_x normal_y normal_z`:
/// PCL's own field layout (`SIZE 4`, `TYPE F`), which `pcl::io::loadPCDFile<pcl::PointXYZ>`
/// (or `<pcl::PointNormal>`) matches. Values are rounded to float32, as PCL stores them; a
/// value beyond float32's range is an error rather than an infinity in the file.
pub fn write_cloud_pcd(
    path: &Path,
    points: &[Point],
    normals: Option<&[Point]>,
    encoding: PcdEncoding,
) -> Result<(), String> {
    if let Some(normals) = normals.filter(|n| n.len() != points.len()) {
        return Err(format!(
            "{}: {} normals for {} points",
            path.display(),
            normals.len(),
            points.len()
        ));
    }
    let per_point = if normals.is_some() { 6 } else { 3 };
    let mut values = Vec::with_capacity(points.len() * per_point);
    for (i, p) in points.iter().enumerate() {
        values.extend(p.iter().map(|&v| v as f32));
        if let Some(n) = normals.map(|n| n[i]) {
            values.extend(n.iter().map(|&v| v as f32));
        }
        if let Some(k) = values[values.len() - per_point..]
            .iter()
            .position(|v| !v.is_finite())
        {
            return Err(format!(
                "{}: point {i} has a value ({}) that float32 cannot hold",
                path.display(),
                if k < 3 {
                    p[k]
                } else {
                    normals.map_or(0.0, |n| n[i][k - 3])
                }
            ));
        }
    }
    write_text(path, |out| {
        let fields = if normals.is_some() {
            "x y z normal_x normal_y normal_z"
        } else {
            "x y z"
        };
        writeln!(out, "# .PCD v0.7 - Point Cloud Data file format")?;
        writeln!(out, "VERSION 0.7")?;
        writeln!(out, "FIELDS {fields}")?;
        writeln!(out, "SIZE{}", " 4".repeat(per_point))?;
        writeln!(out, "TYPE{}", " F".repeat(per_point))?;
        writeln!(out, "COUNT{}", " 1".repeat(per_point))?;
        writeln!(out, "WIDTH {}", points.len())?;
        writeln!(out, "HEIGHT 1")?;
        writeln!(out, "VIEWPOINT 0 0 0 1 0 0 0")?;
        writeln!(out, "POINTS {}", points.len())?;
        match encoding {
            PcdEncoding::Binary => {
                writeln!(out, "DATA binary")?;
                for v in &values {
                    out.write_all(&v.to_le_bytes())?;
                }
            }
            PcdEncoding::Ascii => {
                writeln!(out, "DATA ascii")?;
                for record in values.chunks_exact(per_point) {
                    let line: Vec<String> = record.iter().map(f32::to_string).collect();
                    writeln!(out, "{}", line.join(" "))?;
                }
            }
        }
        Ok(())
    })
}

fn write_text(
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

/// Library messages (ply-rs in particular) span lines; callers expect one.
fn one_line(message: &dyn Display) -> String {
    message
        .to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

type ParseFn = fn(&[u8]) -> Result<RawCloud, String>;

/// Points and optional normals as parsed, before the non-finite policy.
struct RawCloud {
    points: Vec<Point>,
    normals: Option<Vec<Point>>,
    warnings: Vec<String>,
}

impl RawCloud {
    fn finish(self, non_finite: NonFinite) -> Result<CloudFile, String> {
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
const READ_BYTES_PER_POINT: u64 = 4 * size_of::<Point>() as u64;

/// Asks for the memory a file's declared counts need before any of it is used.
fn ensure_memory(bytes: u64, what: &str) -> Result<(), String> {
    let bytes = usize::try_from(bytes).unwrap_or(usize::MAX);
    crate::memory::ensure_available(bytes, what).map_err(|e| e.to_string())
}

/// Names under which a cloud's normal components appear.
const NORMAL_FIELD_NAMES: [[&str; 3]; 2] = [["normal_x", "normal_y", "normal_z"], ["nx", "ny", "nz"]];

// ----------------------------------------------------------------------------------------------
// PCD

/// Largest accepted record (one point); far above any real layout, small enough that pcd-rs's
/// per-record buffers cannot exhaust memory.
const PCD_MAX_RECORD_BYTES: u64 = 1 << 20;

/// LZF emits at least 2 bytes per 264 output bytes; more claimed output means corruption.
const LZF_MAX_EXPANSION: u64 = 132;

fn parse_pcd(bytes: &[u8]) -> Result<RawCloud, String> {
    let layout = check_pcd_layout(bytes)?;
    if let Some(layout) = &layout {
        // pcd-rs holds the compressed block, the decompressed one and its row-major copy.
        let blocks = layout
            .compressed
            .map_or(0, |(compressed, uncompressed)| compressed + 2 * uncompressed);
        // A count the data cannot hold fails when read: ask only for what the bytes can hold
        // (a header claiming 10^16 points in a 300-byte file is not a reason to probe 10^18
        // bytes).
        let need = layout
            .points_present(bytes.len())
            .saturating_mul(READ_BYTES_PER_POINT)
            .saturating_add(blocks);
        ensure_memory(need, &format!("reading {} points", layout.points))?;
    }
    let reader = DynReader::from_bytes(bytes).map_err(|e| format!("PCD header: {e}"))?;
    let meta = reader.meta();
    // pcd-rs drops `_` padding fields from records.
    let names: Vec<&str> = meta
        .field_defs
        .iter()
        .filter(|f| f.name != "_")
        .map(|f| f.name.as_str())
        .collect();
    let find = |wanted: [&str; 3]| -> Option<[usize; 3]> {
        let [x, y, z] = wanted.map(|name| names.iter().position(|&n| n == name));
        Some([x?, y?, z?])
    };
    let position_fields = find(["x", "y", "z"])
        .ok_or_else(|| format!("PCD has no x, y, z fields (fields: {})", names.join(" ")))?;
    let normal_fields = NORMAL_FIELD_NAMES.into_iter().find_map(find);
    let declared = usize::try_from(meta.num_points).unwrap_or(usize::MAX);
    let capacity = declared.min(bytes.len() / 3);
    let mut points = try_points(capacity)?;
    let mut normals = match normal_fields {
        Some(_) => Some(try_points(capacity)?),
        None => None,
    };
    for (i, record) in reader.enumerate() {
        let record = record.map_err(|e| format!("PCD point {} of {declared}: {e}", i + 1))?;
        let field = |at: [usize; 3]| at.map(|f| pcd_value(&record, f));
        points.push(field(position_fields));
        if let (Some(normals), Some(at)) = (normals.as_mut(), normal_fields) {
            normals.push(field(at));
        }
    }
    let warnings = layout
        .and_then(|layout| layout.undeclared_data(bytes, points.len()))
        .into_iter()
        .collect();
    Ok(RawCloud {
        points,
        normals,
        warnings,
    })
}

fn try_points(count: usize) -> Result<Vec<Point>, String> {
    crate::memory::try_vec(count, &format!("{count} points")).map_err(|e| e.to_string())
}

/// First value of field `index` as f64 (NaN if absent, so the non-finite policy applies).
fn pcd_value(record: &DynRecord, index: usize) -> f64 {
    let first = match record.0.get(index) {
        Some(Field::F32(v)) => v.first().map(|&x| x as f64),
        Some(Field::F64(v)) => v.first().copied(),
        Some(Field::I8(v)) => v.first().map(|&x| x as f64),
        Some(Field::I16(v)) => v.first().map(|&x| x as f64),
        Some(Field::I32(v)) => v.first().map(|&x| x as f64),
        Some(Field::I64(v)) => v.first().map(|&x| x as f64),
        Some(Field::U8(v)) => v.first().map(|&x| x as f64),
        Some(Field::U16(v)) => v.first().map(|&x| x as f64),
        Some(Field::U32(v)) => v.first().map(|&x| x as f64),
        Some(Field::U64(v)) => v.first().map(|&x| x as f64),
        None => None,
    };
    first.unwrap_or(f64::NAN)
}

/// What the header says about the data, as far as the checks here need it.
struct PcdLayout {
    /// Byte offset of the data, right after the DATA line.
    data_start: usize,
    kind: PcdData,
    /// POINTS.
    points: u64,
    record_bytes: u64,
    /// binary_compressed: the block's compressed and uncompressed sizes.
    compressed: Option<(u64, u64)>,
}

impl PcdLayout {
    /// At most how many of the declared points the data after the header can hold: a byte
    /// each in ascii, a record each in binary or in the block's uncompressed size (none when
    /// the block's sizes are missing).
    fn points_present(&self, file_bytes: usize) -> u64 {
        let data = file_bytes.saturating_sub(self.data_start) as u64;
        let record = self.record_bytes.max(1);
        let fits = match (self.kind, self.compressed) {
            (PcdData::Ascii, _) => data,
            (PcdData::Binary, _) => data / record,
            (PcdData::BinaryCompressed, Some((_, uncompressed))) => uncompressed / record,
            (PcdData::BinaryCompressed, None) => 0,
        };
        self.points.min(fits)
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum PcdData {
    Ascii,
    Binary,
    BinaryCompressed,
}

impl PcdLayout {
    /// A warning when the file holds data beyond the `read` points its header declares. PCL
    /// reads the declared points and warns ("input has more points than advertised"); so does
    /// this reader, so that nothing is dropped without a word.
    fn undeclared_data(&self, bytes: &[u8], read: usize) -> Option<String> {
        let data = bytes.get(self.data_start..)?;
        match self.kind {
            PcdData::Ascii => {
                let lines = data
                    .split(|&b| b == b'\n')
                    .filter(|line| line.iter().any(|b| !b.is_ascii_whitespace()))
                    .count();
                (lines > read).then(|| {
                    format!(
                        "the file holds {lines} points but its header declares {} (POINTS); the first \
                         {read} were read, as PCL does",
                        self.points
                    )
                })
            }
            PcdData::Binary => {
                let declared_bytes = self.points.saturating_mul(self.record_bytes);
                let extra = (data.len() as u64).saturating_sub(declared_bytes);
                (extra > 0).then(|| {
                    let more = extra / self.record_bytes.max(1);
                    format!(
                        "the file holds {extra} bytes after the {} points its header declares (POINTS; \
                         {more} more {}-byte points); the declared points were read, as PCL does",
                        self.points, self.record_bytes
                    )
                })
            }
            PcdData::BinaryCompressed => {
                let (compressed, _) = self.compressed?;
                let extra = (data.len() as u64).saturating_sub(8 + compressed);
                (extra > 0).then(|| {
                    format!(
                        "the file holds {extra} bytes after its compressed block of the {} points its header \
                         declares; they were not read",
                        self.points
                    )
                })
            }
        }
    }
}

/// Rejects the header sizes on which pcd-rs 0.13 would panic or allocate unboundedly: record
/// sizes that overflow, binary_compressed blocks whose sizes disagree with the header (its
/// column transposition indexes out of bounds), and header keys that are not ASCII (pcd-rs
/// upper-cases keys by Unicode rules, so `ſIZE` would reach it as SIZE unchecked here).
/// Returns the layout when the header gives it; anything else is left to pcd-rs.
fn check_pcd_layout(bytes: &[u8]) -> Result<Option<PcdLayout>, String> {
    let mut sizes: Option<Vec<u64>> = None;
    let mut counts: Option<Vec<u64>> = None;
    let mut declared_points: Option<u64> = None;
    let mut rest = bytes;
    let mut line_number = 0;
    let data_kind = loop {
        let Some(line_end) = rest.iter().position(|&b| b == b'\n') else {
            return Ok(None);
        };
        let line = String::from_utf8_lossy(&rest[..line_end]);
        rest = &rest[line_end + 1..];
        line_number += 1;
        let content = line.split('#').next().unwrap_or("");
        let tokens: Vec<&str> = content.split_ascii_whitespace().collect();
        let Some((key, values)) = tokens.split_first() else {
            continue;
        };
        if !key.is_ascii() {
            return Err(format!(
                "PCD header line {line_number}: the key {key:?} is not ASCII (PCD header keys are \
                 VERSION, FIELDS, SIZE, TYPE, COUNT, WIDTH, HEIGHT, VIEWPOINT, POINTS, DATA)"
            ));
        }
        let numbers = || {
            values
                .iter()
                .map(|v| v.parse::<u64>())
                .collect::<Result<Vec<_>, _>>()
                .ok()
        };
        match key.to_ascii_uppercase().as_str() {
            "SIZE" => sizes = numbers(),
            "COUNT" => counts = numbers(),
            "POINTS" => declared_points = numbers().and_then(|v| v.first().copied()),
            "DATA" => break values.first().unwrap_or(&"").to_string(),
            _ => {}
        }
    };
    let data_start = bytes.len() - rest.len();
    let (Some(sizes), Some(points)) = (sizes, declared_points) else {
        return Ok(None);
    };
    let counts = counts.unwrap_or_else(|| vec![1; sizes.len()]);
    if counts.len() != sizes.len() {
        return Ok(None); // pcd-rs reports the mismatch
    }
    let record_bytes = sizes
        .iter()
        .zip(&counts)
        .try_fold(0u64, |sum, (&size, &count)| {
            sum.checked_add(size.checked_mul(count.max(1))?)
        })
        .filter(|&b| b <= PCD_MAX_RECORD_BYTES)
        .ok_or("PCD header: SIZE × COUNT gives an implausibly large point record")?;
    let kind = match data_kind.as_str() {
        "ascii" => PcdData::Ascii,
        "binary" => PcdData::Binary,
        "binary_compressed" => PcdData::BinaryCompressed,
        _ => return Ok(None), // pcd-rs reports it
    };
    let mut layout = PcdLayout {
        data_start,
        kind,
        points,
        record_bytes,
        compressed: None,
    };
    if kind != PcdData::BinaryCompressed || rest.len() < 8 {
        return Ok(Some(layout));
    }
    let compressed = u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]) as u64;
    let uncompressed = u32::from_le_bytes([rest[4], rest[5], rest[6], rest[7]]) as u64;
    let present = (rest.len() - 8) as u64;
    if compressed > present {
        return Err(format!(
            "PCD binary_compressed data truncated: {compressed} compressed bytes declared, {present} present"
        ));
    }
    layout.compressed = Some((compressed, uncompressed));
    if compressed == 0 && uncompressed == 0 {
        return Ok(Some(layout));
    }
    let expected = points.checked_mul(record_bytes);
    if expected != Some(uncompressed) {
        return Err(format!(
            "PCD binary_compressed block holds {uncompressed} bytes but POINTS {points} × {record_bytes}-byte \
             records need {}",
            expected.map_or("more than 2^64".to_string(), |e| e.to_string())
        ));
    }
    if uncompressed > compressed.saturating_mul(LZF_MAX_EXPANSION) + 1024 {
        return Err(format!(
            "PCD binary_compressed block is corrupt: {compressed} bytes cannot expand to {uncompressed}"
        ));
    }
    Ok(Some(layout))
}

// ----------------------------------------------------------------------------------------------
// PLY

/// One vertex as ply-rs reports it; other properties are ignored as they arrive.
struct PlyVertex {
    position: Point,
    normal: Point,
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        PlyVertex {
            position: [f64::NAN; 3],
            normal: [f64::NAN; 3],
        }
    }

    fn set_property(&mut self, name: String, property: Property) {
        let Some(value) = ply_scalar(&property) else {
            return;
        };
        let slot = match name.as_str() {
            "x" => &mut self.position[0],
            "y" => &mut self.position[1],
            "z" => &mut self.position[2],
            "nx" | "normal_x" => &mut self.normal[0],
            "ny" | "normal_y" => &mut self.normal[1],
            "nz" | "normal_z" => &mut self.normal[2],
            _ => return,
        };
        *slot = value;
    }
}

fn ply_scalar(property: &Property) -> Option<f64> {
    Some(match *property {
        Property::Char(v) => v as f64,
        Property::UChar(v) => v as f64,
        Property::Short(v) => v as f64,
        Property::UShort(v) => v as f64,
        Property::Int(v) => v as f64,
        Property::UInt(v) => v as f64,
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        _ => return None,
    })
}

fn ply_scalar_bytes(scalar: &ScalarType) -> usize {
    match scalar {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// Reads the `vertex` element; the other elements (a camera before it, faces or the Stanford
/// scans' `range_grid` after it) are read and discarded, so that data beyond everything the
/// header declares is noticed: it is an error, as nothing in a PLY file says what it would be
/// (a vertex count too small in the header, usually).
fn parse_ply(bytes: &[u8]) -> Result<RawCloud, String> {
    check_ply_header_numbers(bytes)?;
    let mut reader: &[u8] = bytes;
    let parser = Parser::<PlyVertex>::new();
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| format!("PLY header: {e}"))?;
    let vertex = header.elements.get("vertex").ok_or("PLY has no vertex element")?;
    let has = |name: &str| {
        matches!(
            vertex.properties.get(name).map(|p| &p.data_type),
            Some(PropertyType::Scalar(_))
        )
    };
    if !["x", "y", "z"].iter().all(|n| has(n)) {
        let names: Vec<&str> = vertex.properties.keys().map(String::as_str).collect();
        return Err(format!(
            "PLY vertex has no scalar x, y, z properties (properties: {})",
            names.join(" ")
        ));
    }
    let with_normals = NORMAL_FIELD_NAMES
        .iter()
        .any(|names| names.iter().all(|n| has(n)));
    // ply-rs holds one record per entry of an element while it reads it.
    // Counts the payload cannot hold are refused before memory is asked for them.
    for element in header.elements.values() {
        check_ply_element_fits(element, &header.encoding, reader.len())?;
    }
    let largest = header.elements.values().map(|e| e.count).max().unwrap_or(0);
    let need = (vertex.count as u64)
        .saturating_add(largest as u64)
        .saturating_mul(READ_BYTES_PER_POINT);
    ensure_memory(need, &format!("reading {} vertices", vertex.count))?;
    let mut cloud = None;
    for (name, element) in &header.elements {
        check_ply_element_fits(element, &header.encoding, reader.len())?;
        let read = parser
            .read_payload_for_element(&mut reader, element, &header)
            .map_err(|e| format!("PLY element {name:?}: {e}"))?;
        if name == "vertex" {
            let mut points = try_points(read.len())?;
            points.extend(read.iter().map(|v| v.position));
            let normals = match with_normals {
                true => {
                    let mut normals = try_points(read.len())?;
                    normals.extend(read.iter().map(|v| v.normal));
                    Some(normals)
                }
                false => None,
            };
            cloud = Some(RawCloud {
                points,
                normals,
                warnings: Vec::new(),
            });
        }
    }
    check_ply_end(reader, &header)?;
    cloud.ok_or_else(|| "PLY has no vertex element".into())
}

/// Data after the last declared element: an error naming how much.
fn check_ply_end(rest: &[u8], header: &ply_rs::ply::Header) -> Result<(), String> {
    let last = header
        .elements
        .values()
        .next_back()
        .map_or_else(String::new, |e| format!("{} {:?} entries", e.count, e.name));
    match header.encoding {
        Encoding::Ascii => {
            let lines = rest
                .split(|&b| b == b'\n')
                .filter(|line| line.iter().any(|b| !b.is_ascii_whitespace()))
                .count();
            if lines > 0 {
                return Err(format!(
                    "PLY holds {lines} more lines after the data its header declares (ending with \
                     {last}); is an element count in the header too small?"
                ));
            }
        }
        _ if !rest.is_empty() => {
            return Err(format!(
                "PLY holds {} more bytes after the data its header declares (ending with {last}); is \
                 an element count in the header too small?",
                rest.len()
            ));
        }
        _ => {}
    }
    Ok(())
}

/// ply-rs 0.1 unwraps its header integers into u64 and would panic on longer digit runs.
fn check_ply_header_numbers(bytes: &[u8]) -> Result<(), String> {
    for line in bytes.split(|&b| b == b'\n') {
        let longest_digit_run = line
            .split(|b| !b.is_ascii_digit())
            .map(<[u8]>::len)
            .max()
            .unwrap_or(0);
        if longest_digit_run > 19 {
            return Err(format!(
                "PLY header has a number too large: {}",
                String::from_utf8_lossy(line).trim()
            ));
        }
        if line.starts_with(b"end_header") {
            break;
        }
    }
    Ok(())
}

/// Catches truncated files (and element counts that would loop or allocate far beyond the
/// file) before reading: every entry takes at least one byte per property in ascii and the
/// sum of its scalar sizes in binary.
fn check_ply_element_fits(element: &ElementDef, encoding: &Encoding, remaining: usize) -> Result<(), String> {
    if element.count == 0 {
        return Ok(());
    }
    if element.properties.is_empty() {
        return Err(format!(
            "PLY element {:?} has entries but no properties",
            element.name
        ));
    }
    let entry_bytes = match encoding {
        Encoding::Ascii => element.properties.len(),
        _ => element
            .properties
            .values()
            .map(|p| match &p.data_type {
                PropertyType::Scalar(s) | PropertyType::List(s, _) => ply_scalar_bytes(s),
            })
            .sum(),
    };
    if element.count.saturating_mul(entry_bytes) > remaining {
        return Err(format!(
            "PLY file truncated: element {:?} declares {} entries, only {remaining} bytes follow",
            element.name, element.count
        ));
    }
    Ok(())
}

// ----------------------------------------------------------------------------------------------
// XYZ text and transforms

/// Tokens of one text line: `#` comment removed, separated by whitespace and/or commas.
fn text_tokens(line: &str) -> impl Iterator<Item = &str> {
    let content = line.split('#').next().unwrap_or("");
    content
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
}

fn parse_xyz(bytes: &[u8]) -> Result<RawCloud, String> {
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

fn parse_transform(text: &str) -> Result<Matrix4<f64>, String> {
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
    use super::*;
    use rand::rngs::Xoshiro256PlusPlus;
    use rand::{RngExt, SeedableRng};
    use std::path::PathBuf;

    /// A file path unique to this process and test.
    fn temp_path(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("sie-io-test-{}-{name}", std::process::id()))
    }

    fn write_temp(name: &str, bytes: &[u8]) -> PathBuf {
        let path = temp_path(name);
        fs::write(&path, bytes).unwrap();
        path
    }

    const PCD_ASCII: &str = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z normal_x normal_y normal_z curvature\n\
        SIZE 4 4 4 4 4 4 4\nTYPE F F F F F F F\nCOUNT 1 1 1 1 1 1 1\nWIDTH 3\nHEIGHT 1\n\
        VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n\
        1 2 3 0 0 1 0.1\n4 5 6 0 1 0 0.2\n7 8 9 nan nan nan 0.3\n";

    /// Binary PCD with a padding field and a double-precision z.
    fn pcd_binary(points: &[Point]) -> Vec<u8> {
        let mut bytes = format!(
            "VERSION .7\nFIELDS x _ y z\nSIZE 4 1 4 8\nTYPE F U F F\nCOUNT 1 3 1 1\nWIDTH {n}\nHEIGHT 1\n\
             POINTS {n}\nDATA binary\n",
            n = points.len()
        )
        .into_bytes();
        for p in points {
            bytes.extend((p[0] as f32).to_le_bytes());
            bytes.extend([7, 7, 7]);
            bytes.extend((p[1] as f32).to_le_bytes());
            bytes.extend(p[2].to_le_bytes());
        }
        bytes
    }

    /// binary_compressed with a literal-only LZF stream (valid LZF, no back references).
    fn pcd_compressed(points: &[Point]) -> Vec<u8> {
        let mut columns = Vec::new();
        for d in 0..3 {
            for p in points {
                columns.extend((p[d] as f32).to_le_bytes());
            }
        }
        let mut lzf = Vec::new();
        for run in columns.chunks(32) {
            lzf.push((run.len() - 1) as u8);
            lzf.extend(run);
        }
        let mut bytes = format!(
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\n\
             POINTS {n}\nDATA binary_compressed\n",
            n = points.len()
        )
        .into_bytes();
        bytes.extend((lzf.len() as u32).to_le_bytes());
        bytes.extend((columns.len() as u32).to_le_bytes());
        bytes.extend(lzf);
        bytes
    }

    fn ply_binary(points: &[Point]) -> Vec<u8> {
        let mut bytes = format!(
            "ply\nformat binary_little_endian 1.0\ncomment test\nelement vertex {}\nproperty float x\n\
             property float y\nproperty double z\nproperty uchar intensity\nelement face 1\n\
             property list uchar int vertex_indices\nend_header\n",
            points.len()
        )
        .into_bytes();
        for p in points {
            bytes.extend((p[0] as f32).to_le_bytes());
            bytes.extend((p[1] as f32).to_le_bytes());
            bytes.extend(p[2].to_le_bytes());
            bytes.push(200);
        }
        bytes.push(3);
        for i in 0..3i32 {
            bytes.extend(i.to_le_bytes());
        }
        bytes
    }

    const PLY_ASCII: &str = "ply\nformat ascii 1.0\nelement camera 1\nproperty float f\n\
        element vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\n\
        property float ny\nproperty float nz\nelement range_grid 3\nproperty list uchar int vertex_indices\n\
        end_header\n0.5\n1 2 3 0 0 1\n-1 -2 -3.5 1 0 0\n1 0\n0\n1 1\n";

    const SAMPLE: [Point; 3] = [[1.0, 2.0, 3.0], [-4.5, 0.25, 6.0], [7.0, -8.0, 0.125]];

    #[test]
    fn reads_pcd_ascii_with_normals_and_nan() {
        let cloud = parse_pcd(PCD_ASCII.as_bytes())
            .and_then(|r| r.finish(NonFinite::Reject))
            .unwrap();
        assert_eq!(
            cloud.points,
            vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
        );
        // The NaN normal becomes "no normal".
        assert_eq!(
            cloud.normals.unwrap(),
            vec![[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0; 3]]
        );
    }

    #[test]
    fn reads_pcd_binary_and_compressed() {
        let cloud = parse_pcd(&pcd_binary(&SAMPLE))
            .unwrap()
            .finish(NonFinite::Reject)
            .unwrap();
        assert_eq!(cloud.points, SAMPLE.to_vec());
        assert_eq!(cloud.normals, None);
        let cloud = parse_pcd(&pcd_compressed(&SAMPLE))
            .unwrap()
            .finish(NonFinite::Reject)
            .unwrap();
        assert_eq!(cloud.points, SAMPLE.to_vec());
    }

    #[test]
    fn reads_ply_binary_and_ascii() {
        let cloud = parse_ply(&ply_binary(&SAMPLE))
            .unwrap()
            .finish(NonFinite::Reject)
            .unwrap();
        assert_eq!(cloud.points, SAMPLE.to_vec());
        assert_eq!(cloud.normals, None);
        let cloud = parse_ply(PLY_ASCII.as_bytes())
            .unwrap()
            .finish(NonFinite::Reject)
            .unwrap();
        assert_eq!(cloud.points, vec![[1.0, 2.0, 3.0], [-1.0, -2.0, -3.5]]);
        assert_eq!(cloud.normals.unwrap(), vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]);
    }

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

    #[test]
    fn compressed_block_sizes_are_checked() {
        let good = pcd_compressed(&SAMPLE);
        let header_end = good
            .windows(18)
            .position(|w| w == b"binary_compressed\n")
            .unwrap()
            + 18;
        let mut wrong_size = good.clone();
        wrong_size[header_end + 4..header_end + 8].copy_from_slice(&8u32.to_le_bytes());
        let err = parse_pcd(&wrong_size).err().unwrap();
        assert!(err.contains("need 36"), "{err}");
        let mut too_many_points = good.clone();
        let text = String::from_utf8_lossy(&good[..header_end]).replace("POINTS 3", "POINTS 3000000000");
        too_many_points.splice(..header_end, text.into_bytes());
        assert!(parse_pcd(&too_many_points).is_err());
    }

    fn pcd_ascii(declared: usize, lines: usize) -> Vec<u8> {
        let mut text = format!(
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {declared}\nHEIGHT 1\n\
             POINTS {declared}\nDATA ascii\n"
        );
        for i in 0..lines {
            text.push_str(&format!("{i} 0.5 -1\n"));
        }
        text.into_bytes()
    }

    /// 1 318 points under a header of 1 000 were read as 1 000 without a word. PCL reads the
    /// declared points and warns; so does this reader now. Fewer points than declared are an
    /// error (PCL too).
    #[test]
    fn pcd_holding_more_points_than_declared_warns_and_fewer_fails() {
        let read = |bytes: &[u8]| parse_pcd(bytes).and_then(|raw| raw.finish(NonFinite::Reject));
        let cloud = read(&pcd_ascii(1000, 1318)).unwrap();
        assert_eq!(cloud.points.len(), 1000);
        assert_eq!(cloud.warnings.len(), 1, "{:?}", cloud.warnings);
        assert!(
            cloud.warnings[0].contains("1318 points") && cloud.warnings[0].contains("declares 1000"),
            "{:?}",
            cloud.warnings
        );
        // Blank lines at the end are not points.
        let mut padded = pcd_ascii(3, 3);
        padded.extend(b"\n  \n\r\n");
        assert_eq!(read(&padded).unwrap().warnings, Vec::<String>::new());
        assert_eq!(read(&pcd_ascii(3, 3)).unwrap().warnings, Vec::<String>::new());

        let mut binary = pcd_binary(&SAMPLE);
        assert_eq!(read(&binary).unwrap().warnings, Vec::<String>::new());
        // Two more 19-byte records.
        let extra = binary[binary.len() - 2 * 19..].to_vec();
        binary.extend(extra);
        let cloud = read(&binary).unwrap();
        assert_eq!(cloud.points, SAMPLE.to_vec());
        assert!(
            cloud.warnings.len() == 1 && cloud.warnings[0].contains("2 more 19-byte points"),
            "{:?}",
            cloud.warnings
        );

        let mut compressed = pcd_compressed(&SAMPLE);
        compressed.extend([1, 2, 3, 4]);
        let cloud = read(&compressed).unwrap();
        assert!(
            cloud.warnings.len() == 1 && cloud.warnings[0].contains("4 bytes after"),
            "{:?}",
            cloud.warnings
        );

        let err = read(&pcd_ascii(1000, 700)).unwrap_err();
        assert!(err.contains("point 701 of 1000"), "{err}");
        let mut short = pcd_binary(&SAMPLE);
        short.truncate(short.len() - 19);
        assert!(read(&short).is_err());
    }

    /// A header that declares far more points than its data can hold is refused for that, not
    /// by asking for the memory those points would need (the fuzzer's input: POINTS
    /// 8 552 921 648 689 607 in a 300-byte PCD made the memory probe ask for 8·10^17 bytes,
    /// which a sanitiser's allocator treats as a crash; a PLY vertex count likewise).
    #[test]
    fn impossible_declared_counts_fail_without_a_memory_probe() {
        let pcd = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 20\nHEIGHT 1\n\
                    VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 8552921648689607\nDATA binary\n\
                    \x00\x00\x80\x3f\x00\x00\x80\x3f\x00\x00\x80\x3f";
        let layout = check_pcd_layout(pcd).unwrap().unwrap();
        assert_eq!(layout.points, 8_552_921_648_689_607);
        assert_eq!(layout.points_present(pcd.len()), 1);
        let err = parse_pcd(pcd).err().unwrap();
        assert!(!err.contains("memory"), "{err}");
        let ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 8552921648689607\n\
                    property float x\nproperty float y\nproperty float z\nend_header\n\
                    \x00\x00\x80\x3f\x00\x00\x80\x3f\x00\x00\x80\x3f";
        let err = parse_ply(ply).err().unwrap();
        assert!(err.contains("truncated") && !err.contains("memory"), "{err}");
    }

    /// A PLY file with 313 395 vertices under `element vertex 300000` was read as 300 000.
    /// Nothing in a PLY file says what undeclared data would be, so it is an error; fewer
    /// vertices than declared too.
    #[test]
    fn ply_holding_more_or_fewer_vertices_than_declared_is_an_error() {
        let ascii = |declared: usize, lines: usize| {
            let mut text = format!(
                "ply\nformat ascii 1.0\nelement vertex {declared}\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n"
            );
            for i in 0..lines {
                text.push_str(&format!("{i} 1 2\n"));
            }
            text.into_bytes()
        };
        assert_eq!(parse_ply(&ascii(300, 300)).unwrap().points.len(), 300);
        let err = parse_ply(&ascii(300, 313)).err().unwrap();
        assert!(
            err.contains("13 more lines") && err.contains("300 \"vertex\""),
            "{err}"
        );
        assert!(parse_ply(&ascii(300, 290)).is_err());
        // Trailing blank lines are fine.
        let mut padded = ascii(3, 3);
        padded.extend(b"\n\n");
        assert!(parse_ply(&padded).is_ok());

        // Binary with a face element after the vertices: bytes after the face.
        let mut binary = ply_binary(&SAMPLE);
        assert!(parse_ply(&binary).is_ok());
        binary.extend([0u8; 17]);
        let err = parse_ply(&binary).err().unwrap();
        assert!(
            err.contains("17 more bytes") && err.contains("1 \"face\""),
            "{err}"
        );
        let mut short = ply_binary(&SAMPLE);
        short.truncate(short.len() - 5);
        assert!(parse_ply(&short).is_err());
        // The ascii sample ends with its range_grid element: read to the end, nothing left.
        assert!(parse_ply(PLY_ASCII.as_bytes()).is_ok());
    }

    /// pcd-rs upper-cases header keys by Unicode rules: `ſIZE` is SIZE and `POıNTS` is POINTS
    /// to it, so they reached it past the size checks here (which upper-case ASCII only) and
    /// it panicked. Non-ASCII keys are an error.
    #[test]
    fn non_ascii_pcd_header_keys_are_rejected() {
        // Each extra line contradicts the compressed block, which pcd-rs then indexes past.
        for (after, extra) in [
            ("POINTS 3\n", "POıNTS 3000000000\n"),
            ("SIZE 4 4 4\n", "ſIZE 8 8 8\n"),
        ] {
            let good = pcd_compressed(&SAMPLE);
            let at = good
                .windows(after.len())
                .position(|w| w == after.as_bytes())
                .unwrap()
                + after.len();
            let mut bytes = good.clone();
            bytes.splice(at..at, extra.bytes());
            let key = extra.split(' ').next().unwrap();
            let err = parse_pcd(&bytes)
                .err()
                .unwrap_or_else(|| panic!("{key} was accepted"));
            assert!(err.contains("not ASCII") && err.contains(key), "{key}: {err}");
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
