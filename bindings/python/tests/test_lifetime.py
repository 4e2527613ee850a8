"""close() while a call uses the context or target (issue 28, item 3): from the context's own
callback, or from another thread during align(). The free is deferred to the end of the running
call, which returns normally; later calls say "closed". Each case runs in a subprocess, so that
a crash fails the test instead of killing pytest. The other thread is synchronised with the
progress callback by events, not by sleeping."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

import sie

# The start of every script: two clouds, a helper asserting a "closed" SieError, and events.
PRELUDE = """
import threading
import numpy as np
import sie

rng = np.random.default_rng(7)
target = rng.uniform(-1, 1, (3000, 3)) * [2, 2, 0.5]
source = target[:2000] + [0.02, -0.01, 0.005]


# What call() raised: collected in callbacks and threads, checked by says_closed afterwards.
def refusal(call):
    try:
        call()
    except Exception as error:
        return error
    return None


def says_closed(error, what="context"):
    if callable(error):
        error = refusal(error)
    assert isinstance(error, sie.SieError) and error.status is sie.Status.NULL_ARGUMENT, repr(error)
    assert str(error) == f"null argument: the {what} is closed", error


def wait(event):
    assert event.wait(120), "the other side never came"  # a safety net, not a synchronisation
"""


def run_isolated(body: str) -> None:
    """Runs PRELUDE + body in a fresh interpreter (the same sie, the same library); it must exit
    0 and print "ok" last."""
    script = PRELUDE + textwrap.dedent(body) + '\nprint("ok")\n'
    result = subprocess.run([sys.executable, "-c", script], env=dict(os.environ), capture_output=True,
                            text=True, timeout=600, check=False)
    crashed = f" (killed by signal {-result.returncode})" if result.returncode < 0 else ""
    assert result.returncode == 0 and result.stdout.strip().endswith("ok"), (
        f"exit {result.returncode}{crashed}\nstdout: {result.stdout}\nstderr: {result.stderr}")


def test_close_inside_the_progress_callback():
    run_isolated("""
        ctx = sie.Context()
        refused = []

        def progress(entry):
            ctx.close()
            ctx.close()  # idempotent, also while deferred
            refused.append(refusal(lambda: ctx.set_seed(1)))

        ctx.set_progress_callback(progress)
        result = ctx.align(source, target)
        assert result.summary.converged, result.summary
        assert refused
        for error in refused:
            says_closed(error)
        assert result.inlier_probabilities.shape == (2000,)
        says_closed(ctx.summary)
        says_closed(lambda: ctx.align(source, target))
        ctx.close()
    """)


def test_close_inside_the_noise_callback_and_in_a_with_block():
    run_isolated("""
        with sie.Context() as ctx:
            def noise(cloud, xyz):
                ctx.close()
                return np.ones(len(xyz))

            ctx.set_noise_callback(noise)
            assert ctx.align(source, target).summary.converged
        says_closed(ctx.summary)
    """)


def test_close_inside_a_callback_that_then_raises():
    run_isolated("""
        ctx = sie.Context()

        def progress(entry):
            ctx.close()
            raise KeyError("after close")

        ctx.set_progress_callback(progress)
        try:
            ctx.align(source, target)
        except KeyError as error:
            assert "after close" in str(error)
        else:
            raise AssertionError("the callback's error was lost")
        says_closed(ctx.summary)
    """)


def test_close_from_another_thread_during_align():
    run_isolated("""
        ctx = sie.Context()
        inside, closed = threading.Event(), threading.Event()
        seen_by_closer = []

        def progress(entry):
            if not inside.is_set():
                inside.set()  # align() is running: the closer may close now
                wait(closed)  # and align() goes on only once close() has returned

        def closer():
            wait(inside)
            try:
                ctx.close()
                seen_by_closer.append(refusal(ctx.summary))
            finally:
                closed.set()

        thread = threading.Thread(target=closer)
        thread.start()
        ctx.set_progress_callback(progress)
        result = ctx.align(source, target)
        thread.join()
        assert result.summary.converged, result.summary
        says_closed(seen_by_closer[0])
        says_closed(ctx.summary)
    """)


def test_close_then_cancel_from_another_thread_stops_the_running_align():
    run_isolated("""
        ctx = sie.Context()
        inside, closed = threading.Event(), threading.Event()

        def progress(entry):
            if not inside.is_set():
                inside.set()
                wait(closed)

        def closer():
            wait(inside)
            try:
                ctx.close()
                ctx.cancel()  # reaches the running registration: the context is not freed yet
            finally:
                closed.set()

        thread = threading.Thread(target=closer)
        thread.start()
        ctx.set_progress_callback(progress)
        result = ctx.align(source, target)
        thread.join()
        assert result.summary.stop_reason is sie.StopReason.CANCELLED, result.summary
        says_closed(ctx.summary)
        ctx.cancel()  # a no-op once freed
    """)


def test_closing_a_target_while_an_align_uses_it():
    run_isolated("""
        ctx = sie.Context()
        prepared = sie.Target(target)
        ctx.set_progress_callback(lambda entry: prepared.close())
        assert ctx.align(source, prepared).summary.converged
        assert len(prepared) == 0
        says_closed(lambda: ctx.align(source, prepared), "target")
        says_closed(prepared.estimate_normals, "target")

        # From another thread.
        prepared = ctx.prepare_target(target)
        inside, closed = threading.Event(), threading.Event()

        def progress(entry):
            if not inside.is_set():
                inside.set()
                wait(closed)

        def closer():
            wait(inside)
            try:
                prepared.close()
            finally:
                closed.set()

        thread = threading.Thread(target=closer)
        thread.start()
        ctx.set_progress_callback(progress)
        assert ctx.align(source, prepared).summary.converged
        thread.join()
        says_closed(lambda: ctx.align(source, prepared), "target")
    """)


def test_closed_context_says_closed():
    ctx = sie.Context()
    ctx.close()
    ctx.close()  # idempotent
    for call in (lambda: ctx.set_seed(3), ctx.summary, ctx.trace, lambda: ctx.estimate_inliers([1.0] * 20)):
        with pytest.raises(sie.SieError) as error:
            call()
        # NULL_ARGUMENT as before (the C library's status for a NULL context); the text is new.
        assert error.value.status is sie.Status.NULL_ARGUMENT
        assert str(error.value) == "null argument: the context is closed"
    ctx.cancel()  # allowed at any time
