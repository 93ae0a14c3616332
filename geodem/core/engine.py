"""The time-step loop and its books: stepping, neighbour rebuilds, crack log, energy, checks.

The loop (``Simulation.run``) does per step exactly two backend calls, ``move`` and ``force``
(velocity Verlet, see ``geodem.backends.step_bodies``), and nothing else: no Python loop over
elements, no allocation, no host/device copy. A backend with ``steps`` (numba) takes the
stretch of steps up to the next event (check, coupled field, callback) in one call instead,
the same passes in the same order. Every ``check_every`` steps at most (sooner when
elements move fast) it asks whether the neighbour rows need a rebuild (skin test), harvests new
cracks and checks that the state is finite. Energies are computed on demand (``energies``).

Skin test (``geodem.core.neighbors.check_plan``): the rows are rebuilt when the next step could
take an element past half the skin since the last rebuild, and the next check comes before the
current top speed could; a fixed interval let the default landslide's front touch 13 pairs
unseen.

Energy balance (PHYSICS.md section 4)::

    E_k + E_g + E_el + Q_visc + Q_break_n + Q_break_s + Q_fric + E_removed = E_0 + W_ext

``closure_error`` is the residual divided by the largest energy in play. ``E_removed`` is the
kinetic, gravity and elastic energy carried out of the model by elements removed between steps
(``Simulation.remove_elements``, an excavation); the heat and the work the removed elements had
booked stay in ``Q_*`` and ``W_ext``. It is 0 in a model that loses no element.
"""
from __future__ import annotations

import math

import numpy as np

from geodem.backends import select
from geodem.core import neighbors, timestep
from geodem.core.state import BONDED, BROKEN_BASE, broken_code, decode_broken


#: the books of removed elements kept by ``Simulation.remove_elements`` (``Simulation.gone``)
GONE_TERMS = ("kinetic", "gravity", "elastic", "heat_viscous", "heat_break_normal",
              "heat_break_shear", "heat_friction", "work_external")


class InstabilityError(RuntimeError):
    """The run became unstable (NaN, energy growth, deep overlap); the message says what to do."""


def check_layout(state) -> None:
    """ValueError unless every array of ``state`` has the shape, kind of number and memory
    layout the kernels take: ``(N, dim)`` float64 element vectors, ``(N,)`` element scalars,
    ``(N, W)`` rows, writeable and C-contiguous. Cheap (no pass over the data)."""
    from geodem.core.state import PROPS_WIDTH

    n, d = state.n, state.dim
    if d not in (2, 3):
        raise ValueError(f"dim is {d!r}; allowed: 2 or 3")
    w = state.nbr.shape[1] if getattr(state.nbr, "ndim", 0) == 2 else -1
    nr = state.nrot
    want = {k: ((n, d), "f8") for k in ("x", "v", "a", "dx", "x_ref", "free", "fload")}
    want.update({k: ((n,), "f8") for k in ("m", "eta", "q_visc", "q_break_n", "q_break_s",
                                            "q_fric", "w_ext")})
    want.update(props=((n, PROPS_WIDTH), "f8"), group=((n,), "i"), nbr=((n, w), "i"),
                cstate=((n, w), "i"), fs=((n, w, d), "f8"), brate=((n, w), "f4"))
    if state.rotation:
        want.update({k: ((n, nr), "f8") for k in ("w", "wa", "dth", "rfree")})
        want.update(inertia=((n,), "f8"), rot_props=((n, 2), "f8"), mr=((n, w, nr), "f8"))
    if state.fdash is not None:
        want.update(fdash=((n, d), "f8"))
    if state.row_stiffness:
        want.update(krate=((n, w), "f8"))
    for name, (shape, kind) in want.items():
        arr = getattr(state, name)
        if not isinstance(arr, np.ndarray):
            raise ValueError(f"{name} is a {type(arr).__name__}; allowed: a NumPy array of "
                             f"shape {shape}")
        if arr.shape != shape:
            raise ValueError(f"{name} has shape {arr.shape}; allowed: {shape} ({n} elements, "
                             f"dim {d}, row width {w}); build states with "
                             f"geodem.core.state.new_state and never resize them")
        ok = arr.dtype.kind == "i" if kind == "i" else arr.dtype == np.dtype(kind)
        if not ok:
            allowed = "an integer type" if kind == "i" else str(np.dtype(kind))
            raise ValueError(f"{name} has dtype {arr.dtype}; allowed: {allowed} (assign "
                             f"values into the array, e.g. state.{name}[...] = values)")
        if not (arr.flags.c_contiguous and arr.flags.writeable):
            raise ValueError(f"{name} is not a writeable C-contiguous array; allowed: one "
                             f"(assign into it: state.{name}[...] = values)")
    g = state.gravity
    if not isinstance(g, np.ndarray) or g.ndim != 1 or g.size < d or g.dtype.kind != "f":
        raise ValueError(f"gravity is {g!r}; allowed: a float NumPy array of {d} (or 3) "
                         f"components [m/s^2], e.g. np.array([0.0, -9.81])")


def validate_state(state) -> None:
    """Reject non-physical input before any stepping (ValueError naming the parameter/range)."""
    n = state.n
    if n == 0:
        raise ValueError("the model has no elements")
    check_layout(state)
    for name in ("x", "v", "fload"):
        arr = getattr(state, name)
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{name} of element {i} is not finite ({arr[i]}); "
                             f"all {name} must be finite numbers")
    g = np.asarray(state.gravity, dtype=np.float64)
    if not np.isfinite(g).all():
        raise ValueError(f"gravity is not finite ({g}); allowed: finite numbers [m/s^2]")
    bad = ~((state.free == 0.0) | (state.free == 1.0)).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"free of element {i} is {state.free[i]}; allowed: 1.0 (a free degree "
                         f"of freedom) or 0.0 (fixed or prescribed)")
    checks = (("r", 0.0, False), ("m", 0.0, False), ("kn", 0.0, False), ("ks", 0.0, True),
              ("xb", 0.0, True), ("fs0", 0.0, True), ("mu", 0.0, True), ("eta", 0.0, True),
              ("mu_r", 0.0, True))
    if state.rotation:
        checks = checks + (("inertia", 0.0, False), ("bond_moment", 0.0, True),
                           ("rolling_stiffness", 0.0, True))
    if state.contact_damping and (state.fdash is None or state.fdash.shape != state.x.shape):
        raise ValueError("contact_damping is on but the state has no dashpot forces; switch it "
                         "on with geodem.core.state.enable_contact_damping")
    checks = checks + (("zeta_n", 0.0, True),)
    for name, lo, allow_zero in checks:
        arr = getattr(state, name)
        ok = np.isfinite(arr) & ((arr >= lo) if allow_zero else (arr > lo))
        if not ok.all():
            i = int(np.flatnonzero(~ok)[0])
            rng = ">= 0" if allow_zero else "> 0"
            raise ValueError(f"parameter {name} of element {i} is {arr[i]!r}; allowed range: "
                             f"finite and {rng}")
    if not ((state.brate >= 0) & np.isfinite(state.brate)).all():
        raise ValueError("bond_rate must be finite and >= 0")
    bad = np.argwhere(~((state.krate > 0) & (state.krate <= 1))) if state.row_stiffness else ()
    if len(bad):
        i, k = (int(v) for v in bad[0])
        raise ValueError(f"contact stiffness factor krate[{i}, {k}] is "
                         f"{float(state.krate[i, k])!r}; "
                         "allowed: 0 < krate <= 1 (a contact no stiffer than its elements)")
    rows, cols = np.nonzero(state.nbr >= 0)
    if rows.size:
        j = state.nbr[rows, cols]
        if int(j.max()) >= n:
            raise ValueError(f"a neighbour row names element {int(j.max())}, but the model has "
                             f"{n} elements; rebuild the rows (geodem.core.neighbors.build_rows)")
        same = (state.x[rows] == state.x[j]).all(axis=1)
        if same.any():
            a, b = int(rows[same][0]), int(j[same][0])
            raise ValueError(f"elements {a} and {b} are at the same position {state.x[a]}: their "
                             f"contact has no direction; move one of them apart")
    # fixed elements must not overlap each other beyond contact
    fixed = ~(state.free != 0).any(axis=1)
    idx = np.flatnonzero(fixed)
    if 1 < idx.size <= 20000:
        from scipy.spatial import cKDTree

        xf, rf = state.x[idx], state.r[idx]
        pairs = cKDTree(xf).query_pairs(2.0 * rf.max(), output_type="ndarray")
        if len(pairs):
            d = np.linalg.norm(xf[pairs[:, 1]] - xf[pairs[:, 0]], axis=1)
            ov = rf[pairs[:, 0]] + rf[pairs[:, 1]] - d
            deep = ov > 0.5 * np.minimum(rf[pairs[:, 0]], rf[pairs[:, 1]])
            if deep.any():
                a, b = idx[pairs[np.argmax(deep), 0]], idx[pairs[np.argmax(deep), 1]]
                raise ValueError(f"fixed elements {a} and {b} overlap by more than half a radius; "
                                 "fixed elements may touch but not interpenetrate")


def _check_count(name, value, lo) -> None:
    """ValueError unless ``value`` is an integer >= ``lo`` (a count of steps)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}")


def _check_initial_overlaps(state, limit: float) -> None:
    """Refuse a model whose unbonded contacts (a free element in each) already overlap beyond
    ``limit`` x the smaller radius: the first step would fire the pair apart. ValueError naming
    the pair, before stepping; bonded pairs may be built in compression on purpose."""
    from geodem.core.checks import initial_overlap

    ratio, a, b = initial_overlap(state, bonded=False)
    if ratio > limit:
        raise ValueError(
            f"elements {a} and {b} overlap by {ratio:.3g} x the smaller radius before the "
            f"first step; allowed: overlap_limit = {limit:g} (build a looser packing, relax it "
            f"first, or raise overlap_limit)")


def _refresh_acceleration(st, snap) -> None:
    """Make ``a`` consistent with changed freedom, velocity, load or damping (see ``change``)."""
    m = st.m[:, None]
    g = np.asarray(st.gravity, dtype=np.float64)[:st.dim][None, :]
    g0 = np.asarray(snap.get("gravity", st.gravity), dtype=np.float64)[:st.dim][None, :]
    fr0, fr1 = snap["free"] != 0.0, st.free != 0.0
    changed = (fr0 != fr1) | (snap["v"] != st.v) | (snap["fload"] != st.fload) | \
        (snap["eta"] != st.eta)[:, None] | (g0 != g)
    if not changed.any():
        return
    f_contact = np.where(fr0, m * st.a - m * g0 - snap["fload"] + snap["eta"][:, None] * snap["v"],
                         m * st.a)
    a_new = np.where(fr1, (f_contact + m * g + st.fload - st.eta[:, None] * st.v) / m,
                     f_contact / m)
    st.a[changed] = a_new[changed]
    if st.rotation and "w" in snap:
        ii = st.inertia[:, None]
        eta0 = (snap["eta"] * st.inertia / st.m)[:, None]
        eta1 = (st.eta * st.inertia / st.m)[:, None]
        r0, r1 = snap["rfree"] != 0.0, st.rfree != 0.0
        ch = (r0 != r1) | (snap["w"] != st.w) | (snap["eta"] != st.eta)[:, None]
        if ch.any():
            t_contact = np.where(r0, ii * st.wa + eta0 * snap["w"], ii * st.wa)
            wa_new = np.where(r1, (t_contact - eta1 * st.w) / ii, t_contact / ii)
            st.wa[ch] = wa_new[ch]


class Simulation:
    """Advance a :class:`~geodem.core.state.State` in time on a chosen backend.

    Parameters
    ----------
    state: the model (modified in place; call :meth:`sync` before reading arrays on a GPU).
    backend: ``auto | numba | numpy | cupy`` (default: ``$GEODEM_BACKEND`` or ``auto``).
    dt: time step [s]; default ``dt_fraction`` x the smallest element period.
    check_every: most steps between neighbour/crack/finiteness checks (fewer while elements
        move fast: see the module doc).
    overlap_limit: largest allowed overlap as a fraction of the smaller radius; a model whose
        unbonded contacts start beyond it is refused (ValueError) unless the monitor is off.
    monitor_every: steps between energy-growth and overlap checks (0 = never, e.g. while a
        packing is being relaxed); the monitor runs at the first check at or after each multiple
        of ``monitor_every``.
    allow_unstable_dt: skip the refusal of a ``dt`` above the (conservative) stability bound;
        only for studies that measure where the integration fails
        (:mod:`geodem.studies.stability`): the run then stops with InstabilityError.
    """

    # the steps between two events (check, field, callback) in one backend call where the
    # backend offers it (``steps``: numba); False: one call per pass and step, the same results
    stretches = True

    def __init__(self, state, backend=None, dt=None, dt_fraction=timestep.DEFAULT_FRACTION,
                 check_every=10, overlap_limit=0.5, monitor_every=1000,
                 allow_unstable_dt=False):
        _check_count("check_every", check_every, 1)
        _check_count("monitor_every", monitor_every, 0)
        if isinstance(overlap_limit, (bool, np.bool_)) \
                or not isinstance(overlap_limit, (int, float, np.integer, np.floating)) \
                or not 0.0 < overlap_limit <= 1.0:
            raise ValueError(f"overlap_limit must be a number with 0 < overlap_limit <= 1 (a "
                             f"fraction of the smaller radius), got {overlap_limit!r}")
        validate_state(state)
        self.state = state
        if dt is None:
            dt = state.dt if state.dt > 0 else timestep.default_dt(state, dt_fraction)
        if allow_unstable_dt:
            if not (dt > 0.0 and math.isfinite(dt)):
                raise ValueError(f"time step dt must be a positive finite number [s], got {dt}")
            self._dt_bound = timestep.stable_dt_bound(state)
        else:
            self._dt_bound = timestep.check_dt(state, dt)
        if monitor_every:
            # the overlap monitor would stop this run at its first check: refuse it now
            _check_initial_overlaps(state, overlap_limit)
        state.dt = float(dt)
        self.check_every = int(check_every)
        self.overlap_limit = float(overlap_limit)
        self.monitor_every = int(monitor_every)
        self._schedule_checks()
        self.rebuilds = 0
        self.cracks = {"i": [], "j": [], "time": [], "type": []}
        self._time_ref = (int(state.step), float(state.time))  # crack times: see _harvest_host
        self.fields = []
        self._field_every = 0
        self._no_removals()
        self.backend = select(backend)
        if state.step == 0:
            # a fresh model: evaluate the initial forces so the first step starts from a = F/m
            # (dt = 0 changes no velocity and no spring); bonds already beyond their strength
            # break now and are logged at time 0
            self.backend.attach(state)
            self.refresh_forces()
        else:
            self.backend.attach(state)
        self._harvest()
        self.reset_energy()
        self._plan_first_check()

    def _plan_first_check(self):
        # a model that starts with fast elements is checked as soon as the skin asks (the
        # regular schedule would first look after check_every steps, missing contacts and
        # overlaps meanwhile); one that starts at rest keeps the regular schedule
        s = self.state
        if s.skin > 0.0 and s.n:
            disp, speed = self.backend.max_disp_speed()
            if math.isfinite(disp) and math.isfinite(speed):
                rebuild, interval = neighbors.check_plan(disp, s.dt * speed, s.skin,
                                                         self.check_every)
                self._next_check = min(self._next_check, s.step + (1 if rebuild else interval))

    # ------------------------------------------------------------------ stepping
    def run(self, nsteps: int, callback=None, every: int = 0):
        """Advance ``nsteps`` steps; ``callback(sim)`` every ``every`` steps if given."""
        s, b = self.state, self.backend
        dt = s.dt
        every_field = self._field_every
        stretch = getattr(b, "steps", None) if self.stretches else None
        if isinstance(nsteps, float) and nsteps.is_integer():
            nsteps = int(nsteps)
        _check_count("nsteps", nsteps, 0)
        if callback is not None:
            _check_count("every", every, 1)
        check_layout(s)  # arrays replaced since the last run (cheap: no pass over the data)
        left = int(nsteps)
        while left > 0:
            # the steps up to the next event (check, field, callback) in one call where the
            # backend can; the same steps, bit for bit, as one at a time
            k = 1
            if stretch is not None:
                k = min(left, max(1, self._next_check - s.step))
                if every_field:
                    k = min(k, every_field - s.step % every_field)
                if callback is not None and every:
                    k = min(k, every - s.step % every)
            if k > 1 and stretch(dt, k, s.step):
                for _ in range(k):
                    s.time += dt  # as k single steps add it
                nxt = s.step + k
            else:
                k = 1
                b.move(dt)
                nxt = s.step + 1
                b.force(dt, broken_code(nxt, 1), broken_code(nxt, 2))
                s.time += dt
            s.step = nxt
            left -= k
            if every_field and nxt % every_field == 0:
                self._advance_fields(nxt)
            if nxt >= self._next_check:
                self._checks()
            if callback is not None and every and nxt % every == 0:
                callback(self)
        self._harvest()
        b.settle()
        return self

    # ------------------------------------------------------------------ coupled fields
    def add_field(self, field) -> None:
        """Couple a :class:`geodem.fields.CoupledField`; it advances every ``field.every``
        steps by that span of time, sub-stepping on its own stable step."""
        field.attach(self)
        # attaching may set up what the field writes (loads, damping): the device must see it
        self.backend.push(tuple(field.writes))
        self.fields.append(field)
        self._field_every = math.gcd(*[f.every for f in self.fields])

    def field(self, kind: str):
        """The coupled field of ``kind`` (KeyError if none)."""
        for f in self.fields:
            if f.kind == kind:
                return f
        raise KeyError(f"no coupled field {kind!r} in this simulation "
                       f"(coupled: {[f.kind for f in self.fields]})")

    def _advance_fields(self, step: int) -> None:
        b, dt = self.backend, self.state.dt
        for f in self.fields:
            if step % f.every == 0:
                b.pull(tuple(f.reads) + tuple(f.writes))
                f.advance(self, f.every * dt)
                b.push(tuple(f.writes))

    def _schedule_checks(self, next_check=None, next_monitor=None):
        """The steps of the next check and the next monitor (default: the next multiples of
        ``check_every`` and ``monitor_every`` after the current step)."""
        step = self.state.step
        self._next_check = (int(next_check) if next_check is not None
                            else (step // self.check_every + 1) * self.check_every)
        me = self.monitor_every
        self._next_monitor = (int(next_monitor) if next_monitor is not None
                              else (step // me + 1) * me if me else 0)

    def _checks(self):
        s, b = self.state, self.backend
        interval = self.check_every
        fast = False
        if s.skin > 0.0:
            # one scan answers both: a non-finite position or velocity makes it non-finite
            disp, speed = b.max_disp_speed()
            if not (math.isfinite(disp) and math.isfinite(speed)):
                b.pull(("x", "v"))
                self._raise_nonfinite()
            # an element moving more than overlap_limit x the smallest radius per step can
            # overlap a partner beyond the limit within one step: run the monitor's checks at
            # once rather than at the next monitor (the checks then come every step)
            fast = s.dt * speed > self.overlap_limit * self._smallest_radius()
            rebuild, interval = neighbors.check_plan(disp, s.dt * speed, s.skin, self.check_every)
            if rebuild:
                # the rebuild reads x and the rows and writes the rows and x_ref: only those
                # travel (a device backend's other arrays are newer than the host's copies)
                rows = ("x_ref",) + s.row_array_names()
                b.pull(("x",) + rows)
                self._harvest_host()
                neighbors.build_rows(s)
                self.rebuilds += 1
                b.push(rows)
            else:
                self._harvest()
        else:
            if not b.all_finite():
                b.pull(("x", "v"))
                self._raise_nonfinite()
            self._harvest()
        self._next_check = s.step + interval
        # a rebuild must not skip the monitor: a run blowing up rebuilds at every check
        if self.monitor_every and s.step >= self._next_monitor:
            self.check_energy()
            self.check_overlaps()
            self._next_monitor = (s.step // self.monitor_every + 1) * self.monitor_every
        elif self.monitor_every and fast:
            # the energy first: a diverging time step shows as energy growth, and its message
            # names the cause (dt); a fast collision keeps the books and shows as an overlap
            self.check_energy()
            self.check_overlaps()

    def _smallest_radius(self) -> float:
        # radii change only through fields (thermal expansion), between rebuilds by little
        r_min = getattr(self, "_r_min", None)
        if r_min is None or self.rebuilds != self._r_min_at:
            r_min = self._r_min = float(self.state.r.min())
            self._r_min_at = self.rebuilds
        return r_min

    def check_finite(self) -> None:
        """Raise :class:`InstabilityError` (naming the elements) if a position or velocity is
        not finite: one scan, no copy. The runner calls it before every checkpoint, so that no
        checkpoint ever holds a broken state."""
        if not self.backend.all_finite():
            self.backend.pull(("x", "v"))
            self._raise_nonfinite()

    def _raise_nonfinite(self):
        s = self.state
        self.sync()
        bad = np.flatnonzero(~np.isfinite(s.x).all(axis=1) | ~np.isfinite(s.v).all(axis=1))
        what = "positions/velocities"
        if not bad.size:
            # finite motion, non-finite books or accelerations (e.g. a mass set to 0)
            books = np.stack([getattr(s, k) for k in ("q_visc", "q_break_n", "q_break_s",
                                                      "q_fric", "w_ext")], axis=1)
            bad = np.flatnonzero(~np.isfinite(s.a).all(axis=1) | ~np.isfinite(books).all(axis=1))
            what = "accelerations or energy books"
        raise InstabilityError(
            f"the run became unstable at step {s.step}: non-finite {what} of "
            f"elements {bad[:10].tolist()}{' ...' if bad.size > 10 else ''}; reduce dt "
            f"(now {s.dt:.4g} s, stability bound at the start of the run "
            f"{self._dt_bound:.4g} s) or check their stiffness and mass")

    # ------------------------------------------------------------------ cracks
    def _harvest(self):
        b = self.backend
        if b.has_new_cracks():
            b.pull(("nbr", "cstate"))
            self._harvest_host()
            b.push(("cstate",))

    def _harvest_host(self):
        s = self.state
        hit = s.cstate >= BROKEN_BASE
        if not hit.any():
            return
        rows, cols = np.nonzero(hit)
        step, kind = decode_broken(s.cstate[rows, cols])
        j = s.nbr[rows, cols]
        once = rows < j
        i, j, step, kind = rows[once], j[once], step[once], kind[once]
        # in the order they broke (then by pair), whichever steps one harvest spans: the log
        # is the same however a run was cut into calls (a resumed run, other chunks)
        order = np.lexsort((j, i, step))
        i, j, step, kind = i[order], j[order], step[order], kind[order]
        if self.ids is not None:  # after a removal: in the numbering of the built model
            i, j = self.ids[i], self.ids[j]
        self.cracks["i"].extend(i.tolist())
        self.cracks["j"].extend(j.tolist())
        # a code's step is the step that broke it, within this simulation's constant dt, counted
        # from the step and time this simulation started at (an earlier stage may have run at
        # another dt, so not step * dt; and not from the time now, whose sum of dt's depends on
        # when the harvest happens)
        step0, time0 = self._time_ref
        self.cracks["time"].extend((time0 + (step - step0) * s.dt).tolist())
        self.cracks["type"].extend(kind.tolist())
        s.cstate[hit] = 0

    def cut(self, i, j) -> int:
        """Pre-cut joints: remove the bonds of pairs ``(i, j)`` and log them as type 0 cracks.

        A loaded bond releases what it held: the drop of the elastic energy is booked as normal
        breaking heat (half on each side, as a tensile break), and the forces are evaluated
        again at the same positions (``dt = 0``), so the next step starts from the cut model.
        Returns the number of bonds cut (pairs that were not bonded are ignored)."""
        s = self.sync()
        e_before = np.array(self.backend.elastic_energy(), dtype=np.float64)
        n = 0
        for a, b in zip(np.atleast_1d(i).tolist(), np.atleast_1d(j).tolist()):
            ka = np.flatnonzero(s.nbr[a] == b)
            kb = np.flatnonzero(s.nbr[b] == a)
            if ka.size and kb.size and s.cstate[a, ka[0]] == BONDED:
                s.cstate[a, ka[0]] = 0
                s.cstate[b, kb[0]] = 0
                lo, hi = min(a, b), max(a, b)
                if self.ids is not None:
                    lo, hi = int(self.ids[lo]), int(self.ids[hi])
                for key, val in (("i", lo), ("j", hi), ("time", s.time), ("type", 0)):
                    self.cracks[key].append(val)
                n += 1
        self.backend.push(("cstate",))
        if n:
            s.q_break_n += e_before - np.asarray(self.backend.elastic_energy())
            self.refresh_forces(push=("q_break_n",))
            self._harvest()
        return n

    def refresh_forces(self, push=()) -> None:
        """Evaluate the forces again at the current positions, between steps: ``dx = 0`` and
        ``dt = 0``, so no velocity, spring or heat changes, and the next velocity-Verlet step
        starts from ``a = F(x) / m`` of the model as it now is (after a cut, new radii, ...).
        A bond already beyond its strength breaks now, at the current step. ``push``: host
        changes to send to the backend first. Turning elements: the step's rotation increment
        ``dth`` is zeroed too (it loads the rolling springs like ``dx`` the shear springs;
        left, a refresh applied the last step's rotation again, and a heated plate of turning
        elements, refreshed as its radii grow, gained energy until it stopped at step 1000)."""
        s = self.state
        s.dx.fill(0.0)
        names = ("dx",)
        if s.rotation:
            s.dth.fill(0.0)
            names += ("dth",)
        self.backend.push(names + tuple(push))
        self.backend.force(0.0, broken_code(s.step, 1), broken_code(s.step, 2))

    def crack_log(self) -> np.ndarray:
        """Structured array of cracks ``(i, j, time, type)``; type 1 tensile, 2 shear, 0 joint."""
        self._harvest()
        c = self.cracks
        out = np.zeros(len(c["i"]), dtype=[("i", "i4"), ("j", "i4"), ("time", "f8"),
                                           ("type", "i1")])
        for k in out.dtype.names:
            out[k] = c[k]
        return out

    # ------------------------------------------------------------------ energy
    def sync(self):
        """Bring every array of the backend back into ``state`` (no-op on CPU backends)."""
        self.backend.pull()
        return self.state

    def _parts(self):
        s = self.state
        self.sync()
        fr = s.free != 0.0
        e_el = np.asarray(self.backend.elastic_energy())
        ke = 0.5 * (s.m[:, None] * s.v * s.v * fr).sum(axis=1)
        if s.rotation:
            ke = ke + 0.5 * (s.inertia[:, None] * s.w * s.w * (s.rfree != 0.0)).sum(axis=1)
        eg = -(s.m[:, None] * s.x * s.gravity[None, :s.dim] * fr).sum(axis=1)
        return {"kinetic": ke, "gravity": eg, "elastic": e_el.copy(),
                "heat_viscous": s.q_visc.copy(), "heat_break_normal": s.q_break_n.copy(),
                "heat_break_shear": s.q_break_s.copy(), "heat_friction": s.q_fric.copy(),
                "work_external": s.w_ext.copy()}

    def reset_energy(self):
        """Zero the heat/work books and take the current energy as ``E_0``."""
        s = self.state
        self.sync()
        self.gone = dict.fromkeys(GONE_TERMS, 0.0)
        for k in ("q_visc", "q_break_n", "q_break_s", "q_fric", "w_ext"):
            getattr(s, k)[:] = 0.0
        self.backend.push(("q_visc", "q_break_n", "q_break_s", "q_fric", "w_ext"))
        p = self._parts()
        # below this the books are round-off: squeezing every element by 1e-6 of its radius
        self._floor = max(1e-12 * 0.5 * float((s.kn * s.r * s.r).sum()), 1e-300)
        self._eg0 = float(p["gravity"].sum())
        self._emech0 = float(p["kinetic"].sum() + p["elastic"].sum())
        s.e0 = self._emech0 + self._eg0

    def energies(self, by_group: bool = False) -> dict:
        """Energy terms [J]: totals, plus per-group arrays indexed by group name if asked."""
        p = self._parts()
        tot = {k: float(v.sum()) for k, v in p.items()}
        gone = self.gone  # the books of removed elements (remove_elements): 0 without one
        for k in ("heat_viscous", "heat_break_normal", "heat_break_shear", "heat_friction",
                  "work_external"):
            tot[k] += gone[k]
        tot["heat_total"] = (tot["heat_viscous"] + tot["heat_break_normal"]
                             + tot["heat_break_shear"] + tot["heat_friction"])
        tot["removed"] = gone["kinetic"] + gone["gravity"] + gone["elastic"]
        tot["total"] = tot["kinetic"] + tot["gravity"] + tot["elastic"] + tot["heat_total"] \
            + tot["removed"]
        tot["initial"] = self.state.e0
        resid = tot["total"] - self.state.e0 - tot["work_external"]
        scale = max(self._emech0, tot["kinetic"] + tot["elastic"] + tot["heat_total"]
                    + gone["kinetic"] + gone["elastic"], abs(tot["work_external"]),
                    abs(tot["gravity"] + gone["gravity"] - self._eg0), self._floor)
        tot["closure_residual"] = resid
        tot["closure_error"] = abs(resid) / scale
        if by_group:
            s = self.state
            tot["groups"] = {name: {k: float(v[s.group == gid].sum()) for k, v in p.items()}
                             for name, gid in s.groups.items()}
            if "all" in tot["groups"]:
                tot["groups"]["all"] = {k: float(v.sum()) for k, v in p.items()}
        return tot

    def closure_error(self) -> float:
        return self.energies()["closure_error"]

    def check_energy(self, limit: float = 0.5):
        """Raise InstabilityError when the books are off by more than ``limit`` (energy growth)."""
        e = self.energies()
        if not (math.isfinite(e["total"]) and math.isfinite(e["closure_error"])):
            self._raise_nonfinite()
        if e["closure_error"] > limit:
            s = self.state
            ke = (s.m[:, None] * s.v * s.v * (s.free != 0.0)).sum(axis=1)
            fast = [i for i in np.argsort(-ke)[:5].tolist() if ke[i] > 0.01 * ke.max()]
            how = "grew without a source" if e["closure_residual"] > 0 else \
                "was lost without a sink"
            raise InstabilityError(
                f"energy {how} at step {s.step}: closure error "
                f"{e['closure_error']:.3g} > {limit} (fastest elements {fast}); the time step "
                f"{s.dt:.4g} s is probably too large (stability bound at the start of the run "
                f"{self._dt_bound:.4g} s): reduce dt or check those elements' "
                f"stiffness and mass")
        return e

    def check_overlaps(self):
        """Raise InstabilityError when an overlap exceeds ``overlap_limit`` x the smaller radius."""
        from geodem.core.checks import max_overlap

        s = self.state
        self.backend.pull(("x", "nbr"))
        worst, i, j = max_overlap(s.x, s.r, s.nbr)
        if worst > self.overlap_limit:
            raise InstabilityError(
                f"elements {i} and {j} overlap by {worst:.2f} x the smaller radius "
                f"(limit {self.overlap_limit}) at step {s.step}: reduce the loading rate or dt "
                f"(now {s.dt:.4g} s), or raise kn of these elements")
        return worst

    # ------------------------------------------------------------------ quasi-static helpers
    def unbalanced_force_ratio(self) -> float:
        """Mean |net force| / mean |contact force| (see ``geodem.core.checks``)."""
        from geodem.core.checks import unbalanced_force_ratio

        return unbalanced_force_ratio(self.sync())

    def balance(self, n_across: float, standard_damping: bool = True, steps: int | None = None):
        """MatDEM's standard balance: ``50 N`` steps (``N`` elements across the loading direction),
        with the standard damping ``eta_c / N`` on every element unless told otherwise.

        Simulated time stays constant when the element size changes. Returns the unbalanced-force
        ratio at the end (small = equilibrium).
        """
        if standard_damping:
            eta = timestep.standard_damping(self.sync(), n_across)
            self.change(lambda st: st.eta.__setitem__(slice(None), eta), book_energy=False)
        self.run(timestep.standard_balance_steps(n_across) if steps is None else steps)
        return self.unbalanced_force_ratio()

    def change(self, fn, book_energy: bool = True, group: str | None = None) -> float:
        """Change the model between steps: ``fn(state)`` may fix, free or move degrees of
        freedom, change velocities, loads or damping.

        The stored acceleration of every changed degree of freedom is recomputed for the new
        conditions (free: ``(F_contact + m g + F_load - eta v) / m``; fixed or kinematic:
        ``F_contact / m``), so the next velocity-Verlet step starts consistently (without this,
        switching damping on in a moving model leaves a closure error of a few %). With
        ``book_energy`` the energy the change itself adds or removes (e.g. the kinetic energy of
        a group that is stopped) is booked as external work on ``group`` (default: every element).
        Returns that energy [J].
        """
        from geodem.core import groups

        if group is not None:
            groups.members(self.state, group)  # an unknown group: KeyError before any change
        before = self.energies()["total"] if book_energy else 0.0
        st = self.sync()
        snap = {k: np.array(getattr(st, k), dtype=np.float64)
                for k in ("free", "v", "fload", "eta", "gravity")
                + (("w", "rfree") if st.rotation else ())}
        fn(st)
        validate_state(st)  # the changed model must still be a valid one (ValueError)
        _refresh_acceleration(st, snap)
        self.backend.push()
        if not book_energy:
            return 0.0
        delta = self.energies()["total"] - before
        idx = groups.members(st, group or "all")
        if idx.size and delta != 0.0:
            st.w_ext[idx] += delta / idx.size
            self.backend.push(("w_ext",))
        return delta

    def set_fixed_velocity(self, moves) -> bool:
        """Prescribe velocities of elements whose every degree of freedom is already fixed
        (kinematic walls): ``moves`` is a list of ``(idx, v)``, ``v`` a (dim,) velocity [m/s].

        The light form of ``change(fn, book_energy=False)`` for a servo that moves its walls
        every few steps, with the same numbers: where a velocity changes, the fixed DOF's
        stored reaction ``a = F_contact / m`` is recomputed as :meth:`change` recomputes it
        (``(m a) / m``), nothing else is touched, and neither is the whole model validated
        and sent to the backend again (on a CPU backend that was most of a servo update).
        Returns False, changing nothing, when a DOF of some ``idx`` is free (or, with
        rotation, turns or spins): :meth:`change` is then the way. ValueError for a velocity
        that is not finite."""
        st = self.state
        names = ("free", "v", "a") + (("rfree", "w") if st.rotation else ())
        self.backend.pull(names)
        for idx, v in moves:
            if (st.free[idx] != 0.0).any() or st.rotation and (
                    (st.rfree[idx] != 0.0).any() or (st.w[idx] != 0.0).any()):
                return False
            if not np.isfinite(np.asarray(v, dtype=np.float64)).all():
                raise ValueError(f"velocity {v!r}: allowed: finite numbers [m/s]")
        for idx, v in moves:
            new = np.broadcast_to(np.asarray(v, dtype=np.float64), st.v[idx].shape)
            changed = st.v[idx] != new
            m = st.m[idx][:, None]
            a = st.a[idx]
            st.a[idx] = np.where(changed, (m * a) / m, a)
            st.v[idx] = new
        self.backend.push(("v", "a"))
        return True

    # ------------------------------------------------------------------ removing elements
    def _no_removals(self):
        #: original index (in the model as built) of each element; None: no element removed
        self.ids = None
        self.gone = dict.fromkeys(GONE_TERMS, 0.0)
        self.removals = 0

    def remove_elements(self, mask) -> dict:
        """Remove the elements selected by ``mask`` (bool (N,) or indices) between steps: an
        excavation. The one place where a running simulation changes its number of elements.

        The state is replaced by one without them (:func:`geodem.core.state.take`: every
        array, the rows relabelled with their contact history, the groups kept, so removed
        elements leave every group), the backend is attached to it again and the forces are
        evaluated again at the same positions (``dt = 0``: the elements left lose the pull and
        push of the removed ones at once, no velocity changes). Nothing of this touches the
        time-step loop; the cost is one copy of the state per call.

        Books: what leaves with the removed elements is kept so the energy balance stays
        closed: their kinetic and gravity energy and the elastic energy of their contacts and
        bonds (the drop of the model's elastic energy, [J]) go to the term ``removed`` of
        :meth:`energies`; the heat and external work they had booked stay in the totals
        (``gone``). :attr:`ids` maps each element to its index in the model as built, and
        the crack log is written in that numbering from then on (checkpoints keep both).

        Returns the energy carried out by this call [J]: ``kinetic``, ``gravity``, ``elastic``
        and their sum ``removed``, plus ``n_removed`` and ``n_left``. ValueError when a coupled
        field is attached (their per-element arrays are not cut), or when every element would go.
        """
        s = self.sync()
        m = np.asarray(mask)
        if m.dtype != bool:
            sel = np.zeros(s.n, bool)
            sel[m.astype(np.int64)] = True
            m = sel
        if m.shape != (s.n,):
            raise ValueError(f"mask must have shape ({s.n},), got {m.shape}")
        n_rm = int(m.sum())
        out = {"n_removed": n_rm, "n_left": int(s.n - n_rm), "kinetic": 0.0, "gravity": 0.0,
               "elastic": 0.0, "removed": 0.0}
        if n_rm == 0:
            return out
        if self.fields:
            raise ValueError(f"cannot remove elements from a model with coupled fields "
                             f"({', '.join(f.kind for f in self.fields)}): their per-element "
                             f"arrays would not follow; remove elements before coupling them")
        if n_rm == s.n:
            raise ValueError(f"removing all {s.n} elements would leave no model")
        from geodem.core.state import take

        self._harvest()
        p = self._parts()
        el_before = float(p["elastic"].sum())
        for k in GONE_TERMS:
            if k not in ("kinetic", "gravity", "elastic"):
                self.gone[k] += float(p[k][m].sum())
        keep = ~m
        new = take(s, keep)
        self.ids = (np.arange(s.n) if self.ids is None else self.ids)[keep]
        self.state = new
        self.backend.attach(new)
        self.backend.push()
        el_after = float(np.asarray(self.backend.elastic_energy()).sum())
        out["kinetic"] = float(p["kinetic"][m].sum())
        out["gravity"] = float(p["gravity"][m].sum())
        out["elastic"] = el_before - el_after
        out["removed"] = out["kinetic"] + out["gravity"] + out["elastic"]
        for k in ("kinetic", "gravity", "elastic"):
            self.gone[k] += out[k]
        self._r_min = None
        self.removals += 1
        self.refresh_forces()
        self._harvest()
        self.backend.settle()
        return out

    # ------------------------------------------------------------------ checkpoints
    def save(self, path) -> None:
        """Write a complete checkpoint (state, energy books, crack log) atomically."""
        from geodem.core.checkpoint import save_state

        self.sync()
        self._harvest()
        from geodem.fields import pack_arrays

        save_state(self.state, path, extra={"cracks": self.cracks, "eg0": self._eg0,
                                            "emech0": self._emech0,
                                            "check_every": self.check_every,
                                            "monitor_every": self.monitor_every,
                                            "overlap_limit": self.overlap_limit,
                                            "time_ref": list(self._time_ref),
                                            "gone": self.gone, "removals": self.removals,
                                            "next_check": self._next_check,
                                            "next_monitor": self._next_monitor,
                                            "fields": [{"kind": f.kind, "config": f.config(),
                                                        "substeps": f.substeps}
                                                       for f in self.fields]},
                   extra_arrays={**pack_arrays(self.fields),
                                 **({} if self.ids is None else {"element_ids": self.ids})})

    @classmethod
    def load(cls, path, backend=None) -> "Simulation":
        """Resume from :meth:`save`'s checkpoint; stepping continues bit-identically on CPU."""
        from geodem.core.checkpoint import load_state

        from geodem.fields import field_from_config, unpack_arrays

        state, extra, more = load_state(path, with_arrays=True)
        if "check_every" not in extra:
            raise ValueError(f"{path} holds a state (geodem.core.checkpoint.save_state) but no "
                             f"simulation: continue it with Simulation(load_state(path)), or "
                             f"save simulations with Simulation.save")
        sim = cls.__new__(cls)
        sim.state = state
        sim.check_every = int(extra["check_every"])
        sim.overlap_limit = float(extra.get("overlap_limit", 0.5))
        sim.monitor_every = int(extra.get("monitor_every", 1000))
        sim._schedule_checks(extra.get("next_check"), extra.get("next_monitor"))
        sim.rebuilds = 0
        sim.cracks = extra["cracks"]
        ref = extra.get("time_ref", (0, 0.0))  # checkpoints before it: times were step * dt
        sim._time_ref = (int(ref[0]), float(ref[1]))
        sim._eg0, sim._emech0 = extra["eg0"], extra["emech0"]
        sim._no_removals()
        sim.gone.update(extra.get("gone") or {})
        sim.removals = int(extra.get("removals", 0))
        if "element_ids" in more:
            sim.ids = np.asarray(more.pop("element_ids"), dtype=np.int64)
        sim._floor = max(1e-12 * 0.5 * float((state.kn * state.r * state.r).sum()), 1e-300)
        sim._dt_bound = timestep.stable_dt_bound(state)
        sim.backend = select(backend)
        sim.backend.attach(state)
        sim.fields, sim._field_every = [], 0
        for k, rec in enumerate(extra.get("fields", [])):
            f = field_from_config(rec["kind"], rec["config"])
            sim.add_field(f)
            f.restore(unpack_arrays(k, more))
            f.substeps = int(rec.get("substeps", 0))
        sim.backend.push()
        for f in sim.fields:
            if hasattr(f, "resume"):  # a field that tells the backend what to step
                f.resume(sim)
        return sim

    def bonded_count(self) -> int:
        self.backend.pull(("cstate",))
        return int((self.state.cstate == BONDED).sum() // 2)
