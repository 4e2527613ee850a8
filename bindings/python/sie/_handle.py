"""A library handle (context or target) that close() may be asked to free while a call is using
it: from that call's own callback, or from another thread. The library would ignore the free of
a busy context and use a freed target; the binding would drop the callback objects the library
still calls. So the free is deferred: close() marks the handle closed at once (new calls are
refused) and the last running call frees it when it returns."""

from __future__ import annotations

import ctypes
import threading
from contextlib import contextmanager
from typing import Any, Callable, Dict, Iterator

from ._enums import Status
from ._library import SieError


class _Handle:
    def __init__(self, pointer: Any, free: Callable[[ctypes.c_void_p], None], what: str) -> None:
        # Reentrant: a signal handler may call cancel() on a thread that holds the lock.
        self._lock = threading.RLock()
        self._pointer = pointer if isinstance(pointer, ctypes.c_void_p) else ctypes.c_void_p(pointer)
        self._free = free
        self._what = what
        self._calls = 0  # methods using the pointer now (nested ones from callbacks included)
        self._closing = False
        # Objects the library points at (ctypes callbacks): dropped only once it is freed.
        self.keep: Dict[str, Any] = {}

    @property
    def closed(self) -> bool:
        return self._closing or not self._pointer.value

    @contextmanager
    def use(self) -> Iterator[ctypes.c_void_p]:
        """The live pointer for the duration of one method's calls into the library."""
        with self._lock:
            if self.closed:
                raise SieError(Status.NULL_ARGUMENT, f"the {self._what} is closed")
            self._calls += 1
        try:
            yield self._pointer
        finally:
            with self._lock:
                self._calls -= 1
                pointer = self._detach()
            self._release(pointer)

    def close(self) -> None:
        """Frees the handle now, or when the last call using it returns. Idempotent."""
        with self._lock:
            self._closing = True
            pointer = self._detach()
        self._release(pointer)

    def cancel(self, function: Callable[[ctypes.c_void_p], Any]) -> None:
        """function(pointer) under the lock, if not freed yet (closing included): for
        sie_context_cancel, which may stop the call a deferred close waits for."""
        with self._lock:
            if self._pointer.value:
                function(self._pointer)

    def _detach(self) -> ctypes.c_void_p:
        """Under the lock: the pointer to free, once closing and no call uses it (else NULL)."""
        if not self._closing or self._calls:
            return ctypes.c_void_p(None)
        pointer, self._pointer = self._pointer, ctypes.c_void_p(None)
        return pointer

    def _release(self, pointer: ctypes.c_void_p) -> None:
        if pointer.value:
            self._free(pointer)
            self.keep.clear()
