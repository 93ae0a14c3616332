"""ParaView output: one ``.vtp`` file per frame plus a ``.pvd`` collection.

The files are VTK XML PolyData written directly (base64 binary arrays, UInt64 headers), so no VTK
library is needed to write them; ParaView, pyvista or any VTK reader opens them. Each element is
a point (with a vertex cell) carrying its radius, velocity, displacement, group and bond count;
each bond broken so far is a line cell between its two elements (cell data ``crack_type``: 1
tensile, 2 shear, 0 joint; -1 on the vertex cells), so ParaView shows the crack network.
"""
from __future__ import annotations

import base64
import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np


_VTK_TYPES = {"f8": "Float64", "i4": "Int32", "i8": "Int64"}


def _data_array(name, arr, comps=1) -> list[bytes]:
    """An inline binary ``DataArray`` element as byte pieces (written one after another, never
    joined: at 10^6 elements a frame is ~100 MB, and joining its pieces copied it again and
    again)."""
    arr = np.ascontiguousarray(arr)
    payload = base64.b64encode(np.uint64(arr.nbytes).tobytes() + arr.tobytes())
    typ = _VTK_TYPES[arr.dtype.str[1:]]
    nm = f' Name="{name}"' if name else ""
    return [f'<DataArray type="{typ}"{nm} NumberOfComponents="{comps}" format="binary">'
            .encode(), payload, b"</DataArray>\n"]


def to_xyz(a):
    """(N, 2|3) points as (N, 3): 2-D points at z = 0."""
    a = np.asarray(a, dtype=np.float64)
    return a if a.shape[1] == 3 else np.column_stack([a, np.zeros(len(a))])


def rows_of(ids, numbers) -> np.ndarray:
    """Rows of the elements whose built numbers are ``numbers`` in a model whose rows carry the
    built numbers ``ids`` (``Simulation.ids``; the crack log names elements by them); -1 for
    an element no longer in the model (excavated)."""
    ids, numbers = np.asarray(ids), np.asarray(numbers)
    if len(ids) == 0:
        return np.full(len(numbers), -1, np.int64)
    order = np.argsort(ids, kind="stable")
    pos = np.clip(np.searchsorted(ids[order], numbers), 0, len(ids) - 1)
    return np.where(ids[order][pos] == numbers, order[pos], -1)


def crack_lines(ids, log):
    """``(rows (M, 2), types (M,))`` of the cracks of ``log`` (``Simulation.crack_log``) whose
    two elements are still in the model; ``ids`` None: no element was removed (row = number)."""
    if ids is None:
        i, j = np.asarray(log["i"], np.int64), np.asarray(log["j"], np.int64)
    else:
        i, j = rows_of(ids, log["i"]), rows_of(ids, log["j"])
    keep = (i >= 0) & (j >= 0)
    return np.column_stack([i[keep], j[keep]]), np.asarray(log["type"])[keep]


def write_vtp(path, points, point_data: dict, lines=None, line_types=None) -> None:
    """Write points (N, 2|3) with ``point_data`` {name: (N,) or (N, 2|3) array} as a .vtp file
    (atomically: temp file + rename); ``lines`` (M, 2) point indices become line cells, with
    ``line_types`` (M,) as the cell data ``crack_type``."""
    pts = to_xyz(points)
    n = len(pts)
    lines = np.zeros((0, 2), np.int64) if lines is None else np.asarray(lines, np.int64)
    m = len(lines)
    pieces = [b'<?xml version="1.0"?>\n'
              b'<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" '
              b'header_type="UInt64">\n<PolyData>\n',
              f'<Piece NumberOfPoints="{n}" NumberOfVerts="{n}" NumberOfLines="{m}" '
              'NumberOfStrips="0" NumberOfPolys="0">\n<PointData>\n'.encode()]
    for name, val in point_data.items():
        val = np.asarray(val)
        if val.dtype.kind == "f":
            val = val.astype(np.float64)
        elif val.dtype.kind in "iub":
            val = val.astype(np.int32)
        pieces += _data_array(name, to_xyz(val), 3) if val.ndim == 2 else _data_array(name, val)
    pieces.append(b"</PointData>\n")
    ids = np.arange(n, dtype=np.int64)
    if m:
        types = (np.zeros(m) if line_types is None else np.asarray(line_types)).astype(np.int32)
        cell_type = np.concatenate([np.full(n, -1, np.int32), types])  # verts first, then lines
        pieces += [b"<CellData>\n", *_data_array("crack_type", cell_type), b"</CellData>\n"]
    pieces += [b"<Points>\n", *_data_array("Points", pts, 3), b"</Points>\n<Verts>\n",
               *_data_array("connectivity", ids), *_data_array("offsets", ids + 1),
               b"</Verts>\n"]
    if m:
        pieces += [b"<Lines>\n", *_data_array("connectivity", lines.ravel()),
                   *_data_array("offsets", 2 * np.arange(1, m + 1, dtype=np.int64)),
                   b"</Lines>\n"]
    pieces.append(b"</Piece>\n</PolyData>\n</VTKFile>\n")
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.writelines(pieces)
    os.replace(tmp, path)


def read_vtp(path) -> dict:
    """Read back what :func:`write_vtp` wrote: {'Points': (N, 3), name: array, ...}; the line
    cells as 'lines' (M, 2) when there are any."""
    import re

    out = {}
    text = Path(path).read_text()
    block = re.search(r"<Lines>(.*?)</Lines>", text, re.S)
    if block:
        conn = re.search(r'Name="connectivity" NumberOfComponents="1" format="binary">([^<]*)<',
                         block.group(1)).group(1)
        raw = base64.b64decode(conn)
        nbytes = int(np.frombuffer(raw[:8], np.uint64)[0])
        out["lines"] = np.frombuffer(raw[8:8 + nbytes], np.int64).reshape(-1, 2)
        text = text.replace(block.group(0), "")
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

    def write(self, state, step: int, reference=None, cracks=None) -> str:
        """One frame; ``cracks``: ``(rows (M, 2), types (M,))`` of the bonds broken so far."""
        x = np.asarray(state.x)
        data = {"radius": np.asarray(state.r), "velocity": np.asarray(state.v)}
        if reference is not None:
            data["displacement"] = x - reference
        data["group"] = np.asarray(state.group)
        data["bonds"] = (np.asarray(state.cstate) == 1).sum(axis=1)
        name = f"frame_{int(step):012d}.vtp"
        lines, types = (None, None) if cracks is None else cracks
        write_vtp(self.folder / name, x, data, lines=lines, line_types=types)
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
