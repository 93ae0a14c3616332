"""Granular column collapse (runout validation), as workflow pieces: the ``granular_column``
model and the ``column_collapse`` step.

* model ``granular_column`` (2-D, plane collapse as in the quasi-2-D channel experiments of
  Lube et al. 2005 and Lajeunesse et al. 2005): one column of unbonded, cohesionless frictional
  elements per entry of ``aspect_ratios`` (``a = H0 / L0``), each in its own channel, the
  channels stacked one above the other (each on its own floor, far enough apart that nothing
  passes between them). A channel is: a rough floor of fixed elements of diameter ``d_mean``
  (centre spacing 0.85 d: bumps of about 0.24 d, plus the floor friction), a back wall at
  ``x = 0``, a gate at ``x = L0`` holding the column, and an end wall far beyond the expected
  runout, reaching up to the floor of the channel above (nothing thrown ahead of the flow
  leaves its channel). The narrower side of every column has ``n = round(10 scale)`` elements
  (``d_mean = column_size / n``): ``L0 = column_size`` and ``H0 = a column_size`` for ``a >= 1``,
  ``H0 = column_size`` and ``L0 = column_size / a`` below.

  Column build (:mod:`geodem.build.packing`): random placement of enough elements to fill the
  column at a packing fraction of 0.86, gravity deposition of the packing material in the
  column's box (:func:`~geodem.build.packing.deposition_state`,
  :func:`~geodem.build.packing.deposit`; frictionless by default: a dense packing),
  elements whose top lies above ``H0 + d/4`` removed;
  then the real material (``kn, ks`` proportional to the element diameter, friction ``mu``,
  mass ``rho pi r^2 2r``: the 2-D thickness convention), real gravity ``g`` and the friction of
  floor and walls, and the assembled model balanced (standard damping) with the gates in
  place. The measured ``L0``, ``H0`` and aspect ratio of each packed column are in the model
  information and are what the results use.

  ``packings: N`` builds every column N times, packing ``j`` with the seed ``seed + j``
  (column seed ``seed + j + 7919 i`` for ratio ``i``; ``N = 1``: the single set of columns).

  Groups: ``column_K`` (the elements of column K, ``K = j len(aspect_ratios) + i`` for packing
  j of ratio i, in the order of ``aspect_ratios``), ``floor_K``, ``back_K``, ``gate_K``,
  ``end_K`` (fixed walls).

* step ``column_collapse``: removes every gate at once (its elements are moved behind the back
  wall, outside the channel: an instantaneous release, as in the discrete simulations of
  Staron & Hinch 2005) and lets the columns collapse under gravity with little or no global
  damping: ``eta = damping x m / tau``, ``tau = sqrt(H0_max / g)`` of the tallest column
  (default ``damping = 0``: the flow dissipates its energy by friction only; the contact law
  has no normal viscosity, so collisions are elastic). Every ``sample`` x tau it records the
  kinetic energy and the front of every deposit. The flow is over when every front (of every
  packing) has moved less than ``still_tolerance`` x d_mean over the last ``still_time`` x tau
  (and not before ``min_time`` x tau); the elastic rattle left in the heap (no contact
  damping) is then damped out with MatDEM's standard damping until the kinetic energy is below
  ``rest_ke`` x the potential energy released, at most ``settle_balances`` standard
  balances: the deposit is at rest. ``max_time`` x tau caps the flow phase (then
  ``at_rest: false`` and a warning).

  **Runout.** The deposit of a column is the largest cluster of its elements linked by gaps
  smaller than ``link_gap`` x d_mean (isolated or ejected elements and small groups that left
  the heap are excluded); its front is the largest ``x + r`` of the cluster and the runout
  ``L_inf`` = front - back wall surface. Normalised runout ``(L_inf - L0) / L0`` against the
  law of Lube et al. (2005) for quasi-2-D collapses (:func:`lube_2005`)::

      (L_inf - L0) / L0 = 1.2 a             a <= 2.3
                        = 1.9 a^(2/3)       a >  2.3

  summary.json, per aspect ratio and averaged over the packings (:func:`packing_means`):
  ``aspect_ratios`` (measured), ``runouts`` (mean normalised runouts), ``runout_reference``
  (the law at those ratios), ``runout_rel_errors`` (``|mean - law| / law``),
  ``runout_rel_error`` (their maximum), ``runout_lengths`` [m] (``L_inf``), ``final_heights``
  [m], ``at_rest``; ``packings``, ``runouts_per_packing`` (per ratio, every packing's value),
  ``runout_std`` (their sample standard deviation), ``runout_rel_error_per_packing`` (per
  packing, its own max error).

  Files: ``collapse_history.csv`` (time, kinetic energy, front of every column), per column
  ``collapse_a<a>.png`` (initial and final deposit) and ``collapse_a<a>.vtp`` (final deposit
  for ParaView: radius, velocity, displacement, column; packing j > 0: ``collapse_a<a>_p<j>``),
  ``collapse_initial.vtp``, ``collapse_runout.png`` (normalised runout against aspect ratio
  with the law; with several packings every packing and the mean),
  ``collapse_history.png`` (fronts and kinetic energy against time) and ``collapse.gif``
  (the collapse of column ``gif_column``; Pillow, else imageio, else skipped with the reason).

Only one ``column_collapse`` step per workflow: the file names above are fixed.

References: Lube, G., Huppert, H. E., Sparks, R. S. J., Freundt, A. (2005) Collapses of
two-dimensional granular columns, Phys. Rev. E 72, 041301; Lajeunesse, E., Monnier, J. B.,
Homsy, G. M. (2005) Granular slumping on a horizontal surface, Phys. Fluids 17, 103302;
Staron, L., Hinch, E. J. (2005) Study of the collapse of granular columns using
two-dimensional discrete-grain simulation, J. Fluid Mech. 545, 1-27.
"""
from __future__ import annotations

import csv
import json
import math
from typing import Literal, Optional

import numpy as np
from pydantic import PrivateAttr

from geodem.cases.common import frames_gif
from geodem.workflow.models import BuildError, BuiltModel, element_params, state_bytes_per_element
from geodem.workflow.schema import F, Int, ModelBase, Name, StepBase, register_model, \
    register_step
from geodem.workflow.animation import label_map, pyplot

HISTORY = "collapse_history.csv"
PROGRESS = "collapse.json"
FRAMES_DIR = "collapse_frames"
PACKING_FRACTION = 0.86  # placement target; the 2-D deposit packs at ~0.82-0.84
FLOOR_SPACING = 0.85  # floor element spacing / d (geodem.build.walls.SPACING)
LUBE_BREAK = 2.3
REFERENCE = "Lube et al. 2005 (Phys. Rev. E 72, 041301), quasi-2-D: 1.2 a (a <= 2.3), " \
            "1.9 a^(2/3) (a > 2.3)"


def lube_2005(a):
    """Normalised runout ``(L_inf - L0) / L0`` of a quasi-2-D column of aspect ratio ``a``
    (Lube et al. 2005): ``1.2 a`` for ``a <= 2.3``, ``1.9 a^(2/3)`` above."""
    a = np.asarray(a, float)
    out = np.where(a <= LUBE_BREAK, 1.2 * a, 1.9 * np.cbrt(a) ** 2)
    return float(out) if out.ndim == 0 else out


def column_dims(a: float, column_size: float) -> tuple[float, float]:
    """``(L0, H0)`` [m] of a column of aspect ratio ``a`` whose narrower side is
    ``column_size``."""
    return (column_size, a * column_size) if a >= 1.0 else (column_size / a, column_size)


def deposit_front(x, r, link, origin=0.0):
    """``(front, members)`` of a deposit: the largest cluster of elements (centres ``x``
    (N, 2), radii ``r``) linked by surface gaps ``< link`` [m]; ``front`` = its largest
    ``x + r`` minus ``origin`` [m], ``members`` its indices."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(x)
    if n == 0:
        return 0.0, np.zeros(0, int)
    pairs = cKDTree(x).query_pairs(2.0 * float(r.max()) + link, output_type="ndarray")
    if len(pairs):
        gap = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) - r[pairs[:, 0]] - \
            r[pairs[:, 1]]
        pairs = pairs[gap < link]
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) \
        if len(pairs) else coo_matrix((n, n))
    _, lab = connected_components(g, directed=False)
    big = np.argmax(np.bincount(lab))
    idx = np.flatnonzero(lab == big)
    return float((x[idx, 0] + r[idx]).max() - origin), idx


# ============================================================================ model
@register_model("granular_column")
class GranularColumn(ModelBase):
    """Columns of unbonded frictional elements, one per aspect ratio, each in its own channel
    (rough floor, back wall, gate, end wall; channels stacked in y), packed by gravity deposition
    and balanced with the gates in place (groups column_K, floor_K, back_K, gate_K, end_K)."""

    size_field = "scale"
    example = {"type": "granular_column", "aspect_ratios": [1.0], "scale": 0.5,
               "material": "beads"}
    dim: Literal[2] = F(2, description="Dimension (2-D plane collapse)")
    aspect_ratios: list[float] = F([0.5, 1.0, 2.0, 4.0], min_length=1, max_length=12,
                                   description="Column aspect ratios a = H0 / L0 (0.2 to 12), "
                                               "one column each")
    column_size: float = F(0.03, unit="m", gt=0,
                           description="Narrower side of every column (L0 for a >= 1, H0 below)")
    scale: float = F(1.0, ge=0.4, le=20,
                     description="Resolution knob: round(10 scale) elements across the narrower "
                                 "side of every column (elements ~ 10 scale^2 (a + 1/a) x 10 per "
                                 "column)")
    distri_rate: float = F(0.2, ge=0, lt=1, description="Size spread of the packing "
                                                        "(MatDEM distriRate)")
    seed: Optional[int] = F(None, description="Packing seed (default: metadata.seed)")
    material: Name = F(..., description="Material of the elements (element parameters: micro or "
                                        "per-size; unbonded, only rho, kn, ks, mu matter)")
    gravity: float = F(9.81, unit="m/s^2", gt=0, le=1000, description="Gravity (along -y)")
    floor_friction: Optional[float] = F(None, ge=0, le=5,
                                        description="Friction coefficient of the floor elements "
                                                    "(default: the material's mu; a contact uses "
                                                    "the smaller of the two)")
    wall_friction: float = F(0.0, ge=0, le=5,
                             description="Friction coefficient of the back wall and the gate")
    packing_friction: Optional[float] = F(None, ge=0, le=5,
                                          description="Friction of the elements while they are "
                                                      "deposited into the column (default 0: a "
                                                      "dense packing; with friction the elements "
                                                      "land in loose vertical stacks that "
                                                      "translation-only elements keep)")
    floor_element: float = F(0.5, ge=0.25, le=2,
                             description="Floor element diameter / d_mean: 0.5 (default) a "
                                         "frictional floor with bumps of 0.06 d between its "
                                         "elements, 1 a rough one (bumps 0.24 d), 0.25 an almost "
                                         "flat one (0.015 d)")
    channel_length: float = F(2.5, ge=1.2, le=10,
                              description="Floor length beyond the gate / the runout of the "
                                          "reference law (the end wall stands there)")
    rotation: bool = F(False, description="Give the elements rotational degrees of freedom "
                                          "(beyond MatDEM's translation-only elements): discs "
                                          "roll, resisted by rolling_friction")
    restitution: Optional[float] = F(None, gt=0, le=1,
                                     description="Coefficient of restitution of every contact "
                                                 "(a normal dashpot on contacts in compression; "
                                                 "default none: collisions are elastic, as in "
                                                 "MatDEM)")
    rolling_friction: float = F(0.0, ge=0, le=1,
                                description="Rolling-resistance coefficient mu_r of every "
                                            "element with rotation: a contact resists rolling "
                                            "up to mu_r R* |Fn| (R* = R_i R_j / (R_i + R_j))")
    packings: Int = F(1, ge=1, le=16,
                      description="Packings per aspect ratio (1 to 16): every ratio is run with "
                                  "this many columns packed with the seeds seed, seed + 1, ..., "
                                  "each in its own channel; the summary's runouts and "
                                  "runout_rel_error are those of the mean normalised runout "
                                  "(elements and cost ~ packings)")

    def n_side(self) -> int:
        return max(4, int(round(10.0 * self.scale)))

    def d_mean(self) -> float:
        return self.column_size / self.n_side()

    def n_elements(self):
        d = self.d_mean()
        el = math.pi / 4 * d * d
        n = 0.0
        for a in self.aspect_ratios:
            L0, H0 = column_dims(a, self.column_size)
            n += 0.83 * L0 * H0 / el
            n += (L0 * (1.0 + self.channel_length * lube_2005(a)) + 6 * d) / \
                (FLOOR_SPACING * self.floor_element * d)
            n += 2 * (H0 + 2 * d) / (FLOOR_SPACING * 0.5 * d) + (H0 + 4 * d) / (FLOOR_SPACING * d)
        return max(1, int(n * self.packings))

    def bytes_per_element(self):
        return state_bytes_per_element(2, 8) + 3000

    def material_refs(self):
        return [(("material",), self.material)]

    def group_names(self):
        out = ["all"]
        for k in range(len(self.aspect_ratios) * self.packings):
            out += [f"column_{k}", f"floor_{k}", f"back_{k}", f"gate_{k}", f"end_{k}"]
        return out

    def n_across(self):
        d = self.d_mean()
        return max(max(column_dims(a, self.column_size)) for a in self.aspect_ratios) / d

    def check(self, cfg):
        out = []
        for k, a in enumerate(self.aspect_ratios):
            if not (math.isfinite(a) and 0.2 <= a <= 12.0):
                out.append((("aspect_ratios", k), f"aspect ratio {a!r}: allowed 0.2 <= a <= 12 "
                                                  "(H0 / L0)"))
        if len(set(self.aspect_ratios)) != len(self.aspect_ratios):
            out.append((("aspect_ratios",), "aspect ratios must be different"))
        return out

    def build(self, cfg):
        from geodem.core import groups, neighbors
        from geodem.core.engine import Simulation
        from geodem.workflow.models import concat_states

        d = self.d_mean()
        seed = self.seed if self.seed is not None else int(cfg.metadata.seed or 0)
        p = element_params(cfg, self.material, d, 2)
        mu_floor = p["mu"] if self.floor_friction is None else self.floor_friction
        parts, shifts, columns = [], [], []
        y0 = 0.0
        n_ratios = len(self.aspect_ratios)
        # column k = j n_ratios + i: packing j (seed + j) of aspect ratio i
        for k, (j, i) in enumerate((j, i) for j in range(self.packings)
                                   for i in range(n_ratios)):
            a = self.aspect_ratios[i]
            L0, H0 = column_dims(a, self.column_size)
            try:
                col = _packed_column(L0, H0, d, self.distri_rate, p, seed + j + 7919 * i,
                                     self.packing_friction or 0.0)
            except ValueError as exc:
                raise BuildError(("column_size",), str(exc)) from None
            L_meas = float((col.x[:, 0] + col.r).max())
            H_meas = float((col.x[:, 1] + col.r).max())
            a_meas = H_meas / L0
            x_end = L0 * (1.0 + self.channel_length * lube_2005(a_meas)) + 3.0 * d
            st = _channel(col, L0, H_meas, x_end, d, k, mu_floor, self.wall_friction,
                          self.floor_element * d)
            columns.append({"aspect_ratio_nominal": a, "aspect_ratio": a_meas, "L0": L0,
                            "H0": H_meas, "packed_length": L_meas, "elements": int(col.n),
                            "floor_y": y0, "x_end": x_end, "group": f"column_{k}",
                            "gate": f"gate_{k}", "ratio_index": i, "packing": j,
                            "seed": seed + j + 7919 * i})
            parts.append(st)
            shifts.append([0.0, y0])
            y0 += H_meas + 3.0 * d + 2.0 * d  # next floor: above this column, clear of it
        st = _concat(parts, shifts, concat_states)
        st.gravity[:] = [0.0, -self.gravity]
        st.eta[:] = 0.0
        neighbors.build_rows(st)
        if self.rotation:
            from geodem.core.state import enable_rotation

            enable_rotation(st, mu_r=self.rolling_friction)
        if self.restitution is not None:
            from geodem.core.state import enable_contact_damping

            enable_contact_damping(st, restitution=self.restitution)
        # settle the columns behind their gates under real gravity, friction on
        st.dt = 0.0
        sim = Simulation(st, monitor_every=0)
        n_across = self.n_across()
        ratio = math.inf
        for _ in range(6):
            ratio = sim.balance(n_across)
            if ratio < 1e-3:
                break
        st = sim.sync()
        st.v[:] = 0.0
        if st.rotation:
            st.w[:] = 0.0
        st.eta[:] = 0.0
        st.dt = 0.0
        neighbors.spatial_sort(st)
        st.step, st.time = 0, 0.0
        for c in columns:
            idx = groups.members(st, c["group"])
            c["H0"] = float((st.x[idx, 1] + st.r[idx]).max()) - c["floor_y"]
            c["aspect_ratio"] = c["H0"] / c["L0"]
        info = {"diameter": d, "n_side": self.n_side(), "columns": columns,
                "packings": self.packings, "n_ratios": n_ratios,
                "gravity": self.gravity, "material": {k: p[k] for k in ("kn", "ks", "mu", "rho")},
                "floor_friction": mu_floor, "wall_friction": self.wall_friction,
                "rotation": self.rotation,
                "rolling_friction": self.rolling_friction if self.rotation else None,
                "restitution": self.restitution,
                "balance_ratio": ratio}
        return BuiltModel(st, st.x.copy(), n_across, info)


def _packed_column(L0, H0, d, distri_rate, p, seed, mu_pack):
    """Elements packed in ``[0, L0] x [0, H0]`` by gravity deposition, with the real
    material's parameters (a state without walls, no bonds)."""
    from geodem.build import packing
    from geodem.build.shapes import subset_state
    from geodem.core import groups

    if L0 < 3.0 * d or H0 < 3.0 * d:
        raise ValueError(f"a column of {L0:.4g} x {H0:.4g} m is less than 3 elements (d = "
                         f"{d:.4g} m) across: raise scale or column_size")
    lo, hi = np.zeros(2), np.array([L0, H0])
    x, r = packing.random_placement((lo, hi), porosity=1.0 - PACKING_FRACTION, d_mean=d,
                                    distri_rate=distri_rate, seed=seed)
    st = packing.deposition_state(x, r, (lo, hi), rho=p["rho"], d_wall=0.5 * d, platen=False)
    st.mu[st.group_mask("sample")] = mu_pack  # poured with friction: a looser packing
    packing.deposit(st)
    keep = st.group_mask("sample") & (st.x[:, 1] + st.r <= H0 + 0.25 * d)
    col = subset_state(st, keep, rebuild=False)
    col.groups = {"all": 0}
    col.group[:] = 0
    s = 2.0 * col.r / d
    col.kn[:] = p["kn"] * s
    col.ks[:] = p["ks"] * s
    col.mu[:] = p["mu"]
    col.xb[:] = 0.0
    col.fs0[:] = 0.0
    col.m[:] = p["rho"] * packing.element_volume(col.r, 2) * 2.0 * col.r
    col.v[:] = 0.0
    col.eta[:] = 0.0
    col.nbr[:] = -1
    col.cstate[:] = 0
    col.fs[:] = 0.0
    groups.add_group(col, "column", np.arange(col.n))
    return col


def _channel(col, L0, H0, x_end, d, k, mu_floor, mu_wall, d_floor):
    """The column plus its floor (elements of diameter ``d_floor`` from the back wall to the end
    wall), back wall and gate (elements of diameter d/2) and end wall, as one state."""
    from geodem.build.walls import add_walls

    kn = float((col.kn / (2.0 * col.r)).max())
    st = add_walls(col, ["ymin"], d_wall=d_floor, margin=0.0, kn=kn * d_floor, mu=mu_floor,
                   lo=[0.5 * d, 0.0], hi=[x_end + d, H0], names=[f"floor_{k}"])
    dw = 0.5 * d
    st = add_walls(st, ["xmin"], d_wall=dw, margin=0.0, kn=kn * dw, mu=mu_wall,
                   lo=[0.0, 0.6 * d], hi=[L0, H0 + 2.0 * d], names=[f"back_{k}"])
    st = add_walls(st, ["xmax"], d_wall=dw, margin=0.0, kn=kn * dw, mu=mu_wall,
                   lo=[0.0, 0.6 * d], hi=[L0, H0 + d], names=[f"gate_{k}"])
    # the end wall reaches up to the next channel's floor (its elements' bottom 5 d - d_floor
    # above the column): elements ejected ahead of the flow do not fly over it and fall into
    # the channels below. Its element centres span [0.6 d, top] at the wall spacing exactly
    gaps = math.floor((H0 + 4.0 * d - d_floor - 0.6 * d) / (FLOOR_SPACING * d))
    st = add_walls(st, ["xmax"], d_wall=d, margin=0.0, kn=kn * d, mu=mu_wall,
                   lo=[0.0, 0.6 * d], hi=[x_end, (0.6 + FLOOR_SPACING * gaps) * d],
                   names=[f"end_{k}"])
    gid = st.groups.pop("column")
    st.groups[f"column_{k}"] = gid
    return st


def _concat(parts, shifts, concat_states):
    """One state of the channels: group ids renumbered so each keeps its own names."""
    merged = {"all": 0}
    for st in parts:
        old = dict(st.groups)
        remap = np.zeros(max(old.values()) + 1, np.int32)
        for name, gid in old.items():
            if name == "all":
                continue
            new = max(merged.values()) + 1
            merged[name] = new
            remap[gid] = new
        st.group[:] = remap[st.group]
    out = concat_states(parts, [np.asarray(s, float) for s in shifts])
    out.groups = merged
    return out


# ============================================================================ step
@register_step("column_collapse")
class ColumnCollapse(StepBase):
    """Remove the gates of a granular_column model at once and let the columns collapse under
    gravity (little or no global damping); when every front has stopped, damp the rattle out
    (standard damping) until the deposits are at rest. Measures the runout of every deposit
    against Lube et al. 2005; adds aspect_ratios, runouts, runout_reference, runout_rel_errors,
    runout_rel_error, runout_lengths, final_heights and at_rest to summary.json; writes
    collapse_history.csv, collapse_a<a>.png and .vtp, collapse_initial.vtp,
    collapse_runout.png, collapse_history.png and collapse.gif."""

    example = {"kind": "column_collapse", "max_time": 2.0, "min_time": 0.5, "still_time": 0.5,
               "settle_balances": 1, "gif": False}
    example_model = {"type": "granular_column", "aspect_ratios": [1.0], "scale": 0.4,
                     "material": "rock"}
    damping: float = F(0.0, ge=0, le=10,
                       description="Global damping during the flow: eta = damping x m / tau, tau "
                                   "= sqrt(H0_max / g) (0: none; the flow dissipates by "
                                   "friction)")
    max_time: float = F(40.0, gt=0, le=1000,
                        description="Longest flow phase, in tau = sqrt(H0_max / g)")
    min_time: float = F(3.0, ge=0, le=1000, description="Shortest flow phase, in tau")
    sample: float = F(0.05, gt=0, le=1, description="Time between records, in tau")
    still_time: float = F(1.0, gt=0, le=100,
                          description="The flow is over when no front has moved more than "
                                      "still_tolerance over this time, in tau")
    still_tolerance: float = F(0.5, gt=0, le=5,
                               description="Front movement that counts as still, in d_mean")
    link_gap: float = F(0.5, ge=0, le=5,
                        description="Elements closer than this (surface gap, in d_mean) belong "
                                    "to the same deposit cluster")
    rest_ke: float = F(1e-6, gt=0, le=0.1,
                       description="At rest: kinetic energy below rest_ke x the potential energy "
                                   "released")
    settle_balances: Int = F(40, ge=0, le=1000,
                             description="Most standard balances (50 N steps, N = elements "
                                         "across the tallest column) of the settling phase")
    tolerance: float = F(0.15, gt=0, le=10,
                         description="runout_rel_error above this is reported as failed "
                                     "(passed: false in the results)")
    gif: bool = F(True, description="Write collapse.gif")
    gif_column: Optional[Int] = F(None, ge=0,
                                  description="Column shown in the GIF (index in aspect_ratios; "
                                              "default the tallest)")
    gif_frames: Int = F(40, ge=2, le=300, description="Frames of the animation")
    plot: bool = F(True, description="Draw the PNG pictures (needs matplotlib)")
    _tau_est: float = PrivateAttr(0.1)

    def check(self, cfg, groups):
        out = []
        if getattr(cfg.model, "type", None) == "granular_column":
            self._tau_est = self._tau(cfg.model)
        if getattr(cfg.model, "type", None) != "granular_column":
            out.append((("kind",), "column_collapse needs the columns of model type "
                                   "granular_column"))
        elif self.gif_column is not None and self.gif_column >= len(cfg.model.aspect_ratios):
            out.append((("gif_column",), f"gif_column = {self.gif_column}: allowed 0 to "
                                         f"{len(cfg.model.aspect_ratios) - 1} (an index of "
                                         "model.aspect_ratios)"))
        if self.min_time > self.max_time:
            out.append((("min_time",), f"min_time = {self.min_time:g} exceeds max_time = "
                                       f"{self.max_time:g}"))
        return out

    # ------------------------------------------------------------------ plan
    @staticmethod
    def _tau(model_cfg, g=None) -> float:
        h = max(column_dims(a, model_cfg.column_size)[1] for a in model_cfg.aspect_ratios)
        return math.sqrt(h / (g or model_cfg.gravity))

    def planned_steps(self, plan):
        # the flow phase is capped by max_time, the settling by settle_balances (tau is known
        # once check has seen the model)
        flow = max(1, int(math.ceil(self.max_time * self._tau_est / plan.dt)))
        return flow + int(self.settle_balances * 50 * plan.n_across)

    def execute(self, ctx):
        return _Collapse(self, ctx).run()


class _Collapse:
    """One execution of a ``column_collapse`` step."""

    def __init__(self, step: ColumnCollapse, ctx):
        self.p, self.ctx = step, ctx
        info = ctx.model.info
        self.d = float(info["diameter"])
        self.cols = info["columns"]
        self.g = float(info["gravity"])
        st = ctx.state
        from geodem.core import groups

        self.idx = [groups.members(st, c["group"]) for c in self.cols]
        h = max(c["H0"] for c in self.cols)
        self.tau = math.sqrt(h / self.g)
        self.dt = st.dt
        self.sample_steps = max(1, int(round(step.sample * self.tau / self.dt)))
        self.max_steps = max(self.sample_steps,
                             int(math.ceil(step.max_time * self.tau / self.dt)))
        self.n_across = float(ctx.model.n_across)
        self.out = ctx.out_dir
        self.n_ratios = int(info.get("n_ratios", len(self.cols)))
        self.packings = int(info.get("packings", 1))
        # gif_column indexes aspect_ratios: that ratio's first packing
        k = step.gif_column if step.gif_column is not None else \
            int(np.argmax([c["aspect_ratio"] for c in self.cols[:self.n_ratios]]))
        self.gif_k = k

    # ------------------------------------------------------------------ helpers
    def _front(self, st, k):
        i = self.idx[k]
        f, _ = deposit_front(st.x[i], st.r[i], self.p.link_gap * self.d)
        return f

    def _fronts(self, st):
        return [self._front(st, k) for k in range(len(self.cols))]

    def _potential(self, st):
        i = np.concatenate(self.idx)
        return float((st.m[i] * self.g * st.x[i, 1]).sum())

    def _kinetic(self, st):
        i = np.concatenate(self.idx)
        ke = float(0.5 * (st.m[i, None] * st.v[i] ** 2).sum())
        if st.rotation:
            ke += float(0.5 * (st.inertia[i, None] * st.w[i] ** 2).sum())
        return ke

    def _save(self):
        from geodem.workflow.rundir import write_json

        write_json(self.out / PROGRESS, self.prog)

    def _frame(self, st, n):
        i = self.idx[self.gif_k]
        np.savez_compressed(self.out / FRAMES_DIR / f"frame_{int(n):09d}.npz",
                            x=st.x[i].astype(np.float32), r=st.r[i].astype(np.float32),
                            time=st.time - self.prog["release_time"])

    def _row(self, st, phase):
        fr = self._fronts(st)
        row = [int(st.step), float(st.time - self.prog["release_time"]), phase,
               self._kinetic(st), self.prog["ep0"] - self._potential(st)] + fr
        self.rows.append(row)
        with open(self.out / HISTORY, "a", newline="") as f:
            csv.writer(f).writerow(row)
        return row

    # ------------------------------------------------------------------ main
    def run(self):
        ctx = self.ctx
        st = ctx.state
        (self.out / FRAMES_DIR).mkdir(exist_ok=True)
        header = ["step", "time", "phase", "kinetic", "released"] + \
            [f"front_{k}" for k in range(len(self.cols))]
        for name in (HISTORY, PROGRESS):
            if name not in ctx.runner.files:
                ctx.runner.files.append(name)
        if ctx.resumed and (self.out / PROGRESS).exists():
            self.prog = json.loads((self.out / PROGRESS).read_text())
            with open(self.out / HISTORY) as f:
                self.rows = [[int(r[0]), float(r[1]), r[2]] + [float(v) for v in r[3:]]
                             for r in list(csv.reader(f))[1:] if int(r[0]) <= st.step]
        else:
            self.prog = {"release_step": int(st.step), "release_time": float(st.time),
                         "ep0": self._potential(st)}
            self.rows = []
            self._write_initial(st)
            self._release()
            st = ctx.state
            self._frame(st, 0)
        with open(self.out / HISTORY, "w", newline="") as f:
            csv.writer(f).writerow(header)
            csv.writer(f).writerows(self.rows)
        if not self.rows:
            self._row(ctx.state, "flow")
        if "settle_start" not in self.prog:
            self._flow()
        self._settle()
        return self._finish()

    def _write_initial(self, st):
        from geodem.io.vtk import write_vtp

        self.initial = {k: (st.x[i].copy(), st.r[i].copy()) for k, i in enumerate(self.idx)}
        np.savez_compressed(self.out / "collapse_initial.npz",
                            **{f"x{k}": v[0] for k, v in self.initial.items()},
                            **{f"r{k}": v[1] for k, v in self.initial.items()})
        write_vtp(self.out / "collapse_initial.vtp", st.x, self._point_data(st))
        self.ctx.runner.files += ["collapse_initial.vtp", "collapse_initial.npz"]

    def _point_data(self, st, idx=None):
        idx = np.arange(st.n) if idx is None else idx
        col = np.full(st.n, -1, np.int32)
        for k, i in enumerate(self.idx):
            col[i] = k
        ref = self.ctx.model.reference
        out = {"radius": st.r[idx], "velocity": st.v[idx], "displacement": st.x[idx] - ref[idx],
               "column": col[idx], "group": st.group[idx]}
        if st.rotation:
            out["angular_velocity"] = st.w[idx, -1]  # about z [rad/s]
        return out

    def _release(self):
        """Move every gate behind its back wall (outside the channel): instantaneous release."""
        from geodem.core import groups

        ctx = self.ctx
        damping = self.p.damping

        def put(s):
            for c in self.cols:
                g = groups.members(s, c["gate"])
                shift = c["L0"] + 4.0 * self.d
                s.x[g, 0] -= shift
            m = s.m
            s.eta[:] = damping * m / self.tau if damping > 0 else 0.0

        ctx.decree(put)
        ctx.log(f"gates removed; tau = sqrt(H0_max / g) = {self.tau:.4g} s, dt = {self.dt:.4g} "
                f"s, {self.sample_steps} steps per record, flow phase at most "
                f"{self.max_steps} steps")

    def _flow(self):
        ctx, p = self.ctx, self.p
        s0 = self.ctx.start_step
        still_n = max(1, int(round(p.still_time * self.tau / (self.sample_steps * self.dt))))
        min_steps = int(p.min_time * self.tau / self.dt)
        n_frames = p.gif_frames if p.gif else 0
        # frames over the first 8 tau (the flow is over long before max_time)
        frame_every = max(1, int(round(8.0 * self.tau / max(1, n_frames) /
                                       (self.sample_steps * self.dt))))
        reason = "max_time"
        while True:
            st = ctx.state
            done = st.step - s0
            if done >= self.max_steps:
                break
            nxt = (done // self.sample_steps + 1) * self.sample_steps
            ctx.advance(nxt)
            st = ctx.state
            row = self._row(st, "flow")
            k = len(self.rows) - 1
            if n_frames and k % frame_every == 0 and row[1] <= 8.0 * self.tau:
                self._frame(st, st.step - s0)
            if st.step - s0 >= min_steps and len(self.rows) > still_n:
                a = np.array([r[5:] for r in self.rows[-still_n - 1:]], float)
                if float(np.ptp(a, axis=0).max()) <= p.still_tolerance * self.d:
                    reason = "still"
                    break
        st = ctx.state
        self.prog.update({"settle_start": int(st.step), "flow_end_reason": reason,
                          "flow_time": float(st.time - self.prog["release_time"])})
        if reason != "still":
            ctx.log(f"warning: the fronts were still moving after max_time = {p.max_time:g} tau;"
                    " settling anyway (raise max_time)")
        self._frame(st, st.step - s0)
        self._save()

    def _settle(self):
        from geodem.core import timestep

        ctx, p = self.ctx, self.p
        st = ctx.state
        start = self.prog["settle_start"]
        per = timestep.standard_balance_steps(self.n_across)
        if st.step == start:
            ctx.set_eta(timestep.standard_damping(st, self.n_across))
        released = max(self.prog["ep0"] - self._potential(st), 1e-300)
        at_rest = self._kinetic(st) <= p.rest_ke * released
        k = (st.step - start) // per
        while not at_rest and k < p.settle_balances:
            k += 1
            ctx.advance(start + k * per - ctx.start_step)
            st = ctx.state
            self._row(st, "settle")
            released = max(self.prog["ep0"] - self._potential(st), 1e-300)
            at_rest = self._kinetic(st) <= p.rest_ke * released
        self.prog.update({"at_rest": bool(at_rest), "settle_balances": int(k),
                          "end_step": int(st.step)})
        self._save()
        if not at_rest:
            ctx.log(f"warning: kinetic energy {self._kinetic(st):.3g} J still above rest_ke x "
                    f"released = {p.rest_ke * released:.3g} J after {k} settling balances")

    # ------------------------------------------------------------------ results
    def _finish(self):
        from geodem.io.vtk import write_vtp

        ctx, p = self.ctx, self.p
        st = ctx.state
        init = np.load(self.out / "collapse_initial.npz")
        per = []
        for k, c in enumerate(self.cols):
            i = self.idx[k]
            front, members = deposit_front(st.x[i], st.r[i], p.link_gap * self.d)
            y = st.x[i, 1] - c["floor_y"]
            a = c["aspect_ratio"]
            L0 = c["L0"]
            nr = (front - L0) / L0
            ref = lube_2005(a)
            per.append({"aspect_ratio": a, "L0": L0, "H0": c["H0"], "runout_length": front,
                        "runout": nr, "reference": ref, "rel_error": abs(nr - ref) / ref,
                        "final_height": float((y + st.r[i]).max()),
                        "excluded_elements": int(i.size - members.size),
                        "reached_end_wall": bool(front >= c["x_end"] - 1.5 * self.d),
                        "packing": int(c.get("packing", 0)), "seed": c.get("seed")})
            if per[-1]["reached_end_wall"]:
                ctx.log(f"warning: column {k} (a = {a:.3g}) reached its end wall: runout "
                        "truncated (raise model.channel_length)")
            name = f"collapse_a{c['aspect_ratio_nominal']:g}" + \
                (f"_p{c['packing']}" if c.get("packing") else "")
            write_vtp(self.out / f"{name}.vtp", st.x[i], self._point_data(st, i))
            ctx.runner.files.append(f"{name}.vtp")
            if p.plot and ctx.cfg.outputs.plots:
                ctx.plot(f"{name}.png", lambda path, k=k, c=c: plot_snapshots(
                    path, init[f"x{k}"], init[f"r{k}"], st.x[self.idx[k]], st.r[self.idx[k]], c,
                    per[k], self.d))
        mean = packing_means(per, self.n_ratios, self.packings)
        err = max(v["rel_error"] for v in mean)
        nr, npk = self.n_ratios, self.packings
        out = {"aspect_ratios": [v["aspect_ratio"] for v in mean],
               "runouts": [v["runout"] for v in mean],
               "runout_reference": [v["reference"] for v in mean],
               "runout_rel_errors": [v["rel_error"] for v in mean],
               "runout_rel_error": err,
               "runout_lengths": [v["runout_length"] for v in mean],
               "final_heights": [v["final_height"] for v in mean],
               "at_rest": self.prog["at_rest"],
               "packings": npk,
               "runouts_per_packing": [v["runouts"] for v in mean],
               "runout_std": [v["std"] for v in mean],
               "runout_rel_error_per_packing": [
                   max(v["rel_error"] for v in per[j * nr:(j + 1) * nr]) for j in range(npk)]}
        ctx.summary.update(out)
        res = dict(out, columns=per, passed=bool(err <= p.tolerance), tolerance=p.tolerance,
                   reference=REFERENCE, tau=self.tau, flow_time=self.prog["flow_time"],
                   flow_end=self.prog["flow_end_reason"],
                   settle_balances=self.prog["settle_balances"], damping=p.damping,
                   d_mean=self.d)
        ctx.log(("runout (L_inf - L0)/L0" if npk == 1 else
                 f"runout (L_inf - L0)/L0, mean of {npk} packings") + ": " + ", ".join(
            f"a = {v['aspect_ratio']:.3g}: {v['runout']:.3g}" +
            ("" if npk == 1 else " (" + " / ".join(f"{x:.3g}" for x in v["runouts"]) + ")") +
            f" (law {v['reference']:.3g}, {100 * v['rel_error']:.1f} %)" for v in mean) +
            f"; max error {100 * err:.1f} %")
        if p.plot and ctx.cfg.outputs.plots:
            rows = self.rows
            res["plots"] = [
                ctx.plot("collapse_runout.png", lambda path: plot_runout(path, mean, per)),
                ctx.plot("collapse_history.png", lambda path: plot_history(
                    path, rows, self.cols, self.tau, nr)),
            ]
            if p.gif:
                from geodem.workflow.animation import gif_writer_missing

                why = gif_writer_missing()
                if why:
                    res["animation"] = f"skipped: {why}"
                    ctx.runner.plots["collapse.gif"] = res["animation"]
                    ctx.log(f"collapse.gif {res['animation']}")
                else:
                    frames = sorted((self.out / FRAMES_DIR).glob("frame_*.npz"))
                    c = self.cols[self.gif_k]
                    res["animation"] = ctx.plot("collapse.gif", lambda path: write_gif(
                        path, frames, c, per[self.gif_k], self.d))
        return res


def packing_means(per, n_ratios, packings):
    """Per aspect ratio, the packings' results combined: ``per`` holds one dict per column
    (column ``j n_ratios + i``: packing ``j`` of ratio ``i``). Mean measured aspect ratio,
    mean normalised runout ``runout`` (the packings' values in ``runouts``, their sample
    standard deviation in ``std``; 0 for one packing), the law at the mean ratio and the
    relative error of the mean, mean ``runout_length`` and ``final_height``."""
    out = []
    for i in range(n_ratios):
        cs = [per[j * n_ratios + i] for j in range(packings)]
        m = {key: sum(c[key] for c in cs) / packings
             for key in ("aspect_ratio", "runout", "runout_length", "final_height")}
        runouts = [c["runout"] for c in cs]
        ref = lube_2005(m["aspect_ratio"])
        m.update(runouts=runouts, reference=ref, rel_error=abs(m["runout"] - ref) / ref,
                 std=float(np.std(runouts, ddof=1)) if packings > 1 else 0.0)
        out.append(m)
    return out


# ============================================================================ pictures

def _discs(ax, x, r, y0, colour):
    from matplotlib.collections import EllipseCollection

    xy = np.c_[x[:, 0], x[:, 1] - y0]
    ax.add_collection(EllipseCollection(2 * r, 2 * r, np.zeros_like(r), units="xy", offsets=xy,
                                        offset_transform=ax.transData, facecolors=colour,
                                        edgecolors="none"))


def _frame_axes(ax, c, res, d):
    xmax = max(res["runout_length"], c["L0"] * (1.0 + lube_2005(c["aspect_ratio"]))) + 2 * d
    ax.axhline(0.0, color="k", lw=1.0)
    ax.axvline(0.0, color="k", lw=1.0)
    ax.set_xlim(-d, xmax)
    ax.set_ylim(-d, c["H0"] + d)
    ax.set_aspect("equal")


def plot_snapshots(path, x0, r0, x1, r1, c, res, d):
    """Initial column and final deposit of one column, with the measured front and the front of
    the reference law."""
    plt = pyplot()
    if plt is None:
        return None
    xmax = max(res["runout_length"], c["L0"] * (1.0 + lube_2005(c["aspect_ratio"]))) + 2 * d
    w = min(12.0, max(5.0, 1.2 * xmax / max(c["H0"], 1e-300) * 1.6))
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(w, 5.5), sharex=True)
    _discs(a1, x0, r0, c["floor_y"], "0.55")
    a1.set_title(f"a = {c['aspect_ratio']:.3g}: initial column (L0 = {c['L0'] * 1e3:.3g} mm, "
                 f"H0 = {c['H0'] * 1e3:.3g} mm)", fontsize=9)
    _discs(a2, x1, r1, c["floor_y"], "C1")
    ref = c["L0"] * (1.0 + res["reference"])
    for ax in (a1, a2):
        _frame_axes(ax, c, res, d)
    a2.axvline(res["runout_length"], color="C3", lw=1.2,
               label=f"front: (L - L0)/L0 = {res['runout']:.3g}")
    a2.axvline(ref, color="k", ls="--", lw=1.0,
               label=f"Lube et al. 2005: {res['reference']:.3g}")
    a2.set_title(f"final deposit (error {100 * res['rel_error']:.1f} %)", fontsize=9)
    a2.legend(fontsize=7, loc="best")
    label_map(a2, fontsize=8)
    a1.set_ylabel("y [m]", fontsize=8)  # x: shared with a2
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def plot_runout(path, mean, per=None):
    """Normalised runout against aspect ratio with the law of Lube et al. (2005): the mean over
    the packings (``mean``, :func:`packing_means`; with its standard deviation) and, with more
    than one packing, every column of ``per``."""
    plt = pyplot()
    if plt is None:
        return None
    a = np.array([v["aspect_ratio"] for v in mean])
    nr = np.array([v["runout"] for v in mean])
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    aa = np.linspace(0.0, max(5.0, 1.2 * a.max()), 300)
    ax.plot(aa, lube_2005(aa), "k-", lw=1.2, label="Lube et al. 2005 (quasi-2-D)")
    ax.fill_between(aa, 0.85 * lube_2005(aa), 1.15 * lube_2005(aa), color="0.85",
                    label="+-15 %")
    if per is not None and len(per) > len(mean):
        ax.plot([v["aspect_ratio"] for v in per], [v["runout"] for v in per], "o", ms=4,
                color="C0", alpha=0.6, label="geodem, each packing")
        ax.errorbar(a, nr, yerr=[v["std"] for v in mean], fmt="C3o", ms=7, capsize=3,
                    label=f"geodem, mean of {len(per) // len(mean)} packings (+- std)")
    else:
        ax.plot(a, nr, "C3o", ms=7, label="geodem (2-D discs)")
    ax.set_xlabel("aspect ratio a = H0 / L0")
    ax.set_ylabel("(L_inf - L0) / L0")
    ax.set_xlim(0.0, aa[-1])
    ax.set_ylim(0.0, None)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_history(path, rows, cols, tau, n_ratios=None):
    """Normalised fronts and kinetic energy against time / tau (one colour per aspect ratio:
    the first ``n_ratios`` columns labelled, further packings in the same colours)."""
    plt = pyplot()
    if plt is None or not rows:
        return None
    t = np.array([r[1] for r in rows]) / tau
    ke = np.array([r[3] for r in rows])
    fr = np.array([r[5:] for r in rows], float)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    n_ratios = n_ratios or len(cols)
    for k, c in enumerate(cols):
        a1.plot(t, (fr[:, k] - c["L0"]) / c["L0"], color=f"C{k % n_ratios}", lw=1.5,
                alpha=1.0 if k < n_ratios else 0.5,
                label=f"a = {c['aspect_ratio']:.3g}" if k < n_ratios else None)
    a1.set_xlabel("t / tau, tau = sqrt(H0_max / g)")
    a1.set_ylabel("(front - L0) / L0")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3)
    a2.semilogy(t, np.maximum(ke, 1e-300), "C0-")
    a2.set_xlabel("t / tau")
    a2.set_ylabel("kinetic energy [J]")
    a2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def write_gif(path, frames, c, res, d):
    """Animation of one collapse (Pillow, else imageio)."""
    if pyplot() is None or not frames:
        return None
    data = [np.load(f) for f in frames]
    xmax = max(res["runout_length"], c["L0"] * (1.0 + lube_2005(c["aspect_ratio"]))) + 2 * d
    w = min(9.0, max(4.0, 1.1 * xmax / max(c["H0"], 1e-300) * 2.2))

    def draw(ax, z):
        _discs(ax, z["x"].astype(float), z["r"].astype(float), c["floor_y"], "C1")
        _frame_axes(ax, c, res, d)
        ax.set_title(f"a = {c['aspect_ratio']:.3g}, t = {float(z['time']) * 1e3:.0f} ms",
                     fontsize=8)
        label_map(ax, fontsize=7)
        ax.figure.tight_layout()

    return frames_gif(path, data, (w, 2.6), draw, fps=8)


__all__ = ["GranularColumn", "ColumnCollapse", "lube_2005", "column_dims", "deposit_front",
           "packing_means"]
