"""Builds libsie with cargo and puts the shared library inside the `sie` package.

`pip install ./bindings/python` (or `pip wheel ./bindings/python`) from a checkout of the
repository runs `cargo build --release --lib --no-default-features` on ../../Cargo.toml and
copies target/release/libsie.so into the package as sie/libsie.so.<major>.<minor>. The wheel is
tagged py3-none-<platform>: the package is pure Python over ctypes, so one wheel serves every
CPython 3 on that platform, and it needs neither Rust nor a C compiler to install.

The sdist (`python -m build --sdist bindings/python`) carries the Rust sources under rust/
(Cargo.toml without the repository's examples, Cargo.lock, build.rs, cbindgen.toml, src/,
include/), so `pip install sie-<version>.tar.gz` builds the library with cargo outside a checkout.

Environment: CARGO (the cargo to run, default `cargo` on PATH), CARGO_TARGET_DIR (reuse another
build's target directory, e.g. CMake's build/sie/cargo).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist
from setuptools.dist import Distribution

try:  # setuptools >= 70 has its own; older ones use the wheel package's
    from setuptools.command.bdist_wheel import bdist_wheel
except ImportError:  # pragma: no cover - depends on the build environment
    from wheel.bdist_wheel import bdist_wheel

HERE = Path(__file__).resolve().parent
# An unpacked sdist has the Rust sources in rust/; a checkout has them two levels up.
REPOSITORY = HERE / "rust" if (HERE / "rust" / "Cargo.toml").is_file() else HERE.parent.parent
MANIFEST = REPOSITORY / "Cargo.toml"
# What cargo needs to build the library, copied into the sdist's rust/ (files and directories).
RUST_SOURCES = ["Cargo.toml", "Cargo.lock", "build.rs", "cbindgen.toml", "src", "include"]


def library_version() -> str:
    """The Rust package's version: the wheel is versioned with the library it carries."""
    if not MANIFEST.is_file():
        raise SystemExit(
            f"{MANIFEST} not found: the Python package is built from a checkout of the sie repository "
            "(pip install ./bindings/python), where cargo builds the library it carries"
        )
    match = re.search(r'^version\s*=\s*"([0-9]+\.[0-9]+\.[0-9]+)"', MANIFEST.read_text(), re.MULTILINE)
    if not match:
        raise SystemExit(f"no version line in {MANIFEST}")
    return match.group(1)


VERSION = library_version()
MAJOR, MINOR, _ = VERSION.split(".")
# The name the loader looks for (sie/_native.py): the soname of the C library.
BUNDLED_NAME = f"libsie.so.{MAJOR}.{MINOR}" if MAJOR == "0" else f"libsie.so.{MAJOR}"


class build_py_with_cargo(build_py):
    """build_py, then cargo; the library lands next to the package's modules."""

    def run(self) -> None:
        super().run()
        cargo = os.environ.get("CARGO") or shutil.which("cargo")
        if not cargo:
            raise SystemExit(
                "cargo not found: building the sie package compiles libsie from the repository's Rust "
                "sources; install the Rust toolchain (https://rustup.rs), or install a built wheel instead"
            )
        target_dir = Path(os.environ.get("CARGO_TARGET_DIR") or REPOSITORY / "target")
        command = [cargo, "build", "--release", "--locked", "--lib", "--no-default-features",
                   "--manifest-path", str(MANIFEST)]
        self.announce(" ".join(command), level=2)
        subprocess.run(command, check=True, env={**os.environ, "CARGO_TARGET_DIR": str(target_dir)})
        built = target_dir / "release" / "libsie.so"
        destination = Path(self.build_lib) / "sie" / BUNDLED_NAME
        destination.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(built, destination)
        destination.chmod(0o755)


class platform_wheel(bdist_wheel):
    """A platform wheel (it carries a shared library) for any Python 3: py3-none-<platform>."""

    def finalize_options(self) -> None:
        super().finalize_options()
        self.root_is_pure = False

    def get_tag(self):
        _, _, platform = super().get_tag()
        return "py3", "none", platform


def without_examples(manifest: str) -> str:
    """Cargo.toml without its [[example]] tables: their sources are not in the sdist, and cargo
    refuses a manifest that names a target whose file is missing."""
    kept, skipping = [], False
    for line in manifest.splitlines(keepends=True):
        if line.startswith("["):
            skipping = line.strip() == "[[example]]"
        if not skipping:
            kept.append(line)
    return "".join(kept)


class sdist_with_rust(sdist):
    """sdist, plus the Rust sources under rust/ so that installing it builds libsie with cargo."""

    def make_release_tree(self, base_dir: str, files) -> None:
        super().make_release_tree(base_dir, files)
        rust = Path(base_dir) / "rust"
        for name in RUST_SOURCES:
            source = REPOSITORY / name
            if not source.exists():
                raise SystemExit(f"{source} not found: the sdist is made from a checkout of the sie repository")
            if source.is_dir():
                shutil.copytree(source, rust / name, dirs_exist_ok=True)
            else:
                rust.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source, rust / name)
        cargo_toml = rust / "Cargo.toml"
        cargo_toml.write_text(without_examples(cargo_toml.read_text()))


class BinaryDistribution(Distribution):
    def has_ext_modules(self) -> bool:  # install into platlib, tag as a platform wheel
        return True


setup(
    version=VERSION,
    distclass=BinaryDistribution,
    cmdclass={"build_py": build_py_with_cargo, "bdist_wheel": platform_wheel, "sdist": sdist_with_rust},
)
