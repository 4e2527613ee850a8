//! Status texts, the version, and the value tables of the C enums.

use super::*;

#[test]
fn status_strings_and_version() {
    let text = |status| {
        unsafe { CStr::from_ptr(sie_status_str(status)) }
            .to_str()
            .unwrap()
    };
    assert_eq!(text(sie_status::Ok as u32), "ok");
    assert_eq!(text(sie_status::Busy as u32), "context busy");
    assert_eq!(text(sie_status::Panic as u32), "internal panic");
    assert_eq!(text(sie_status::Cancelled as u32), "cancelled");
    assert_eq!(text(sie_status::OutOfMemory as u32), "out of memory");
    assert_eq!(text(11), "unknown status");
    assert_eq!(text(u32::MAX), "unknown status");
    let version = unsafe { CStr::from_ptr(sie_version_string()) }.to_str().unwrap();
    assert_eq!(version, env!("CARGO_PKG_VERSION"));
    let parts: Vec<u32> = version.split('.').map(|p| p.parse().unwrap()).collect();
    assert_eq!(
        sie_version_number(),
        (parts[0] << 16) | (parts[1] << 8) | parts[2]
    );
}

/// The text table is built from the enum: every status maps back from its number and has a
/// text of its own.
#[test]
fn every_status_has_its_own_text() {
    let mut texts = Vec::new();
    for &status in sie_status::ALL {
        assert_eq!(sie_status::from_u32(status as u32), Some(status));
        let text = unsafe { CStr::from_ptr(sie_status_str(status as u32)) };
        assert_eq!(text, status.message());
        assert!(!texts.contains(&text), "{text:?} twice");
        texts.push(text);
    }
    assert_eq!(sie_status::from_u32(11), None);
}

/// The value tables come from the declarations (`CEnum!`); left to keep by hand are the derive
/// on each C enum and its name in cbindgen.toml's export list (an enum missing there is missing
/// from the header, and the header test cannot tell).
#[test]
fn every_c_enum_derives_its_tables_and_is_in_the_header() {
    let source = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/src/ffi/mod.rs"));
    let header = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/include/sie.h"));
    let lines: Vec<&str> = source.lines().collect();
    let mut enums = Vec::new();
    for (index, line) in lines.iter().enumerate() {
        let Some(name) = line
            .strip_prefix("pub enum ")
            .and_then(|rest| rest.strip_suffix(" {"))
        else {
            continue;
        };
        let attributes: Vec<&str> = lines[..index]
            .iter()
            .rev()
            .take_while(|line| line.starts_with("#["))
            .copied()
            .collect();
        assert!(attributes.contains(&"#[repr(u32)]"), "{name} is not #[repr(u32)]");
        assert!(
            attributes.contains(&"#[macro_rules_derive(CEnum!)]"),
            "{name} does not derive its tables: add #[macro_rules_derive(CEnum!)]"
        );
        assert!(
            header.contains(&format!("\nenum {name}\n")),
            "{name} is not in include/sie.h: add it to [export] include in cbindgen.toml"
        );
        enums.push(name);
    }
    assert_eq!(enums.len(), 10, "{enums:?}");
}

/// An unknown value is rejected with "valid: 0..=last", which holds while the values an
/// argument can take are numbered from 0 without gaps.
#[test]
fn enum_arguments_are_numbered_from_zero() {
    fn check<E: CEnum + core::fmt::Debug + PartialEq>() {
        let codes: Vec<u32> = E::ALL.iter().map(|variant| variant.code()).collect();
        assert_eq!(codes, (0..codes.len() as u32).collect::<Vec<_>>(), "{:?}", E::ALL);
        for &variant in E::ALL {
            assert_eq!(E::decode(variant.code(), "x"), Ok(variant));
        }
        let last = codes.len() as u32 - 1;
        let error = E::decode(last + 1, "x").unwrap_err();
        assert_eq!(
            error.message,
            format!("x = {} is not a known value (valid: 0..={last})", last + 1)
        );
    }
    check::<sie_cost_function>();
    check::<sie_metric>();
    check::<sie_noise_model>();
    check::<sie_histogram_mode>();
    check::<sie_starts>();
}
