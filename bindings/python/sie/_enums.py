"""The library's enums (sie.h), as IntEnums that print as their names."""

from __future__ import annotations

import enum
import operator
from typing import Any, Type


class _NamedEnum(enum.IntEnum):
    """An IntEnum that prints as its name (StopReason.CONVERGED), as on every Python version."""

    def __str__(self) -> str:
        return f"{type(self).__name__}.{self.name}"

    def __format__(self, spec: str) -> str:
        return format(str(self), spec)


class Status(_NamedEnum):
    OK = 0
    NULL_ARGUMENT = 1
    INVALID_ARGUMENT = 2
    NON_FINITE_INPUT = 3
    TOO_FEW_POINTS = 4
    CALLBACK_FAILED = 5
    NO_RESULT = 6
    BUFFER_TOO_SMALL = 7
    BUSY = 8
    CANCELLED = 9
    OUT_OF_MEMORY = 10
    PANIC = 100


class CostFunction(_NamedEnum):
    SIE = 0
    L2 = 1
    TRUNCATED_L2 = 2
    LP = 3
    STUDENT_T = 4
    HUBER = 5
    CAUCHY = 6
    GEMAN_MCCLURE = 7
    TUKEY = 8


class Metric(_NamedEnum):
    POINT_TO_POINT = 0
    POINT_TO_PLANE = 1


class NoiseModel(_NamedEnum):
    CONSTANT = 0
    QUADRATIC_DEPTH = 1


class HistogramMode(_NamedEnum):
    POOLED = 0
    PER_COLUMN = 1


class StopReason(_NamedEnum):
    NONE = 0
    CONVERGED = 1
    ITERATION_LIMIT = 2
    DEGENERATE = 3
    CANCELLED = 4


class Starts(_NamedEnum):
    """Where SIE starts (Context.set_starts / starts=...)."""

    AUTOMATIC = 0  # several starts, the most significant result is kept (the default)
    INITIAL_GUESS = 1  # the paper's method from the guess (again from its result if it went > 10 sigma, beyond a local correction; a narrow beta too if that is not GOOD)
    GLOBAL = 2  # no guess needed: descriptor matches propose the starts (slower; small or flat clouds refused)


class Verdict(_NamedEnum):
    """How far to trust a registration (Summary.verdict)."""

    NONE = 0  # no result
    GOOD = 1  # the evidence supports the pose: use it
    DOUBTFUL = 2  # registered, but some evidence is weak: check it, or retry from another guess
    UNSUPPORTED = 3  # no inlier cluster stands out from the background: reject the pose


class StartKind(_NamedEnum):
    """Which start the returned transform came from (Summary.start)."""

    INITIAL_GUESS = 0
    NARROW_BETA = 1
    SCALE_FREE_LEAD = 2
    HYPOTHESIS = 3
    WARM_START = 4
    HALF_TURN = 5  # a near-symmetric scene's rival pose (another start turned half a turn)
    PERIOD_SHIFT = 6  # a repeating scene's rival pose (another start shifted by one period)
    FEATURE_MATCH = 7  # a pose from matched FPFH descriptors (Starts.GLOBAL)
    QUARTER_TURN = 8  # a room's rival pose (another start turned a quarter turn, re-centred)


class FrameStatus(_NamedEnum):
    """What became of a frame given to Odometry.register_frame."""

    FIRST = 0  # the first usable frame: its sensor is the world frame
    ACCEPTED = 1  # registered GOOD onto the last accepted frame: the pose moved
    REPEATED = 2  # bit for bit the last accepted frame again: ignored
    NOT_GOOD = 3  # registered, verdict not GOOD: ignored
    JUMPED = 4  # GOOD, but (a motion known) further from the guess than the frame's median range
    LOOSE = 5  # DOUBTFUL for its conditioning alone: accepted, one direction weakly fixed


class Cloud(_NamedEnum):
    SOURCE = 0
    TARGET = 1


def _enum_or_int(kind: Any, value: int) -> Any:
    try:
        return kind(value)
    except ValueError:
        return int(value)



def _enum_arg(kind: Type[enum.IntEnum], value: Any, name: str) -> int:
    """The C value of an enum argument given as a member of `kind`, its name as a string (any
    case, - for _: "point_to_point", "POINT-TO-POINT") or an integer (passed on as it is: the
    library refuses unknown values)."""
    if isinstance(value, kind):
        return int(value)
    valid = ", ".join(repr(member.name.lower()) for member in kind)
    if isinstance(value, str):
        key = value.strip().upper().replace("-", "_")
        if key in kind.__members__:
            return int(kind[key])
        raise ValueError(f"{name} {value!r} is not a {kind.__name__}; valid names: {valid}")
    if isinstance(value, (enum.Enum, bool)):
        # Metric.POINT_TO_PLANE == 1 == CostFunction.L2: another enum is a mistake, not a value.
        raise TypeError(f"{name} must be a {kind.__name__} or its name ({valid}), got {value}")
    try:
        return operator.index(value)
    except TypeError:
        raise TypeError(f"{name} must be a {kind.__name__} or its name ({valid}), "
                        f"got {type(value).__name__} {value!r}") from None
