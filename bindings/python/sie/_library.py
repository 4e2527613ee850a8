"""The loaded libsie, its errors and its version."""

from __future__ import annotations

from . import _native
from ._enums import Status, _enum_or_int

_lib = _native.load_library()


class SieError(Exception):
    """A call into libsie failed: `status` (Status) and the library's `message`."""

    def __init__(self, status: int, message: str):
        self.status = _enum_or_int(Status, status)
        self.message = message
        text = _lib.sie_status_str(int(status)).decode()
        # Some library messages already start with the status ("no result: no registration ...").
        if not message or message == text or message.startswith(f"{text}:"):
            super().__init__(message or text)
        else:
            super().__init__(f"{text}: {message}")


def library_version() -> str:
    """The loaded library's version, e.g. "0.2.0"."""
    return str(_lib.sie_version_string().decode())


def _package_version() -> str:
    """The installed distribution's version; the wheel is versioned with the library it carries."""
    try:
        from importlib.metadata import PackageNotFoundError, version
    except ImportError:  # pragma: no cover - Python < 3.8
        return library_version()
    try:
        return version("sie")
    except PackageNotFoundError:  # run from a source checkout
        return library_version()

