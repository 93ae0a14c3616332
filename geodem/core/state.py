"""Model state: plain structure-of-arrays data (jax-md style).

Every array is owned by a :class:`State`; kernels receive the arrays, never the object.
Shapes use ``N`` elements, ``W`` row width (neighbour capacity) and ``dim`` = 2 or 3.

Element arrays (SI units)
    x, v, a      (N, dim) float64   position [m], velocity [m/s], acceleration [m/s^2]
                                    (``a`` = F/m of the last force evaluation, for every DOF,
                                    fixed ones included: it carries the reaction force)
    dx           (N, dim) float64   displacement of the last step [m] (shear increments)
    x_ref        (N, dim) float64   positions at the last neighbour build [m]
    m            (N,)     float64   mass [kg]
    eta          (N,)     float64   global (mass) damping coefficient [kg/s]
    props        (N, 8)   float64   the parameters a neighbour's contact needs, packed so that one
                                    cache line holds them all (the kernels gather them per contact):
                                    columns r, kn, ks, xb, fs0, mu, mu_r, zeta_n. Read and write
                                    them through the named column views:
    r            (N,)     view      radius [m]
    kn, ks       (N,)     view      element normal / shear spring stiffness [N/m]
    xb           (N,)     view      element breaking displacement [m]
    fs0          (N,)     view      element initial shear resistance [N]
    mu           (N,)     view      element friction coefficient [-]
    mu_r         (N,)     view      element rolling-resistance coefficient [-] (rotation only)
    zeta_n       (N,)     view      element normal contact damping ratio [-] (used only when
                                    ``contact_damping``; see :func:`enable_contact_damping`)
    free         (N, dim) float64   1.0 for a free degree of freedom, 0.0 for a fixed or
                                    kinematic one (moved at its velocity ``v``)
    fload        (N, dim) float64   external load per element [N] (gravity is separate)
    group        (N,)     int32     group id; names in ``groups``

Contact rows (each contact stored in both elements' rows)
    nbr          (N, W)   int32     neighbour index, -1 = empty; valid entries first, sorted
                                    by index (the numba backend steps a contact once, from
                                    the lower index's row: geodem.backends.numba_backend)
    cstate       (N, W)   int32     0 contact without bond, 1 bonded,
                                    >= 2 bond broken at ``step`` with ``type``:
                                    ``2 + 2*step + (type-1)`` (type 1 tensile, 2 shear),
                                    not yet harvested into the crack log
    fs           (N, W, dim) float64 shear spring force acting on the row's element [N]
    brate        (N, W)   float32   bond_rate: scales the breaking force and Fs0 [-]

Rotation (optional, ``None`` unless :func:`enable_rotation` was called; MatDEM's elements
translate only, PHYSICS.md section 1). ``nr`` = 1 in 2-D (about z), 3 in 3-D.
    w            (N, nr)  float64   angular velocity [rad/s]
    wa           (N, nr)  float64   angular acceleration T/I of the last force evaluation [rad/s^2]
    dth          (N, nr)  float64   rotation of the last step [rad]
    rfree        (N, nr)  float64   1.0 free rotation, 0.0 fixed / prescribed (turns at ``w``)
    inertia      (N,)     float64   moment of inertia [kg m^2]
    rot_props    (N, 2)   float64   the element's rolling parameters, read and written through
                                    the named column views:
    bond_moment  (N,)     view      moment strength of the element's bonds over ``R* F_b``
                                    [-] (0: a bond resists rolling like a broken contact)
    rolling_stiffness (N,) view     rolling stiffness factor ``beta``: ``K_r = beta K_s R*^2``
                                    [-] (1: Iwashita & Oda's default)
    mr           (N, W, nr) float64 rolling-resistance moment acting on the row's element [N m]

Contact stiffness per row (optional, ``None`` unless :func:`enable_row_stiffness` was called)
    krate        (N, W)   float64   stiffness factor of the row's contact: ``Kn`` and ``Ks``
                                    (and so the rolling spring and the dashpot) are the series
                                    stiffness of the two elements times ``krate`` [-]; an
                                    interface softer than the rocks it joins (1 elsewhere)

Contact damping (optional, ``None`` unless :func:`enable_contact_damping` was called)
    fdash        (N, dim) float64   net normal-dashpot force of the last force pass [N]

Accumulated energy [J] per element (half of each contact's share goes to each side)
    q_visc, q_break_n, q_break_s, q_fric, w_ext   (N,) float64
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

ELEMENT_VEC = ("x", "v", "a", "dx", "x_ref", "free", "fload")
ELEMENT_SCALAR = ("m", "eta")
PROPS = ("r", "kn", "ks", "xb", "fs0", "mu", "mu_r", "zeta_n")  # columns of ``props``
PROPS_WIDTH = 8
ROT_PROPS = ("bond_moment", "rolling_stiffness")  # columns of ``rot_props`` (rotation only)
ACCUMULATORS = ("q_visc", "q_break_n", "q_break_s", "q_fric", "w_ext")
ROW_ARRAYS = ("nbr", "cstate", "fs", "brate")
ROT_ELEMENT = ("w", "wa", "dth", "rfree", "inertia", "rot_props")  # present only with rotation
ROT_ROWS = ("mr",)
KROW_ROWS = ("krate",)  # present only with a per-row contact stiffness
DAMP_ELEMENT = ("fdash",)  # present only with contact damping

# contact state codes
UNBONDED = 0
BONDED = 1
BROKEN_BASE = 2  # code = 2 + 2*step + (type-1)
TENSILE = 1
SHEAR = 2
JOINT = 0


def broken_code(step: int, kind: int) -> int:
    """Contact-state code of a bond broken at ``step`` with ``kind`` (1 tensile, 2 shear)."""
    return BROKEN_BASE + 2 * step + (kind - 1)


def decode_broken(code):
    """Inverse of :func:`broken_code`: returns ``(step, kind)`` (arrays allowed)."""
    c = np.asarray(code) - BROKEN_BASE
    return c // 2, c % 2 + 1


@dataclass
class State:
    """All data of one model. Build with :func:`new_state`; never resize in place."""

    dim: int
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    dx: np.ndarray
    x_ref: np.ndarray
    free: np.ndarray
    fload: np.ndarray
    props: np.ndarray
    m: np.ndarray
    eta: np.ndarray
    group: np.ndarray
    nbr: np.ndarray
    cstate: np.ndarray
    fs: np.ndarray
    brate: np.ndarray
    q_visc: np.ndarray
    q_break_n: np.ndarray
    q_break_s: np.ndarray
    q_fric: np.ndarray
    w_ext: np.ndarray
    # rotation (None: translation only, MatDEM's default)
    w: np.ndarray | None = None
    wa: np.ndarray | None = None
    dth: np.ndarray | None = None
    rfree: np.ndarray | None = None
    inertia: np.ndarray | None = None
    rot_props: np.ndarray | None = None  # columns ROT_PROPS
    mr: np.ndarray | None = None
    # contact damping: the net dashpot force of the last force pass (its heat is booked over
    # this step and the next)
    fdash: np.ndarray | None = None
    # per-row contact stiffness factor (None: every contact at its elements' series stiffness)
    krate: np.ndarray | None = None
    gravity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    groups: dict = field(default_factory=dict)  # name -> group id
    thickness: float = 0.0  # 2-D disc thickness [m] (information; masses are given)
    hertz: bool = False  # Hertz law for unbonded contacts in compression
    contact_damping: bool = False  # normal dashpot on contacts in compression (zeta_n)
    dt: float = 0.0
    step: int = 0
    time: float = 0.0
    skin: float = 0.0
    e0: float = 0.0  # reference total energy for the closure check

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def width(self) -> int:
        return self.nbr.shape[1]

    @property
    def rotation(self) -> bool:
        """True when the elements carry rotational degrees of freedom."""
        return self.w is not None

    @property
    def row_stiffness(self) -> bool:
        """True when the contacts carry their own stiffness factor (``krate``)."""
        return self.krate is not None

    @property
    def nrot(self) -> int:
        """Rotational degrees of freedom per element: 1 in 2-D, 3 in 3-D."""
        return 1 if self.dim == 2 else 3

    def array_names(self):
        names = ELEMENT_VEC + ELEMENT_SCALAR + ("props", "group") + ROW_ARRAYS + ACCUMULATORS
        if self.rotation:
            names = names + ROT_ELEMENT + ROT_ROWS
        if self.fdash is not None:
            names = names + DAMP_ELEMENT
        if self.row_stiffness:
            names = names + KROW_ROWS
        return names

    def row_array_names(self):
        """The per-contact arrays (carried by pair identity across neighbour rebuilds)."""
        return ROW_ARRAYS + (ROT_ROWS if self.rotation else ()) + \
            (KROW_ROWS if self.row_stiffness else ())

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.array_names()}

    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self.arrays().values()))

    def copy(self) -> "State":
        kw = {}
        for f in fields(self):
            val = getattr(self, f.name)
            if isinstance(val, np.ndarray):
                val = val.copy()
            elif isinstance(val, dict):
                val = dict(val)
            kw[f.name] = val
        return State(**kw)

    def __repr__(self) -> str:
        """One short line whatever the size (the generated dataclass repr printed every
        array): dim, elements, contacts and bonds, bounding box, groups, step, time and the
        arrays grouped by shape and dtype."""
        try:
            head = [f"dim={self.dim}", f"n={self.n}", f"width={self.width}"]
            if self.nbr.size:
                valid = self.nbr >= 0
                head.append(f"contacts={int(valid.sum()) // 2}")
                head.append(f"bonds={int((valid & (self.cstate == BONDED)).sum()) // 2}")
            if self.n and self.x.size:
                lo, hi = self.x.min(axis=0), self.x.max(axis=0)
                head.append("box=[" + ", ".join(f"{a:.4g}..{b:.4g}" for a, b in zip(lo, hi))
                            + "] m")
            head.append(f"groups=[{_clip(', '.join(self.groups), 50)}]")
            head.append(f"step={self.step}, time={self.time:.4g} s, dt={self.dt:.4g} s")
            if self.rotation:
                head.append("rotation")
            return f"State({', '.join(head)}; arrays {array_summary(self.arrays())})"
        except Exception as exc:  # noqa: BLE001 - a repr must not raise on a broken state
            return f"State(<unprintable: {type(exc).__name__}: {_clip(str(exc), 80)}>)"

    def group_mask(self, name: str) -> np.ndarray:
        if name not in self.groups:
            raise KeyError(f"unknown group {name!r}; groups: {sorted(self.groups)}")
        return self.group == self.groups[name]


def _clip(text: str, n: int) -> str:
    return text if len(text) <= n else text[:n - 3] + "..."


def array_summary(arrays: dict, limit: int = 240) -> str:
    """``"x,v,a (360, 3) f8; m,eta (360,) f8; ..."``: the names of ``arrays`` grouped by shape
    and dtype (numpy's short dtype code), in first-seen order, at most ``limit`` characters."""
    groups: dict = {}
    for name, a in arrays.items():
        if a is None:
            continue
        a = np.asarray(a)
        key = (tuple(a.shape), a.dtype.str.lstrip("<>|="))
        groups.setdefault(key, []).append(name)
    text = "; ".join(f"{','.join(names)} {shape} {dt}" for (shape, dt), names in groups.items())
    return _clip(text, limit)


def _prop(col: int, name: str):
    def get(self):
        return self.props[:, col]

    def put(self, value):
        self.props[:, col] = value

    return property(get, put, doc=f"column {col} of ``props``: {name}")


for _c, _name in enumerate(PROPS):
    setattr(State, _name, _prop(_c, _name))


def _rot_prop(col: int, name: str):
    def get(self):
        return None if self.rot_props is None else self.rot_props[:, col]

    def put(self, value):
        self.rot_props[:, col] = value

    return property(get, put, doc=f"column {col} of ``rot_props``: {name} (rotation only)")


for _c, _name in enumerate(ROT_PROPS):
    setattr(State, _name, _rot_prop(_c, _name))


def new_state(x, r, m, *, dim=None, width=16, kn=0.0, ks=0.0, xb=0.0, fs0=0.0, mu=0.0,
              eta=0.0, mu_r=0.0, zeta_n=0.0) -> State:
    """Allocate a state for elements at ``x`` (N, dim) with radii ``r`` and masses ``m``.

    Scalar parameters are broadcast to all elements. Rows start empty (``nbr = -1``).
    """
    if np.iscomplexobj(x):
        raise ValueError("positions must be real numbers, got complex values")
    if isinstance(width, (bool, np.bool_)) or not isinstance(width, (int, np.integer)) \
            or width < 1:
        raise ValueError(f"width (contacts per row) must be an integer >= 1, got {width!r}")
    x = np.ascontiguousarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] not in (2, 3):
        raise ValueError(f"positions must have shape (N, 2) or (N, 3), got {x.shape}")
    n, d = x.shape
    if dim is not None and dim != d:
        raise ValueError(f"dim={dim} but positions have {d} columns")

    def scal(v, name):
        a = np.asarray(v, dtype=np.float64)
        try:
            return np.ascontiguousarray(np.broadcast_to(a, (n,))).copy()
        except ValueError:
            raise ValueError(f"{name} must be one number or one per element ({n} values for "
                             f"{n} positions), got shape {a.shape}") from None

    props = np.zeros((n, PROPS_WIDTH))
    for c, (v, name) in enumerate(zip((r, kn, ks, xb, fs0, mu, mu_r, zeta_n), PROPS)):
        props[:, c] = scal(v, name)

    z = lambda: np.zeros((n, d))  # noqa: E731
    st = State(
        dim=d, x=x.copy(), v=z(), a=z(), dx=z(), x_ref=x.copy(), free=np.ones((n, d)),
        fload=z(), props=props, m=scal(m, "m"), eta=scal(eta, "eta"),
        group=np.zeros(n, np.int32),
        nbr=np.full((n, width), -1, np.int32), cstate=np.zeros((n, width), np.int32),
        fs=np.zeros((n, width, d)), brate=np.ones((n, width), np.float32),
        q_visc=np.zeros(n), q_break_n=np.zeros(n), q_break_s=np.zeros(n),
        q_fric=np.zeros(n), w_ext=np.zeros(n),
        gravity=np.zeros(d), groups={"all": 0},
    )
    return st


def scale_bond_rate(state: State, sel, factor: float) -> None:
    """Multiply the bond rate (breaking force and Fs0 scale, ``brate``) of the contact rows
    ``sel`` (a boolean mask or an index tuple into the (N, W) rows) by ``factor``, in double
    precision and stored back as float32 (a factor compounds exactly as the rows hold it)."""
    state.brate[sel] = (state.brate[sel].astype(np.float64) * factor).astype(np.float32)


def enable_row_stiffness(state: State) -> State:
    """Give every contact row its own stiffness factor ``krate`` (in place; returns
    ``state``), 1 everywhere to start with: nothing changes until a factor is set
    (:func:`scale_row_stiffness`). The factor moves with its pair across neighbour rebuilds
    like ``brate``; a new pair starts at 1. Calling it again keeps the factors set."""
    if state.krate is None:
        state.krate = np.ones(state.nbr.shape)
    return state


def scale_row_stiffness(state: State, sel, factor: float) -> None:
    """Multiply the contact stiffness factor of the rows ``sel`` (a boolean mask or an index
    tuple into the (N, W) rows) by ``factor`` (0 < factor <= 1: a contact no stiffer than its
    elements, so the stable time step stays the elements'), switching the factors on first
    (:func:`enable_row_stiffness`). Give both rows of each pair: the two sides must agree."""
    f = float(factor)
    if not (0.0 < f <= 1.0):
        raise ValueError(f"contact stiffness factor {factor!r}; allowed: 0 < factor <= 1")
    enable_row_stiffness(state)
    state.krate[sel] *= f


def inertia_of(state: State) -> np.ndarray:
    """Moment of inertia of each element [kg m^2]: a solid sphere ``(2/5) m r^2`` in 3-D, a
    disc (cylinder about its axis) ``(1/2) m r^2`` in 2-D."""
    return (0.5 if state.dim == 2 else 0.4) * state.m * state.r * state.r


def enable_rotation(state: State, mu_r=None, inertia=None, bond_moment=0.0,
                    rolling_stiffness=1.0) -> State:
    """Give every element rotational degrees of freedom (in place; returns ``state``).

    Rotation is an option beyond MatDEM's translation-only elements (PHYSICS.md section 1): the
    shear force then acts at the contact point and turns the elements, and contacts in
    compression resist rolling with an elastic-plastic moment (see
    :func:`geodem.core.law.rolling`). ``mu_r`` (scalar or (N,)) sets the rolling-resistance
    coefficient (default: keep ``state.mu_r``); ``inertia`` defaults to :func:`inertia_of`.
    ``bond_moment`` (scalar or (N,), >= 0) makes bonds moment-resisting: a bonded contact holds
    a rolling moment up to ``bond_moment R* F_b`` on top of ``mu_r R* |Fn|`` (``F_b`` its tensile
    strength; a parallel bond as wide as the elements has about 0.5 in 3-D and 0.67 in 2-D,
    Potyondy & Cundall 2004); 0 (default): a bond resists rolling like a broken contact.
    ``rolling_stiffness`` (scalar or (N,), >= 0) is the factor ``beta`` of the rolling spring,
    ``K_r = beta K_s R*^2`` (default 1: Iwashita & Oda 1998; Jiang et al. 2005 vary it).
    Elements whose translation is entirely fixed or prescribed get a fixed rotation (walls and
    platens do not spin); free them with ``state.rfree``. Calling it again resets the
    angular state.
    """
    n, nr = state.n, state.nrot
    if mu_r is not None:
        state.mu_r = np.broadcast_to(np.asarray(mu_r, dtype=np.float64), (n,))
    state.inertia = np.ascontiguousarray(
        inertia_of(state) if inertia is None
        else np.broadcast_to(np.asarray(inertia, dtype=np.float64), (n,))).copy()
    state.rot_props = np.zeros((n, len(ROT_PROPS)))
    for c, (value, name) in enumerate(((bond_moment, "bond_moment"),
                                       (rolling_stiffness, "rolling_stiffness"))):
        a = np.asarray(value, dtype=np.float64)
        if not (np.isfinite(a).all() and (a >= 0.0).all()):
            raise ValueError(f"{name} = {value!r}: allowed finite values >= 0")
        state.rot_props[:, c] = np.broadcast_to(a, (n,))
    state.w = np.zeros((n, nr))
    state.wa = np.zeros((n, nr))
    state.dth = np.zeros((n, nr))
    moving = (state.free != 0.0).any(axis=1)
    state.rfree = np.repeat(moving.astype(np.float64)[:, None], nr, axis=1)
    state.mr = np.zeros((n, state.width, nr))
    return state


def damping_ratio(restitution: float) -> float:
    """Damping ratio of a linear spring-dashpot contact with coefficient of restitution ``e``:
    ``zeta = -ln e / sqrt(pi^2 + ln^2 e)`` (e in (0, 1]; e = 1 gives 0)."""
    e = float(restitution)
    if not (0.0 < e <= 1.0):
        raise ValueError(f"coefficient of restitution {restitution!r}: allowed 0 < e <= 1")
    le = np.log(e)
    return float(-le / np.sqrt(np.pi ** 2 + le * le))


def enable_contact_damping(state: State, restitution=None, zeta_n=None) -> State:
    """Switch on the normal dashpot of contacts in compression (in place; returns ``state``).

    MatDEM damps only the absolute motion of elements (global damping); a collision of two
    elements is then perfectly elastic. This option adds to each contact in compression the
    normal force ``c (du . n)/dt`` with ``c = 2 zeta sqrt(m* Kn)``, ``m* = m_i m_j/(m_i + m_j)``,
    ``zeta = min(zeta_i, zeta_j)``, ``du . n`` the normal relative displacement of the step
    (so ``du/dt`` is the mid-step relative velocity), capped so that an unbonded contact never
    pulls. A binary collision then rebounds with restitution ``e`` (:func:`damping_ratio`). Give
    ``restitution`` (scalar) or ``zeta_n`` (scalar or (N,)); the heat is booked as viscous.
    """
    if (restitution is None) == (zeta_n is None):
        raise ValueError("give exactly one of restitution and zeta_n")
    z = damping_ratio(restitution) if zeta_n is None else zeta_n
    z = np.broadcast_to(np.asarray(z, dtype=np.float64), (state.n,))
    if not (np.isfinite(z).all() and (z >= 0.0).all()):
        raise ValueError("zeta_n must be finite and >= 0")
    state.zeta_n = z
    state.contact_damping = True
    if state.fdash is None:
        state.fdash = np.zeros((state.n, state.dim))
    return state


def take(state: State, keep) -> State:
    """A new state holding only the elements ``keep`` (bool (N,) or increasing indices), every
    array of the state included (rotation and contact damping too).

    Element arrays are copied for the kept elements in their order; row entries whose partner is
    kept keep their contact history (``cstate``, ``fs``, ``brate``, ``mr``) and are relabelled to
    the new numbering, entries to removed elements are dropped and the rows compacted (valid
    entries first, still sorted by index, width unchanged). Groups (names and ids), gravity,
    flags, ``dt``, ``step``, ``time``, ``skin`` and ``e0`` are carried over as they are; the rows
    are not rebuilt (the pairs within the skin are still all there). Used by
    :meth:`geodem.core.engine.Simulation.remove_elements`."""
    idx = np.asarray(keep)
    if idx.dtype == bool:
        if idx.shape != (state.n,):
            raise ValueError(f"keep must have shape ({state.n},), got {idx.shape}")
        idx = np.flatnonzero(idx)
    idx = idx.astype(np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= state.n or np.any(np.diff(idx) <= 0)):
        raise ValueError(f"keep: increasing element indices in 0..{state.n - 1}")
    inv = np.full(state.n, -1, np.int64)
    inv[idx] = np.arange(idx.size)
    nbr = state.nbr[idx]
    new = np.where(nbr >= 0, inv[np.maximum(nbr, 0)], -1)
    valid = new >= 0
    order = np.argsort(~valid, axis=1, kind="stable")
    ok = np.take_along_axis(valid, order, axis=1)
    rows = set(state.row_array_names())
    empty = {"nbr": -1, "cstate": 0, "fs": 0.0, "brate": 1.0, "mr": 0.0, "krate": 1.0}
    kw = {}
    for f in fields(state):
        val = getattr(state, f.name)
        name = f.name
        if name == "nbr":
            out = np.take_along_axis(new, order, axis=1).astype(state.nbr.dtype)
            out[~ok] = -1
        elif name in rows:
            a = val[idx]
            o = order.reshape(order.shape + (1,) * (a.ndim - 2))
            out = np.take_along_axis(a, o, axis=1)
            out[~ok] = empty[name]
        elif isinstance(val, np.ndarray) and name != "gravity":
            out = val[idx]
        elif isinstance(val, np.ndarray):
            out = val.copy()
        elif isinstance(val, dict):
            out = dict(val)
        else:
            out = val
        kw[name] = np.ascontiguousarray(out) if isinstance(out, np.ndarray) else out
    return State(**kw)
