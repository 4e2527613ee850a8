//! Builds the C test program (tests/c/api_test.c and api_registration_test.c) against the
//! staticlib cargo built for this crate and runs it, and checks that include/sie.h compiles
//! as C++17.
//!
//! Finding the library: the lib target has crate-type staticlib, and cargo builds every crate
//! type of the lib before any integration test, into the directory the test executable lives in
//! (`target/<profile>/deps/libsie.a`; no metadata hash because the package builds a cdylib).
//! So the archive next to this executable is exactly the one this `cargo test` run compiled;
//! nothing needs to invoke cargo again (which would block on the build lock cargo holds while
//! tests run).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The system libraries a Rust staticlib needs (`rustc --print native-static-libs` on Linux).
const NATIVE_LIBRARIES: [&str; 7] = ["-lgcc_s", "-lutil", "-lrt", "-lpthread", "-lm", "-ldl", "-lc"];
const C_WARNINGS: [&str; 5] = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror"];

fn manifest_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Scratch directory cargo provides to integration tests (target/tmp).
fn scratch_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("c_api");
    std::fs::create_dir_all(&dir).expect("create scratch directory");
    dir
}

fn static_library() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let deps = exe.parent().expect("executable directory");
    let library = deps.join("libsie.a");
    assert!(
        library.is_file(),
        "{} not found: the lib target must keep crate-type \"staticlib\" (Cargo.toml), which cargo \
         builds next to the test executables",
        library.display()
    );
    library
}

fn compiler(variable: &str, default: &str) -> String {
    std::env::var(variable).unwrap_or_else(|_| default.to_owned())
}

/// Runs a command, printing its output; panics with that output unless it succeeds.
fn run(command: &mut Command, what: &str) -> String {
    let output = command
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot start {command:?}: {e}"));
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    print!("{stdout}");
    eprint!("{stderr}");
    assert!(
        output.status.success(),
        "{what} failed ({}): {command:?}\n{stdout}{stderr}",
        output.status
    );
    stdout.into_owned()
}

#[test]
fn c_program_exercises_every_entry_point() {
    let root = manifest_dir();
    let executable = scratch_dir().join("api_test");
    let mut build = Command::new(compiler("CC", "cc"));
    build
        .args(C_WARNINGS)
        .arg("-g")
        .arg("-I")
        .arg(root.join("include"))
        .arg(root.join("tests/c/api_test.c"))
        .arg(root.join("tests/c/api_registration_test.c"))
        .arg(static_library())
        .args(NATIVE_LIBRARIES)
        .arg("-o")
        .arg(&executable);
    run(&mut build, "compiling tests/c/api_test.c");

    let output = run(&mut Command::new(&executable), "tests/c/api_test.c");
    assert!(output.contains(", 0 failed"), "{output}");
}

#[test]
fn header_compiles_as_cpp17() {
    let source = scratch_dir().join("header_cpp17.cpp");
    // Included twice to check the include guard; the enums must be 32-bit in C++ too.
    std::fs::write(
        &source,
        "#include \"sie.h\"\n#include \"sie.h\"\n\
         static_assert(sizeof(sie_status) == 4, \"sie_status is uint32_t\");\n\
         static_assert(SIE_STATUS_PANIC == 100, \"fixed value\");\n\
         int main() {\n  sie_summary summary{};\n  sie_context *ctx = nullptr;\n  \
         return (int)sie_context_get_summary(ctx, &summary) == 0;\n}\n",
    )
    .expect("write C++ source");
    let mut check = Command::new(compiler("CXX", "g++"));
    check
        .args([
            "-std=c++17",
            "-Wall",
            "-Wextra",
            "-Wpedantic",
            "-Werror",
            "-fsyntax-only",
        ])
        .arg("-I")
        .arg(manifest_dir().join("include"))
        .arg(&source);
    run(&mut check, "compiling include/sie.h as C++17");
}

#[test]
fn header_compiles_as_c99() {
    let source = scratch_dir().join("header_c99.c");
    std::fs::write(
        &source,
        "#include \"sie.h\"\n#include \"sie.h\"\n\
         typedef char status_is_32_bit[sizeof(sie_status) == 4 ? 1 : -1];\n\
         int main(void) {\n  sie_summary summary;\n  status_is_32_bit check;\n  (void)check;\n  \
         return (int)sie_context_get_summary(NULL, &summary) == 0;\n}\n",
    )
    .expect("write C source");
    let mut check = Command::new(compiler("CC", "cc"));
    check
        .args(C_WARNINGS)
        .arg("-fsyntax-only")
        .arg("-I")
        .arg(manifest_dir().join("include"))
        .arg(&source);
    run(&mut check, "compiling include/sie.h as C99");
}
