"""CPU engine: the single-source kernels compiled by numba, parallel over elements (prange)."""
from __future__ import annotations

import numpy as np

from geodem.backends import register
from geodem.backends.kernels import EXTRA_FORCE, EXTRA_MOVE, make_kernels, placeholders
from geodem.core.checks import any_at_least
from geodem.core.neighbors import (_max_disp_speed, cross_tables, owner_tables,
                                   rows_version, sort_rows)
from geodem.core.state import BROKEN_BASE, broken_code


SLAB_ELEMENTS = 256  # elements per slab at least (a small model keeps few slabs)
SLAB_MAX = 64  # slabs at most: their crossing contacts' spill rows cost memory


def slab_count(n: int) -> int:
    """Slabs of the owner pass for a model of ``n`` elements: ``ceil(n / SLAB_ELEMENTS)``,
    from 1 up to ``SLAB_MAX``. A function of the model only, so the order of every force sum
    (``geodem.backends.step_bodies``, "each contact once") and so every result is the same
    whatever ``NUMBA_NUM_THREADS`` is; up to ``SLAB_MAX`` threads share the slabs, the last
    thread's share at most one slab larger (docs/performance.md, "Any number of threads")."""
    return max(1, min(SLAB_MAX, -(-int(n) // SLAB_ELEMENTS)))


class HostBackend:
    """Shared part of the backends whose arrays are the state's own NumPy arrays."""

    def attach(self, state):
        self.s = state
        self.e_el = np.zeros(state.n)

    def pull(self, names=None):  # arrays are shared with the state
        pass

    def settle(self):
        """End of ``Simulation.run``: leave the state complete for whoever reads it next."""
        self.pull(("fs",))

    def scratch_nbytes(self) -> int:
        """Bytes the backend holds beside the state's arrays (buffers, tables)."""
        return int(self.e_el.nbytes)

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
    """numba on the CPU, parallel over elements.

    A model with sorted, symmetric rows (every model geodem builds) takes each contact once,
    from its owner's row (``owner_body`` in ``geodem.backends.step_bodies``; 1.3-1.6x faster
    than walking both rows, docs/performance.md). The partner's slot then keeps the contact's
    state code, but its shear spring (and rolling moment) is brought up to date only when
    someone reads ``fs`` (``mr``): ``pull`` (the engine's rebuild, energy, sync, checkpoint),
    ``settle`` (end of every ``run``), or a pass that walks every row (steps over the awake
    elements only: ``set_active``). The owner tables are rebuilt by ``push`` when the rows may
    have changed (``push()`` or a push naming ``nbr``), as after the engine's rebuilds; code
    that edits the rows of a running simulation must push them, as it must for the GPU.
    ``once = False`` walks both rows of every contact instead.

    In a model of ``PREFETCH_MIN`` elements or more the owner pass prefetches the partners of
    the element ``PREFETCH_AHEAD`` ahead (``prefetch_partners``): 1.2x at 1e6 elements, 1.05x
    at 1e5, 0.9x at 1e4 where everything is in the caches already; and the own rows of the
    element ``4 * PREFETCH_AHEAD`` ahead (``prefetch_rows``): 1.09x at 1e5, 1.12x at 1e6
    (docs/performance.md). A prefetch is only a hint: the results are the same bit for bit.
    """

    once = True  # each contact once when the model allows it (see the class doc)
    PREFETCH_MIN = 32_768  # elements; below, the partners' rows stay in the caches
    PREFETCH_AHEAD = 2  # elements ahead (1-4 measured alike at 1e6)

    def attach(self, state):
        super().attach(state)
        self.k_key = None
        self.idx = None
        self._ph = placeholders()
        self.buf = None
        self.dirty = False  # partner slots' springs behind the owners'
        self._rows_changed()

    def _extra(self, names):
        """The arrays of the options (rotation, contact damping) for the kernels, looked up per
        call (a rebuild may replace ``mr``); placeholders for an option that is off."""
        s = self.s
        key = (s.rotation, s.contact_damping, s.row_stiffness)
        if key != self.k_key:  # the variant (changes after attach)
            self.k_key = key
            self.k = make_kernels(s.dim, "cpu", *self.k_key)
            if self.buf is not None and self.buf.shape[1] != self._width():
                self._buffers()  # an option's columns
        ph = self._ph
        return tuple(ph[k] if getattr(s, k) is None else getattr(s, k) for k in names)

    def _rows_changed(self):
        """(Re)build the owner tables, the slabs' crossing tables and the posts' buffer from
        the state's rows."""
        s = self.s
        self.rows = s.nbr
        self.tables = owner_tables(s.nbr)
        if self.tables is None and sort_rows(s):
            # rows left unsorted (renumbered by hand): a row is a set, sort it
            self.rows = s.nbr
            self.tables = owner_tables(s.nbr)
        self.rows_version = rows_version(s)
        if self.tables is None:
            self.buf = self.cross = None
            return
        self.ahead = self.PREFETCH_AHEAD if s.n >= self.PREFETCH_MIN else 0
        # the sums' order depends on the slabs, so their number is the model's (its size),
        # never the pool's: the same run gives the same bits on any number of threads
        self.slabs = slab_count(s.n)
        self.cross = cross_tables(s.nbr, self.tables[0], self.slabs)
        self._buffers()

    def _width(self):
        s = self.s
        return 12 if (s.rotation or s.contact_damping) else 6  # step_bodies.owner_body

    def _buffers(self):
        """The posts' buffer: a row per element, then a spill row per contact that crosses a
        slab boundary (``neighbors.cross_tables``); every finish empties it."""
        shape = (self.s.n + max(1, int(self.cross[0][-1])), self._width())
        if self.buf is None or self.buf.shape != shape:
            self.buf = np.zeros(shape)

    def _sync_partners(self):
        if self.dirty:
            ostart, mirror = self.tables
            mr = self._extra(("mr",))[0]
            self.k.mirror(self.s.nbr, ostart, mirror, self.s.cstate, self.s.fs, mr)
            self.dirty = False

    def pull(self, names=None):
        if self.dirty and (names is None or "fs" in names or "mr" in names):
            self._sync_partners()

    def push(self, names=None):
        super().push(names)
        if names is None or "nbr" in names:
            # the owners' slots are the current ones whatever the rows became: new tables
            # first, then their springs to the partners
            self._rows_changed()
            self._sync_partners()

    def scratch_nbytes(self) -> int:
        n = super().scratch_nbytes()
        if self.tables is not None:
            n += sum(int(t.nbytes) for t in self.tables + self.cross)
            n += int(self.buf.nbytes)
        return n

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

    def _each_once(self):
        """Whether the step takes each contact once (owner pass + finish); rows replaced
        without a push (a wider width) get their tables first."""
        if self.s.nbr is not self.rows or rows_version(self.s) != self.rows_version:
            self._rows_changed()
        return self.once and self.idx is None and self.tables is not None

    def _gravity(self):
        g = self.s.gravity
        return g[0], g[1], (g[2] if self.s.dim == 3 else 0.0)

    def force(self, dt, code_t, code_s):
        s = self.s
        extra = self._extra(EXTRA_FORCE)
        g0, g1, g2 = self._gravity()
        if self._each_once():
            ostart, mirror = self.tables
            w, wa, dth, rfree, inertia, fdash, mr, rp, kr = extra
            cstart, spill, inc_start = self.cross
            self.k.force_owner(s.x, s.dx, s.props, s.m, s.nbr, ostart, mirror, s.cstate, s.fs,
                               s.brate, self.buf, cstart, spill, self.slabs, dt, code_t,
                               code_s, int(s.hertz), dth, mr, rp, kr, self.ahead)
            self.k.finish(s.v, s.a, s.dx, s.free, s.fload, s.m, s.eta, self.buf, inc_start,
                          s.q_visc, s.q_break_n, s.q_break_s, s.q_fric, s.w_ext, g0, g1, g2, dt,
                          *extra)
            self.dirty = True
            return
        self._sync_partners()
        args = (s.x, s.v, s.a, s.dx, s.free, s.fload, s.props, s.m, s.eta, s.nbr, s.cstate,
                s.fs, s.brate, s.q_visc, s.q_break_n, s.q_break_s, s.q_fric, s.w_ext,
                g0, g1, g2, dt, code_t, code_s, int(s.hertz), *extra)
        if self.idx is None:
            self.k.force(*args)
        else:
            self.k.force_idx(self.idx, *args)

    def steps(self, dt, nsteps, step0):
        """Advance ``nsteps`` whole steps (``move`` + ``force``) from step ``step0`` in one call
        of the kernels, as the engine does between two events. Returns False, having done
        nothing, where the model takes the per-step path (awake elements only, rows taken
        from both sides)."""
        extra = self._extra(EXTRA_FORCE)  # first: it picks the variant and sizes the buffers
        if not self._each_once():
            return False
        s = self.s
        ostart, mirror = self.tables
        cstart, spill, inc_start = self.cross
        self.k.steps(int(nsteps), broken_code(step0 + 1, 1), broken_code(step0 + 1, 2),
                     s.x, s.v, s.a, s.dx, s.free, s.fload, s.props, s.m, s.eta, s.nbr, ostart,
                     mirror, s.cstate, s.fs, s.brate, self.buf, cstart, spill,
                     inc_start, self.slabs, s.q_visc, s.q_break_n,
                     s.q_break_s, s.q_fric, s.w_ext, *self._gravity(), dt, int(s.hertz),
                     self.ahead, *extra)
        self.dirty = True
        return True

    def elastic_energy(self):
        s = self.s
        self._sync_partners()
        mr, rp, kr = self._extra(("mr", "rot_props", "krate"))
        self.k.energy(s.x, s.props, s.nbr, s.cstate, s.fs, int(s.hertz), self.e_el, mr, rp, kr)
        return self.e_el
