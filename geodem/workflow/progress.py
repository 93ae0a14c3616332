"""Progress reporting: a rich progress bar on a terminal, periodic log lines otherwise.

Every message and a progress line every ``log_every_seconds`` always go to ``log.txt``; on a
terminal (and without ``--no-progress``) the bar shows steps/s, ETA, the kinetic energy of the
last observation and the broken-bond count, otherwise the same progress lines go to stderr.
"""
from __future__ import annotations

import time
from datetime import datetime, timezone

from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)


def now_iso() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def fmt_duration(s: float) -> str:
    if s != s or s == float("inf"):
        return "?"
    s = int(round(s))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}:{m:02d}:{sec:02d}"


class Reporter:
    """Messages and progress of one run (see the module doc)."""

    def __init__(self, log_path=None, *, total_steps: int, n_elements: int, bar: bool,
                 console: Console | None = None, log_every_s: float = 10.0, echo: bool = True):
        self.console = console or Console(stderr=True)
        self.log_fh = open(log_path, "a", buffering=1) if log_path is not None else None
        self.total = max(int(total_steps), 0)
        self.n = int(n_elements)
        self.log_every = float(log_every_s)
        self.echo = echo
        self.bar = None
        self.task = None
        self.step_label = ""
        self._t_last_line = time.perf_counter()
        self._rate_t = time.perf_counter()
        self._rate_step = None
        self.rate = 0.0
        self.ke = None
        self.broken = 0
        if bar:
            self.bar = Progress(
                TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("{task.fields[rate]} steps/s"), TextColumn("ETA"),
                TimeRemainingColumn(), TimeElapsedColumn(),
                TextColumn("KE {task.fields[ke]}"), TextColumn("broken {task.fields[broken]}"),
                console=self.console, transient=False, refresh_per_second=4)

    # ------------------------------------------------------------------ messages
    def _log(self, text: str) -> None:
        if self.log_fh is not None:
            self.log_fh.write(f"{now_iso()} {text}\n")

    def message(self, text: str, echo: bool | None = None) -> None:
        """Log ``text``; also show it on the console (above the bar when there is one)."""
        self._log(text)
        if self.echo if echo is None else echo:
            self.console.print(escape(text), highlight=False, soft_wrap=True)

    # ------------------------------------------------------------------ progress
    def start(self, done: int = 0) -> None:
        self._rate_step = done
        if self.bar is not None:
            self.task = self.bar.add_task("starting", total=self.total or None, completed=done,
                                          rate="-", ke="-", broken="0")
            self.bar.start()

    def start_step(self, index: int, count: int, name: str, kind: str, planned: int) -> None:
        self.step_label = f"step {index + 1}/{count} {name}"
        what = f"{planned} time steps" if planned else "no time steps"
        self.message(f"{self.step_label} ({kind}): {what}")
        if self.bar is not None:
            self.bar.update(self.task, description=escape(f"{index + 1}/{count} {name}"))

    def update(self, step: int, ke=None, broken=None, rate=None, force: bool = False) -> None:
        """New progress: ``step`` done, last kinetic energy ``ke`` [J], ``broken`` bonds so far,
        ``rate`` time steps per second (default: measured between updates)."""
        t = time.perf_counter()
        if ke is not None:
            self.ke = ke
        if broken is not None:
            self.broken = broken
        if rate is not None:
            self.rate = rate
        elif self._rate_step is None:
            self._rate_step, self._rate_t = step, t
        elif t - self._rate_t >= 0.5 and step > self._rate_step:
            self.rate = (step - self._rate_step) / (t - self._rate_t)
            self._rate_step, self._rate_t = step, t
        ke_s = "-" if self.ke is None else f"{self.ke:.3e} J"
        if self.bar is not None:
            self.bar.update(self.task, completed=step, rate=f"{self.rate:.3g}", ke=ke_s,
                            broken=str(self.broken))
        if force or t - self._t_last_line >= self.log_every:
            self._t_last_line = t
            line = self.progress_line(step)
            self._log(line)
            if self.bar is None and self.echo:
                self.console.print(escape(line), highlight=False, soft_wrap=True)

    def progress_line(self, step: int) -> str:
        pct = f" ({100.0 * step / self.total:.0f} %)" if self.total else ""
        eta = (self.total - step) / self.rate if self.rate > 0 and self.total else float("nan")
        ke_s = "-" if self.ke is None else f"{self.ke:.3e} J"
        return (f"[{self.step_label}] {step}/{self.total} time steps{pct}, "
                f"{self.rate:.3g} steps/s, {self.rate * self.n:.3g} element-steps/s, "
                f"ETA {fmt_duration(eta)}, KE {ke_s}, broken bonds {self.broken}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
            self.bar = None
        if self.log_fh is not None:
            self.log_fh.close()
            self.log_fh = None
