"""Freezing elements at rest far from the action, and waking them when touched.

A scene such as a landslide spends most of its element-steps on ground that never moves. This
coupled field (kind ``"freeze"``) puts such elements to sleep and the backends then skip them:

* **calm**: a free element whose speed is below ``v_sleep`` [m/s] and whose acceleration
  (net force / mass, gravity and damping included) is below ``a_sleep`` [m/s^2] (default
  ``omega v_sleep``, ``omega = sqrt(kn / 2m)`` its own frequency: the acceleration of an
  element oscillating at ``v_sleep``);
* **asleep**: calm at ``patience`` consecutive couplings. Its velocity is set to zero and its
  degrees of freedom are fixed: it stays where it is and its stored acceleration becomes its
  contact reaction ``F_contact / m`` (as for any fixed element);
* **awake again**: an asleep element whose unbalanced acceleration
  ``|F_contact/m + g + F_load/m|`` exceeds ``a_wake`` (default ``2 a_sleep``; something
  pushes it: an impact, a neighbour that moved away). Its degrees of freedom are freed
  (velocity zero).

Every coupling sorts the elements at rest (asleep, or fixed with zero velocity) into
**border** ones, that have a neighbour in their row (contacts and near neighbours within the
skin) that is not at rest, and **deep** ones. Deep elements are skipped by the ``move`` and
``force`` kernels (``backend.set_active``): nothing around them moves, so their contacts would
not change. Border elements are still evaluated every step, as fixed elements: their rows stay
exact and their reaction is what wakes them.

Energy books stay closed: the kinetic energy of an element put to sleep is booked as viscous
heat, and since the engine counts gravity energy on free degrees of freedom only, the gravity
energy ``-m g.x`` an element takes out of (or back into) that sum when it falls asleep (wakes)
is booked as external work ``w_ext`` of that element.

Accuracy cost: a border element acts as a rigid obstacle until the next coupling notices the
push (``every`` steps), and elements are asleep at small but non-zero speeds
(``v_sleep``). ``geodem study freeze`` / docs/freezing.md measure both on the landslide case.

Reference: sleeping/deactivation of bodies at rest is standard in rigid-body and DEM codes
(e.g. "sleeping" in Box2D and Bullet; the active-particle lists of MatDEM's "frozen" elements).
"""
from __future__ import annotations

import math

import numpy as np

from geodem.fields import CoupledField, register_field


@register_field("freeze")
class FreezeField(CoupledField):
    """Put calm free elements to sleep and wake them when pushed (see the module doc).

    Parameters: ``v_sleep`` [m/s]; ``a_wake`` [m/s^2] (default per element
    ``2 omega v_sleep``, ``omega = sqrt(kn / 2m)``); ``a_sleep`` [m/s^2] (default
    ``a_wake / 2``); ``patience`` (consecutive calm couplings before sleeping); ``every``
    (mechanical steps between couplings); ``group``: only elements of this group may sleep
    (default every free element).
    """

    reads = {"v": "m/s", "a": "m/s^2", "free": "1", "fload": "N", "m": "kg", "eta": "kg/s",
             "x": "m", "nbr": "1"}
    writes = {"v": "m/s", "a": "m/s^2", "free": "1", "q_visc": "J", "w_ext": "J"}
    safety = 1.0

    def __init__(self, v_sleep: float, a_wake: float | None = None,
                 a_sleep: float | None = None, patience: int = 3, every: int = 10,
                 group: str | None = None):
        super().__init__(every)
        for name, val in (("v_sleep", v_sleep), ("a_wake", a_wake)):
            if val is not None and not (val > 0 and math.isfinite(val)):
                raise ValueError(f"{name} = {val!r}: must be a positive finite number")
        self.v_sleep = float(v_sleep)
        self.a_wake = None if a_wake is None else float(a_wake)
        self.a_sleep = None if a_sleep is None else float(a_sleep)
        if self.a_sleep is not None and not (
                0 < self.a_sleep <= (self.a_wake if self.a_wake is not None else math.inf)):
            raise ValueError(f"a_sleep = {a_sleep!r}: allowed 0 < a_sleep <= a_wake "
                             f"({self.a_wake})")
        if int(patience) < 1:
            raise ValueError(f"patience = {patience!r}: must be >= 1")
        self.patience = int(patience)
        self.group = group
        self.stats = {"fell_asleep": 0, "woke": 0, "max_asleep": 0, "max_deep": 0,
                      "deep_element_steps": 0, "element_steps": 0}

    # ------------------------------------------------------------------ contract
    def attach(self, sim) -> None:
        from geodem.core import groups

        st = sim.state
        self.free0 = st.free.copy()  # what each element's freedom was before any sleep
        self.asleep = np.zeros(st.n, bool)
        self.calm = np.zeros(st.n, np.int32)
        self.may_sleep = (st.free != 0.0).any(axis=1)
        if self.group is not None:
            sel = np.zeros(st.n, bool)
            sel[groups.members(st, self.group)] = True
            self.may_sleep &= sel
        self.n_deep = 0
        self._thresholds(st)

    def _thresholds(self, st) -> None:
        # an element oscillating at speed v_sleep on its own spring (omega = sqrt(kn/(2m)),
        # the wall-bond stiffness of the time step) accelerates at up to omega v_sleep: the
        # default sleep threshold, and twice it wakes (a stiff rock needs larger ones than
        # gravity suggests, or sleepers frozen slightly off balance wake each other in turn)
        omega = np.sqrt(0.5 * st.kn / st.m)
        self.a_wake_i = (np.full(st.n, self.a_wake) if self.a_wake is not None
                         else 2.0 * omega * self.v_sleep)
        self.a_sleep_i = (np.full(st.n, self.a_sleep) if self.a_sleep is not None
                          else 0.5 * self.a_wake_i)

    def stable_dt(self, sim) -> float:
        return math.inf  # no dynamics of its own

    def substep(self, sim, h: float) -> None:
        self._update(sim)

    def advance(self, sim, span: float) -> int:
        self._update(sim)
        self.substeps += 1
        return 1

    def config(self) -> dict:
        return {"v_sleep": self.v_sleep, "a_wake": self.a_wake, "a_sleep": self.a_sleep,
                "patience": self.patience, "every": self.every, "group": self.group}

    def arrays(self) -> dict:
        return {"free0": self.free0, "asleep": self.asleep, "calm": self.calm,
                "may_sleep": self.may_sleep, "a_wake_i": self.a_wake_i,
                "a_sleep_i": self.a_sleep_i}

    def restore(self, arrays: dict) -> None:
        self.free0 = np.array(arrays["free0"])
        self.asleep = np.array(arrays["asleep"], bool)
        self.calm = np.array(arrays["calm"], np.int32)
        self.may_sleep = np.array(arrays["may_sleep"], bool)
        self.a_wake_i = np.array(arrays["a_wake_i"])
        self.a_sleep_i = np.array(arrays["a_sleep_i"])

    def resume(self, sim) -> None:
        """Hand the backend its list again after a checkpoint was loaded."""
        self._classify(sim.state, sim)

    def summary(self) -> dict:
        s = dict(self.stats)
        s["asleep_now"] = int(self.asleep.sum())
        s["deep_now"] = int(self.n_deep)
        s["skipped_fraction"] = (s["deep_element_steps"] / s["element_steps"]
                                 if s["element_steps"] else 0.0)
        return s

    # ------------------------------------------------------------------ the work
    def _update(self, sim) -> None:
        st = sim.state
        g = np.asarray(st.gravity, float)[:st.dim]
        speed2 = (st.v * st.v).sum(axis=1)
        acc2 = (st.a * st.a).sum(axis=1)  # free: the net acceleration; asleep: F_contact/m
        calm = self.may_sleep & ~self.asleep & (speed2 < self.v_sleep ** 2) & \
            (acc2 < self.a_sleep_i ** 2)
        self.calm = np.where(calm, self.calm + 1, 0).astype(np.int32)
        fall = np.flatnonzero(calm & (self.calm >= self.patience))
        sl = np.flatnonzero(self.asleep)
        net = st.a[sl] + g[None, :] + st.fload[sl] / st.m[sl, None]
        wake = sl[(net * net).sum(axis=1) > self.a_wake_i[sl] ** 2]
        if fall.size:
            self._fall_asleep(st, fall, g)
        if wake.size:
            self._wake_up(st, wake, g)
        self._classify(st, sim)
        n = st.n
        self.stats["max_asleep"] = max(self.stats["max_asleep"], int(self.asleep.sum()))
        self.stats["max_deep"] = max(self.stats["max_deep"], self.n_deep)
        self.stats["deep_element_steps"] += self.n_deep * self.every
        self.stats["element_steps"] += n * self.every

    def _gravity_energy(self, st, idx, g):
        """``-m g.x`` over the originally free DOFs of elements ``idx`` [J]."""
        return -(st.m[idx, None] * st.x[idx] * g[None, :] * (self.free0[idx] != 0.0)).sum(axis=1)

    def _fall_asleep(self, st, idx, g) -> None:
        # books: kinetic energy -> heat; gravity energy leaves the engine's sum over free DOFs
        # -> external work (module doc). The stored acceleration of each DOF being fixed
        # becomes the contact reaction F/m = a - g - F_load/m + eta v/m (Simulation.change)
        m = st.m[idx, None]
        fr = st.free[idx] != 0.0
        v = st.v[idx]
        st.q_visc[idx] += 0.5 * st.m[idx] * (v * v * fr).sum(axis=1)
        st.w_ext[idx] -= self._gravity_energy(st, idx, g)
        react = st.a[idx] - g[None, :] - st.fload[idx] / m + st.eta[idx, None] * v / m
        st.a[idx] = np.where(fr, react, st.a[idx])
        st.v[idx] = 0.0
        st.free[idx] = 0.0
        self.asleep[idx] = True
        self.stats["fell_asleep"] += int(idx.size)

    def _wake_up(self, st, idx, g) -> None:
        # the DOFs freed again start at rest: a = (F_contact + m g + F_load) / m
        m = st.m[idx, None]
        fr = self.free0[idx] != 0.0
        st.a[idx] = np.where(fr, st.a[idx] + g[None, :] + st.fload[idx] / m, st.a[idx])
        st.free[idx] = self.free0[idx]
        st.w_ext[idx] += self._gravity_energy(st, idx, g)
        self.asleep[idx] = False
        self.calm[idx] = 0
        self.stats["woke"] += int(idx.size)

    def _classify(self, st, sim) -> None:
        """Deep = at rest with every row neighbour at rest; the backend steps the others."""
        fixed_still = ~(st.free != 0.0).any(axis=1) & ~(st.v != 0.0).any(axis=1)
        rest = self.asleep | fixed_still
        if not self.asleep.any():
            deep = np.zeros(st.n, bool)
        else:
            nb = st.nbr
            valid = nb >= 0
            moving_nb = (valid & ~rest[np.where(valid, nb, 0)]).any(axis=1)
            deep = rest & ~moving_nb
        self.n_deep = int(deep.sum())
        setter = getattr(sim.backend, "set_active", None)
        if setter is not None:
            setter(None if self.n_deep == 0 else np.flatnonzero(~deep))
