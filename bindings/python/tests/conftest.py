"""Shared helpers: optional libraries are skipped when absent, unless CI requires them."""

from __future__ import annotations

import importlib
import os

import pytest


def require(module: str):
    """pytest.importorskip, except that SIE_REQUIRE_OPTIONAL=1 (CI) makes a missing module an
    error: a test that CI is meant to run must not pass by skipping."""
    if os.environ.get("SIE_REQUIRE_OPTIONAL") == "1":
        return importlib.import_module(module)
    return pytest.importorskip(module)
