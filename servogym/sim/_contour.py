"""Coordinated moves and contours of a multi-axis machine's tool point, in each chip's units.

Three pieces, used by :mod:`servogym.sim._multieval`:

* :class:`Kinematics`: the tool point of a two-axis plant in its plane (m): the X/Y
  position of an ``xy-stage``, the tip of a ``two-link-arm`` (forward kinematics, and the
  inverse with the elbow-up or elbow-down solution named).
* Paths of the tool point (:class:`LinePath`, :class:`CirclePath`, :class:`PolylinePath`)
  with the distance of any point from the path: to its *nearest* point, not the
  time-synchronous one (:func:`contour_error`).
* Per-axis command profiles: a coordinated point-to-point move (:func:`coordinated_move`:
  each axis's own chip profile, the slowest axis setting the time and the others' limits
  scaled down so that every axis's move ends on the same tick) and a contour
  (:func:`contour`: the path sampled along a trapezoidal or S-curve feed law and handed to
  each chip the way its own contouring mode takes it, :data:`CONTOUR_MODES`).

Counts are absolute: an axis at joint position ``q`` reads ``round(q * counts_per_unit)``
counts at the start of an episode (:attr:`Commands.start_counts`), and a commanded count
``c`` is the joint position ``q_start + (c - start) / counts_per_unit``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numba import njit

from servogym.chips._base import Move
from servogym.chips._space import ParameterError
from servogym.sim._machine import Switch

ELBOWS = ("up", "down")
"""Inverse-kinematics solutions of the two-link arm: ``"up"``, the elbow on the positive side
of the line from the shoulder to the tool point (elbow angle <= 0; above it when the arm is
mounted vertically), ``"down"`` the mirror image (elbow angle >= 0)."""

KINDS = ("trapezoidal", "s_curve")


CONTOUR_MODES: dict[str, Switch] = {
    name: Switch(ident, "contour mode", "mode", choices)
    for name, ident, choices in (
        ("pmd", "PMD-C1", ("fine", "whole_counts")),
        ("pmac", "PMAC-C1", ("cubic", "linear")),
        ("parker6k", "PK-C1", ("linear", "hold")),
    )
}
"""Per chip family, how a contour reaches the servo filter (docs/simulation.md, "Contours"):

* PMD (external profile, a host-computed table of one position per servo cycle): ``fine``,
  the table holds 32.16 positions, the chip's accumulator; the commanded velocity is the
  accumulator's increment (16.16 counts/cycle) and the acceleration the velocity's change,
  exactly as the chip's own trapezoid reports them; ``whole_counts``: whole-count positions,
  velocity and acceleration the differences of those.
* PMAC (a coordinate system's LINEAR/CIRCLE moves with segmentation, Isx13): the path is
  computed at every segmentation point (``segmentation_s``) and interpolated between them at
  every servo update, ``cubic`` (the interpolating cubic through the segment points,
  Catmull-Rom slopes) or ``linear``; positions in 1/32 count as the jog profile (PMAC-P4).
* Parker 6000 (contouring, PLIN/PARC): the path is computed every trajectory update period
  (SSFR servo samples) and spread over its samples as the single-axis profile does (PK-P2):
  ``linear`` or ``hold``; velocity and acceleration per period as PK-P5.
"""

MAX_JUMP_PER_TICK = 0.2
"""Largest change of a joint's commanded position in one servo tick (rad or m) that
:func:`contour` takes: more is the arm's inverse kinematics flipping near its singularity,
or on the stage a feed no servo loop follows."""

SEGMENTATION_S = 0.005
"""Default PMAC segmentation time (Isx13 = 5 ms), rounded to whole servo updates."""


# --- kinematics ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Kinematics:
    """The tool point of a two-axis plant in its plane, metres.

    ``xy-stage``: the tool point is ``(x, y)``. ``two-link-arm``: the tip,
    ``(l1 cos q1 + l2 cos(q1 + q2), l1 sin q1 + l2 sin(q1 + q2))`` in the arm's plane (x
    along both links at zero angles, y toward positive rotation: up when mounted vertically).

    Attributes:
        family: ``"xy-stage"`` or ``"two-link-arm"``.
        upper_link_m, fore_link_m: The arm's link lengths (m); 0 for the stage.
    """

    family: str
    upper_link_m: float = 0.0
    fore_link_m: float = 0.0

    @classmethod
    def of(cls, plant: Any) -> Kinematics:
        """The kinematics of a built multi-axis plant (its current parameter values)."""
        name = plant.family.name
        if name == "xy-stage":
            return cls(name)
        if name == "two-link-arm":
            v = plant.values
            return cls(name, float(v["upper_link_length_m"]), float(v["fore_link_length_m"]))
        raise ParameterError(
            f"contours and tool-point moves need a two-axis plant with a tool point, "
            f"'two-link-arm' or 'xy-stage'; got plant {name!r}"
        )

    def forward(self, q: Any) -> np.ndarray:
        """Tool points ``(n, 2)`` (m) of joint positions ``q`` ``(n, 2)`` (rad or m)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if self.family == "xy-stage":
            return q.copy()
        l1, l2 = self.upper_link_m, self.fore_link_m
        q12 = q[:, 0] + q[:, 1]
        return np.stack(
            [l1 * np.cos(q[:, 0]) + l2 * np.cos(q12), l1 * np.sin(q[:, 0]) + l2 * np.sin(q12)],
            axis=1,
        )

    def inverse(self, xy: Any, elbow: str = "up") -> np.ndarray:
        """Joint positions ``(n, 2)`` that put the tool point on ``xy`` ``(n, 2)`` (m).

        Raises:
            ParameterError: for an ``elbow`` other than :data:`ELBOWS`, or a point out of
                the arm's reach ``|l1 - l2| <= r <= l1 + l2``.
        """
        if elbow not in ELBOWS:
            raise ParameterError(f"elbow must be one of 'up', 'down'; got elbow={elbow!r}")
        p = np.atleast_2d(np.asarray(xy, dtype=float))
        if self.family == "xy-stage":
            return p.copy()
        l1, l2 = self.upper_link_m, self.fore_link_m
        r2 = np.sum(p * p, axis=1)
        c2 = (r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
        bad = np.flatnonzero(np.abs(c2) > 1.0 + 1e-12)
        if bad.size:
            k = int(bad[0])
            raise ParameterError(
                f"tool point ({p[k, 0]:.6g}, {p[k, 1]:.6g}) m is out of the arm's reach: "
                f"its distance from the shoulder must satisfy {abs(l1 - l2):.6g} <= r <= "
                f"{l1 + l2:.6g} m; got r={math.sqrt(r2[k]):.6g} m"
            )
        q2 = np.arccos(np.clip(c2, -1.0, 1.0))
        if elbow == "up":
            q2 = -q2
        q1 = np.arctan2(p[:, 1], p[:, 0]) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
        q1 = (q1 + np.pi) % (2.0 * np.pi) - np.pi
        return np.stack([q1, q2], axis=1)


# --- paths --------------------------------------------------------------------------------


def _point(name: str, value: Any) -> np.ndarray:
    p = np.asarray(value, dtype=float)
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise ParameterError(f"{name} must be a finite (x, y) point in m; got {name}={value!r}")
    return p


@dataclasses.dataclass(frozen=True, eq=False)
class LinePath:
    """A straight line of the tool point from ``start`` to ``end`` (m)."""

    start: np.ndarray
    end: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", _point("start", self.start))
        object.__setattr__(self, "end", _point("end", self.end))
        if self.length <= 0.0:
            raise ParameterError(
                f"a line needs end != start; got start={tuple(self.start)}, end={tuple(self.end)}"
            )

    @property
    def length(self) -> float:
        """Path length (m)."""
        return float(np.hypot(*(self.end - self.start)))

    def point(self, s: Any) -> np.ndarray:
        """Points ``(n, 2)`` at arc lengths ``s`` (m, clipped to ``[0, length]``)."""
        u = np.clip(np.asarray(s, dtype=float), 0.0, self.length) / self.length
        return self.start + u[:, None] * (self.end - self.start)

    def distance(self, points: Any) -> np.ndarray:
        """Distance (m) of each point ``(n, 2)`` from the nearest point of the segment."""
        p = np.atleast_2d(np.asarray(points, dtype=float))
        d = self.end - self.start
        u = np.clip((p - self.start) @ d / float(d @ d), 0.0, 1.0)
        return np.hypot(*(p - self.start - u[:, None] * d).T)


@dataclasses.dataclass(frozen=True, eq=False)
class CirclePath:
    """An arc of the tool point: ``centre`` (m), ``radius`` (m), from ``start_angle_rad``
    through ``sweep_rad`` (positive: counter-clockwise; ``2 pi`` is a full circle)."""

    centre: np.ndarray
    radius: float
    start_angle_rad: float = 0.0
    sweep_rad: float = 2.0 * math.pi

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", _point("centre", self.centre))
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ParameterError(f"radius must be a finite number > 0 (m); got {self.radius!r}")
        if not (math.isfinite(self.sweep_rad) and 0 < abs(self.sweep_rad) <= 2 * math.pi):
            raise ParameterError(
                f"sweep_rad must satisfy 0 < |sweep_rad| <= 2 pi; got sweep_rad={self.sweep_rad!r}"
            )
        if not math.isfinite(self.start_angle_rad):
            raise ParameterError(f"start_angle_rad must be finite; got {self.start_angle_rad!r}")

    @property
    def length(self) -> float:
        """Path length (m)."""
        return self.radius * abs(self.sweep_rad)

    @property
    def start(self) -> np.ndarray:
        """First point (m)."""
        return self.point(np.zeros(1))[0]

    @property
    def end(self) -> np.ndarray:
        """Last point (m)."""
        return self.point(np.full(1, self.length))[0]

    def point(self, s: Any) -> np.ndarray:
        """Points ``(n, 2)`` at arc lengths ``s`` (m, clipped to ``[0, length]``)."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length)
        a = self.start_angle_rad + math.copysign(1.0, self.sweep_rad) * s / self.radius
        return self.centre + self.radius * np.stack([np.cos(a), np.sin(a)], axis=1)

    def distance(self, points: Any) -> np.ndarray:
        """Distance (m) of each point ``(n, 2)`` from the nearest point of the arc."""
        p = np.atleast_2d(np.asarray(points, dtype=float))
        rel = p - self.centre
        radial = np.abs(np.hypot(*rel.T) - self.radius)
        if abs(self.sweep_rad) >= 2 * math.pi:
            return radial
        sign = math.copysign(1.0, self.sweep_rad)
        phi = (sign * (np.arctan2(rel[:, 1], rel[:, 0]) - self.start_angle_rad)) % (2 * math.pi)
        ends = np.minimum(
            np.hypot(*(p - self.start).T), np.hypot(*(p - self.end).T)
        )  # outside the sweep, the nearest point is an end
        return np.where(phi <= abs(self.sweep_rad), radial, ends)


@njit(cache=True, nogil=True)
def _polyline_distance(p, v):  # pragma: no cover - compiled
    out = np.empty(p.shape[0])
    for i in range(p.shape[0]):
        best = np.inf
        for k in range(v.shape[0] - 1):
            dx, dy = v[k + 1, 0] - v[k, 0], v[k + 1, 1] - v[k, 1]
            px, py = p[i, 0] - v[k, 0], p[i, 1] - v[k, 1]
            dd = dx * dx + dy * dy
            u = 0.0 if dd == 0.0 else min(max((px * dx + py * dy) / dd, 0.0), 1.0)
            ex, ey = px - u * dx, py - u * dy
            e = ex * ex + ey * ey
            if e < best:
                best = e
        out[i] = math.sqrt(best)
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class PolylinePath:
    """A path through ``vertices`` ``(m, 2)`` (m): a coordinated move's commanded tool path,
    one vertex per servo tick."""

    vertices: np.ndarray

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 1 or not np.all(np.isfinite(v)):
            raise ParameterError(f"vertices must be finite, of shape (m, 2); got {v.shape}")
        if v.shape[0] == 1:
            v = np.vstack([v, v])
        object.__setattr__(self, "vertices", v)

    @property
    def length(self) -> float:
        """Path length (m)."""
        return float(np.sum(np.hypot(*np.diff(self.vertices, axis=0).T)))

    def distance(self, points: Any) -> np.ndarray:
        """Distance (m) of each point ``(n, 2)`` from the nearest point of the polyline."""
        p = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=float)))
        return _polyline_distance(p, self.vertices)


# --- the feed law along a path -------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FeedLaw:
    """Arc length along a path against time: a trapezoid of ``speed`` and ``acceleration``
    (a triangle when the path is too short), or for ``"s_curve"`` that trapezoid averaged
    over ``acceleration / jerk`` seconds (the acceleration ramps at the jerk limit).

    Attributes:
        length: Path length (m), > 0.
        speed: Feed rate (m/s), > 0.
        acceleration: Path acceleration (m/s^2), > 0.
        kind: ``"trapezoidal"`` or ``"s_curve"``.
        jerk: Path jerk (m/s^3) for ``"s_curve"``.
    """

    length: float
    speed: float
    acceleration: float
    kind: str = "trapezoidal"
    jerk: float | None = None

    def __post_init__(self) -> None:
        for name in ("length", "speed", "acceleration"):
            x = getattr(self, name)
            if isinstance(x, bool) or not (math.isfinite(x) and x > 0):
                raise ParameterError(f"{name} must be a finite number > 0; got {name}={x!r}")
        if self.kind not in KINDS:
            raise ParameterError(f"kind must be one of {KINDS}; got kind={self.kind!r}")
        if self.kind == "s_curve" and not (self.jerk is not None and self.jerk > 0):
            raise ParameterError(f"kind='s_curve' needs jerk > 0 (m/s^3); got jerk={self.jerk!r}")

    @property
    def window(self) -> float:
        """The S-curve's averaging window (s); 0 for a trapezoid."""
        return self.acceleration / self.jerk if self.kind == "s_curve" else 0.0

    def _pieces(self) -> tuple[float, float, float]:
        v, a, d = self.speed, self.acceleration, self.length
        if d >= v * v / a:
            return v / a, d / v - v / a, v
        peak = math.sqrt(d * a)
        return peak / a, 0.0, peak

    @property
    def duration(self) -> float:
        """Time from the start to the end of the path (s)."""
        t1, tc, _ = self._pieces()
        return 2 * t1 + tc + self.window

    def _trapezoid(self, t: np.ndarray) -> np.ndarray:
        t1, tc, peak = self._pieces()
        a, d = self.acceleration, self.length
        t2, end = t1 + tc, 2 * t1 + tc
        u = np.clip(t, 0.0, end)
        up = 0.5 * a * np.minimum(u, t1) ** 2
        cruise = peak * np.clip(u - t1, 0.0, tc)
        w = np.clip(u - t2, 0.0, t1)
        down = peak * w - 0.5 * a * w * w
        return np.minimum(up + cruise + down, d)

    def _integral(self, t: np.ndarray) -> np.ndarray:
        """``int_0^t s(u) du`` of the trapezoid (m*s), exact piece by piece."""
        t1, tc, peak = self._pieces()
        a, d = self.acceleration, self.length
        t2, end = t1 + tc, 2 * t1 + tc
        u = np.clip(t, 0.0, None)
        r = np.minimum(u, t1)
        total = a * r**3 / 6
        c = np.clip(u - t1, 0.0, tc)
        d1 = 0.5 * a * t1 * t1
        total = total + d1 * c + 0.5 * peak * c * c
        w = np.clip(u - t2, 0.0, t1)
        total = total + (d1 + peak * tc) * w + 0.5 * peak * w * w - a * w**3 / 6
        return total + d * np.clip(u - end, 0.0, None)

    def __call__(self, t: Any) -> np.ndarray:
        """Arc length (m) at times ``t`` (s; 0 before the start, ``length`` after the end)."""
        t = np.asarray(t, dtype=float)
        w = self.window
        if w == 0.0:
            return self._trapezoid(t)
        return np.clip((self._integral(t) - self._integral(t - w)) / w, 0.0, self.length)


# --- per-family command profiles ----------------------------------------------------------


def _wrap32(x: np.ndarray) -> np.ndarray:
    return ((x + 2**31) & 0xFFFFFFFF) - 2**31


def _times(n: int, dt: float) -> np.ndarray:
    """Entry k is the command at the end of servo cycle k, time ``(k + 1) dt``."""
    return (np.arange(n) + 1) * dt


def sampled_profile(
    chip: Any,
    params: Any,
    counts: Any,
    start: int,
    n_ticks: int,
    move_ticks: int,
    *,
    mode: str | None = None,
    segmentation_s: float = SEGMENTATION_S,
) -> Any:
    """One axis's contour in the chip's own profile form (:data:`CONTOUR_MODES`).

    Args:
        chip: The chip family.
        params: The axis's parameter set (its servo period).
        counts: ``counts(t)``: the commanded position in counts (float) at times ``t`` (s,
            an array; ``t <= 0`` is the start), vectorised.
        start: The axis's position at rest before entry 0 (counts).
        n_ticks: Entries of the profile.
        move_ticks: Entries up to the end of the motion (the rest hold).
        mode: The family's :data:`CONTOUR_MODES` choice; ``None``: its default.
        segmentation_s: PMAC only: the segmentation time (s), rounded to whole servo
            updates (at least one).
    """
    choice = CONTOUR_MODES[chip.name].choose(mode)
    dt = chip.sample_time_s(params)
    t = _times(n_ticks, dt)
    if chip.name == "pmd":
        from servogym.chips.pmd._profile import Profile

        if choice == "fine":
            fine = np.floor(0.5 + 65536.0 * np.asarray(counts(t), float)).astype(np.int64)
            velocity = np.diff(fine, prepend=np.int64(65536 * start))
            position = fine >> 16
        else:
            whole = np.floor(0.5 + np.asarray(counts(t), float)).astype(np.int64)
            velocity = 65536 * np.diff(whole, prepend=np.int64(start))
            position = whole
        acceleration = np.diff(velocity, prepend=np.int64(0))
        return Profile(
            position=_wrap32(position), velocity=velocity, acceleration=acceleration,
            move_ticks=move_ticks, start=int(start),
        )  # fmt: skip
    if chip.name == "pmac":
        from servogym.chips.pmac._profile import Profile

        every = max(1, round(segmentation_s / dt))
        seg_t = np.arange(-1, n_ticks // every + 3) * every * dt
        seg_x = np.asarray(counts(seg_t), float)
        x = _interpolate(seg_x, (t / (every * dt)) + 1.0, cubic=choice == "cubic")
        fine = np.floor(32.0 * x + 0.5).astype(np.int64)
        acceleration = np.diff(np.diff(fine, prepend=np.int64(32 * start)), prepend=np.int64(0))
        return Profile(
            position=_wrap32(fine >> 5), velocity=fine & 31, acceleration=acceleration,
            start=int(start), move_ticks=move_ticks,
        )  # fmt: skip
    from servogym.chips.parker6k._profile import MICRO, Parker6kProfile, ssfr_of

    ssfr = ssfr_of(dt)
    tt = ssfr * dt  # trajectory period (s)
    tt_us = round(tt * MICRO)
    n_periods = -(-n_ticks // ssfr)
    points = np.floor(0.5 + MICRO * (np.asarray(counts(np.arange(n_periods + 1) * tt), float)
                                     - start)).astype(np.int64)  # fmt: skip
    points[0] = 0
    steps = np.diff(points)
    i = np.tile(np.arange(1, ssfr + 1, dtype=np.int64), n_periods)
    if choice == "linear":
        x = np.repeat(points[:-1], ssfr) * ssfr + np.repeat(steps, ssfr) * i
    else:
        x = np.repeat(points[1:], ssfr) * ssfr
    position = start + x // (ssfr * MICRO)
    velocity = np.repeat(_round_div(steps, tt_us), ssfr)
    change = np.diff(steps, prepend=np.int64(0))
    acceleration = np.repeat(_round_div(change * MICRO, tt_us * tt_us), ssfr)
    return Parker6kProfile(
        position=_wrap32(position[:n_ticks]), velocity=velocity[:n_ticks],
        acceleration=acceleration[:n_ticks], start=int(start), move_ticks=move_ticks, ssfr=ssfr,
    )  # fmt: skip


def _round_div(x: np.ndarray, d: int) -> np.ndarray:
    """``x / d`` rounded to nearest, halves away from zero (as PK-P5)."""
    return np.sign(x) * ((2 * np.abs(x) + d) // (2 * d))


def _interpolate(y: np.ndarray, u: np.ndarray, *, cubic: bool) -> np.ndarray:
    """``y`` (samples at 0, 1, 2, ...) at fractional indices ``u``: linear, or the
    interpolating cubic with Catmull-Rom slopes (end slopes one-sided)."""
    k = np.clip(np.floor(u).astype(np.int64), 0, y.shape[0] - 2)
    f = u - k
    y0, y1 = y[k], y[k + 1]
    if not cubic:
        return y0 + f * (y1 - y0)
    slope = np.gradient(y)
    m0, m1 = slope[k], slope[k + 1]
    f2, f3 = f * f, f * f * f
    return (
        (2 * f3 - 3 * f2 + 1) * y0 + (f3 - 2 * f2 + f) * m0 + (-2 * f3 + 3 * f2) * y1
        + (f3 - f2) * m1
    )  # fmt: skip


def _hold(chip: Any, profile: Any, before: int, n_ticks: int) -> Any:
    """``profile`` with ``before`` entries at rest on its start and held on its last entry
    up to ``n_ticks`` entries (PMAC: the last fraction held too)."""
    n = profile.n_ticks
    after = n_ticks - before - n
    pos = np.concatenate([np.full(before, profile.start, np.int64), profile.position,
                          np.full(after, profile.position[-1], np.int64)])  # fmt: skip
    last_v = int(profile.velocity[-1]) if chip.name == "pmac" else 0
    vel = np.concatenate([np.zeros(before, np.int64), profile.velocity,
                          np.full(after, last_v, np.int64)])  # fmt: skip
    acc = np.concatenate([np.zeros(before, np.int64), profile.acceleration,
                          np.zeros(after, np.int64)])  # fmt: skip
    move_ticks = before + int(profile.move_ticks if profile.move_ticks is not None else n)
    return dataclasses.replace(
        profile, position=pos, velocity=vel, acceleration=acc, move_ticks=move_ticks
    )


# --- commands of every axis ---------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class Commands:
    """Every axis's profile for one episode, with what the contouring error needs.

    Attributes:
        profiles: One chip profile per axis, all ``n_ticks`` long.
        start_counts: Each axis's position at the start (counts; ``round(q_start * cpu)``).
        start_qpos: Each axis's joint position at the start (rad or m).
        counts_per_unit: Each axis's encoder counts per joint unit.
        path: The commanded tool path (:class:`LinePath`, :class:`CirclePath`, or for a
            point-to-point move the :class:`PolylinePath` of the commanded positions).
        kinematics: The plant's :class:`Kinematics`.
        motion: ``(first, end)``: the entries over which the tool point is measured, from
            the first entry of the motion to the end of the episode.
        move_ticks: Per axis, the entry after which its profile holds (the same for every
            moving axis of a coordinated move).
        distances_counts: Per axis, the span of its commanded position (counts): the move
            length the per-axis cost scales its errors by.
        settle_s: Time at rest after the motion (s).
    """

    profiles: tuple[Any, ...]
    start_counts: tuple[int, ...]
    start_qpos: tuple[float, ...]
    counts_per_unit: tuple[float, ...]
    path: Any
    kinematics: Kinematics
    motion: tuple[int, int]
    move_ticks: tuple[int, ...]
    distances_counts: tuple[int, ...]
    settle_s: float

    @property
    def n_ticks(self) -> int:
        """Entries of every profile."""
        return int(self.profiles[0].n_ticks)

    def joint_positions(self, counts: np.ndarray) -> np.ndarray:
        """Joint positions ``(n, axes)`` of counts ``(axes, n)`` (measured or commanded)."""
        c = np.asarray(counts, dtype=float)
        return np.stack(
            [q0 + (c[i] - s) / cpu for i, (q0, s, cpu) in
             enumerate(zip(self.start_qpos, self.start_counts, self.counts_per_unit, strict=True))],
            axis=1,
        )  # fmt: skip

    def commanded_counts(self) -> np.ndarray:
        """The commanded positions ``(axes, n_ticks)`` in counts, with their fraction where
        the chip's profile has one (PMAC's 1/32 count), unwrapped from the start."""
        out = []
        for p, s in zip(self.profiles, self.start_counts, strict=True):
            steps = ((np.diff(p.position, prepend=s) + 2**31) % 2**32) - 2**31
            c = s + np.cumsum(steps).astype(float)
            if hasattr(p, "fine_position"):
                c = p.fine_position / 32.0
            out.append(c)
        return np.stack(out)


def _axes_setup(loop_or_plant: Any, start_qpos: Sequence[float] | None):
    plant = getattr(loop_or_plant, "plant", loop_or_plant)
    ios = tuple(plant.ios)
    q0 = (
        tuple(float(io.start_qpos) for io in ios)
        if start_qpos is None
        else tuple(float(q) for q in start_qpos)
    )
    if len(q0) != len(ios):
        raise ParameterError(f"start_qpos must give one position per axis ({len(ios)}); got {q0}")
    for k, (io, q) in enumerate(zip(ios, q0, strict=True)):
        _check_travel(plant, io, k, q, "start_qpos")
    cpu = tuple(float(io.counts_per_unit) for io in ios)
    starts = tuple(round(q * c) for q, c in zip(q0, cpu, strict=True))
    return plant, ios, q0, cpu, starts


def _check_travel(plant: Any, io: Any, k: int, q: float, what: str) -> None:
    from servogym.sim._runner import TRAVEL_MARGIN

    span = io.travel_max - io.travel_min
    lo, hi = io.travel_min + TRAVEL_MARGIN * span, io.travel_max - TRAVEL_MARGIN * span
    if not lo <= q <= hi:
        axis = plant.family.axes[k] if hasattr(plant.family, "axes") else str(k)
        raise ParameterError(
            f"{what} puts axis {axis!r} at {q:.6g}, outside its travel: it must satisfy "
            f"{lo:.6g} <= {axis} <= {hi:.6g} (the travel less a 1 % margin at each end)"
        )


def contour(
    loop: Any,
    path: LinePath | CirclePath,
    speed: float,
    acceleration: float,
    *,
    kind: str = "trapezoidal",
    jerk: float | None = None,
    elbow: str = "up",
    dwell_s: float = 0.02,
    settle_s: float = 0.1,
    mode: str | None = None,
    segmentation_s: float = SEGMENTATION_S,
) -> Commands:
    """Every axis's profile for the tool point to follow ``path``.

    The tool point rests on the path's start for ``dwell_s``, follows the path along a
    :class:`FeedLaw` of ``speed`` (m/s) and ``acceleration`` (m/s^2) (``kind``, ``jerk``),
    then rests on its end for ``settle_s``. Each axis's joint position follows from the
    inverse kinematics (``elbow`` for the arm) and reaches its chip as the family's
    contouring mode takes it (:func:`sampled_profile`). The episode starts with the
    machine at rest on the path's start: run it with ``start_qpos=commands.start_qpos``.

    Args:
        loop: A :class:`~servogym.sim.MultiServoLoop` (its plant, chip and parameters).
        path: The tool path.
        speed, acceleration, kind, jerk: The feed law.
        elbow: ``"up"`` or ``"down"`` (two-link arm).
        dwell_s, settle_s: Rest before and after the motion (s), >= 0.
        mode: The chip family's :data:`CONTOUR_MODES` choice; ``None``: its default.
        segmentation_s: PMAC's segmentation time (s).
    """
    for name, value in (("dwell_s", dwell_s), ("settle_s", settle_s)):
        if isinstance(value, bool) or not (math.isfinite(value) and value >= 0):
            raise ParameterError(f"{name} must be a finite number >= 0 (s); got {name}={value!r}")
    kin = Kinematics.of(loop.plant)
    law = FeedLaw(path.length, speed, acceleration, kind, jerk)
    q_start = kin.inverse(path.point(np.zeros(1)), elbow)[0]
    plant, ios, q0, cpu, starts = _axes_setup(loop, q_start)
    dt = loop.dt
    before = round(dwell_s / dt)
    moving = math.ceil(law.duration / dt - 1e-9)
    n = before + moving + round(settle_s / dt)
    dense = kin.inverse(path.point(law(_times(moving, dt))), elbow)
    for k, io in enumerate(ios):
        for q in (dense[:, k].min(), dense[:, k].max()):
            _check_travel(plant, io, k, float(q), "the path")
    jumps = np.abs(np.diff(np.vstack([q_start[None, :], dense]), axis=0)).max(axis=0)
    for k, j in enumerate(jumps):
        if j > MAX_JUMP_PER_TICK:
            unit, hint = "m", ""
            if kin.family == "two-link-arm":
                unit = "rad"
                hint = (
                    "keep the path away from the edges of the arm's reach (its singularities) or "
                )
            raise ParameterError(
                f"the contour moves axis {plant.family.axes[k]!r} {j:.3g} {unit} in one tick, "
                f"more than {MAX_JUMP_PER_TICK} {unit}: {hint}lower speed={speed!r} (m/s)"
            )
    t_shift = before * dt
    profiles = []
    for k, chip_params in enumerate(loop.params):

        def counts(t, k=k):
            q = kin.inverse(path.point(law(np.asarray(t) - t_shift)), elbow)[:, k]
            return starts[k] + (q - q0[k]) * cpu[k]

        profiles.append(
            sampled_profile(
                loop.chip, chip_params, counts, starts[k], n, before + moving, mode=mode,
                segmentation_s=segmentation_s,
            )
        )  # fmt: skip
    return _commands(profiles, starts, q0, cpu, path, kin, (before, n), settle_s)


def _commands(profiles, starts, q0, cpu, path, kin, motion, settle_s) -> Commands:
    cmd = Commands(tuple(profiles), tuple(starts), tuple(q0), tuple(cpu), path, kin, motion,
                   tuple(int(p.move_ticks) for p in profiles), (0,) * len(profiles),
                   float(settle_s))  # fmt: skip
    counts = cmd.commanded_counts()
    spans = tuple(round(c.max() - c.min()) for c in counts)
    if path is None:  # a point-to-point move: the commanded tool path, from the start
        verts = kin.forward(np.vstack([np.array([q0]), cmd.joint_positions(counts)]))
        path = PolylinePath(verts)
    return dataclasses.replace(cmd, distances_counts=spans, path=path)


def coordinated_move(
    loop: Any,
    targets: Sequence[float] | None = None,
    *,
    max_velocity: Sequence[float],
    max_acceleration: Sequence[float],
    tool_target: Sequence[float] | None = None,
    elbow: str = "up",
    kind: str = "trapezoidal",
    jerk: Sequence[float] | None = None,
    start_qpos: Sequence[float] | None = None,
    settle_s: float = 0.1,
) -> Commands:
    """Every axis's own point-to-point profile, timed so that all arrive together.

    Each axis gets its chip's single-axis profile (``chip.profile``: PMD trapezoid or
    S-curve, PMAC jog, 6000-series A/V/D) of its distance ``d_k``. The axes share one
    shape, so that they keep step (a straight line in joint space): each axis's velocity,
    acceleration and jerk limits become ``d_k`` times the smallest ``limit_j / d_j`` over
    the moving axes, so the axis whose limits bind (the slowest) sets the time and every
    other axis's limits are scaled down. The chips' integer arithmetic may still end them
    a tick or so apart: every axis that ends before the slowest has its limits scaled
    once more by a time scale ``r`` (velocity ``r v``, acceleration ``r^2 a``, jerk
    ``r^3 j``), found so that its move ends on the slowest axis's move tick. If no ``r``
    lands there (a chip's ticks jump past it), that axis sets a longer time and every
    axis is fitted again.

    Args:
        loop: A :class:`~servogym.sim.MultiServoLoop`.
        targets: Per axis, the target joint position (rad or m); or ``tool_target``.
        max_velocity, max_acceleration: Per axis, its limits (joint units per s, s^2), > 0.
        tool_target: The tool point's target (m), through the inverse kinematics (``elbow``).
        elbow: ``"up"`` or ``"down"`` for ``tool_target`` on the two-link arm.
        kind: ``"trapezoidal"`` or ``"s_curve"`` (then ``jerk`` per axis, units per s^3).
        start_qpos: Per axis, the joint position at the start; ``None``: the plant's.
        settle_s: Rest on the targets after the move (s).

    Raises:
        ParameterError: naming the argument, the value and the legal range.
    """
    plant, ios, q0, cpu, starts = _axes_setup(loop, start_qpos)
    n_axes = len(ios)
    if (targets is None) == (tool_target is None):
        raise ParameterError("give exactly one of targets (joint units) and tool_target (m)")
    kin = Kinematics.of(plant)
    if tool_target is not None:
        targets = kin.inverse(_point("tool_target", tool_target)[None, :], elbow)[0]
    lists = {"targets": targets, "max_velocity": max_velocity,
             "max_acceleration": max_acceleration}  # fmt: skip
    if kind == "s_curve":
        lists["jerk"] = jerk
    for name, value in lists.items():
        if value is None or len(value) != n_axes:
            raise ParameterError(f"{name} must give one value per axis ({n_axes}); got {value!r}")
    if kind not in KINDS:
        raise ParameterError(f"kind must be one of {KINDS}; got kind={kind!r}")
    for k, q in enumerate(targets):
        _check_travel(plant, ios[k], k, float(q), "targets")
    chip, dt = loop.chip, loop.dt
    moves = []
    for k in range(n_axes):
        d = round(float(targets[k]) * cpu[k]) - starts[k]
        j = float(jerk[k]) * cpu[k] if kind == "s_curve" else None
        moves.append(Move(d, float(max_velocity[k]) * cpu[k], float(max_acceleration[k]) * cpu[k],
                          0.0, kind, j, starts[k]))  # fmt: skip

    def build(k: int, r: float) -> Any:
        m = moves[k]
        jj = None if m.jerk_counts_per_s3 is None else m.jerk_counts_per_s3 * r**3
        return chip.profile(
            dataclasses.replace(
                m, max_velocity_counts_per_s=m.max_velocity_counts_per_s * r,
                max_acceleration_counts_per_s2=m.max_acceleration_counts_per_s2 * r * r,
                jerk_counts_per_s3=jj,
            ),
            dt,
        )  # fmt: skip

    moving = [k for k in range(n_axes) if moves[k].distance_counts != 0]
    moves = _common_shape(moves, moving)
    own = [build(k, 1.0) for k in range(n_axes)]
    ticks = max([int(own[k].move_ticks) for k in moving], default=1)
    profiles = list(own)
    for _ in range(8):
        longer = None
        for k in moving:
            fitted = _fit(build, k, ticks, int(own[k].move_ticks))
            if isinstance(fitted, int):
                longer = max(longer or 0, fitted)
            else:
                profiles[k] = fitted
        if longer is None:
            break
        ticks = longer
    else:  # pragma: no cover - the ticks grow every round, so this is not reached
        raise ParameterError("could not time the axes to arrive on one tick")
    n = ticks + round(settle_s / dt)
    profiles = [_hold(chip, p, 0, n) if p.n_ticks <= n else p for p in profiles]
    return _commands(profiles, starts, q0, cpu, None, kin, (0, n), settle_s)


def _common_shape(moves: list[Move], moving: list[int]) -> list[Move]:
    """Every moving axis's limits as its distance times the tightest per-unit-distance
    limit over the axes: one shape for all, within every axis's own limits."""
    if not moving:
        return moves
    dist = {k: abs(moves[k].distance_counts) for k in moving}
    v = min(moves[k].max_velocity_counts_per_s / dist[k] for k in moving)
    a = min(moves[k].max_acceleration_counts_per_s2 / dist[k] for k in moving)
    jerks = [moves[k].jerk_counts_per_s3 for k in moving]
    j = None if jerks[0] is None else min(jj / dist[k] for jj, k in zip(jerks, moving, strict=True))
    return [dataclasses.replace(m, max_velocity_counts_per_s=v * dist[k],
                                max_acceleration_counts_per_s2=a * dist[k],
                                jerk_counts_per_s3=None if j is None else j * dist[k])
            if k in dist else m for k, m in enumerate(moves)]  # fmt: skip


def _fit(build: Any, k: int, ticks: int, own_ticks: int) -> Any:
    """Axis ``k``'s profile with ``move_ticks == ticks`` (its limits times ``r``,
    ``r^2``, ``r^3``, the ``r <= 1`` found by bisection), or the fewest ticks above
    ``ticks`` it can reach when it cannot land on them."""

    def length(r: float) -> int | None:
        try:
            return int(build(k, r).move_ticks)
        except ParameterError:
            return None  # a limit below one register step: too slow

    if own_ticks == ticks:
        return build(k, 1.0)
    lo, hi = 0.0, 1.0  # length(hi) < ticks; length(lo) >= ticks (or illegal)
    r = min(1.0, own_ticks / ticks)
    for _ in range(60):
        got = length(r)
        if got == ticks:
            return build(k, r)
        if got is None or got > ticks:
            lo = r
        else:
            hi = r
        r = 0.5 * (lo + hi)
        if hi - lo < 1e-12:
            break
    got = length(lo) if lo > 0 else None
    return got if got is not None and got > ticks else ticks + 1


# --- contouring error ---------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ContourError:
    """Distance of the measured tool point from the commanded path, micrometres.

    Attributes:
        max_um: Largest distance over the measured ticks.
        rms_um: Root mean square distance over them.
        n_ticks: Ticks measured (from the motion's first tick to the end of the run).
    """

    max_um: float
    rms_um: float
    n_ticks: int

    def to_dict(self) -> dict:
        """Every field, JSON-ready."""
        return dataclasses.asdict(self)


def contour_error(commands: Commands, actual_counts: Any, n_run: int | None = None) -> ContourError:
    """The contouring error of measured positions ``actual_counts`` ``(axes, n)``.

    The tool point of each tick's measured joint positions (:meth:`Commands.joint_positions`,
    :meth:`Kinematics.forward`) is compared with the nearest point of ``commands.path``,
    over ``commands.motion`` (cut at ``n_run`` ticks for an episode that ended early).
    """
    actual = np.asarray(actual_counts)
    first, end = commands.motion
    end = min(end, actual.shape[1] if n_run is None else n_run)
    if end <= first:
        return ContourError(0.0, 0.0, 0)
    steps = ((np.diff(actual[:, first:end], axis=1, prepend=actual[:, [first]]) + 2**31)
             % 2**32) - 2**31  # fmt: skip
    unwrapped = actual[:, [first]] + np.cumsum(steps, axis=1)
    tool = commands.kinematics.forward(commands.joint_positions(unwrapped))
    d = commands.path.distance(tool) * 1e6
    return ContourError(float(d.max()), float(np.sqrt(np.mean(d * d))), int(end - first))


__all__ = [
    "CONTOUR_MODES",
    "ELBOWS",
    "SEGMENTATION_S",
    "CirclePath",
    "Commands",
    "ContourError",
    "FeedLaw",
    "Kinematics",
    "LinePath",
    "PolylinePath",
    "contour",
    "contour_error",
    "coordinated_move",
    "sampled_profile",
]
