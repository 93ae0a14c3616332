"""ParaView output: one ``.vtp`` file per frame plus a ``.pvd`` collection.

The files are VTK XML PolyData written directly (base64 binary arrays, UInt64 headers), so no VTK
library is needed to write them; ParaView, pyvista or any VTK reader opens them. Each element is
a point (with a vertex cell) carrying its radius, velocity, displacement, group and bond count.
"""
from __future__ import annotations

import base64
import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np


_VTK_TYPES = {"f8": "Float64", "i4": "Int32", "i8": "Int64"}


def _data_array(name, arr, comps=1) -> str:
    arr = np.ascontiguousarray(arr)
    raw = arr.tobytes()
    payload = base64.b64encode(np.uint64(len(raw)).tobytes() + raw).decode("ascii")
    typ = _VTK_TYPES[arr.dtype.str[1:]]
    nm = f' Name="{name}"' if name else ""
    return (f'<DataArray type="{typ}"{nm} NumberOfComponents="{comps}" format="binary">'
            f"{payload}</DataArray>")


def _xyz(a):
    a = np.asarray(a, dtype=np.float64)
    return a if a.shape[1] == 3 else np.column_stack([a, np.zeros(len(a))])


def write_vtp(path, points, point_data: dict) -> None:
    """Write points (N, 2|3) with ``point_data`` {name: (N,) or (N, 2|3) array} as a .vtp file
    (atomically: temp file + rename)."""
    pts = _xyz(points)
    n = len(pts)
    arrays = []
    for name, val in point_data.items():
        val = np.asarray(val)
        if val.dtype.kind == "f":
            val = val.astype(np.float64)
        elif val.dtype.kind in "iub":
            val = val.astype(np.int32)
        if val.ndim == 2:
            arrays.append(_data_array(name, _xyz(val), 3))
        else:
            arrays.append(_data_array(name, val))
    ids = np.arange(n, dtype=np.int64)
    text = (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64">\n'
        "<PolyData>\n"
        f'<Piece NumberOfPoints="{n}" NumberOfVerts="{n}" NumberOfLines="0" '
        'NumberOfStrips="0" NumberOfPolys="0">\n'
        "<PointData>\n" + "\n".join(arrays) + "\n</PointData>\n"
        "<Points>\n" + _data_array("Points", pts, 3) + "\n</Points>\n"
        "<Verts>\n" + _data_array("connectivity", ids) + "\n"
        + _data_array("offsets", ids + 1) + "\n</Verts>\n"
        "</Piece>\n</PolyData>\n</VTKFile>\n")
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def read_vtp(path) -> dict:
    """Read back what :func:`write_vtp` wrote: {'Points': (N, 3), name: array, ...}."""
    import re

    out = {}
    text = Path(path).read_text()
    for typ, name, comps, payload in re.findall(
            r'<DataArray type="(\w+)" Name="(\w+)" NumberOfComponents="(\d+)" '
            r'format="binary">([^<]*)</DataArray>', text):
        raw = base64.b64decode(payload)
        nbytes = int(np.frombuffer(raw[:8], np.uint64)[0])
        dt = {"Float64": np.float64, "Int32": np.int32, "Int64": np.int64}[typ]
        arr = np.frombuffer(raw[8:8 + nbytes], dt)
        out[name] = arr.reshape(-1, int(comps)) if int(comps) > 1 else arr
    return out


class VtkWriter:
    """Write ``frame_<step>.vtp`` (points with radius, velocity, displacement, group) and keep
    ``frames.pvd`` listing every frame with its time (rewritten after each frame)."""

    def __init__(self, folder, pvd_name: str = "frames.pvd"):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.pvd = self.folder / pvd_name
        self.frames: list[tuple[float, str]] = []
        if self.pvd.exists():  # resumed run: keep the frames already listed
            import re

            for t, f in re.findall(r'timestep="([^"]+)"[^>]*file="([^"]+)"', self.pvd.read_text()):
                self.frames.append((float(t), f))

    def write(self, state, step: int, reference=None) -> str:
        x = np.asarray(state.x)
        data = {"radius": np.asarray(state.r), "velocity": np.asarray(state.v)}
        if reference is not None:
            data["displacement"] = x - reference
        data["group"] = np.asarray(state.group)
        data["bonds"] = (np.asarray(state.cstate) == 1).sum(axis=1)
        name = f"frame_{int(step):012d}.vtp"
        write_vtp(self.folder / name, x, data)
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
