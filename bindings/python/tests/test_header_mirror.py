"""The ctypes mirror of include/sie.h is checked against the header itself (as tests/header.rs
checks the header against the Rust code): every struct's fields and types in order, every
function's return and argument types, every enum's values."""

from __future__ import annotations

import ctypes
import re
from pathlib import Path

import pytest

import sie
from sie import _native

HEADER = Path(__file__).resolve().parents[3] / "include" / "sie.h"

# C type spellings in sie.h -> the ctypes type the mirror must use.
SCALARS = {
    "double": ctypes.c_double,
    "float": ctypes.c_float,
    "uint64_t": ctypes.c_uint64,
    "uint32_t": ctypes.c_uint32,
    "int32_t": ctypes.c_int32,
    "int64_t": ctypes.c_int64,
    "size_t": ctypes.c_size_t,
    "bool": ctypes.c_bool,
    "sie_status": ctypes.c_uint32,
}


def header_text() -> str:
    if not HEADER.exists():
        pytest.skip(f"{HEADER} not found (installed package without the source tree)")
    # Comments out; preprocessor lines out (the enums' C23 underlying-type guards).
    text = re.sub(r"/\*.*?\*/", "", HEADER.read_text(), flags=re.S)
    text = re.sub(r"//[^\n]*", "", text)
    return "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))


def c_structs(text: str) -> dict[str, list[tuple[str, str, int]]]:
    """name -> [(field, C type, array length or 0)]."""
    structs = {}
    for name, body in re.findall(r"typedef struct (\w+) \{(.*?)\} \1;", text, flags=re.S):
        fields = []
        for declaration in body.split(";"):
            declaration = " ".join(declaration.split())
            if not declaration:
                continue
            match = re.fullmatch(r"([\w ]+?) (\w+)(?:\[(\d+)\])?", declaration)
            assert match, f"{name}: cannot read {declaration!r}"
            fields.append((match.group(2), match.group(1), int(match.group(3) or 0)))
        structs[name] = fields
    return structs


def test_every_struct_matches_field_by_field():
    structs = c_structs(header_text())
    assert {"sie_summary", "sie_model", "sie_trace_entry"} <= set(structs)
    for name, fields in structs.items():
        mirror = getattr(_native, name, None)
        assert mirror is not None, f"_native has no {name}"
        assert [f for f, _ in mirror._fields_] == [f for f, _, _ in fields], name
        for (field, ctype), (_, c_type, length) in zip(mirror._fields_, fields):
            expected = SCALARS[c_type]
            if length:
                expected = expected * length
                assert ctype._type_ == SCALARS[c_type] and ctype._length_ == length, f"{name}.{field}"
            else:
                assert ctype == expected, f"{name}.{field}: {ctype} vs {c_type}"


def c_type_of(spelling: str):
    """How a C parameter or return type is mirrored: a ctypes type, or ("pointer", pointee) /
    ("named", typedef) for the checks below."""
    spelling = " ".join(spelling.replace("const ", "").replace("*", " *").split()).replace("* *", "**")
    if spelling == "void":
        return None
    struct = re.match(r"struct (sie_\w+)", spelling)
    if struct and isinstance(getattr(_native, struct.group(1), None), type(ctypes.Structure)):
        spelling = spelling[len("struct "):]  # a struct the caller allocates, not a handle
    elif spelling.startswith("struct sie_"):
        # Opaque handles; a pointer to one (an out parameter) is a pointer to a handle.
        return ("pointer", "handle") if spelling.endswith("**") else ctypes.c_void_p
    if spelling == "char *":
        return ctypes.c_char_p
    if spelling.endswith("*"):
        return ("pointer", spelling[:-1].strip())
    if spelling in SCALARS:
        return SCALARS[spelling]
    return ("named", spelling)  # callback typedefs


def test_every_function_has_the_header_signature():
    text = header_text()
    declarations = re.findall(r"^(\w[\w *]*?)\s*\b(sie_\w+)\(([^)]*)\);", text, flags=re.M)
    assert len(declarations) >= 35
    names = {name for _, name, _ in declarations}
    assert names == set(_native._SIGNATURES), (
        f"only in sie.h: {sorted(names - set(_native._SIGNATURES))}; "
        f"only in _native: {sorted(set(_native._SIGNATURES) - names)}"
    )
    for returns, name, arguments in declarations:
        restype, argtypes = _native._SIGNATURES[name]
        parameters = [" ".join(p.split()) for p in arguments.split(",")]
        if parameters == ["void"]:
            parameters = []
        assert len(parameters) == len(argtypes), f"{name}: {len(parameters)} parameters in sie.h"
        check(name, "return", c_type_of(returns), restype)
        for index, (parameter, argtype) in enumerate(zip(parameters, argtypes)):
            spelling = re.fullmatch(r"(.*?)\s*\b\w+", parameter).group(1)  # without the name
            check(name, f"argument {index}", c_type_of(spelling), argtype)


def check(function: str, what: str, expected, mirrored) -> None:
    if not isinstance(expected, tuple):
        assert mirrored == expected, f"{function} {what}: {mirrored} vs {expected}"
        return
    kind, pointee = expected
    if kind == "named":
        assert mirrored in (_native.NOISE_FN, _native.PROGRESS_FN), f"{function} {what}: {mirrored}"
    elif pointee == "handle":
        assert mirrored in (ctypes.POINTER(ctypes.c_void_p), ctypes.c_void_p), f"{function} {what}: {mirrored}"
    elif pointee == "void":
        assert mirrored == ctypes.c_void_p, f"{function} {what}: {mirrored}"
    elif pointee in SCALARS:
        assert mirrored == ctypes.POINTER(SCALARS[pointee]), f"{function} {what}: {mirrored} vs {pointee} *"
    else:
        struct = getattr(_native, pointee)
        assert mirrored in (ctypes.POINTER(struct), ctypes.c_void_p), f"{function} {what}: {mirrored}"


def c_enums(text: str) -> dict[str, dict[str, int]]:
    enums = {}
    for name, body in re.findall(r"enum (sie_\w+)\s*(?::\s*uint32_t\s*)?\{(.*?)\};", text, flags=re.S):
        values = {}
        for constant, value in re.findall(r"(SIE_\w+)\s*=\s*(\d+)", body):
            values[constant] = int(value)
        enums[name] = values
    return enums


# The Python enum for each C enum, and the prefix its constants carry in C.
PYTHON_ENUMS = {
    "sie_status": (sie.Status, "SIE_STATUS_"),
    "sie_cost_function": (sie.CostFunction, "SIE_COST_FUNCTION_"),
    "sie_metric": (sie.Metric, "SIE_METRIC_"),
    "sie_noise_model": (sie.NoiseModel, "SIE_NOISE_MODEL_"),
    "sie_histogram_mode": (sie.HistogramMode, "SIE_HISTOGRAM_MODE_"),
    "sie_stop_reason": (sie.StopReason, "SIE_STOP_REASON_"),
    "sie_starts": (sie.Starts, "SIE_STARTS_"),
    "sie_verdict": (sie.Verdict, "SIE_VERDICT_"),
    "sie_start_kind": (sie.StartKind, "SIE_START_KIND_"),
    "sie_cloud": (sie.Cloud, "SIE_CLOUD_"),
    "sie_frame_status": (sie.FrameStatus, "SIE_FRAME_STATUS_"),
}


def test_every_enum_has_the_header_values():
    enums = c_enums(header_text())
    assert set(enums) == set(PYTHON_ENUMS), f"enums in sie.h: {sorted(enums)}"
    for name, values in enums.items():
        python, prefix = PYTHON_ENUMS[name]
        mirrored = {member.name: int(member) for member in python}
        expected = {constant[len(prefix):]: value for constant, value in values.items()}
        assert mirrored == expected, f"{name}: {mirrored} vs {expected}"
