//! The PCD, PLY and XYZ readers on arbitrary bytes: an error or a cloud, never a panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sie::NonFinite;
use sie::io::{CloudFormat, parse_cloud};

fuzz_target!(|data: &[u8]| {
    let Some((&selector, bytes)) = data.split_first() else {
        return;
    };
    let format = [CloudFormat::Pcd, CloudFormat::Ply, CloudFormat::Xyz][(selector % 3) as usize];
    let policy = if selector & 4 != 0 {
        NonFinite::Skip
    } else {
        NonFinite::Reject
    };
    if let Ok(cloud) = parse_cloud(bytes, format, policy) {
        assert!(!cloud.points.is_empty());
        if let Some(normals) = &cloud.normals {
            assert_eq!(normals.len(), cloud.points.len());
        }
    }
});
