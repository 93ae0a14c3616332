"""Errors of the workflow layer and how they map to exit codes.

* :class:`WorkflowError` -- invalid input (schema, semantics, sizes, time step, run directory):
  exit status 2. It carries one :class:`ErrorItem` per problem, each printed on one line as
  ``FILE.yaml:LINE: <field path>: <message>``.
* :class:`RunFailure` -- the run itself failed (instability, I/O): exit status 1.
* :class:`Interrupted` -- the run stopped cleanly (``--stop-after-steps``, SIGINT, SIGTERM) after
  writing a checkpoint.
"""
from __future__ import annotations

from dataclasses import dataclass

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_INVALID = 2
#: exit status of a run stopped by a signal (after its checkpoint): 128 + signal number
EXIT_SIGNAL_BASE = 128


def format_path(loc) -> str:
    """``('steps', 0, 'nsteps')`` -> ``steps[0].nsteps``."""
    out = ""
    for comp in loc:
        if isinstance(comp, int):
            out += f"[{comp}]"
        else:
            out += ("." if out else "") + str(comp)
    return out or "(top level)"


@dataclass
class ErrorItem:
    """One located problem. ``file`` is the YAML file (or the command-line option that set the
    value), ``line`` its 1-based line (None when unknown), ``path`` the field path."""

    file: str | None
    line: int | None
    path: str
    message: str

    def format(self) -> str:
        where = self.file or "<input>"
        if self.line is not None:
            where = f"{where}:{self.line}"
        return f"{where}: {self.path}: {self.message}"


class WorkflowError(ValueError):
    """Invalid workflow input (exit status 2); ``items`` hold the located messages."""

    def __init__(self, items):
        if isinstance(items, ErrorItem):
            items = [items]
        self.items = list(items)
        super().__init__("\n".join(i.format() for i in self.items))

    def lines(self) -> list[str]:
        return [i.format() for i in self.items]


class RunFailure(RuntimeError):
    """The run failed at run time (instability, I/O): exit status 1."""


class Interrupted(Exception):
    """The run stopped cleanly after a checkpoint; ``reason`` says why, ``signum`` which signal
    (None for ``--stop-after-steps``)."""

    def __init__(self, reason: str, signum: int | None = None):
        super().__init__(reason)
        self.reason = reason
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return EXIT_OK if self.signum is None else EXIT_SIGNAL_BASE + int(self.signum)
