"""Enum-typed settings given by name, and the messages of setting and result errors (issue 28,
item 7)."""

from __future__ import annotations

import numpy as np
import pytest

import sie

# Every enum-typed argument of the binding: (setting, enum, the C setter it reaches).
ENUM_SETTINGS = [
    ("metric", sie.Metric, "sie_context_set_metric"),
    ("cost", sie.CostFunction, "sie_context_set_cost_function"),
    ("starts", sie.Starts, "sie_context_set_starts"),
    ("noise_model", sie.NoiseModel, "sie_context_set_noise_model"),
    ("histogram_mode", sie.HistogramMode, "sie_context_set_histogram_mode"),
]


@pytest.mark.parametrize("setting, kind, setter", ENUM_SETTINGS)
def test_enum_settings_take_names(monkeypatch, setting, kind, setter):
    """The member, its name in lower or upper case or with - for _, and its integer value all
    reach the library as the same value, through Context(**settings) and set_<name>()."""
    received = []
    original = getattr(sie._lib, setter)

    def recording(handle, value, *rest):
        received.append(value)
        return original(handle, value, *rest)

    monkeypatch.setattr(sie._lib, setter, recording)
    cost = setting == "cost"
    for member in kind:
        spellings = [member, member.name.lower(), member.name, member.name.lower().replace("_", "-"),
                     f" {member.name.title()} ", int(member)]
        for value in spellings:
            received.clear()
            # The baseline costs need a parameter; 1 suits all of them.
            ctx = sie.Context(**{setting: (value, 1.0) if cost else value})
            if cost:
                ctx.set_cost_function(value, 1.0)
            else:
                getattr(ctx, f"set_{setting}")(value)
            assert received == [int(member)] * 2, (value, received)
            assert all(type(v) is int for v in received), received
            ctx.close()


@pytest.mark.parametrize("setting, kind, setter", ENUM_SETTINGS)
def test_bad_enum_names_list_the_valid_ones(setting, kind, setter):
    with pytest.raises(ValueError) as error:
        sie.Context(**{setting: "no_such_name"})
    message = str(error.value)
    assert setting in message and "'no_such_name'" in message and kind.__name__ in message
    for member in kind:
        assert repr(member.name.lower()) in message, message
    # Another enum's member is not taken for its integer value (POINT_TO_PLANE == 1 == L2).
    other = sie.Verdict.GOOD
    with pytest.raises(TypeError, match=kind.__name__):
        sie.Context(**{setting: other})
    with pytest.raises(TypeError, match=kind.__name__):
        sie.Context(**{setting: 1.5})


def test_names_in_align_and_cost_tuples():
    rng = np.random.default_rng(5)
    target = rng.uniform(-1, 1, (1500, 3))
    source = target + [0.01, 0.0, 0.0]
    by_name = sie.align(source, target, metric="point_to_point", starts="initial_guess")
    by_enum = sie.align(source, target, metric=sie.Metric.POINT_TO_POINT, starts=sie.Starts.INITIAL_GUESS)
    np.testing.assert_array_equal(by_name.transform, by_enum.transform)
    huber = sie.align(source, target, cost=("huber", 0.05), metric="point_to_point")
    assert huber.summary.converged
    with pytest.raises(sie.SieError) as error:
        sie.Context(cost="huber")  # no scale: the library's refusal, as with CostFunction.HUBER
    assert error.value.status is sie.Status.INVALID_ARGUMENT


def test_result_before_any_registration_says_no_result_once():
    with pytest.raises(sie.SieError) as error:
        sie.Context().summary()
    text = str(error.value)
    assert error.value.status is sie.Status.NO_RESULT
    assert text.startswith("no result: ") and text.count("no result") == 1, text
    # Messages that do not repeat the status still get it in front.
    with pytest.raises(sie.SieError) as error:
        sie.Context().set_max_iterations(0)
    assert str(error.value) == f"invalid argument: {error.value.message}"
