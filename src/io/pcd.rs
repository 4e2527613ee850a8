//! PCD files (PCL's format): the reader with the header checks that keep pcd-rs from
//! panicking or allocating without bound, and the writer.
use std::io::Write;
use std::path::Path;

use pcd_rs::{DynReader, DynRecord, Field};

use super::cloud::{
    NORMAL_FIELD_NAMES, READ_BYTES_PER_POINT, RawCloud, ensure_memory, try_points, write_text,
};
use crate::point::Point;

/// Largest accepted record (one point); far above any real layout, small enough that pcd-rs's
/// per-record buffers cannot exhaust memory.
const PCD_MAX_RECORD_BYTES: u64 = 1 << 20;

/// LZF emits at least 2 bytes per 264 output bytes; more claimed output means corruption.
const LZF_MAX_EXPANSION: u64 = 132;

pub(super) fn parse_pcd(bytes: &[u8]) -> Result<RawCloud, String> {
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

/// The DATA line: how the points follow the header.
#[derive(Clone, Copy, PartialEq, Eq)]
enum PcdData {
    Ascii,
    Binary,
    BinaryCompressed,
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
/// upper-cases keys by Unicode rules, so `ſIZE` would reach it as SIZE unchecked here). Also
/// the headers pcd-rs reads without a word though they are wrong: a field with `COUNT 0` (it
/// takes 1) and a WIDTH × HEIGHT beyond 2^64 points (it ignores both).
/// Returns the layout when the header gives it; anything else is left to pcd-rs.
fn check_pcd_layout(bytes: &[u8]) -> Result<Option<PcdLayout>, String> {
    let mut fields: Vec<String> = Vec::new();
    let mut sizes: Option<Vec<u64>> = None;
    let mut counts: Option<Vec<u64>> = None;
    let mut width: Option<u64> = None;
    let mut height: Option<u64> = None;
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
        let first = || numbers().and_then(|v| v.first().copied());
        match key.to_ascii_uppercase().as_str() {
            "FIELDS" | "COLUMNS" => fields = values.iter().map(|v| v.to_string()).collect(),
            "SIZE" => sizes = numbers(),
            "COUNT" => counts = numbers(),
            "WIDTH" => width = first(),
            "HEIGHT" => height = first(),
            "POINTS" => declared_points = first(),
            "DATA" => break values.first().unwrap_or(&"").to_string(),
            _ => {}
        }
    };
    let data_start = bytes.len() - rest.len();
    if let Some(zero) = counts.iter().flatten().position(|&count| count == 0) {
        let field = fields
            .get(zero)
            .map_or_else(|| (zero + 1).to_string(), Clone::clone);
        return Err(format!(
            "PCD header: COUNT of field {field} is 0; each field holds at least 1 value"
        ));
    }
    if let (Some(width), Some(height)) = (width, height) {
        if width.checked_mul(height).is_none() {
            return Err(format!(
                "PCD header: WIDTH {width} × HEIGHT {height} is more than 2^64 points"
            ));
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::samples::{PCD_ASCII, SAMPLE, pcd_binary, pcd_compressed};
    use crate::point::NonFinite;

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
    /// which a sanitiser's allocator treats as a crash).
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
    }

    /// `COUNT 0` (pcd-rs takes it as 1) and a WIDTH × HEIGHT beyond 2^64 points were read
    /// without a word; both are errors naming the field.
    #[test]
    fn zero_counts_and_overflowing_dimensions_are_refused() {
        let pcd = |fields: &str, count: &str, width: &str, height: &str| {
            format!(
                "VERSION 0.7\n{fields}\nSIZE 4 4 4\nTYPE F F F\nCOUNT {count}\nWIDTH {width}\nHEIGHT {height}\n\
                 POINTS 3\nDATA ascii\n1 2 3\n4 5 6\n7 8 9\n"
            )
        };
        let read = |text: String| parse_pcd(text.as_bytes()).and_then(|r| r.finish(NonFinite::Reject));
        assert_eq!(
            read(pcd("FIELDS x y z", "1 1 1", "3", "1")).unwrap().points.len(),
            3
        );
        // Organised clouds: WIDTH × HEIGHT, up to the largest product that fits.
        read(pcd("FIELDS x y z", "1 1 1", "4294967295", "4294967297")).unwrap();
        for (fields, count, field) in [
            ("FIELDS x y z", "1 0 1", "COUNT of field y is 0"),
            ("FIELDS x y z", "0 1 1", "COUNT of field x is 0"),
            ("COLUMNS x y z", "1 1 0", "COUNT of field z is 0"),
        ] {
            let err = read(pcd(fields, count, "3", "1")).unwrap_err();
            assert!(err.contains(field) && err.contains("at least 1"), "{err}");
        }
        for (width, height) in [
            ("4294967296", "4294967296"),
            ("3", "9223372036854775808"),
            ("18446744073709551615", "2"),
        ] {
            let err = read(pcd("FIELDS x y z", "1 1 1", width, height)).unwrap_err();
            assert!(
                err.contains(&format!("WIDTH {width} × HEIGHT {height}")) && err.contains("2^64"),
                "{err}"
            );
        }
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
}
