//! Build script: only gives the shared library a versioned soname (cargo has no setting for it).
//!
//! The ABI version is `0.<minor>` while the major version is 0 (every 0.x minor release may
//! break the ABI) and `<major>` from 1.0 on, so `libsie.so.0.2` for 0.2.z. The root
//! CMakeLists.txt installs the file under that name, with a `libsie.so` link for the linker.

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    let target_os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    // -soname is an ELF linker flag; macOS and Windows name their libraries differently.
    if !matches!(
        target_os.as_str(),
        "linux" | "android" | "freebsd" | "netbsd" | "openbsd" | "dragonfly"
    ) {
        return;
    }
    let major = env!("CARGO_PKG_VERSION_MAJOR");
    let minor = env!("CARGO_PKG_VERSION_MINOR");
    let abi = if major == "0" {
        format!("0.{minor}")
    } else {
        major.to_owned()
    };
    println!("cargo::rustc-cdylib-link-arg=-Wl,-soname,libsie.so.{abi}");
}
