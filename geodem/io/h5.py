"""H5MD-like HDF5 output (h5py).

Layout (after H5MD 1.1, https://www.nongnu.org/h5md/)::

    /h5md                          attrs version; groups author, creator (name, version)
    /particles/<group>/box         attrs dimension, boundary
    /particles/<group>/<field>/    value (T, n, ...), step (T,), time (T,)   time-dependent
    /particles/<group>/<field>     (n, ...)                                  static (written once)
    /observables/<name>/           value (T, ...), step (T,), time (T,)
    /cracks/{i, j, time, type}     the crack log (written at the end)
    attributes of /                config (resolved YAML), config_hash, workflow, status, ...

Every time-dependent dataset is chunked and grows along its first axis. Values are buffered in
memory and written by :meth:`H5Writer.flush` (the runner flushes every few seconds, keeping the
writes near 1 % of the run, after every frame and before every checkpoint), which also flushes
the file: a killed run leaves a readable file holding everything up to the last flush.
:meth:`H5Writer.truncate` drops the entries after a step (resuming from a checkpoint).
"""
from __future__ import annotations

import os

import h5py
import numpy as np

H5MD_VERSION = (1, 1)


class H5Writer:
    """Append-only writer of time series and static datasets (see the module doc)."""

    def __init__(self, path, mode: str = "w", attrs: dict | None = None,
                 creator: tuple = ("geodem", "")):
        self.path = os.fspath(path)
        self.f = h5py.File(self.path, mode)
        self._series: dict[str, h5py.Group] = {}
        self._buf: dict[str, list] = {}
        self._handles: dict[str, tuple] = {}
        if mode == "w":
            h = self.f.create_group("h5md")
            h.attrs["version"] = np.array(H5MD_VERSION, np.int32)
            h.create_group("creator").attrs.update({"name": creator[0], "version": creator[1]})
            h.create_group("author").attrs["name"] = creator[0]
        else:
            self._find_series()
        for k, v in (attrs or {}).items():
            self.f.attrs[k] = v

    # ------------------------------------------------------------------ declaring
    def series(self, path: str, shape=(), dtype="f8", unit: str | None = None,
               chunk_rows: int | None = None):
        """Declare a time series ``path`` with per-sample ``shape`` (no-op if it exists)."""
        if path in self._series:
            return
        if path in self.f:
            self._series[path] = self.f[path]
            self._buf.setdefault(path, [])
            return
        g = self.f.require_group(path)
        shape = tuple(int(s) for s in shape)
        per = max(1, int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize)
        rows = chunk_rows or int(max(1, min(1024, (256 * 1024) // per)))
        inner = shape
        if shape and per > (1 << 22):  # big frames: chunks of at most ~4 MB along the elements
            keep = max(1, (1 << 22) // max(1, per // shape[0]))
            inner = (min(shape[0], keep),) + shape[1:]
        v = g.create_dataset("value", shape=(0,) + shape, maxshape=(None,) + shape,
                             dtype=dtype, chunks=(rows,) + inner)
        if unit:
            v.attrs["unit"] = unit
        g.create_dataset("step", shape=(0,), maxshape=(None,), dtype="i8", chunks=(max(rows, 64),))
        t = g.create_dataset("time", shape=(0,), maxshape=(None,), dtype="f8",
                             chunks=(max(rows, 64),))
        t.attrs["unit"] = "s"
        self._series[path] = g
        self._buf[path] = []

    def static(self, path: str, data, unit: str | None = None):
        """A dataset fixed in time (written once; replaced if it exists)."""
        if path in self.f:
            del self.f[path]
        d = self.f.create_dataset(path, data=np.asarray(data))
        if unit:
            d.attrs["unit"] = unit
        return d

    def box(self, group: str, dim: int):
        g = self.f.require_group(f"particles/{group}/box")
        g.attrs["dimension"] = int(dim)
        g.attrs["boundary"] = np.array(["none"] * dim, dtype=h5py.string_dtype())

    # ------------------------------------------------------------------ writing
    def append(self, path: str, step: int, time: float, value) -> None:
        """Buffer one sample of series ``path`` (declared with :meth:`series`)."""
        self._buf[path].append((int(step), float(time), np.asarray(value)))

    def flush(self) -> None:
        """Write every buffered sample and flush the file to disk."""
        for path, buf in self._buf.items():
            if not buf:
                continue
            value, step, time = self._datasets(path)
            n0 = step.shape[0]
            n1 = n0 + len(buf)
            vals = np.stack([b[2] for b in buf]).astype(value.dtype, copy=False)
            for ds, data in ((value, vals), (step, np.array([b[0] for b in buf])),
                             (time, np.array([b[1] for b in buf]))):
                ds.resize((n1,) + ds.shape[1:])
                ds[n0:n1] = data
            buf.clear()
        self.f.flush()

    def _datasets(self, path: str) -> tuple:
        """The value, step and time datasets of series ``path``, looked up once (a lookup
        by name costs about as much as the write of one sample)."""
        ds = self._handles.get(path)
        if ds is None:
            g = self._series[path]
            ds = self._handles[path] = (g["value"], g["step"], g["time"])
        return ds

    def truncate(self, max_step: int) -> None:
        """Drop every sample with ``step > max_step`` (resuming from a checkpoint)."""
        self.flush()
        for g in self._series.values():
            steps = g["step"][()]
            keep = int(np.searchsorted(steps, max_step, side="right")) if steps.size else 0
            if (steps[:keep] > max_step).any():  # not sorted: keep by mask (never expected)
                keep = int((steps <= max_step).sum())
            for name in ("value", "step", "time"):
                ds = g[name]
                if ds.shape[0] != keep:
                    ds.resize((keep,) + ds.shape[1:])
        self.f.flush()

    def read(self, path: str):
        """``(step, time, value)`` arrays of series ``path`` (buffer flushed first)."""
        if self._buf.get(path):
            self.flush()
        g = self.f[path]
        return g["step"][()], g["time"][()], g["value"][()]

    def last_step(self, path: str):
        self.flush()
        s = self.f[path]["step"]
        return int(s[-1]) if s.shape[0] else None

    def last_step_of(self, path: str):
        """The last step of series ``path``, or None when the file has no such series."""
        if not path or (path not in self._series and path not in self.f):
            return None
        return self.last_step(path)

    def set_attrs(self, **attrs) -> None:
        for k, v in attrs.items():
            self.f.attrs[k] = v

    def close(self) -> None:
        if self.f.id.valid:
            self.flush()
            self.f.close()

    # ------------------------------------------------------------------ internals
    def _find_series(self):
        def visit(name, obj):
            if isinstance(obj, h5py.Group) and {"value", "step", "time"} <= set(obj.keys()):
                self._series[name] = obj
                self._buf[name] = []

        self.f.visititems(visit)


def read_series(path, name: str):
    """``(step, time, value)`` of series ``name`` in the file ``path``."""
    with h5py.File(os.fspath(path), "r") as f:
        g = f[name]
        return g["step"][()], g["time"][()], g["value"][()]
