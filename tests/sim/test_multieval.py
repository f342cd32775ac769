"""The multi-axis evaluator (servogym.sim._multieval): per-axis metrics, the contouring error
and the documented cost, for every chip family of the registry."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from servogym.chips._family import families
from servogym.chips._space import ParameterError
from servogym.plants import MULTI_PLANTS
from servogym.sim import COST_CAP, move_cost
from servogym.sim._contour import CirclePath, LinePath
from servogym.sim._machine import machine_params
from servogym.sim._multieval import (
    DEFAULT_TASKS,
    ContourSpec,
    CoordinatedSpec,
    MultiCostWeights,
    MultiEvaluator,
    task_cost,
)
from tests.sim.test_runner import TWIN_PARAMS

SHORT = (
    CoordinatedSpec((0.5, 0.4), (5.0, 5.0), targets=(0.01, 0.004), settle_s=0.02),
    ContourSpec(LinePath((0.0, 0.0), (0.006, 0.004)), 0.1, 2.0, settle_s=0.02),
)


def gains(family: str, n_axes: int = 2):
    model, values = TWIN_PARAMS[family]
    return model, machine_params(model, n_axes, values)


@pytest.mark.parametrize("family", sorted(families()))
def test_every_family_gives_axis_metrics_contouring_error_and_the_documented_cost(family):
    model, params = gains(family)
    ev = MultiEvaluator("xy-stage", model, SHORT)
    e = ev.evaluate(params)
    assert not e.diverged and len(e.tasks) == 2
    for task in e.tasks:
        assert len(task.metrics) == 2 and task.axis == -1
        assert task.contour.n_ticks == task.commands.n_ticks - task.commands.motion[0]
        assert 0 < task.contour.rms_um <= task.contour.max_um
        w = MultiCostWeights()
        spans = task.commands.distances_counts
        axes = [move_cost(m, d, task.commands.settle_s, w.axis)
                for m, d in zip(task.metrics, spans, strict=True)]  # fmt: skip
        expected = np.mean(axes) + (task.contour.rms_um + 0.1 * task.contour.max_um) / 10.0
        assert task.cost == pytest.approx(min(expected, COST_CAP), rel=1e-12)
        assert task.cost == task_cost(task.metrics, task.commands, task.contour)
    assert e.cost == pytest.approx(np.mean([t.cost for t in e.tasks]))
    assert e.max_contour_error_um == max(t.contour.max_um for t in e.tasks)
    summary = e.summary()
    assert summary["tasks"][1]["contour"]["max_um"] == e.tasks[1].contour.max_um
    # the same sets again: the same cost to the bit (the profiles are cached, the loop reset)
    assert ev.evaluate(params).cost == e.cost


def test_contour_weights_enter_the_cost_as_documented():
    model, params = gains("pmac")
    ev = MultiEvaluator("xy-stage", model, SHORT[1:])
    task = ev.evaluate(params).tasks[0]
    without = MultiCostWeights(contour_rms=0.0, contour_peak=0.0)
    base = task_cost(task.metrics, task.commands, task.contour, without)
    doubled = task_cost(task.metrics, task.commands, task.contour,
                        MultiCostWeights(contour_ref_um=5.0))  # fmt: skip
    assert base < task.cost < doubled
    assert doubled - base == pytest.approx(2 * (task.cost - base))
    with pytest.raises(ParameterError, match="contour_ref_um must be a finite number > 0"):
        MultiCostWeights(contour_ref_um=0.0)
    with pytest.raises(ParameterError, match="contour_rms must be a finite number >= 0"):
        MultiCostWeights(contour_rms=-1.0)


def test_contouring_error_is_at_most_the_synchronous_error():
    """The nearest point of the path is never farther than the point commanded at the same
    tick, and a lagging axis pair is much closer to the path than to that point."""
    model, params = gains("pmac")
    circle = CirclePath((0.0, 0.0), 0.005)
    ev = MultiEvaluator("xy-stage", model, [ContourSpec(circle, 0.05, 1.0, settle_s=0.01)])
    task = ev.evaluate(params, traces=True).tasks[0]
    first = task.commands.motion[0]
    cpu = np.array(task.commands.counts_per_unit)[:, None]
    error = np.stack([t.error for t in task.traces])[:, first:] / cpu
    synchronous = np.hypot(*error) * 1e6
    actual = np.stack([t.actual for t in task.traces])
    tool = task.commands.kinematics.forward(task.commands.joint_positions(actual[:, first:]))
    nearest = circle.distance(tool) * 1e6
    assert task.contour.max_um == pytest.approx(nearest.max())
    assert np.all(nearest <= synchronous + 1.0)  # + the commanded point's 1 um resolution
    assert task.contour.rms_um < 0.5 * np.sqrt(np.mean(synchronous**2))


def test_a_heavier_payload_and_a_weaker_gain_each_raise_the_cost():
    model, params = gains("pmac")
    ev = MultiEvaluator("xy-stage", model, SHORT)
    nominal = ev.evaluate(params)
    assert not nominal.diverged and nominal.cost < COST_CAP  # below the cap: comparable
    heavy = ev.evaluate(params, {"payload_kg": 10.0})
    assert not heavy.diverged and nominal.cost < heavy.cost
    assert heavy.max_contour_error_um > nominal.max_contour_error_um
    weak = [dataclasses.replace(p, proportional_gain=p.proportional_gain // 2) for p in params]
    again = ev.evaluate(weak, {"payload_kg": MULTI_PLANTS["xy-stage"].validate({})["payload_kg"]})
    assert not again.diverged and nominal.cost < again.cost < COST_CAP


def test_plant_values_reach_every_axis_setting_of_the_loop():
    """A screw lead changed through ``evaluate(plant_values=)`` changes the encoder counts per
    metre, the profiles and the loop alike: the cost of a fresh evaluator of that plant."""
    model, params = gains("pmac")
    ev = MultiEvaluator("xy-stage", model, SHORT)
    nominal = ev.evaluate(params).cost
    longer = {"x_screw_lead_m": 0.02, "x_peak_current_a": 5.0}
    edited = ev.evaluate(params, longer)
    fresh = MultiEvaluator("xy-stage", model, SHORT, plant_values=longer).evaluate(params)
    assert edited.cost == fresh.cost != nominal
    for a, b in zip(edited.tasks, fresh.tasks, strict=True):
        assert a.metrics == b.metrics and a.contour == b.contour


@pytest.mark.parametrize("plant", sorted(MULTI_PLANTS))
def test_default_tasks_fit_the_plants(plant):
    model, params = gains("pmac")
    ev = MultiEvaluator(plant, model)
    assert ev.tasks == DEFAULT_TASKS[plant]
    ev.loop.set_params(params)
    for cmd in ev.commands():
        assert {p.n_ticks for p in cmd.profiles} == {cmd.n_ticks}
        assert min(cmd.distances_counts) > 0


def test_bad_input_names_the_parameter():
    with pytest.raises(ParameterError, match="plant must be a multi-axis plant, one of "):
        MultiEvaluator("rotary", "MC2100")
    with pytest.raises(ParameterError, match="tasks must hold at least one"):
        MultiEvaluator("xy-stage", "MC2100", ())
    ev = MultiEvaluator("xy-stage", "MC2100", SHORT[1:], contour_mode="cubic")
    with pytest.raises(ParameterError, match="PMD-C1 contour mode must be one of"):
        ev.evaluate(gains("pmd")[1])
