"""CPU engine: the single-source kernels compiled by numba, parallel over elements (prange)."""
from __future__ import annotations

import numpy as np

from geodem.backends import register
from geodem.backends.kernels import EXTRA_FORCE, EXTRA_MOVE, make_kernels, placeholders
from geodem.core.checks import any_at_least
from geodem.core.neighbors import _max_disp_speed
from geodem.core.state import BROKEN_BASE


class HostBackend:
    """Shared part of the backends whose arrays are the state's own NumPy arrays."""

    def attach(self, state):
        self.s = state
        self.e_el = np.zeros(state.n)

    def pull(self, names=None):  # arrays are shared with the state
        pass

    def push(self, names=None):
        if self.e_el.shape[0] != self.s.n:
            self.e_el = np.zeros(self.s.n)

    def all_finite(self):
        # the reduction turns NaN into inf, so one allocation-free pass answers both questions
        d2, v2 = _max_disp_speed(self.s.x, self.s.x_ref, self.s.v)
        return bool(np.isfinite(d2) and np.isfinite(v2))

    def max_disp_speed(self):
        d2, v2 = _max_disp_speed(self.s.x, self.s.x_ref, self.s.v)
        return float(np.sqrt(d2)), float(np.sqrt(v2))

    def has_new_cracks(self):
        return any_at_least(self.s.cstate, BROKEN_BASE)

    def set_active(self, idx=None):
        """Which elements to step (None: all). The whole-matrix reference steps every element
        whatever it is told: asleep elements are fixed and at rest, so only their stored
        reactions differ from a backend that skips them."""
        self.idx = None

    @staticmethod
    def is_available():
        return True

    @staticmethod
    def why_not():
        return ""


@register("numba")
class NumbaBackend(HostBackend):
    def attach(self, state):
        super().attach(state)
        self.k_key = None
        self.idx = None
        self._ph = placeholders()

    def _extra(self, names):
        """The arrays of the options (rotation, contact damping) for the kernels, looked up per
        call (a rebuild may replace ``mr``); placeholders for an option that is off."""
        s = self.s
        if (s.rotation, s.contact_damping) != self.k_key:  # the variant (changes after attach)
            self.k_key = (s.rotation, s.contact_damping)
            self.k = make_kernels(s.dim, "cpu", *self.k_key)
        ph = self._ph
        return tuple(ph[k] if getattr(s, k) is None else getattr(s, k) for k in names)

    def set_active(self, idx=None):
        """Step only the elements in ``idx`` (None: every element); see geodem.fields.freeze."""
        self.idx = None if idx is None else np.ascontiguousarray(idx, dtype=np.int64)

    def move(self, dt):
        s = self.s
        args = (s.x, s.v, s.a, s.dx, s.free, s.fload, s.m, s.eta, s.q_visc, s.w_ext, dt,
                *self._extra(EXTRA_MOVE))
        if self.idx is None:
            self.k.move(*args)
        else:
            self.k.move_idx(self.idx, *args)

    def force(self, dt, code_t, code_s):
        s = self.s
        g = s.gravity
        args = (s.x, s.v, s.a, s.dx, s.free, s.fload, s.props, s.m, s.eta, s.nbr, s.cstate,
                s.fs, s.brate, s.q_visc, s.q_break_n, s.q_break_s, s.q_fric, s.w_ext,
                g[0], g[1], g[2] if s.dim == 3 else 0.0, dt, code_t, code_s, int(s.hertz),
                *self._extra(EXTRA_FORCE))
        if self.idx is None:
            self.k.force(*args)
        else:
            self.k.force_idx(self.idx, *args)

    def elastic_energy(self):
        s = self.s
        mr = self._extra(EXTRA_FORCE)[-1]
        self.k.energy(s.x, s.props, s.nbr, s.cstate, s.fs, int(s.hertz), self.e_el, mr)
        return self.e_el
