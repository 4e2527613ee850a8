//! PLY files: the reader, with the header checks that keep ply-rs from panicking or
//! allocating without bound.
use ply_rs::parser::Parser;
use ply_rs::ply::{ElementDef, Encoding, Property, PropertyAccess, PropertyType, ScalarType};

use super::cloud::{NORMAL_FIELD_NAMES, READ_BYTES_PER_POINT, RawCloud, ensure_memory, try_points};
use crate::point::Point;

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
pub(super) fn parse_ply(bytes: &[u8]) -> Result<RawCloud, String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::samples::{PLY_ASCII, SAMPLE, ply_binary};
    use crate::point::NonFinite;

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

    /// A vertex count far beyond what the data can hold is refused for that, not by asking for
    /// the memory those vertices would need (as the PCD reader's point count).
    #[test]
    fn impossible_declared_counts_fail_without_a_memory_probe() {
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
}
