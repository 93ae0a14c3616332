"""ParaView output: one ``.vtp`` file per frame (pyvista) plus a ``.pvd`` collection.

pyvista is optional (``pip install 'geodem[vis]'``); :func:`pyvista_missing` says why it cannot
be used, and :class:`VtkWriter` is only created when it can.
"""
from __future__ import annotations

import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np


def pyvista_missing() -> str:
    """'' when pyvista is importable, else the reason."""
    try:
        import pyvista  # noqa: F401
    except Exception as exc:  # noqa: BLE001 - missing or broken install
        return f"pyvista is not installed ({type(exc).__name__}); pip install 'geodem[vis]'"
    return ""


class VtkWriter:
    """Write ``frame_<step>.vtp`` (points with radius, velocity, displacement, group) and keep
    ``frames.pvd`` listing every frame with its time (rewritten after each frame)."""

    def __init__(self, folder, pvd_name: str = "frames.pvd"):
        import pyvista  # noqa: F401 - fail early

        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.pvd = self.folder / pvd_name
        self.frames: list[tuple[float, str]] = []
        if self.pvd.exists():  # resumed run: keep the frames already listed
            import re

            for t, f in re.findall(r'timestep="([^"]+)"[^>]*file="([^"]+)"', self.pvd.read_text()):
                self.frames.append((float(t), f))

    def write(self, state, step: int, reference=None) -> str:
        import pyvista

        x = np.asarray(state.x)
        pts = x if x.shape[1] == 3 else np.column_stack([x, np.zeros(len(x))])
        cloud = pyvista.PolyData(np.ascontiguousarray(pts))
        cloud["radius"] = np.asarray(state.r)
        v = np.asarray(state.v)
        cloud["velocity"] = v if v.shape[1] == 3 else np.column_stack([v, np.zeros(len(v))])
        if reference is not None:
            u = x - reference
            cloud["displacement"] = u if u.shape[1] == 3 else np.column_stack(
                [u, np.zeros(len(u))])
        cloud["group"] = np.asarray(state.group)
        cloud["bonds"] = (np.asarray(state.cstate) == 1).sum(axis=1).astype(np.int32)
        name = f"frame_{int(step):012d}.vtp"
        tmp = self.folder / f".{name}.tmp.vtp"
        cloud.save(str(tmp))
        os.replace(tmp, self.folder / name)
        self.frames = [(t, f) for t, f in self.frames if f != name]
        self.frames.append((float(state.time), name))
        self._write_pvd()
        return name

    def _write_pvd(self):
        rows = "\n".join(f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>'
                         for t, f in self.frames)
        text = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n'
                f"  <Collection>\n{rows}\n  </Collection>\n</VTKFile>\n")
        tmp = self.pvd.with_suffix(".pvd.tmp")
        tmp.write_text(text)
        os.replace(tmp, self.pvd)
