"""The check of one controller's parameter sets on a multi-axis machine.

The single-axis check (:mod:`servogym.sim._check`) generalised to N axes closed around one
multi-axis plant (``two-link-arm``, ``xy-stage``). :func:`check_machine_params` re-runs the
machine's tasks (:class:`~servogym.sim._multieval.MultiEvaluator`: coordinated moves and
contours) with the fine reference integration (RK4, ``CheckLimits.reference_substeps`` per
period) on a stress set:

* the machine as given (``reference``),
* every other choice of the chip's ``loop_latency`` assumption,
* every other choice of the family's axis-sequencing assumption
  (:data:`~servogym.sim.SEQUENCING`),
* the load (the family's ``load_param``, the payload) at -20 % and +20 %,
* every friction parameter of every axis at -50 % and +50 % together,

and, in every case, each loop's stability and margins with the other loops closed:

* The plant is linearised at each operating configuration of the tasks (every task's
  start and end, where the machine holds still) with MuJoCo's ``mjd_transitionFD``, one
  column per motor (:func:`machine_continuous_model`: the single-axis
  :func:`~servogym.sim._margins.continuous_model` per axis, Coulomb friction off), each
  axis with its amplifier lag, its ``amps_per_count`` and its encoder scale, and
  discretised exactly for each axis's own loop latency (the sequencing assumption gives
  axis k its own; :func:`machine_linearize`).
* Loop k's plant is the transfer from its motor command to its encoder with every other
  loop closed by its chip filter's linear part (``ChipFamily.filter_response``, the
  arithmetic model of the single-axis margins): ``P_k = G_kk - G_ko C_o (I + G_oo C_o)^-1
  G_ok``, evaluated pointwise from the state space (:func:`loop_response`). Loop k's
  margins are the single-axis :func:`~servogym.sim._margins.frequency_margins` of
  ``C_k P_k``. Closing loop k on ``P_k`` closes the whole machine: its stability is
  decided exactly from the poles of the N-loop closed-loop matrix built from every
  filter's polynomials (``ChipFamily.filter_polynomials``; eigenvalues, or for a high
  order the zeros of its characteristic determinant counted by the argument principle;
  :func:`machine_stability`), never from a frequency grid.

The margins also cover every latency x sequencing combination on the given plant (a linear
analysis; the simulation runs each alternative alone). A set passes when every case runs
without divergence, every axis keeps its following error and saturation within the limits
(:class:`~servogym.sim.CheckLimits`: by default 1 % of the axis's longest commanded span, 5 %
of ticks), no axis's set limits its motor command below what the tasks need of its motor
(:func:`~servogym.plants._multi.commanded_efforts`), the closed loop of the whole machine is
stable in every case and configuration, and every loop's gain and phase margins with the
others closed meet the minima. Each failure
names the case, the axis and by how much. docs/simulation.md, "The check of a multi-axis
machine", states the rules and the assumptions.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import math
import os
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import scipy.linalg

from servogym.chips._space import ParameterError
from servogym.sim._check import (
    FULL_SCALE,
    CheckLimits,
    _scaled,
    command_limit_failure,
    margin_failures,
    run_failures,
    worst_margins,
)
from servogym.sim._machine import SEQUENCING, axis_latencies, machine_axes
from servogym.sim._margins import (
    EIGEN_MAX_ORDER,
    STABILITY_EPS,
    LoopAnalysis,
    Margins,
    Stability,
    continuous_model,
    frequency_grid,
    frequency_margins,
    linearize,
    winding_number,
)
from servogym.sim._multieval import MultiCostWeights, MultiEvaluator
from servogym.sim._operating import POSITION_DECIMALS, _same_loop, severity


@dataclasses.dataclass(frozen=True)
class _AxisView:
    """One axis of a multi-axis plant as the single-axis linearisation reads a plant."""

    model: Any
    io: Any


# --- the linear machine --------------------------------------------------------------------


def machine_continuous_model(
    plant: Any, qpos: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, d)`` of a multi-axis plant from every motor's current (A) to every encoder
    (counts), continuous time, at rest at ``qpos`` (``model.nq`` values; default ``qpos0``).

    The state is ``(qpos, qvel)`` and then one current per axis with a current-loop lag, in
    axis order. ``B`` is ``(n, N)`` (per ampere), ``C`` is ``(N, n)``; ``d`` as for
    :func:`~servogym.sim._margins.continuous_model`, whose model of each axis (one
    ``mjd_transitionFD`` per axis, Coulomb friction off) this assembles.
    """
    ios = tuple(plant.ios) if hasattr(plant, "ios") else (plant.io,)
    nv = plant.model.nv
    parts = [continuous_model(_AxisView(plant.model, io), qpos) for io in ios]
    lag = [p[0].shape[0] > 2 * nv for p in parts]
    n = 2 * nv + sum(lag)
    a = np.zeros((n, n))
    b = np.zeros((n, len(ios)))
    c = np.zeros((len(ios), n))
    d = np.zeros(n)
    a[: 2 * nv, : 2 * nv] = parts[0][0][: 2 * nv, : 2 * nv]
    d[: 2 * nv] = parts[0][3][: 2 * nv]
    s = 2 * nv
    for k, (ak, bk, ck, _) in enumerate(parts):
        c[k, : 2 * nv] = ck[: 2 * nv]
        if lag[k]:
            a[nv : 2 * nv, s] = ak[nv : 2 * nv, 2 * nv]
            a[s, s] = ak[2 * nv, 2 * nv]
            b[s, k] = bk[2 * nv]
            s += 1
        else:
            b[: 2 * nv, k] = bk[: 2 * nv]
    return a, b, c, d


@dataclasses.dataclass(frozen=True)
class MachineLinear:
    """A multi-axis plant discretised at one servo period, each axis with its own latency:
    ``x[k+1] = phi x[k] + g_new u[k] + g_old u[k-1]``, ``y = c x``.

    Attributes:
        phi: ``(n, n)`` state transition over one period.
        g_new, g_old: ``(n, N)``: each axis's new and held command (counts) per column.
        c: ``(N, n)``: each axis's encoder counts.
        dt: Servo period (s).
        latencies: Each axis's loop latency (s).
    """

    phi: np.ndarray
    g_new: np.ndarray
    g_old: np.ndarray
    c: np.ndarray
    dt: float
    latencies: tuple[float, ...]

    @property
    def n_axes(self) -> int:
        """Number of axes (inputs and outputs)."""
        return int(self.c.shape[0])


def machine_linearize(
    plant: Any, dt: float, latencies: Sequence[float], continuous: Any = None
) -> MachineLinear:
    """The plant at period ``dt`` (s), axis k's command held until ``latencies[k]`` (s):
    each column is the single-axis :func:`~servogym.sim._margins.linearize` of that axis
    (its amplifier's ``amps_per_count``) on the whole plant's continuous model
    (``continuous``: :func:`machine_continuous_model`'s, computed here when ``None``)."""
    a, b, c, d = continuous if continuous is not None else machine_continuous_model(plant)
    ios = tuple(plant.ios) if hasattr(plant, "ios") else (plant.io,)
    if len(latencies) != len(ios):
        raise ValueError(f"give one latency per axis ({len(ios)}); got {len(latencies)}")
    cols = [
        linearize(_AxisView(plant.model, io), dt, lat, (a, b[:, k], c[k], d))
        for k, (io, lat) in enumerate(zip(ios, latencies, strict=True))
    ]
    return MachineLinear(
        phi=cols[0].phi,
        g_new=np.column_stack([x.g_new for x in cols]),
        g_old=np.column_stack([x.g_old for x in cols]),
        c=np.asarray(c, dtype=float),
        dt=float(dt),
        latencies=tuple(float(x) for x in latencies),
    )


def _normalised(polys: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, int]:
    """A filter's ``(num, den)`` divided by ``den[0]``, padded to one length, and its order
    (as :func:`~servogym.sim._margins.closed_loop_matrix` takes them)."""
    num, den = (np.asarray(v, dtype=float) for v in polys)
    num, den = num / den[0], den / den[0]
    m = max(num.size, den.size) - 1
    nn = np.zeros(m + 1)
    dd = np.zeros(m + 1)
    nn[: num.size], dd[: den.size] = num, den
    return nn, dd, m


def machine_closed_loop_matrix(
    lin: MachineLinear, filters: Sequence[tuple[np.ndarray, np.ndarray] | None]
) -> np.ndarray:
    """State matrix of the machine with each axis's loop closed by its filter ``(num, den)``
    (``ChipFamily.filter_polynomials``); an axis whose filter is ``None`` stays open.

    The state is ``x``, then per closed axis its held command ``u[k-1]`` and its filter's
    states in transposed direct form II (``u = w_1 + num_0 E``, ``E = -c x``): for one
    axis, :func:`~servogym.sim._margins.closed_loop_matrix` exactly.
    """
    if len(filters) != lin.n_axes:
        raise ValueError(f"give one filter (or None) per axis ({lin.n_axes}); got {len(filters)}")
    phi = np.asarray(lin.phi, dtype=float)
    n = phi.shape[0]
    blocks = []
    size = n
    for j, polys in enumerate(filters):
        if polys is not None:
            nn, dd, m = _normalised(polys)
            blocks.append((j, size, nn, dd, m))
            size += 1 + m
    out = np.zeros((size, size))
    out[:n, :n] = phi
    for j, at, nn, dd, m in blocks:
        c, n0 = lin.c[j], nn[0]
        out[:n, :n] = out[:n, :n] - n0 * np.outer(lin.g_new[:, j], c)
        out[:n, at] = lin.g_old[:, j]
        out[at, :n] = -n0 * c
        if m:
            w = at + 1
            out[:n, w] = lin.g_new[:, j]
            out[at, w] = 1.0
            out[w : w + m, :n] = -np.outer(nn[1:] - dd[1:] * n0, c)
            out[w : w + m, w] = -dd[1:]
            out[w : w + m - 1, w + 1 : w + m] += np.eye(m - 1)
    return out


def machine_response(lin: MachineLinear, z: np.ndarray) -> np.ndarray:
    """``G(z)``, ``(len(z), N, N)``: axis i's encoder counts per command count of axis j
    (row i, column j), from the state space by one solve per point (for one axis,
    :meth:`~servogym.sim._margins.LinearPlant.response`)."""
    n = lin.phi.shape[0]
    z = np.asarray(z, dtype=complex)
    lhs = z[:, None, None] * np.eye(n)[None] - lin.phi[None]
    rhs = lin.g_new[None] + lin.g_old[None] / z[:, None, None]
    return np.einsum("in,mnj->mij", lin.c, np.linalg.solve(lhs, rhs))


def loop_response(
    lin: MachineLinear, filter_at: Sequence[Any], axis: int, z: np.ndarray
) -> np.ndarray:
    """Loop ``axis``'s open loop ``C_k P_k`` at ``z``, every other loop closed:
    ``P_k = G_kk - G_ko C_o (I + G_oo C_o)^-1 G_ok`` (``o`` the other axes, ``C_o`` their
    filters' responses, ``filter_at[j](z)``), evaluated pointwise from the state space
    (not from polynomials: closing the other loops puts their poles and zeros into ``P_k``
    close together, where the ratio of two polynomials loses every digit)."""
    z = np.asarray(z, dtype=complex)
    g = machine_response(lin, z)
    others = [j for j in range(lin.n_axes) if j != axis]
    p = g[:, axis, axis]
    if others:
        c_o = np.stack([filter_at[j](z) for j in others], axis=1)  # (m, N-1)
        g_oo = g[:, others][:, :, others]
        m = np.eye(len(others))[None] + g_oo * c_o[:, None, :]
        sol = np.linalg.solve(m, g[:, others, axis][..., None])[..., 0]
        p = p - np.sum(g[:, axis, others] * c_o * sol, axis=1)
    return filter_at[axis](z) * p


def machine_stability(
    lin: MachineLinear, filters: Sequence[tuple[np.ndarray, np.ndarray]]
) -> Stability:
    """Stability of the machine with every loop closed, decided from its poles: the
    eigenvalues of :func:`machine_closed_loop_matrix` up to
    :data:`~servogym.sim._margins.EIGEN_MAX_ORDER` (for one axis, the single-axis
    :func:`~servogym.sim._margins.closed_loop_stability` exactly); above it (long PMD
    DerivativeTime filters, whose shift registers make eigenvalues inaccurate) the zeros of
    the characteristic polynomial (:func:`characteristic_values`) inside ``|x| = 1 / (1 -
    STABILITY_EPS)``, one per closed-loop pole outside ``|z| = 1 - STABILITY_EPS``, counted
    by the argument principle (:func:`count_zeros_inside`)."""
    matrix = machine_closed_loop_matrix(lin, filters)
    order = matrix.shape[0]
    limit = 1.0 - STABILITY_EPS
    if order <= EIGEN_MAX_ORDER:
        poles = scipy.linalg.eigvals(matrix, overwrite_a=True, check_finite=False)
        radius = float(np.max(np.abs(poles)))
        n_unstable = int(np.sum(np.abs(poles) >= limit))
        return Stability(n_unstable == 0, n_unstable, radius, order, "eigenvalues")
    inside = count_zeros_inside(lambda x: characteristic_values(lin, filters, x), order,
                                1.0 / limit)  # fmt: skip
    if inside is None:  # a zero on the circle: a marginal pole, not stable
        return Stability(False, 1, math.nan, order, "encirclement")
    return Stability(inside == 0, inside, math.nan, order, "encirclement")


def characteristic_values(
    lin: MachineLinear, filters: Sequence[tuple[np.ndarray, np.ndarray]], x: np.ndarray
) -> np.ndarray:
    """``det(I - x M)`` of the closed-loop matrix ``M`` (:func:`machine_closed_loop_matrix`)
    at each ``x = z^-1``, without ``M``: the determinant of the polynomial system matrix

        [[I - x Phi, x (g_new + x g_old) N(x)], [-C, D(x)]]

    (``N``, ``D``: the filters' numerators and denominators, diagonal; its Schur complement
    is ``det(I - x Phi) det(D + G N)``, the return difference), of size ``n + N`` whatever
    the filters' orders, and with no inverse, so accurate next to the plant's poles on the
    unit circle."""
    x = np.asarray(x, dtype=complex)
    n, n_axes = lin.phi.shape[0], lin.n_axes
    s = np.zeros((x.size, n + n_axes, n + n_axes), dtype=complex)
    s[:, :n, :n] = np.eye(n)[None] - x[:, None, None] * lin.phi[None]
    s[:, n:, :n] = -lin.c[None]
    poly = np.polynomial.polynomial.polyval
    for j, polys in enumerate(filters):
        nn, dd, _ = _normalised(polys)
        b = x[:, None] * (lin.g_new[None, :, j] + x[:, None] * lin.g_old[None, :, j])
        s[:, :n, n + j] = b * poly(x, nn)[:, None]
        s[:, n + j, n + j] = poly(x, dd)
    return np.linalg.det(s)


def count_zeros_inside(fn: Any, degree: int, radius: float) -> int | None:
    """Zeros with ``|x| < radius`` of a polynomial of degree at most ``degree`` given
    pointwise (``fn``: ``x`` array -> values): its winding number round the circle, on at
    least 8 points per degree, every step whose phase change exceeds 45 degrees split (16
    points each) until none does (as :func:`~servogym.sim._margins.count_roots_inside` does
    from coefficients). ``None`` when it vanishes on the circle or the steps do not settle."""
    n = max(4096, 1 << math.ceil(math.log2(8 * (degree + 1))))
    return winding_number(
        n, fn(radius * np.exp(1j * (2 * np.pi * np.arange(n) / n))),
        lambda t: fn(radius * np.exp(1j * t)),
        lambda v: not np.all(np.isfinite(v)) or np.min(np.abs(v)) == 0,
    )  # fmt: skip


def machine_loops(
    chip: Any, sets: Sequence[Any], assumptions: Any, lin: MachineLinear
) -> tuple[LoopAnalysis, ...]:
    """Each axis's :class:`~servogym.sim._margins.LoopAnalysis` with the other loops closed:
    its margins by :func:`~servogym.sim._margins.frequency_margins` on
    :func:`loop_response`, its ``stability`` the whole machine's (:func:`machine_stability`,
    the same for every axis), its Bode data on
    :func:`~servogym.sim._margins.frequency_grid`."""
    filters = [chip.filter_polynomials(p, assumptions) for p in sets]
    stability = machine_stability(lin, filters)
    filter_at = [functools.partial(chip.filter_response, p, assumptions) for p in sets]
    freqs = frequency_grid(lin.dt)
    out = []
    for k in range(len(sets)):

        def loop_fn(theta: np.ndarray, k: int = k) -> np.ndarray:
            return loop_response(lin, filter_at, k, np.exp(1j * np.asarray(theta, dtype=float)))

        margins = frequency_margins(loop_fn, lin.dt, stability)
        loop = loop_fn(2 * np.pi * freqs * lin.dt)
        out.append(LoopAnalysis(freqs, loop, margins, stability))
    return tuple(out)


# --- where the machine operates ------------------------------------------------------------


def operating_configurations(commands: Sequence[Any]) -> tuple[tuple[float, ...], ...]:
    """Each task's start and end (every axis's joint position, rad or m), distinct, in the
    order visited: where the machine holds still (``commands``: the tasks'
    :class:`~servogym.sim._contour.Commands`)."""
    out: list[tuple[float, ...]] = []
    for cmd in commands:
        end = cmd.joint_positions(cmd.commanded_counts()[:, -1:])[0]
        for q in (cmd.start_qpos, end):
            p = tuple(round(float(x), POSITION_DECIMALS) for x in q)
            if p not in out:
                out.append(p)
    return tuple(out)


def machine_qpos(plant: Any, configuration: Sequence[float]) -> np.ndarray:
    """The model's reset position with every axis's joint at ``configuration``."""
    qpos = np.array(plant.model.qpos0, dtype=float)
    for io, q in zip(plant.ios, configuration, strict=True):
        qpos[io.qpos_adr] = float(q)
    return qpos


@dataclasses.dataclass(frozen=True)
class MachineMargins:
    """Every loop of one machine's sets, with the other loops closed, at each configuration.

    Attributes:
        configurations: The operating configurations (joint positions per axis).
        analyses: Per configuration, per axis, its loop analysis.
        latencies: Each axis's loop latency (s).
    """

    configurations: tuple[tuple[float, ...], ...]
    analyses: tuple[tuple[LoopAnalysis, ...], ...]
    latencies: tuple[float, ...]

    @property
    def stable(self) -> bool:
        """Whether the machine's closed loop is stable at every configuration."""
        return all(a.margins.stable for per in self.analyses for a in per)

    def worst(self, axis: int, limits: CheckLimits) -> int:
        """Index of the configuration where loop ``axis`` is worst (unstable first, then
        the margin furthest below its minimum, relative to it)."""
        keys = [severity(per[axis].margins, limits.min_gain_margin_db,
                         limits.min_phase_margin_deg) for per in self.analyses]  # fmt: skip
        return min(range(len(keys)), key=keys.__getitem__)


def machine_margins(
    chip: Any,
    sets: Sequence[Any],
    assumptions: Any,
    plant: Any,
    configurations: Sequence[Sequence[float]],
    latencies: Sequence[float],
    cache: dict | None = None,
) -> MachineMargins:
    """:func:`machine_loops` at each configuration (a configuration whose continuous model
    equals an earlier one's, as everywhere on the ``xy-stage``, is analysed once).

    Args:
        chip: The chip family.
        sets: One parameter set per axis.
        assumptions: The chip's assumption switches.
        plant: The built multi-axis plant (its values as set).
        configurations: Joint positions per axis at each configuration.
        latencies: Each axis's loop latency (s).
        cache: A dict reused across calls (continuous models per plant instance and
            configuration).
    """
    dt = chip.sample_time_s(sets[0])
    instance = tuple(sorted(plant.values.items()))
    cache = {} if cache is None else cache
    models: list[Any] = []
    out: list[tuple[LoopAnalysis, ...]] = []
    for config in configurations:
        key = (instance, tuple(config))
        if key not in cache:
            cache[key] = machine_continuous_model(plant, machine_qpos(plant, config))
        same = next((i for i, m in enumerate(models) if _same_loop(m, cache[key])), None)
        models.append(cache[key])
        if same is not None:
            out.append(out[same])
            continue
        lin = machine_linearize(plant, dt, latencies, cache[key])
        out.append(machine_loops(chip, sets, assumptions, lin))
    return MachineMargins(tuple(tuple(c) for c in configurations), tuple(out), tuple(latencies))


# --- the report ----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class AxisResult:
    """One axis in one case.

    Attributes:
        axis: The axis's name (``"x"``, ``"shoulder"``).
        max_following_error: Largest following error over the tasks run (counts).
        following_error_limit: The axis's limit (counts).
        saturation_fraction: Fraction of the ticks run with the command at the motor limit.
        margins: The axis's loop, the other loops closed, at its worst configuration.
        configuration: That configuration (every axis's joint position, rad or m).
    """

    axis: str
    max_following_error: float
    following_error_limit: float
    saturation_fraction: float
    margins: Margins
    configuration: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"axis": self.axis, "max_following_error": self.max_following_error,
                "following_error_limit": self.following_error_limit,
                "saturation_fraction": self.saturation_fraction,
                "margins": self.margins.to_dict(),
                "configuration": list(self.configuration)}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class MachineCase:
    """One case of the machine's stress set.

    Attributes:
        name: ``reference``, ``latency same_tick``, ``sequencing in_turn``, ``load +20%`` ...
        loop_latency: The case's ``loop_latency`` assumption.
        sequencing: The case's sequencing choice.
        plant_changes: The plant values the case changes.
        cost: The machine's cost (docs/cost.md; the divergence penalty when a task diverged).
        diverged: Whether a task's episode diverged.
        divergence: ``"task <i>, axis <name>: <reason> at t = <s> s"``, or ``""``.
        max_contour_error_um: Largest contouring error over the tasks run (um).
        axes: Per axis, its :class:`AxisResult`.
        stable: Whether the machine's closed loop is stable at every configuration.
        spectral_radius: Largest closed-loop pole magnitude over the configurations
            (``nan`` where decided by a root count).
        failures: Each limit the case misses, naming it and by how much.
    """

    name: str
    loop_latency: str
    sequencing: str
    plant_changes: dict[str, float]
    cost: float
    diverged: bool
    divergence: str
    max_contour_error_um: float
    axes: tuple[AxisResult, ...]
    stable: bool
    spectral_radius: float
    failures: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        """Whether the case meets every limit."""
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        radius = self.spectral_radius
        return {"name": self.name, "loop_latency": self.loop_latency,
                "sequencing": self.sequencing, "plant_changes": dict(self.plant_changes),
                "cost": self.cost, "diverged": self.diverged, "divergence": self.divergence,
                "max_contour_error_um": self.max_contour_error_um,
                "axes": [a.to_dict() for a in self.axes], "stable": self.stable,
                "spectral_radius": radius if math.isfinite(radius) else None,
                "failures": list(self.failures), "passed": self.passed}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class AxisLoop:
    """One loop of the reference case, the other loops closed.

    Attributes:
        axis: The axis's name.
        latency_s: Its loop latency (s).
        margins: At its worst configuration.
        configuration: That configuration.
        by_configuration: ``(configuration, margins)`` at every configuration.
    """

    axis: str
    latency_s: float
    margins: Margins
    configuration: tuple[float, ...]
    by_configuration: tuple[tuple[tuple[float, ...], Margins], ...]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"axis": self.axis, "latency_s": self.latency_s,
                "margins": self.margins.to_dict(), "configuration": list(self.configuration),
                "by_configuration": [{"configuration": list(c), "margins": m.to_dict()}
                                     for c, m in self.by_configuration]}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class MachineCheckReport:
    """The outcome of :func:`check_machine_params`.

    Attributes:
        passed: Whether the sets passed every check.
        failures: One line per failed check, naming the case, the axis and by how much.
        cases: The stress set's results, the reference first.
        loops: Per axis, its loop with the other loops closed (reference case).
        timing: Per ``"<loop_latency>/<sequencing>"`` combination (every one), per axis,
            the margins at the worst configuration on the given plant.
        worst: Per axis name, the worst of each margin over the cases and the timing
            combinations, with where: ``{"x": {"gain_margin_db": {"value": ..., "case":
            ...}, ...}, ...}``.
        stable: Whether the machine's closed loop is stable in every case and combination.
        axes: The axis names, in axis order.
        plant: The plant family's name.
        chip_model: The chip model.
        limits: The limits applied.
        elapsed_s: Wall time of the check (s).
    """

    passed: bool
    failures: tuple[str, ...]
    cases: tuple[MachineCase, ...]
    loops: tuple[AxisLoop, ...]
    timing: dict[str, tuple[Margins, ...]]
    worst: dict[str, dict[str, dict[str, Any]]]
    stable: bool
    axes: tuple[str, ...]
    plant: str
    chip_model: str
    limits: CheckLimits
    elapsed_s: float

    @property
    def reasons(self) -> tuple[str, ...]:
        """Why the sets fail (:attr:`failures`)."""
        return self.failures

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``inf`` and ``nan`` as ``None``)."""

        def finite(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {
            "passed": self.passed,
            "failures": list(self.failures),
            "plant": self.plant,
            "chip_model": self.chip_model,
            "axes": list(self.axes),
            "stable": self.stable,
            "loops": [x.to_dict() for x in self.loops],
            "worst": {axis: {k: {"value": finite(v["value"]), "case": v["case"]}
                             for k, v in w.items()} for axis, w in self.worst.items()},
            "timing": {k: [m.to_dict() for m in v] for k, v in self.timing.items()},
            "cases": [c.to_dict() for c in self.cases],
            "limits": dataclasses.asdict(self.limits),
            "elapsed_s": self.elapsed_s,
        }  # fmt: skip


# --- the stress set ------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _MachineCase:
    name: str
    loop_latency: str
    sequencing: str
    plant_changes: dict[str, float]


@dataclasses.dataclass(frozen=True)
class _Machine:
    """What every case shares: the evaluator's settings."""

    plant: str
    chip_model: str
    tasks: tuple[Any, ...]
    plant_values: dict[str, Any]
    weights: MultiCostWeights
    assumptions: Any
    sequencing: str
    contour_mode: str | None
    segmentation_s: float

    def evaluator(self, case: _MachineCase, limits: CheckLimits) -> MultiEvaluator:
        asm = dataclasses.replace(self.assumptions, loop_latency=case.loop_latency)
        return MultiEvaluator(
            self.plant, self.chip_model, self.tasks,
            plant_values={**self.plant_values, **case.plant_changes}, weights=self.weights,
            assumptions=asm, sequencing=case.sequencing, contour_mode=self.contour_mode,
            segmentation_s=self.segmentation_s, integrator="rk4",
            substeps=limits.reference_substeps,
        )  # fmt: skip


def machine_stress_cases(machine: _Machine, limits: CheckLimits) -> list[_MachineCase]:
    """The cases :func:`check_machine_params` simulates (see the module doc)."""
    from servogym.plants import MULTI_PLANTS

    asm, seq = machine.assumptions, machine.sequencing
    family = MULTI_PLANTS[machine.plant]
    nominal = {**family.nominal(), **machine.plant_values}
    cases = [_MachineCase("reference", asm.loop_latency, seq, {})]
    for choice in type(asm).CHOICES["loop_latency"]:
        if choice != asm.loop_latency:
            cases.append(_MachineCase(f"latency {choice}", choice, seq, {}))
    chip_name = _chip_name(machine.chip_model)
    for choice in SEQUENCING[chip_name].choices:
        if choice != seq:
            cases.append(_MachineCase(f"sequencing {choice}", asm.loop_latency, choice, {}))
    for label, names, spread in (
        ("load", [family.load_param], limits.load_spread),
        ("friction", [p.name for p in family.params if "friction" in p.name],
         limits.friction_spread),
    ):  # fmt: skip
        pct = round(100 * spread)
        for sign in (-1, 1):
            changes = _scaled(family, nominal, names, 1 + sign * spread)
            cases.append(_MachineCase(f"{label} {sign * pct:+d}%", asm.loop_latency, seq, changes))
    return cases


def _chip_name(chip_model: str) -> str:
    from servogym.chips._family import get_chip

    return get_chip(chip_model)[0].name


def _spans(commands: Sequence[Any]) -> np.ndarray:
    """Per axis, its longest commanded span over the tasks (counts)."""
    return np.max([np.abs(c.distances_counts) for c in commands], axis=0).astype(float)


def _fmt_config(config: Sequence[float], axes: Sequence[str]) -> str:
    return ", ".join(f"{a} {q:+.4g}" for a, q in zip(axes, config, strict=True))


def _run_case(
    machine: _Machine,
    sets: Sequence[Any],
    case: _MachineCase,
    limits: CheckLimits,
    max_contour_error_um: float | None,
) -> tuple[MachineCase, MachineMargins]:
    ev = machine.evaluator(case, limits)
    e = ev.evaluate(sets)
    names = tuple(ev.plant.family.axes)
    commands = ev.commands()
    spans = _spans(commands)
    if limits.max_following_error is not None:
        fe_limits = np.full(len(names), float(limits.max_following_error))
    else:
        fe_limits = 0.01 * np.where(spans > 0, spans, np.max(spans))
    asm = ev.loop.assumptions
    mm = machine_margins(ev.chip, sets, asm, ev.plant, operating_configurations(commands),
                         ev.loop.latencies_s)  # fmt: skip
    axes, failures = [], []
    divergence = ""
    for i, task in enumerate(e.tasks):
        if task.diverged:
            k = max(task.axis, 0)
            m = task.metrics[k]
            divergence = (f"task {i + 1}, axis {names[k]}: {m.divergence_reason} at t = "
                          f"{m.n_ticks * m.dt:.4g} s")  # fmt: skip
            failures.append(f"{case.name}: diverged ({divergence})")
    for k, name in enumerate(names):
        ms = [t.metrics[k] for t in e.tasks]
        ticks = sum(m.n_ticks for m in ms)
        fe = max(m.max_following_error for m in ms)
        sat = sum(m.saturation_fraction * m.n_ticks for m in ms) / max(ticks, 1)
        w = mm.worst(k, limits)
        axes.append(AxisResult(name, float(fe), float(fe_limits[k]), float(sat),
                               mm.analyses[w][k].margins, mm.configurations[w]))  # fmt: skip
        failures += run_failures(f"{case.name}: {name}", fe, fe_limits[k], sat, limits)
    failures += _loop_failures(case.name, mm, names, limits)
    failures[:0] = _command_limit_failures(case.name, ev, sets, commands, names)
    contour = max(t.contour.max_um for t in e.tasks)
    if max_contour_error_um is not None and contour > max_contour_error_um:
        failures.append(
            f"{case.name}: contouring error: {contour:.4g} um > {max_contour_error_um:.4g} um "
            f"({contour - max_contour_error_um:.4g} um over)"
        )
    radii = [per[0].margins.spectral_radius for per in mm.analyses]
    result = MachineCase(
        name=case.name, loop_latency=case.loop_latency, sequencing=case.sequencing,
        plant_changes=dict(case.plant_changes), cost=float(e.cost), diverged=bool(e.diverged),
        divergence=divergence, max_contour_error_um=float(contour), axes=tuple(axes),
        stable=mm.stable, spectral_radius=float(max(radii)), failures=tuple(failures),
    )  # fmt: skip
    return result, mm


def _command_limit_failures(
    where: str,
    ev: MultiEvaluator,
    sets: Sequence[Any],
    commands: Sequence[Any],
    names: Sequence[str],
) -> list[str]:
    """Each axis whose set limits the motor command below what the tasks need of its motor
    (the single-axis rule, :func:`~servogym.sim._check.command_limit_failure`, with the need
    read off the commanded trajectories: :func:`~servogym.plants._multi.commanded_efforts`);
    named first, as the cause of what else fails."""
    from servogym.plants._multi import commanded_efforts

    trajectories = [c.joint_positions(c.commanded_counts()) for c in commands]
    needs = commanded_efforts(ev.plant, trajectories, ev.loop.dt)
    out = []
    for name, params, need in zip(names, sets, needs, strict=True):
        share = ev.chip.motor_limit(params) / FULL_SCALE
        if share < need.fraction:
            out.append(command_limit_failure(f"{where}: {name}", share, need))
    return out


def _loop_failures(
    where: str, mm: MachineMargins, names: Sequence[str], limits: CheckLimits
) -> list[str]:
    """The machine's closed loop unstable (once, at its first unstable configuration), else
    each loop's margins below the minima at its worst configuration."""
    for config, per in zip(mm.configurations, mm.analyses, strict=True):
        if not all(a.margins.stable for a in per):
            m = next(a.margins for a in per if not a.margins.stable)
            at = f"{where}: the machine (every loop closed, at {_fmt_config(config, names)})"
            return margin_failures(at, m, limits)
    out = []
    for k, name in enumerate(names):
        w = mm.worst(k, limits)
        at = f"{where}: {name} loop (the others closed"
        if len(set(map(id, (per[k] for per in mm.analyses)))) > 1:
            at += f", at {_fmt_config(mm.configurations[w], names)}"
        out += margin_failures(at + ")", mm.analyses[w][k].margins, limits)
    return out


@dataclasses.dataclass(frozen=True)
class _Named:
    name: str
    margins: Margins


def _machine(
    params: Any,
    evaluator_or_plant: Any,
    tasks: Any,
    plant_values: Any,
    assumptions: Any,
    sequencing: Any,
    contour_mode: Any,
    weights: Any,
) -> tuple[_Machine, list[Any]]:
    """The check's machine and the sets in axis order, from the arguments."""
    from servogym.plants import MULTI_PLANTS

    axes = machine_axes(params)
    chip, model = axes.family, axes.model
    ev = evaluator_or_plant if isinstance(evaluator_or_plant, MultiEvaluator) else None
    if ev is not None:
        if ev.chip_model != model:
            raise ParameterError(
                f"the evaluator runs the {ev.chip_model}, but the parameter sets are for the "
                f"{model}; check sets of the evaluator's chip model."
            )
        plant, values = ev.plant.family.name, dict(ev.plant.values)
        tasks = ev.tasks if tasks is None else tasks
        weights = ev.weights if weights is None else weights
        contour_mode = ev.contour_mode if contour_mode is None else contour_mode
        segmentation_s = ev.segmentation_s
        assumptions = ev.loop.assumptions if assumptions is None else assumptions
        sequencing = ev.loop.sequencing if sequencing is None else sequencing
    else:
        from servogym.sim._contour import SEGMENTATION_S

        segmentation_s = SEGMENTATION_S
        if isinstance(evaluator_or_plant, str):
            plant, values = evaluator_or_plant, {}
        elif hasattr(evaluator_or_plant, "ios"):
            plant, values = evaluator_or_plant.family.name, dict(evaluator_or_plant.values)
        else:
            plant, values = evaluator_or_plant, {}
        if plant not in MULTI_PLANTS:
            names = ", ".join(map(repr, MULTI_PLANTS))
            raise ParameterError(
                f"evaluator_or_plant must be a MultiEvaluator, a built multi-axis plant or "
                f"one of {names}; got evaluator_or_plant={evaluator_or_plant!r}"
            )
    values.update(plant_values or {})
    n = MULTI_PLANTS[plant].n_axes
    if len(axes) != n:
        raise ParameterError(
            f"the {plant!r} plant has {n} axes; give one parameter set per axis, got {len(axes)}"
        )
    machine = _Machine(
        plant=plant, chip_model=model, tasks=tuple(tasks) if tasks is not None else None,
        plant_values=values, weights=weights or MultiCostWeights(),
        assumptions=assumptions if assumptions is not None else chip.default_assumptions(),
        sequencing=SEQUENCING[chip.name].choose(sequencing), contour_mode=contour_mode,
        segmentation_s=segmentation_s,
    )  # fmt: skip
    return machine, axes.sets


def check_machine_params(
    params: Any,
    evaluator_or_plant: Any,
    limits: CheckLimits | None = None,
    *,
    tasks: Sequence[Any] | None = None,
    plant_values: Mapping[str, Any] | None = None,
    assumptions: Any = None,
    sequencing: str | None = None,
    contour_mode: str | None = None,
    weights: MultiCostWeights | None = None,
    max_contour_error_um: float | None = None,
    workers: int | None = None,
) -> MachineCheckReport:
    """Check one controller's parameter sets on a multi-axis machine: the stress set and
    every loop's margins with the other loops closed (see the module doc).

    Args:
        params: One parameter set per axis, in the plant's axis order: a
            :class:`~servogym.chips.MultiAxisParams`, a mapping of axis numbers or a
            sequence (as :class:`~servogym.sim.MultiServoLoop` takes them).
        evaluator_or_plant: A :class:`~servogym.sim._multieval.MultiEvaluator` (its plant
            values, tasks, weights, assumptions, sequencing and contour mode are the
            reference), a built multi-axis plant (its values) or a multi-axis plant name
            (``"two-link-arm"``, ``"xy-stage"``).
        limits: The minima, spreads and reference integration (:class:`CheckLimits`; its
            ``max_following_error``, when set, applies to every axis).
        tasks: The tasks (default: the evaluator's, else the plant's ``DEFAULT_TASKS``).
        plant_values: Plant values on top of the evaluator's or plant's.
        assumptions: The chip's assumption switches (default: the evaluator's, else the
            family's defaults).
        sequencing: The family's axis-sequencing choice (default: the evaluator's, else the
            family's default).
        contour_mode: The family's contour mode (default: the evaluator's, else its own).
        weights: The cost's weights (default: the evaluator's, else the defaults).
        max_contour_error_um: Largest contouring error in any case (um); ``None``: no limit
            (the error is reported).
        workers: Threads for the cases (default: every core).

    Returns:
        A :class:`MachineCheckReport`; ``passed`` only when every case passes, the
        machine's closed loop is stable everywhere and every loop's margins meet the minima.

    Raises:
        ParameterError: for sets the machine does not take (:func:`~servogym.sim.
            check_machine`), a count of sets other than the plant's axes, a chip model other
            than the evaluator's, an unknown plant, sequencing or latency choice.
    """
    limits = limits or CheckLimits()
    if max_contour_error_um is not None and not (
        isinstance(max_contour_error_um, int | float)
        and not isinstance(max_contour_error_um, bool)
        and 0 < max_contour_error_um < math.inf
    ):
        raise ParameterError(
            f"max_contour_error_um must be > 0 um (or None for no limit); got "
            f"max_contour_error_um={max_contour_error_um!r}."
        )
    t0 = time.perf_counter()
    machine, sets = _machine(params, evaluator_or_plant, tasks, plant_values, assumptions,
                             sequencing, contour_mode, weights)  # fmt: skip
    cases = machine_stress_cases(machine, limits)
    n_workers = workers or os.cpu_count() or 1
    with cf.ThreadPoolExecutor(n_workers) as pool:
        ran = list(pool.map(lambda c: _run_case(machine, sets, c, limits, max_contour_error_um),
                            cases))  # fmt: skip
    results = [r for r, _ in ran]
    failures = [line for r in results for line in r.failures]
    reference, ref_mm = ran[0]
    names = tuple(a.axis for a in reference.axes)

    # every latency x sequencing combination, linear analysis on the given plant
    ev = machine.evaluator(cases[0], limits)
    ev.loop.set_params(sets)
    configs = ref_mm.configurations
    chip = ev.chip
    timing: dict[str, tuple[Margins, ...]] = {}
    named: list[list[_Named]] = [
        [_Named(r.name, r.axes[k].margins) for r in results] for k in range(len(names))
    ]  # cases first: ties name a case
    cache: dict = {}
    for latency in type(machine.assumptions).CHOICES["loop_latency"]:
        asm = dataclasses.replace(machine.assumptions, loop_latency=latency)
        for seq in SEQUENCING[chip.name].choices:
            key = f"{latency}/{seq}"
            mm = machine_margins(chip, sets, asm, ev.plant, configs,
                                 axis_latencies(sets, asm, seq), cache)  # fmt: skip
            timing[key] = tuple(mm.analyses[mm.worst(k, limits)][k].margins
                                for k in range(len(names)))  # fmt: skip
            covered = any(c.loop_latency == latency and c.sequencing == seq
                          and not c.plant_changes for c in cases)  # fmt: skip
            if not covered:
                failures += _loop_failures(f"timing {key}", mm, names, limits)
            for k in range(len(names)):
                named[k].append(_Named(f"timing {key}", timing[key][k]))
    loops = []
    for k, name in enumerate(names):
        w = ref_mm.worst(k, limits)
        loops.append(AxisLoop(
            axis=name, latency_s=float(ref_mm.latencies[k]),
            margins=ref_mm.analyses[w][k].margins, configuration=ref_mm.configurations[w],
            by_configuration=tuple((c, per[k].margins) for c, per in
                                   zip(ref_mm.configurations, ref_mm.analyses, strict=True)),
        ))  # fmt: skip
    stable = all(r.stable for r in results) and all(
        m.stable for per in timing.values() for m in per
    )
    return MachineCheckReport(
        passed=not failures, failures=tuple(failures), cases=tuple(results), loops=tuple(loops),
        timing=timing, worst={name: worst_margins(named[k]) for k, name in enumerate(names)},
        stable=stable, axes=names, plant=machine.plant, chip_model=machine.chip_model,
        limits=limits, elapsed_s=time.perf_counter() - t0,
    )  # fmt: skip


__all__ = [
    "AxisLoop",
    "AxisResult",
    "MachineCase",
    "MachineCheckReport",
    "MachineLinear",
    "MachineMargins",
    "characteristic_values",
    "check_machine_params",
    "count_zeros_inside",
    "loop_response",
    "machine_closed_loop_matrix",
    "machine_continuous_model",
    "machine_linearize",
    "machine_loops",
    "machine_margins",
    "machine_qpos",
    "machine_response",
    "machine_stability",
    "machine_stress_cases",
    "operating_configurations",
]
