#!/usr/bin/env python3
"""README.md's samples of program output are outputs of their commands: regenerate or check them.

    python3 scripts/readme-samples.py            # rerun each sample's command, rewrite the samples that drifted
    python3 scripts/readme-samples.py --check    # rerun them, exit 1 with a diff when README.md differs
    python3 scripts/readme-samples.py --list     # the samples and their commands

A sample sits between `<!-- sample: NAME -->` and `<!-- /sample -->` in README.md: a fenced
block whose first lines are the command (`$ ...`) and the rest its output, or, inline, a
sentence made from another sample's output. SAMPLES below says how each is run.

What legitimately varies from machine to machine is masked before comparing (wall times, the
worker's host:pid, the machine line), and a number may differ by one unit in its last printed
digit (numpy's BLAS and Open3D pick their kernels by CPU). Everything else must be equal: the
registrations are deterministic and do not depend on the thread count (checked with 1, 2 and 4
threads). Rewriting keeps a sample that only differs in masked parts, so timings in README.md
are those of the machine that last changed a result.

Environment: SIE_DATA_DIR (the scans, default ../shared/data; samples that need them are
skipped with a message when absent), SIE_SAMPLE_PYTHON (a Python with sie, open3d, small_gicp
and dask, for the Python samples), SIE_SAMPLE_EXAMPLES (the examples-cpp build directory, for
compare_pcl), SIE_SAMPLE_SIE (the CLI built from this checkout, for example CMake's
install of it; default: cargo builds target/release/sie). A sample whose requirement is
missing is skipped, never failed.
"""

from __future__ import annotations

import argparse
import difflib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DATA = Path(os.environ.get("SIE_DATA_DIR") or ROOT.parent / "shared" / "data").resolve()
# How README.md's commands spell the data folder (the default, beside the checkout).
SHOWN_DATA = "../shared/data"
PYTHON = os.environ.get("SIE_SAMPLE_PYTHON") or ""
EXAMPLES = os.environ.get("SIE_SAMPLE_EXAMPLES") or ""

NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
MASK = "<varies>"


@dataclass
class Sample:
    name: str
    shown: str  # the command as README.md shows it, after "$ "
    run: Callable[["Sample", Path], str]  # the output, given a scratch directory
    needs: List[tuple] = field(default_factory=list)  # (ok, message when not)
    masks: List[str] = field(default_factory=list)  # regexes; group 1 (else the match) varies
    files: Dict[Path, Path] = field(default_factory=dict)  # files it wrote -> where README.md's copy is


def sh(command: List[str], cwd: Path, env: Optional[Dict[str, str]] = None, stderr: bool = True,
       exit_codes=(0,)) -> tuple:
    """Runs a command; returns (stdout, stderr, exit code). Fails on an exit code not expected."""
    done = subprocess.run(command, cwd=cwd, env={**os.environ, **(env or {})}, capture_output=True, text=True)
    if done.returncode not in exit_codes:
        raise RuntimeError(f"{' '.join(command)} exited with {done.returncode}:\n{done.stdout}{done.stderr}")
    return done.stdout, done.stderr, done.returncode


def data_scratch(scratch: Path) -> Path:
    """A working directory from which ../shared/data is the data folder, as in README.md."""
    work = scratch / "work"
    (scratch / "shared").mkdir(parents=True, exist_ok=True)
    link = scratch / "shared" / "data"
    if not link.exists():
        link.symlink_to(DATA)
    work.mkdir(exist_ok=True)
    return work


def sie_binary() -> str:
    """The CLI built from this checkout: SIE_SAMPLE_SIE (e.g. CMake's install of it), else cargo's."""
    if os.environ.get("SIE_SAMPLE_SIE"):
        return str(Path(os.environ["SIE_SAMPLE_SIE"]).resolve())
    sh(["cargo", "build", "--release", "--locked", "--quiet", "--bin", "sie"], ROOT)
    target = Path(os.environ.get("CARGO_TARGET_DIR") or ROOT / "target")
    return str((ROOT / target / "release" / "sie").resolve())


# ---- how each sample runs ---------------------------------------------------------------------


def run_demo(sample: Sample, scratch: Path) -> str:
    # `cargo run --release -- demo` is `sie demo` with the binary cargo builds from this checkout.
    out, _, _ = sh([sie_binary(), "demo"], ROOT)
    return out


LIDAR = f"{SHOWN_DATA}/small_gicp-data"


def run_lidar(sample: Sample, scratch: Path) -> str:
    work = data_scratch(scratch)
    (work / "docs").mkdir(exist_ok=True)
    args = sample.shown.split()[1:]
    out, err, code = sh([sie_binary(), *args], work, exit_codes=(0, 1, 3))
    # The figure is part of the sample: README.md shows it next to the text.
    sample.files = {work / "docs" / "fig1-lidar.png": ROOT / "docs" / "fig1-lidar.png"}
    return out + err + f"[exit code {code}]\n"


# Point 2 of 5 is not a number: the error a user with a broken export sees.
BAD_XYZ = "0.1 0.2 0.3\nnan 0.5 0.6\n0.7 0.8 0.9\n1.0 1.1 1.2\n1.3 1.4 1.5\n"


def run_bad_file(sample: Sample, scratch: Path) -> str:
    work = scratch / "bad"
    work.mkdir(exist_ok=True)
    (work / "scan.xyz").write_text(BAD_XYZ)
    shutil.copyfile(DATA / "pcl-test-bunny" / "bun4.pcd", work / "bun4.pcd")
    out, err, code = sh([sie_binary(), *sample.shown.split()[1:]], work, exit_codes=(2,))
    return out + err + f"[exit code {code}]\n"


def run_compare_pcl(sample: Sample, scratch: Path) -> str:
    work = data_scratch(scratch)
    build = work / "build"
    if not build.exists():
        build.symlink_to(Path(EXAMPLES).resolve())
    # The shell expands {a,b,c}; the list here is what it passes.
    args: List[str] = []
    for word in sample.shown.split()[1:]:
        match = re.fullmatch(r"(.*)\{(.*)\}", word)
        args += [match.group(1) + part for part in match.group(2).split(",")] if match else [word]
    out, _, _ = sh([str(build / "compare_pcl"), *args], work, env={"SIE_DATA_DIR": SHOWN_DATA})
    return out


def run_python(sample: Sample, scratch: Path) -> str:
    words = sample.shown.split()
    env = dict(word.split("=", 1) for word in words if "=" in word and not word.startswith("-"))
    args = [w for w in words if "=" not in w or w.startswith("-")][1:]
    out, _, _ = sh([PYTHON, *args], ROOT, env={**env, "SIE_DATA_DIR": str(DATA)})
    return out


def dask_count(output: str) -> str:
    """The sentence under the Dask table, from the table itself."""
    rows = [line.split(",") for line in output.splitlines()[1:] if line.count(",") > 5]
    header = output.splitlines()[0].split(",")
    success, verdict = header.index("success"), header.index("verdict")
    right = [r for r in rows if r[success] == "True"]
    wrong_good = sum(r[verdict] == "good" for r in rows if r[success] != "True")
    right_good = sum(r[verdict] == "good" for r in right)
    return (f"{len(right)} of the {len(rows)} pairs are within the table's bar ({right_good} of them called good); "
            f"of the {len(rows) - len(right)} wrong ones, {wrong_good} {'is' if wrong_good == 1 else 'are'} called good")


have_data = (DATA / "small_gicp-data" / "source.ply").is_file() and (DATA / "pcl-test-bunny" / "bun4.pcd").is_file()
DATA_NEEDED = (have_data, f"the scans are not in {DATA} (set SIE_DATA_DIR)")
PYTHON_NEEDED = (bool(PYTHON), "SIE_SAMPLE_PYTHON is not set (a Python with sie, open3d, small_gicp, dask)")
EXAMPLES_NEEDED = (bool(EXAMPLES) and Path(EXAMPLES, "compare_pcl").is_file(),
                   "SIE_SAMPLE_EXAMPLES is not an examples-cpp build with compare_pcl")
TIME = r"^(?:PCL|sie) .* (\d+\.\d+)$"  # compare_pcl's time column
# compare_open3d_small_gicp.py's time column (fixed widths: method 34, then 10, 10, 7, 11, 10;
# the sample is indented in a list item).
OPEN3D_TIME = r"^[ \t]*(?=sie \(|Open3D ICP|small_gicp PLANE).{34}.{10}.{10}.{7}.{11}(.{10})"

SAMPLES = [
    Sample("demo", "cargo run --release -- demo", run_demo, masks=[r" (\d+\.\d)$"]),
    Sample("lidar", f"sie register {LIDAR}/source.ply {LIDAR}/target.ply --ground-truth "
                    f"{LIDAR}/T_target_source.txt -o T.txt --plot docs/fig1-lidar.png", run_lidar,
           needs=[DATA_NEEDED], masks=[r"in (\d+\.\d+ s \(reading \d+\.\d+ s\))"]),
    Sample("bad-file", "sie register scan.xyz bun4.pcd", run_bad_file, needs=[DATA_NEEDED]),
    Sample("compare-pcl-bunny", "./build/compare_pcl", run_compare_pcl, needs=[DATA_NEEDED, EXAMPLES_NEEDED],
           masks=[r"^machine: (.*)$", TIME]),
    Sample("compare-pcl-lidar", f"./build/compare_pcl {LIDAR}/{{source.ply,target.ply,T_target_source.txt}} "
                                "--tolerance 0.5 0.05", run_compare_pcl, needs=[DATA_NEEDED, EXAMPLES_NEEDED],
           masks=[r"^machine: (.*)$", TIME]),
    Sample("open3d-bunny", "OMP_NUM_THREADS=1 python bindings/python/examples/compare_open3d_small_gicp.py --pair bunny",
           run_python, needs=[DATA_NEEDED, PYTHON_NEEDED], masks=[OPEN3D_TIME]),
    Sample("open3d-lidar", "OMP_NUM_THREADS=1 python bindings/python/examples/compare_open3d_small_gicp.py",
           run_python, needs=[DATA_NEEDED, PYTHON_NEEDED], masks=[OPEN3D_TIME]),
    Sample("dask", "python bindings/python/examples/dask_pairs.py --workers 2", run_python,
           needs=[DATA_NEEDED, PYTHON_NEEDED], masks=[r",([\d.]+,[^,]+)$"]),
]
DERIVED = {"dask-count": ("dask", dask_count)}  # inline samples: made from another's output


# ---- README.md: find, compare, rewrite ---------------------------------------------------------

BLOCK = re.compile(r"(?P<indent>[ \t]*)<!-- sample: (?P<name>[\w-]+) -->(?P<body>.*?)<!-- /sample -->", re.S)


def fenced(sample: Sample, output: str, indent: str) -> str:
    command = f"$ {sample.shown}"
    if len(command) > 100 and " --" in command:  # README.md's width: continue long commands
        head, _, tail = command.partition(" --")
        command = f"{head} \\\n      --{tail}"
    lines = ["```text", *command.splitlines(), *output.rstrip().splitlines(), "```"]
    return "\n" + "".join(f"{indent}{line}".rstrip() + "\n" for line in lines) + indent


def masked(sample: Optional[Sample], text: str) -> List[str]:
    lines = []
    for line in text.strip().splitlines():
        for pattern in sample.masks if sample else []:
            match = re.search(pattern, line)
            if match:
                start, end = match.span(1) if match.groups() else match.span()
                line = line[:start] + MASK + line[end:]
        # Column widths follow the widest value, a masked time too.
        lines.append(" ".join(line.split()))
    return lines


def last_digit(number: str) -> float:
    mantissa, _, exponent = number.partition("e")
    decimals = len(mantissa.partition(".")[2])
    if not decimals and not exponent:
        return 0.0  # counts (iterations, points) must be equal
    return 10.0 ** (-decimals + (int(exponent) if exponent else 0))


def same(sample: Optional[Sample], old: str, new: str) -> bool:
    """Equal after masking, numbers within one unit of their last printed digit."""
    a, b = masked(sample, old), masked(sample, new)
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if NUMBER.sub("#", x) != NUMBER.sub("#", y):
            return False
        for p, q in zip(NUMBER.findall(x), NUMBER.findall(y)):
            if abs(float(p) - float(q)) > 1.0001 * max(last_digit(p), last_digit(q)):
                return False
    return True


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare only; exit 1 with a diff on drift")
    parser.add_argument("--only", action="append", help="only this sample (repeatable)")
    parser.add_argument("--list", action="store_true")
    args = parser.parse_args()
    if args.list:
        for sample in SAMPLES:
            print(f"{sample.name:<18} $ {sample.shown}")
        return 0

    text = README.read_text()
    present = {m.group("name"): m.group("body") for m in BLOCK.finditer(text)}
    indents = {m.group("name"): m.group("indent") for m in BLOCK.finditer(text)}
    known = {s.name for s in SAMPLES} | set(DERIVED)
    problems = [f"README.md has a sample named {n!r} that this script does not know" for n in present if n not in known]
    problems += [f"README.md lacks the sample {n!r}" for n in known if n not in present]
    outputs: Dict[str, str] = {}
    replacements: Dict[str, str] = {}
    skipped = drifted = 0
    with tempfile.TemporaryDirectory(prefix="readme-samples-") as scratch_dir:
        scratch = Path(scratch_dir)
        for sample in SAMPLES:
            if args.only and sample.name not in args.only:
                continue
            missing = [message for ok, message in sample.needs if not ok]
            if missing:
                print(f"readme-samples: skipped {sample.name}: {'; '.join(missing)}")
                skipped += 1
                continue
            try:
                output = sample.run(sample, scratch)
            except (RuntimeError, OSError) as error:
                problems.append(f"{sample.name}: {error}")
                continue
            output = output.replace(str(DATA), SHOWN_DATA)
            outputs[sample.name] = output
            body = fenced(sample, output, indents.get(sample.name, ""))
            if same(sample, present.get(sample.name, ""), body):
                print(f"readme-samples: {sample.name} matches")
                continue
            drifted += 1
            print(f"readme-samples: {sample.name} differs from its command's output:")
            sys.stdout.writelines(difflib.unified_diff(
                present.get(sample.name, "").strip().splitlines(True), body.strip().splitlines(True),
                f"README.md ({sample.name})", f"$ {sample.shown}"))
            print()
            replacements[sample.name] = body
            if not args.check:
                for built, kept in sample.files.items():
                    shutil.copyfile(built, kept)
        for name, (source, derive) in DERIVED.items():
            if source not in outputs:
                print(f"readme-samples: skipped {name}: made from {source}, which did not run")
                skipped += 1
                continue
            sentence = derive(outputs[source])
            if present.get(name, "").strip() != sentence:
                drifted += 1
                print(f"readme-samples: {name} differs:\n- {present.get(name, '').strip()}\n+ {sentence}")
                replacements[name] = sentence
            else:
                print(f"readme-samples: {name} matches")

    if replacements and not args.check:
        text = BLOCK.sub(lambda m: f"{m.group('indent')}<!-- sample: {m.group('name')} -->"
                         f"{replacements.get(m.group('name'), m.group('body'))}<!-- /sample -->", text)
        README.write_text(text)
        print(f"readme-samples: rewrote {len(replacements)} sample(s) in README.md")
    for problem in problems:
        print(f"readme-samples: error: {problem}")
    checked = len(outputs)
    print(f"readme-samples: {checked} run, {drifted} differ, {skipped} skipped, {len(problems)} error(s)")
    return 1 if problems or (args.check and drifted) else 0


if __name__ == "__main__":
    sys.exit(main())
