"""Coordinated moves, contours and the contouring error (servogym.sim._contour): kinematics
against MuJoCo, distances against known offsets, every axis arriving on one tick, the
commands on the path, for every chip family (from the registry) and both multi-axis plants."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from servogym.chips._family import families
from servogym.chips._space import ParameterError
from servogym.plants import MULTI_PLANTS
from servogym.sim import MultiServoLoop, machine_params
from servogym.sim._contour import (
    CONTOUR_MODES,
    CirclePath,
    FeedLaw,
    Kinematics,
    LinePath,
    PolylinePath,
    contour,
    contour_error,
    coordinated_move,
)

FAMILIES = sorted(families())
PLANTS = sorted(MULTI_PLANTS)


def first_model(family: str) -> str:
    return next(iter(families()[family].models))


@pytest.fixture(scope="module")
def built():
    return {name: MULTI_PLANTS[name].build() for name in PLANTS}


def machine(built, plant: str, family: str) -> MultiServoLoop:
    return MultiServoLoop(built[plant], machine_params(first_model(family), 2))


# --- kinematics ---------------------------------------------------------------------------


@pytest.mark.parametrize("vertical", [0, 1])
def test_arm_forward_kinematics_is_mujocos_payload_position(vertical):
    plant = MULTI_PLANTS["two-link-arm"].build({"vertical": vertical, "upper_link_length_m": 0.4})
    kin = Kinematics.of(plant)
    rng = np.random.default_rng(1)
    q = rng.uniform(-2.0, 2.0, size=(5, 2))
    tool = kin.forward(q)
    for qi, ti in zip(q, tool, strict=True):
        plant.data.qpos[[io.qpos_adr for io in plant.ios]] = qi
        mujoco.mj_forward(plant.model, plant.data)
        world = plant.data.body("payload").xpos
        # the arm's plane: x, and z when vertical (positive = up), else y
        np.testing.assert_allclose(ti, [world[0], world[2] if vertical else world[1]], atol=1e-12)


@pytest.mark.parametrize("elbow", ["up", "down"])
def test_inverse_then_forward_kinematics_round_trip(built, elbow):
    kin = Kinematics.of(built["two-link-arm"])
    rng = np.random.default_rng(2)
    r = rng.uniform(0.1, 0.5, 50)
    a = rng.uniform(-3.0, 3.0, 50)
    xy = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    q = kin.inverse(xy, elbow)
    np.testing.assert_allclose(kin.forward(q), xy, atol=1e-12)
    assert np.all(q[:, 1] <= 0) if elbow == "up" else np.all(q[:, 1] >= 0)
    np.testing.assert_allclose(kin.inverse(kin.forward(q), elbow), q, atol=1e-9)


def test_elbow_up_puts_the_elbow_above_the_line_to_the_tool(built):
    kin = Kinematics.of(built["two-link-arm"])
    up, down = kin.inverse([[0.4, 0.0]], "up")[0], kin.inverse([[0.4, 0.0]], "down")[0]
    assert math.sin(up[0]) > 0 > math.sin(down[0])  # the elbow's height, l1 sin q1
    assert up[1] == pytest.approx(-down[1])


def test_kinematics_refuse_bad_input(built):
    kin = Kinematics.of(built["two-link-arm"])
    with pytest.raises(ParameterError, match=r"out of the arm's reach.*0.05 <= r <= 0.55"):
        kin.inverse([[0.6, 0.0]])
    with pytest.raises(ParameterError, match="elbow must be one of 'up', 'down'; got elbow='left'"):
        kin.inverse([[0.4, 0.0]], "left")
    stage = Kinematics.of(built["xy-stage"])
    np.testing.assert_array_equal(stage.forward([[0.1, -0.2]]), [[0.1, -0.2]])


# --- paths and distances ------------------------------------------------------------------


def test_line_distance_is_the_nearest_point_not_the_synchronous_one():
    line = LinePath((0.0, 0.0), (0.1, 0.0))
    s = np.linspace(0, 0.1, 11)
    on = line.point(s)
    # points on the line, in any order, are at 0; points 7 um off it at 7 um
    np.testing.assert_allclose(line.distance(on[::-1]), 0.0, atol=1e-15)
    np.testing.assert_allclose(line.distance(on + np.array([0.0, 7e-6])), 7e-6, rtol=1e-9)
    # beyond the ends: the distance to the end point
    assert line.distance([[0.13, 0.04]])[0] == pytest.approx(0.05)
    assert line.length == pytest.approx(0.1)
    with pytest.raises(ParameterError, match="a line needs end != start"):
        LinePath((0.1, 0.1), (0.1, 0.1))


def test_circle_and_arc_distances():
    circle = CirclePath((0.01, -0.02), 0.03)
    pts = circle.point(np.linspace(0, circle.length, 40))
    np.testing.assert_allclose(circle.distance(pts), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.hypot(*(pts - circle.centre).T), 0.03, rtol=1e-12)
    outward = circle.centre + (pts - circle.centre) * (0.03 + 5e-6) / 0.03
    np.testing.assert_allclose(circle.distance(outward), 5e-6, rtol=1e-6)
    # a quarter arc: a point on the circle outside the sweep is as far as the nearer end
    arc = CirclePath((0.0, 0.0), 1.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(arc.end, [0.0, 1.0], atol=1e-15)
    assert arc.distance([[-1.0, 0.0]])[0] == pytest.approx(math.sqrt(2))
    assert arc.distance([[0.6, 0.8]])[0] == pytest.approx(0.0, abs=1e-15)
    clockwise = CirclePath((0.0, 0.0), 1.0, 0.0, -math.pi / 2)
    assert clockwise.distance([[0.6, -0.8]])[0] == pytest.approx(0.0, abs=1e-15)
    assert clockwise.distance([[0.6, 0.8]])[0] == pytest.approx(math.hypot(0.4, 0.8))
    with pytest.raises(ParameterError, match=r"0 < \|sweep_rad\| <= 2 pi"):
        CirclePath((0.0, 0.0), 1.0, 0.0, 7.0)
    with pytest.raises(ParameterError, match="radius must be a finite number > 0"):
        CirclePath((0.0, 0.0), 0.0)


def test_polyline_distance_equals_the_exact_line_distance():
    line = LinePath((0.0, 0.0), (0.3, 0.1))
    poly = PolylinePath(line.point(np.linspace(0, line.length, 7)))
    pts = np.random.default_rng(3).uniform(-0.1, 0.4, size=(200, 2))
    np.testing.assert_allclose(poly.distance(pts), line.distance(pts), atol=1e-12)
    assert poly.length == pytest.approx(line.length)


@pytest.mark.parametrize("kind", ["trapezoidal", "s_curve"])
def test_feed_law_covers_the_path_within_its_limits(kind):
    law = FeedLaw(0.05, 0.2, 2.0, kind, 100.0 if kind == "s_curve" else None)
    t = np.linspace(-0.01, law.duration + 0.01, 20001)
    s = law(t)
    v = np.diff(s) / np.diff(t)
    assert s[0] == 0.0 and s[-1] == pytest.approx(0.05)
    assert np.all(np.diff(s) >= -1e-15) and v.max() <= 0.2 + 1e-9
    a = np.diff(v) / np.diff(t[1:])
    assert np.abs(a).max() <= 2.0 * 1.01
    # 0.05 m at 0.2 m/s, 2 m/s^2: 0.1 s ramps, 0.15 s cruise (plus the S-curve window)
    assert law.duration == pytest.approx(0.35 + (0.02 if kind == "s_curve" else 0.0))


# --- contours -----------------------------------------------------------------------------

PATHS = {
    "xy-stage": (LinePath((-0.02, 0.01), (0.02, -0.01)), CirclePath((0.01, 0.0), 0.01, 1.0, -5.0)),
    "two-link-arm": (LinePath((0.4, -0.03), (0.37, 0.03)), CirclePath((0.4, 0.0), 0.02)),
}


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("plant", PLANTS)
def test_contour_commands_lie_on_the_path(built, family, plant):
    loop = machine(built, plant, family)
    for path in PATHS[plant]:
        for mode in CONTOUR_MODES[family].choices:
            cmd = contour(loop, path, 0.1, 2.0, mode=mode)
            assert {p.n_ticks for p in cmd.profiles} == {cmd.n_ticks}
            tool = cmd.kinematics.forward(cmd.joint_positions(cmd.commanded_counts()))
            # within the encoder's resolution at the tool point (PMAC: plus the segment
            # interpolation's departure, a few um at these speeds)
            assert path.distance(tool).max() < 3e-6, (family, plant, mode)
            np.testing.assert_allclose(tool[0], path.start, atol=2e-6)
            np.testing.assert_allclose(tool[-1], path.end, atol=2e-6)
            first, end = cmd.motion
            assert end == cmd.n_ticks and first == round(0.02 / loop.dt)
            # it moves: the tool point travels the path's length, to the encoder's resolution
            assert np.sum(np.hypot(*np.diff(tool, axis=0).T)) >= 0.99 * path.length


def test_pmac_linear_segments_cut_the_chord_of_a_circle(built):
    """PMAC-C1 'linear': the commanded tool point between segment points is on the chord,
    inside the circle by up to ``R (1 - cos(theta / 2))``; 'cubic' stays much closer."""
    loop = machine(built, "xy-stage", "pmac")
    circle = CirclePath((0.0, 0.0), 0.01)
    sag = 0.01 * (1 - math.cos(0.1 * 0.005 / 0.01 / 2))  # 0.1 m/s over 5 ms segments
    found = {}
    for mode in ("linear", "cubic"):
        cmd = contour(loop, circle, 0.1, 0.5, mode=mode, segmentation_s=0.005)
        tool = cmd.kinematics.forward(cmd.joint_positions(cmd.commanded_counts()))
        found[mode] = circle.distance(tool).max()
    assert found["linear"] == pytest.approx(sag, rel=0.15)
    assert found["cubic"] < 0.1 * found["linear"]


def test_contour_error_of_a_perfect_and_an_offset_tracking(built):
    loop = machine(built, "xy-stage", "pmd")
    line = LinePath((0.01, -0.02), (0.01, 0.02))  # along y
    cmd = contour(loop, line, 0.2, 2.0)
    whole = np.stack([p.position for p in cmd.profiles])
    perfect = contour_error(cmd, whole)
    assert perfect.n_ticks == cmd.n_ticks - cmd.motion[0]
    assert perfect.max_um < 1.0  # one count of y is 1 um, of x 0.08 um
    offset = whole.copy()
    offset[0] += 131  # x: 131 counts of 1 / 13107200 m = 9.994 um off the line
    err = contour_error(cmd, offset)
    expected = 131 / built["xy-stage"].ios[0].counts_per_unit * 1e6
    assert err.max_um == pytest.approx(expected, abs=0.08)
    assert err.rms_um == pytest.approx(expected, abs=0.08)
    # a lag along the path is no contouring error: the same positions 30 ticks late
    late = np.concatenate([np.repeat(whole[:, :1], 30, axis=1), whole[:, :-30]], axis=1)
    assert contour_error(cmd, late).max_um < 1.0
    # an episode that ran part of its ticks is measured over those
    assert contour_error(cmd, whole, n_run=cmd.motion[0] + 10).n_ticks == 10


def test_contour_refuses_bad_input(built):
    loop = machine(built, "two-link-arm", "pmd")
    with pytest.raises(ParameterError, match=r"PMD-C1 contour mode must be one of 'fine', "):
        contour(loop, PATHS["two-link-arm"][0], 0.1, 2.0, mode="cubic")
    with pytest.raises(ParameterError, match="out of the arm's reach"):
        contour(loop, LinePath((0.4, 0.0), (0.6, 0.0)), 0.1, 2.0)
    with pytest.raises(ParameterError, match="speed must be a finite number > 0; got speed=0"):
        contour(loop, PATHS["two-link-arm"][0], 0, 2.0)
    with pytest.raises(ParameterError, match="dwell_s must be a finite number >= 0"):
        contour(loop, PATHS["two-link-arm"][0], 0.1, 2.0, dwell_s=-1.0)
    stage = machine(built, "xy-stage", "pmd")
    with pytest.raises(ParameterError, match=r"axis 'x' at 0.3.*-0.196 <= x <= 0.196"):
        contour(stage, LinePath((0.0, 0.0), (0.3, 0.0)), 0.1, 2.0)


# --- coordinated moves --------------------------------------------------------------------


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("plant", PLANTS)
@pytest.mark.parametrize("kind", ["trapezoidal", "s_curve"])
def test_coordinated_move_axes_arrive_on_one_tick(built, family, plant, kind):
    loop = machine(built, plant, family)
    targets = (0.05, 0.01) if plant == "xy-stage" else (0.5, -0.3)
    vmax, amax = ((0.5, 0.4), (5.0, 5.0)) if plant == "xy-stage" else ((2.0, 3.0), (20.0, 30.0))
    jerk = tuple(200 * a for a in amax) if kind == "s_curve" else None
    cmd = coordinated_move(loop, targets, max_velocity=vmax, max_acceleration=amax, kind=kind,
                           jerk=jerk, settle_s=0.05)  # fmt: skip
    # every profile's move (the chip's own move_ticks: at rest on the target) ends on one
    # tick, and the axes keep step all the way: each one's fraction of its distance
    # travelled is the others' (the same shape, stretched in time)
    assert len(set(cmd.move_ticks)) == 1, cmd.move_ticks
    c = cmd.commanded_counts()
    progress = (c - c[:, :1]) / (c[:, -1:] - c[:, :1])
    assert np.abs(progress[0] - progress[1]).max() < 0.02
    for k, p in enumerate(cmd.profiles):
        assert p.position[-1] == round(targets[k] * cmd.counts_per_unit[k])
        assert p.n_ticks == cmd.move_ticks[0] + round(0.05 / loop.dt)
    # the axis that is not the slowest alone moved slower than its own limits allow
    alone = [coordinated_move(loop, [t if i == k else 0.0 for i, t in enumerate(targets)],
                              max_velocity=vmax, max_acceleration=amax, kind=kind, jerk=jerk,
                              settle_s=0.0).move_ticks[k] for k in range(2)]  # fmt: skip
    assert max(alone) == cmd.move_ticks[0] and min(alone) < cmd.move_ticks[0]


@pytest.mark.parametrize("family", FAMILIES)
def test_tool_point_move_through_the_inverse_kinematics(built, family):
    loop = machine(built, "two-link-arm", family)
    ends = {}
    for elbow in ("up", "down"):
        cmd = coordinated_move(loop, tool_target=(0.3, 0.2), elbow=elbow,
                               max_velocity=(2.0, 3.0), max_acceleration=(20.0, 30.0))  # fmt: skip
        q = cmd.joint_positions(cmd.commanded_counts())
        np.testing.assert_allclose(cmd.kinematics.forward(q[-1:])[0], (0.3, 0.2), atol=2e-6)
        ends[elbow] = q[-1]
        # the commanded tool path is the move's own: perfect tracking is on it
        whole = np.stack([p.position for p in cmd.profiles])
        assert contour_error(cmd, whole).max_um < 1.0
    assert ends["up"][1] < 0 < ends["down"][1]
    with pytest.raises(ParameterError, match="give exactly one of targets"):
        coordinated_move(loop, (0.1, 0.1), tool_target=(0.3, 0.2), max_velocity=(1, 1),
                         max_acceleration=(1, 1))  # fmt: skip
    with pytest.raises(ParameterError, match=r"max_velocity must give one value per axis \(2\)"):
        coordinated_move(loop, (0.1, 0.1), max_velocity=(1.0,), max_acceleration=(1, 1))


# --- through the N-axis loop --------------------------------------------------------------


@pytest.mark.parametrize("family", FAMILIES)
def test_a_contour_runs_from_its_start_configuration(built, family):
    loop = machine(built, "two-link-arm", family)
    cmd = contour(loop, LinePath((0.4, -0.01), (0.4, 0.01)), 0.05, 1.0, dwell_s=0.0,
                  settle_s=0.01)  # fmt: skip
    r = loop.run(list(cmd.profiles), start_counts=cmd.start_counts, start_qpos=cmd.start_qpos,
                 traces=True)  # fmt: skip
    actual = np.stack([t.actual for t in r.traces])
    # the encoders read the start positions at the start, so the error starts near 0
    assert np.all(np.abs(actual[:, 0] - np.array(cmd.start_counts)) <= 2)
    err = contour_error(cmd, actual, r.metrics[0].n_ticks)
    assert err.n_ticks == r.metrics[0].n_ticks and np.isfinite(err.max_um)
    assert err.rms_um <= err.max_um
    with pytest.raises(ValueError, match=r"give one start_qpos per axis \(2\); got 1"):
        loop.run(list(cmd.profiles), start_qpos=[0.1])


def test_a_jump_in_one_tick_is_refused_in_the_plant_s_own_terms(built):
    arm = MultiServoLoop(built["two-link-arm"], machine_params("MC2100", 2))
    with pytest.raises(
        ParameterError, match=r"moves axis '\w+' .* rad in one tick.*edges of the arm's reach"
    ):
        contour(arm, LinePath((0.3, -0.1), (0.3, 0.1)), 300.0, 1e9)
    stage = MultiServoLoop(built["xy-stage"], machine_params("MC2100", 2))
    with pytest.raises(
        ParameterError, match=r"moves axis 'x' .* m in one tick.*: lower speed=1000"
    ):
        contour(stage, LinePath((-0.15, 0.0), (0.15, 0.0)), 1000.0, 1e8)
