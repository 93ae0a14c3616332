"""Build progress: the stages of a model build (deposition, compaction, jamming, balance
rounds, ...) told to whoever listens, without the builders knowing who.

Builders call :func:`report` at their natural stages (and, in long loops, when an
:class:`Every` says it is time); :func:`listening` sets the callback for the builds run
inside it (``geodem run``, ``validate`` and ``--dry-run`` print to a terminal). Without a
listener :func:`report` does nothing. A report only reads numbers the build has already
computed: it never changes a build.
"""
from __future__ import annotations

import contextvars
import time
from contextlib import contextmanager
from typing import Callable, Optional

#: seconds between two progress lines of one long build loop
INTERVAL_S = 5.0

_SINK: contextvars.ContextVar[Optional[Callable[[str], None]]] = contextvars.ContextVar(
    "geodem_build_progress", default=None)


def active() -> bool:
    """Whether anyone listens (builders may skip work done only for a report)."""
    return _SINK.get() is not None


def report(text: str) -> None:
    """Tell the listener, if any, ``text`` (one line, no trailing newline)."""
    sink = _SINK.get()
    if sink is not None:
        sink(text)


@contextmanager
def listening(callback: Optional[Callable[[str], None]]):
    """Send the :func:`report` calls of the code run inside to ``callback`` (None: nowhere)."""
    token = _SINK.set(callback)
    try:
        yield
    finally:
        _SINK.reset(token)


class Every:
    """``due()`` is true once every ``interval`` seconds (default :data:`INTERVAL_S`; first
    after ``interval``), and only while someone listens."""

    def __init__(self, interval: float | None = None):
        self.interval = INTERVAL_S if interval is None else float(interval)
        self._last = time.perf_counter()

    def due(self) -> bool:
        if not active():
            return False
        t = time.perf_counter()
        if t - self._last < self.interval:
            return False
        self._last = t
        return True
