"""The tunnel case: a thin step on top of a ``scene`` and the generic steps.

workflows/tunnel.yaml composes the case from parts: a ``scene`` whose layers come from a label
image, ``pressure`` steps for the in-situ stress, a ``snapshot`` of the positions before the
excavation, ``excavate`` in stages, ``monitor`` at the wall. Only what is special to a tunnel
is here:

* step ``tunnel_check``: the radial displacement of the wall since a ``snapshot``, against
  Kirsch's solution for a circular hole of radius ``a`` excavated in an elastic medium under an
  isotropic in-situ stress ``p`` (Kirsch 1898; Jaeger, Cook & Zimmerman 2007, section 8.4),
  inward positive::

      u_r(r) = p a^2 / (2 G r),      G = E / (2 (1 + nu))

  with ``E, nu`` of the close-packed lattice of the wall's elements (2-D triangular lattice of
  discs of thickness t = d, docs/physics.md section 11)::

      E = 2 sqrt(3) Kn (Kn + Ks) / (t (3 Kn + Ks)),   nu = (Kn - Ks) / (3 Kn + Ks)

  (``Kn = kn / 2``, ``Ks = ks / 2``). Under an isotropic stress the displacement is radial and
  curl-free, so the shear springs' resistance to rigid rotation plays no part. The model is
  finite (outer boundary at ``b``, traction held): Lame's thick ring gives
  ``u_r = p a^2 / (E (b^2 - a^2)) ((1 - nu) r + (1 + nu) b^2 / r)``, reported as
  ``lame_displacement`` with ``b`` the half width of the model.

  Results: ``wall_displacement`` (mean inward u_r of the wall ring, elements with centres within
  ``ring`` d of the hole) [m], ``kirsch_displacement`` and ``lame_displacement`` at the ring's
  mean radius [m], their ratios, ``convergence`` (the closure of the diameter, 2 x the wall
  displacement) [m], ``E_lattice`` [Pa], ``nu_lattice``, the cracks since the snapshot and the
  ``damaged_zone_radius`` (the farthest crack from the axis, over ``a``; 0 without cracks); the
  picture ``<name>.png`` (radial displacement of every element, cracks).
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from geodem.workflow.schema import F, Name, StepBase, register_step


def lattice_moduli_2d(kn, ks, d) -> tuple[float, float]:
    """``(E [Pa], nu)`` of a 2-D triangular lattice of discs of diameter and thickness ``d``
    [m] with element stiffnesses ``kn, ks`` [N/m] (contact stiffness Kn = kn / 2)."""
    Kn, Ks = 0.5 * kn, 0.5 * ks
    return (2.0 * math.sqrt(3.0) * Kn * (Kn + Ks) / (d * (3.0 * Kn + Ks)),
            (Kn - Ks) / (3.0 * Kn + Ks))


def kirsch_radial(p, a, r, E, nu):
    """Inward radial displacement [m] at ``r`` of a hole of radius ``a`` excavated under the
    isotropic stress ``p`` [Pa] in an infinite elastic plane: ``p a^2 (1 + nu) / (E r)``."""
    return p * a * a * (1.0 + nu) / (E * r)


def lame_radial(p, a, b, r, E, nu):
    """The same in a ring of outer radius ``b`` whose outer traction is held (Lame)."""
    return p * a * a / (E * (b * b - a * a)) * ((1.0 - nu) * r + (1.0 + nu) * b * b / r)


@register_step("tunnel_check")
class TunnelCheck(StepBase):
    """Radial displacement of a tunnel's wall since a snapshot against Kirsch's solution, the
    convergence and the damaged zone (geodem.cases.tunnel)."""

    example = {"kind": "tunnel_check", "center": [0.025, 0.022], "radius": 0.008,
               "pressure": 1.0e6}
    since: Optional[Name] = F(None, description="Name of the snapshot step taken before the "
                                                "excavation (default: the model as built)")
    center: list[float] = F(..., unit="m", min_length=2, max_length=2,
                            description="Axis of the tunnel")
    radius: float = F(..., unit="m", gt=0, description="Radius a of the excavated disc")
    pressure: float = F(..., unit="Pa", gt=0, description="Isotropic in-situ stress p")
    ring: float = F(1.0, gt=0, le=10, description="Wall ring: centres within a + ring x d")
    plot: bool = F(True, description="Draw <name>.png (needs matplotlib)")

    def check(self, cfg, groups):
        out = []
        if cfg.model.dim != 2:
            out.append((("kind",), "tunnel_check is 2-D (Kirsch's plane solution)"))
        names = [s.name for s in cfg.steps]
        k = names.index(self.name) if self.name in names else len(names)
        snaps = [s.name for s in cfg.steps[:k] if s.kind == "snapshot"]
        if self.since is not None and self.since not in snaps:
            out.append((("since",), f"no snapshot step named {self.since!r} before this step; "
                                    f"allowed: {', '.join(snaps) or 'none (add a snapshot)'}"))
        return out

    def execute(self, ctx):
        from geodem.workflow.monitoring import read_snapshot

        sim = ctx.sim
        st = sim.sync()
        if self.since is None:  # the model as built (rows kept in step with an excavation)
            x0 = np.array(ctx.model.reference, float)
            present, when = np.ones(st.n, bool), {"step": 0, "time": -np.inf}
        else:
            x0, present, when = read_snapshot(ctx.out_dir, self.since, sim)
        c = np.asarray(self.center, float)
        d = float(np.mean(2.0 * st.r))
        a = float(self.radius)
        rel0 = x0 - c
        r0 = np.hypot(rel0[:, 0], rel0[:, 1])
        ring = present & (r0 > a) & (r0 <= a + self.ring * d)
        if not ring.any():
            raise ValueError(f"step {self.name!r}: no element within {self.ring:g} d of the "
                             f"hole's wall (radius {a:g} m at {self.center})")
        u = st.x - x0
        u_in = -(u * rel0).sum(axis=1) / np.where(r0 > 0, r0, 1.0)  # inward positive
        E, nu = lattice_moduli_2d(float(st.kn[ring].mean()), float(st.ks[ring].mean()), d)
        r_ring = float(r0[ring].mean())
        b = 0.5 * float(min(np.ptp(x0[present, 0]), np.ptp(x0[present, 1])) + d)
        u_wall = float(u_in[ring].mean())
        kirsch = kirsch_radial(self.pressure, a, r_ring, E, nu)
        lame = lame_radial(self.pressure, a, b, r_ring, E, nu)
        cracks = self._cracks_since(sim, when["time"], st, c)
        res = {"since": self.since or "the model as built", "since_step": when["step"], "ring_elements": int(ring.sum()),
               "ring_radius": r_ring, "radius": a, "pressure": float(self.pressure),
               "E_lattice": E, "nu_lattice": nu, "outer_half_width": b,
               "wall_displacement": u_wall, "wall_displacement_std": float(u_in[ring].std()),
               "kirsch_displacement": kirsch, "lame_displacement": lame,
               "wall_over_kirsch": u_wall / kirsch, "wall_over_lame": u_wall / lame,
               "convergence": 2.0 * u_wall, "cracks": len(cracks),
               "damaged_zone_radius": float(cracks.max() / a) if len(cracks) else 0.0}
        ctx.log(f"{self.name}: wall moved in {u_wall:.4g} m (ring of {int(ring.sum())} elements "
                f"at r = {r_ring:.4g} m); Kirsch {kirsch:.4g} m (x {u_wall / kirsch:.3f}), Lame "
                f"{lame:.4g} m (x {u_wall / lame:.3f}); {len(cracks)} cracks since "
                f"{self.since!r}")
        if self.plot and ctx.cfg.outputs.plots:
            res["plot"] = ctx.plot(f"{self.name}.png", lambda path: _plot(
                path, st.x, u_in, present, cracks, c, a, self.name))
        return res

    @staticmethod
    def _cracks_since(sim, t0, st, c) -> np.ndarray:
        """Distances from the axis [m] of the bonds broken after time ``t0`` whose two elements
        are still there (crack log numbering: the model as built)."""
        from geodem.workflow.monitoring import current_rows

        log = sim.crack_log()
        log = log[log["time"] > t0]
        pi, oki = current_rows(sim, log["i"])
        pj, okj = current_rows(sim, log["j"])
        ok = oki & okj
        mid = 0.5 * (st.x[pi[ok]] + st.x[pj[ok]])
        return np.hypot(mid[:, 0] - c[0], mid[:, 1] - c[1])


def _plot(path, x, u_in, present, crack_r, c, a, title):
    from geodem.workflow.animation import pyplot

    plt = pyplot()
    if plt is None:
        return None
    fig, ax = plt.subplots(figsize=(5.4, 4.4))
    # the field binned on a grid of about 2 x 2 elements per cell: a small picture at any size
    ok = present & np.isfinite(u_in)
    lo, hi = x[ok].min(axis=0), x[ok].max(axis=0)
    nb = int(min(100, max(10, round(0.5 * math.sqrt(ok.sum())))))
    bins = [np.linspace(lo[0], hi[0], nb + 1), np.linspace(lo[1], hi[1], nb + 1)]
    tot, _, _ = np.histogram2d(x[ok, 0], x[ok, 1], bins, weights=u_in[ok] * 1e6)
    cnt, _, _ = np.histogram2d(x[ok, 0], x[ok, 1], bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, tot / cnt, np.nan)
    im = ax.imshow(mean.T, origin="lower", extent=(lo[0], hi[0], lo[1], hi[1]),
                   cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="inward radial displacement since the snapshot [µm]")
    ax.add_patch(plt.Circle(tuple(c), a, fill=False, color="k", lw=0.8, ls="--"))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.set_title(f"{title}: {len(crack_r)} cracks since the snapshot")
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)
    return path
