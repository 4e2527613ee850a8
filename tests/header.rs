//! include/sie.h is generated from src/ffi by cbindgen and committed; this test regenerates it in
//! memory and fails when the committed file differs. `SIE_BLESS=1` rewrites the file instead.

use std::path::Path;

/// The SIE_VERSION_* macros, from the same Cargo.toml version the library reports at runtime.
fn version_macros() -> String {
    let part = |text: &str| -> u32 { text.parse().expect("numeric version component") };
    let major = part(env!("CARGO_PKG_VERSION_MAJOR"));
    let minor = part(env!("CARGO_PKG_VERSION_MINOR"));
    let patch = part(env!("CARGO_PKG_VERSION_PATCH"));
    let number = (major << 16) | (minor << 8) | patch;
    format!(
        "\n/** Version of this header; compare with sie_version_number() / sie_version_string(). */\n\
         #define SIE_VERSION_MAJOR {major}\n\
         #define SIE_VERSION_MINOR {minor}\n\
         #define SIE_VERSION_PATCH {patch}\n\
         #define SIE_VERSION_STRING \"{}\"\n\
         /** (SIE_VERSION_MAJOR << 16) | (SIE_VERSION_MINOR << 8) | SIE_VERSION_PATCH */\n\
         #define SIE_VERSION_NUMBER {number:#08x}u\n",
        env!("CARGO_PKG_VERSION")
    )
}

fn generate_header(root: &Path) -> Vec<u8> {
    let mut config = cbindgen::Config::from_file(root.join("cbindgen.toml")).expect("cbindgen.toml parses");
    config.after_includes = Some(version_macros());
    let bindings = cbindgen::Builder::new()
        .with_config(config)
        .with_src(root.join("src/ffi/mod.rs"))
        .generate()
        .expect("cbindgen generates the header");
    let mut header = Vec::new();
    bindings.write(&mut header);
    header
}

#[test]
fn committed_header_matches_generated() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = root.join("include/sie.h");
    let generated = generate_header(root);
    if std::env::var_os("SIE_BLESS").is_some_and(|v| v == "1") {
        std::fs::write(&path, &generated).expect("write include/sie.h");
        return;
    }
    let committed = std::fs::read(&path).unwrap_or_default();
    if generated != committed {
        let generated = String::from_utf8_lossy(&generated);
        let committed = String::from_utf8_lossy(&committed);
        let first_difference = generated
            .lines()
            .zip(committed.lines())
            .position(|(g, c)| g != c)
            .unwrap_or_else(|| generated.lines().count().min(committed.lines().count()));
        panic!(
            "include/sie.h is out of date (first difference at line {}):\n  generated: {:?}\n  committed: {:?}\n\
             Regenerate it with `SIE_BLESS=1 cargo test --test header` and review the diff.",
            first_difference + 1,
            generated.lines().nth(first_difference).unwrap_or("<end of file>"),
            committed.lines().nth(first_difference).unwrap_or("<end of file>"),
        );
    }
}

/// Compilers reading sources in a legacy code page (MSVC without /utf-8) warn on non-ASCII.
#[test]
fn header_is_ascii() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let header = String::from_utf8(generate_header(root)).expect("UTF-8");
    if let Some((number, line)) = header.lines().enumerate().find(|(_, line)| !line.is_ascii()) {
        panic!("line {} of the header is not ASCII: {line}", number + 1);
    }
}

#[test]
fn version_macros_match_the_library() {
    let macros = version_macros();
    let expected = format!(
        "#define SIE_VERSION_NUMBER {:#08x}u",
        sie::ffi::sie_version_number()
    );
    assert!(macros.contains(&expected), "{macros}");
}
