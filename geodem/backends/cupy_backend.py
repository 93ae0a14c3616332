"""GPU engine: CuPy arrays stepped by the single-source kernels compiled with numba's CUDA target.

The state is copied to the device once (``attach``), element-major so that a warp's loads
coalesce; the step loop launches two fused kernels per step with no host transfer. ``pull``/``push`` move arrays only when the engine asks (output,
neighbour rebuilds, checks).

Without a GPU, ``GEODEM_CUDA_SIM=1`` (which sets ``NUMBA_ENABLE_CUDASIM=1`` before numba is
imported) runs the very same kernels in numba's CUDA simulator on NumPy arrays, so CI exercises
the GPU kernel logic on tiny models.
"""
from __future__ import annotations

import os

import numpy as np

from geodem.backends import register
from geodem.backends.kernels import EXTRA_FORCE, EXTRA_MOVE, make_kernels, placeholders
from geodem.core.state import BROKEN_BASE

THREADS = 128
DEVICE_ARRAYS = ("x", "v", "a", "dx", "x_ref", "free", "fload", "props", "m", "eta", "nbr",
                 "cstate", "fs", "brate", "q_visc", "q_break_n", "q_break_s", "q_fric", "w_ext")
# what the kernels write: the rest of the device arrays changes only by a push from the host
STEPPED = ("x", "v", "a", "dx", "cstate", "fs", "q_visc", "q_break_n", "q_break_s", "q_fric",
           "w_ext")
STEPPED_OPTIONS = ("w", "wa", "dth", "fdash", "mr")  # rotation, contact damping


def stepped_arrays(state) -> tuple:
    """The device arrays the step kernels change, for ``state``'s options."""
    return STEPPED + tuple(k for k in STEPPED_OPTIONS if getattr(state, k) is not None)


def simulated() -> bool:
    return os.environ.get("GEODEM_CUDA_SIM", "") == "1" or \
        os.environ.get("NUMBA_ENABLE_CUDASIM", "") == "1"


def _gpu_reason() -> str:
    if simulated():
        if os.environ.get("NUMBA_ENABLE_CUDASIM", "") != "1":
            return "GEODEM_CUDA_SIM=1 needs NUMBA_ENABLE_CUDASIM=1 set before numba is imported"
        return ""
    try:
        import cupy  # noqa: F401
    except Exception as exc:  # pragma: no cover - depends on the machine
        return f"cupy is not installed ({exc.__class__.__name__}); pip install 'geodem[gpu]'"
    try:
        import cupy

        if cupy.cuda.runtime.getDeviceCount() < 1:
            return "no CUDA device"
        from numba import cuda

        if not cuda.is_available():
            return "numba's CUDA target is not usable (pip install 'numba-cuda[cu12]')"
    except Exception as exc:  # pragma: no cover
        return f"no usable GPU ({exc})"
    return ""


@register("cupy")
class CupyBackend:
    @staticmethod
    def is_available():
        return _gpu_reason() == ""

    @staticmethod
    def why_not():
        return _gpu_reason() or "available"

    def __init__(self):
        if simulated():
            self.xp = np
        else:  # pragma: no cover - needs a GPU
            import cupy

            self.xp = cupy

    def attach(self, state):
        self.s = state
        self.idx = None
        self.dev = {}
        self.push()

    def _names(self):
        return DEVICE_ARRAYS + tuple(k for k in EXTRA_FORCE if getattr(self.s, k) is not None)

    def _blocks(self):
        return (self.s.n + THREADS - 1) // THREADS

    def push(self, names=None):
        key = (self.s.rotation, self.s.contact_damping, self.s.row_stiffness)
        if key != getattr(self, "k_key", None):  # the kernel variant (may change after attach)
            self.k = make_kernels(self.s.dim, "cuda", *key)
            self.k_key = key
            names = None
        names = self._names() if names is None else names
        for k in names:
            # element-major ("Fortran") order on the device: thread i reading a[i, k] while its
            # warp neighbours read a[i+1, k], ... touches consecutive addresses (coalesced); the
            # kernels index [i, k] as on the CPU, only the strides differ
            host = getattr(self.s, k)
            if self.xp is np:
                self.dev[k] = np.array(host, order="F")
            else:  # pragma: no cover
                self.dev[k] = self.xp.asfortranarray(self.xp.asarray(host))
        self.e_el = self.xp.zeros(self.s.n)
        self._bind()

    def _bind(self):
        if self.xp is np:
            self.view = dict(self.dev)
            self.view["e_el"] = self.e_el
        else:  # pragma: no cover - zero-copy views numba can launch on
            from numba import cuda

            self.view = {k: cuda.as_cuda_array(v) for k, v in self.dev.items()}
            self.view["e_el"] = cuda.as_cuda_array(self.e_el)
        ph = placeholders(self.xp)
        if self.xp is not np:  # pragma: no cover
            from numba import cuda

            ph = {k: cuda.as_cuda_array(v) for k, v in ph.items()}
        for k in EXTRA_FORCE:  # options that are off
            if k not in self.view:
                self.view[k] = ph[k]
        self.extra_move = tuple(self.view[k] for k in EXTRA_MOVE)
        self.extra_force = tuple(self.view[k] for k in EXTRA_FORCE)

    def pull(self, names=None):
        names = self._names() if names is None else names
        for k in names:
            arr = self.dev[k]
            host = arr if self.xp is np else arr.get()
            getattr(self.s, k)[...] = host

    def settle(self):
        """End of ``Simulation.run``: leave the state complete for whoever reads it next, as
        every backend does (callers read ``sim.state`` after a run): the arrays the kernels
        changed come back, one copy per ``run`` call, never per step."""
        self.pull(stepped_arrays(self.s))

    def scratch_nbytes(self) -> int:
        return 0

    def all_finite(self):
        xp, d = self.xp, self.dev
        return bool(xp.isfinite(d["x"]).all() and xp.isfinite(d["v"]).all())

    def max_disp_speed(self):
        xp, d = self.xp, self.dev
        disp = xp.sqrt(((d["x"] - d["x_ref"]) ** 2).sum(axis=1)).max()
        speed = xp.sqrt((d["v"] ** 2).sum(axis=1)).max()
        return float(disp), float(speed)

    def has_new_cracks(self):
        return bool((self.dev["cstate"] >= BROKEN_BASE).any())

    def set_active(self, idx=None):
        """Step only the elements in ``idx`` (None: every element); see geodem.fields.freeze."""
        if idx is None:
            self.idx = None
            return
        arr = np.ascontiguousarray(idx, dtype=np.int64)
        if self.xp is np:
            self.idx = arr
        else:  # pragma: no cover - needs a GPU
            from numba import cuda

            self.idx = cuda.as_cuda_array(self.xp.asarray(arr))

    def _launch(self, full, sub, *args):
        if self.idx is None:
            full[self._blocks(), THREADS](*args)
        else:
            blocks = (self.idx.shape[0] + THREADS - 1) // THREADS
            if blocks:
                sub[blocks, THREADS](self.idx, *args)

    def move(self, dt):
        d = self.view
        self._launch(self.k.move, self.k.move_idx, d["x"], d["v"], d["a"], d["dx"], d["free"],
                     d["fload"], d["m"], d["eta"], d["q_visc"], d["w_ext"], dt, *self.extra_move)

    def force(self, dt, code_t, code_s):
        s, d = self.s, self.view
        g = s.gravity
        self._launch(self.k.force, self.k.force_idx,
                     d["x"], d["v"], d["a"], d["dx"], d["free"], d["fload"], d["props"], d["m"],
                     d["eta"], d["nbr"], d["cstate"], d["fs"],
                     d["brate"], d["q_visc"], d["q_break_n"], d["q_break_s"], d["q_fric"],
                     d["w_ext"], float(g[0]), float(g[1]), float(g[2]) if s.dim == 3 else 0.0,
                     dt, code_t, code_s, int(s.hertz), *self.extra_force)

    def elastic_energy(self):
        d = self.view
        self.k.energy[self._blocks(), THREADS](d["x"], d["props"], d["nbr"],
                                               d["cstate"], d["fs"], int(self.s.hertz),
                                               d["e_el"], self.view["mr"],
                                               self.view["rot_props"], self.view["krate"])
        return self.e_el if self.xp is np else self.e_el.get()
