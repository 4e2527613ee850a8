//! Sample files in every encoding the readers take, shared by the readers' tests.
use std::fs;
use std::path::PathBuf;

use crate::point::Point;

/// A file path unique to this process and test.
pub(super) fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("sie-io-test-{}-{name}", std::process::id()))
}

pub(super) fn write_temp(name: &str, bytes: &[u8]) -> PathBuf {
    let path = temp_path(name);
    fs::write(&path, bytes).unwrap();
    path
}

pub(super) const PCD_ASCII: &str = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z normal_x normal_y normal_z curvature\n\
    SIZE 4 4 4 4 4 4 4\nTYPE F F F F F F F\nCOUNT 1 1 1 1 1 1 1\nWIDTH 3\nHEIGHT 1\n\
    VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n\
    1 2 3 0 0 1 0.1\n4 5 6 0 1 0 0.2\n7 8 9 nan nan nan 0.3\n";

/// Binary PCD with a padding field and a double-precision z.
pub(super) fn pcd_binary(points: &[Point]) -> Vec<u8> {
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
pub(super) fn pcd_compressed(points: &[Point]) -> Vec<u8> {
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

pub(super) fn ply_binary(points: &[Point]) -> Vec<u8> {
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

pub(super) const PLY_ASCII: &str = "ply\nformat ascii 1.0\nelement camera 1\nproperty float f\n\
    element vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\n\
    property float ny\nproperty float nz\nelement range_grid 3\nproperty list uchar int vertex_indices\n\
    end_header\n0.5\n1 2 3 0 0 1\n-1 -2 -3.5 1 0 0\n1 0\n0\n1 1\n";

pub(super) const SAMPLE: [Point; 3] = [[1.0, 2.0, 3.0], [-4.5, 0.25, 6.0], [7.0, -8.0, 0.125]];
