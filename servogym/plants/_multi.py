"""Multi-axis plant families: several motors, one MuJoCo model, coupled axes.

A :class:`MultiAxisPlantFamily` is a :class:`~servogym.plants.PlantFamily` (same parameters,
validation, sampling and ranges) whose model has one joint, one actuator, one encoder and one
amplifier per axis, named after the axis (:attr:`MultiAxisPlantFamily.axes`). Its compiled
instance, a :class:`MultiAxisPlant`, gives one :class:`~servogym.plants.AxisIO` per axis
(``plant.ios``) and is edited in place by ``set_params`` exactly as a single-axis plant (the
two paths from numbers to model, through the compiler and into the compiled arrays, give
bit-identical trajectories: tests/plants/test_multi.py).

Two families (:data:`MULTI_PLANTS`, docs/plants.md "Multi-axis plants"):

* ``two-link-arm``: a shoulder and an elbow, each a geared motor; the shoulder's inertia
  changes several-fold with the elbow angle, the elbow's motion torques the shoulder, and
  mounted vertically (``vertical=1``) gravity acts on both joints.
* ``xy-stage``: an X axis carrying the Y axis (so X moves Y's carriage and payload), each a
  ball-screw or a linear-motor axis (``x_drive``, ``y_drive``).

Parameters of an axis carry its name as a prefix (``shoulder_gear_ratio``, ``x_screw_lead_m``).
:func:`~servogym.plants.get_plant` (single-axis families) refuses them in one line;
``servogym.sim.MultiServoLoop`` runs them, and ``servogym tune``, ``check`` and ``export`` and
the machine env ids (``servogym.envs``) take them through their multi-axis paths.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np

from servogym.plants._base import (
    _STATE_SIG,
    COMMAND_FULL_SCALE,
    DEFAULT_TIMESTEP_S,
    FRICTION_SOLIMP,
    FRICTION_SOLREF,
    GRAVITY_MPS2,
    LIMIT_SOLREF,
    AxisIO,
    Plant,
    PlantFamily,
    PlantParam,
    _BodyNumbers,
    _check_timestep,
    _GeomNumbers,
    _JointNumbers,
    _set_coef,
    _set_statistics,
)
from servogym.plants._families import (
    _X_TO_Z,
    LINK_RADIUS_M,
    PAYLOAD_RADIUS_M,
    _add_body,
    _add_geom,
    _box_inertia,
    _motor_params,
)

DRIVE_BALL_SCREW, DRIVE_LINEAR_MOTOR = 0, 1
"""Values of an ``xy-stage`` axis's ``*_drive`` parameter."""

_HORIZONTAL_BASE = (math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0)
"""Base of a horizontal (SCARA) two-link arm: -90 deg about x, so the joint axes (local -y)
point up (+z) and gravity acts along them (no torque on either joint)."""

_VERTICAL_BASE = (1.0, 0.0, 0.0, 0.0)
"""Base of a vertical two-link arm: joint axes along -y (horizontal), positive angle = up."""


@dataclasses.dataclass(frozen=True)
class _MultiNumbers:
    """Every model number of a multi-axis instance that depends on the parameter values."""

    bodies: dict[str, _BodyNumbers]
    body_quats: dict[str, tuple[float, float, float, float]]
    joints: dict[str, _JointNumbers]
    geoms: dict[str, _GeomNumbers]
    gears: dict[str, float]
    """Actuator gear by axis (joint force or torque per unit of ``ctrl``)."""
    peak_efforts: dict[str, float]
    """``ctrlrange`` half-width by axis: peak motor torque (N*m) or force (N)."""


def _axis_params(axis: str, params: list[PlantParam], note: str = "") -> list[PlantParam]:
    """``params`` renamed for one axis: ``shoulder_gear_ratio``, doc prefixed ``Shoulder:``."""
    label = axis.capitalize() if len(axis) > 1 else axis.upper()
    return [
        dataclasses.replace(p, name=f"{axis}_{p.name}", doc=f"{label}{note}: {p.doc}")
        for p in params
    ]


class MultiAxisPlantFamily(PlantFamily):
    """A plant family with one motor, encoder and amplifier per axis.

    Subclasses set :attr:`axes`, :attr:`joint_units` and :attr:`moves` and implement
    :meth:`_skeleton` (the bodies and one joint per axis, named as the axis),
    :meth:`_multi_numbers` and :meth:`_axis_transmission`.

    Attributes:
        axes: Axis names, in axis order (axis 0 first); each names its joint and actuator.
        joint_units: Unit of each axis's joint, ``"rad"`` or ``"m"``.
        moves: The default moves of each axis as ``(distance, max_velocity,
            max_acceleration, settle_s)`` tuples in joint units, run by all axes together
            (:meth:`default_moves`).
    """

    axes: tuple[str, ...]
    joint_units: tuple[str, ...]
    moves: tuple[tuple[tuple[float, float, float, float], ...], ...]

    @property
    def n_axes(self) -> int:
        """Number of axes (motors)."""
        return len(self.axes)

    def default_moves(self) -> tuple[tuple[Any, ...], ...]:
        """Per axis, the default moves as ``servogym.sim.MoveSpec`` (joint units)."""
        from servogym.sim._scenario import MoveSpec

        return tuple(tuple(MoveSpec(*m) for m in axis) for axis in self.moves)

    def build(
        self, values: Mapping[str, Any] | None = None, *, timestep_s: float = DEFAULT_TIMESTEP_S
    ) -> MultiAxisPlant:
        """Compile an instance (see :meth:`PlantFamily.build`)."""
        full = self.validate(values)
        timestep_s = _check_timestep(timestep_s)
        spec = self._make_spec(full, timestep_s)
        return MultiAxisPlant(self, full, spec, spec.compile())

    def _make_spec(self, values: Mapping[str, Any], timestep_s: float) -> mujoco.MjSpec:
        spec = mujoco.MjSpec()
        spec.modelname = self.name
        spec.compiler.degree = False
        spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
        spec.compiler.autolimits = False
        spec.option.timestep = timestep_s
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.gravity = [0.0, 0.0, -GRAVITY_MPS2]
        spec.option.disableflags |= (
            mujoco.mjtDisableBit.mjDSBL_CONTACT
            | mujoco.mjtDisableBit.mjDSBL_AUTORESET
            | mujoco.mjtDisableBit.mjDSBL_REFSAFE
        )
        self._skeleton(spec)
        for joint in spec.joints:
            joint.limited = mujoco.mjtLimited(int(joint.name in self.axes))
            joint.solref_limit = list(LIMIT_SOLREF)
            joint.solref_friction = list(FRICTION_SOLREF)
            joint.solimp_friction = list(FRICTION_SOLIMP)
        for geom in spec.geoms:
            geom.contype = 0
            geom.conaffinity = 0
        for axis in self.axes:
            spec.add_actuator(
                name=axis,
                trntype=mujoco.mjtTrn.mjTRN_JOINT,
                target=axis,
                ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
            )
        _write_spec(spec, self._multi_numbers(values))
        return spec

    def _numbers(self, values: Mapping[str, Any]) -> Any:
        return self._multi_numbers(values)

    def _multi_numbers(self, values: Mapping[str, Any]) -> _MultiNumbers:
        """Every model number that depends on the (validated, complete) parameter values."""
        raise NotImplementedError

    def _axis_transmission(self, values: Mapping[str, Any], axis: str) -> tuple[float, float]:
        """Motor angle per joint unit and encoder counts per joint unit of one axis."""
        raise NotImplementedError

    def _axis_constant(self, values: Mapping[str, Any], axis: str) -> float:
        """Motor torque (N*m) or force (N) per ampere of one axis."""
        return float(values[f"{axis}_torque_constant_nm_per_a"])

    def _transmission(self, values: Mapping[str, Any]) -> tuple[float, float]:
        return self._axis_transmission(values, self.axes[0])

    def axis_ios(self, model: mujoco.MjModel, values: Mapping[str, Any]) -> tuple[AxisIO, ...]:
        """One :class:`AxisIO` per axis, in axis order."""
        out = []
        for axis in self.axes:
            joint = model.joint(axis)
            ratio, counts_per_unit = self._axis_transmission(values, axis)
            peak = float(values[f"{axis}_peak_current_a"])
            out.append(
                AxisIO(
                    qpos_adr=int(joint.qposadr[0]),
                    qvel_adr=int(joint.dofadr[0]),
                    ctrl_index=int(model.actuator(axis).id),
                    counts_per_unit=counts_per_unit,
                    motor_rad_per_unit=ratio,
                    travel_min=float(joint.range[0]),
                    travel_max=float(joint.range[1]),
                    amp_amps_per_count=peak / COMMAND_FULL_SCALE,
                    peak_current_a=peak,
                    torque_constant_nm_per_a=self._axis_constant(values, axis),
                    current_bandwidth_hz=float(values[f"{axis}_current_bandwidth_hz"]),
                    start_qpos=float(model.qpos0[joint.qposadr[0]]),
                )
            )
        return tuple(out)

    def _axis_io(self, model: mujoco.MjModel, values: Mapping[str, Any]) -> AxisIO:
        raise TypeError(
            f"the {self.name!r} plant has {self.n_axes} axes ({', '.join(self.axes)}): "
            "use plant.ios (one AxisIO per axis), not plant.io"
        )


def _write_spec(spec: mujoco.MjSpec, n: _MultiNumbers) -> None:
    """Write the numbers into the spec (the path through the compiler)."""
    for name, b in n.bodies.items():
        body = spec.body(name)
        body.mass = b.mass
        body.inertia = list(b.inertia)
        body.ipos = list(b.ipos)
        body.pos = list(b.pos)
    for name, q in n.body_quats.items():
        spec.body(name).quat = list(q)
    for name, j in n.joints.items():
        joint = spec.joint(name)
        joint.armature = j.armature
        _set_coef(joint, "damping", j.damping)
        _set_coef(joint, "stiffness", j.stiffness)
        joint.frictionloss = j.frictionloss
        joint.range = list(j.range)
    for name, g in n.geoms.items():
        geom = spec.geom(name)
        geom.pos = list(g.pos)
        geom.size = list(g.size)
    for name, gear in n.gears.items():
        actuator = spec.actuator(name)
        actuator.gear = [gear, 0.0, 0.0, 0.0, 0.0, 0.0]
        peak = n.peak_efforts[name]
        actuator.ctrlrange = [-peak, peak]


def _write_model(model: mujoco.MjModel, n: _MultiNumbers) -> None:
    """Write the numbers into the compiled model's arrays (the in-place path)."""
    for name, b in n.bodies.items():
        i = model.body(name).id
        model.body_mass[i] = b.mass
        model.body_inertia[i] = b.inertia
        model.body_ipos[i] = b.ipos
        model.body_pos[i] = b.pos
    for name, q in n.body_quats.items():
        model.body_quat[model.body(name).id] = q
    for name, j in n.joints.items():
        joint = model.joint(name)
        dof = joint.dofadr[0]
        model.dof_armature[dof] = j.armature
        model.dof_damping[dof] = j.damping
        model.dof_frictionloss[dof] = j.frictionloss
        model.jnt_stiffness[joint.id] = j.stiffness
        model.jnt_range[joint.id] = j.range
    for name, g in n.geoms.items():
        i = model.geom(name).id
        model.geom_pos[i] = g.pos
        model.geom_size[i] = g.size
    for name, gear in n.gears.items():
        i = model.actuator(name).id
        model.actuator_gear[i, 0] = gear
        peak = n.peak_efforts[name]
        model.actuator_ctrlrange[i] = (-peak, peak)


class MultiAxisPlant(Plant):
    """One compiled multi-axis instance, edited in place between episodes.

    As :class:`~servogym.plants.Plant`, with :attr:`ios` (one :class:`AxisIO` per axis, in
    the family's axis order) instead of ``io``.
    """

    def __init__(
        self,
        family: MultiAxisPlantFamily,
        values: dict[str, float | int],
        spec: mujoco.MjSpec,
        model: mujoco.MjModel,
    ) -> None:
        self.family = family
        self.values = dict(values)
        self.spec = spec
        self.model = model
        self.data = mujoco.MjData(model)
        self.ios = family.axis_ios(model, self.values)
        self._state_buffer = np.zeros(mujoco.mj_stateSize(model, _STATE_SIG))
        self.reset()

    @property
    def io(self) -> AxisIO:  # type: ignore[override]
        """Refused: a multi-axis plant has one AxisIO per axis (:attr:`ios`)."""
        return self.family._axis_io(self.model, self.values)

    def set_params(
        self, values: Mapping[str, Any] | None = None, *, keep_state: bool = False, **kw: Any
    ) -> None:
        """Change the instance in place (see :meth:`Plant.set_params`); ``ios`` follows."""
        updates = dict(values or {})
        updates.update(kw)
        full = self.family.validate({**self.values, **updates})
        numbers_ = self.family._multi_numbers(full)  # type: ignore[attr-defined]
        if keep_state:
            mujoco.mj_getState(self.model, self.data, self._state_buffer, _STATE_SIG)
        _write_spec(self.spec, numbers_)
        _write_model(self.model, numbers_)
        mujoco.mj_setConst(self.model, self.data)
        _set_statistics(self.model)
        self.values = full
        self.ios = self.family.axis_ios(self.model, full)  # type: ignore[attr-defined]
        self.reset()
        if keep_state:
            mujoco.mj_setState(self.model, self.data, self._state_buffer, _STATE_SIG)
            mujoco.mj_forward(self.model, self.data)

    def __repr__(self) -> str:
        axes = ", ".join(self.family.axes)  # type: ignore[attr-defined]
        return f"<MultiAxisPlant {self.family.name!r} axes ({axes}) timestep_s={self.timestep_s:g}>"


# --- two-link arm -------------------------------------------------------------------------


def _link_friction(axis: str) -> list[PlantParam]:
    return [
        PlantParam(
            f"{axis}_viscous_friction_nms",
            "N*m*s/rad",
            0.01,
            1e-4,
            0.5,
            "loguniform",
            f"Viscous friction of the {axis} joint, at the link (joint damping).",
            randomised=True,
        ),
        PlantParam(
            f"{axis}_coulomb_friction_nm",
            "N*m",
            0.3,
            0.01,
            3.0,
            "loguniform",
            f"Coulomb friction torque of the {axis} joint, at the link (joint frictionloss).",
            randomised=True,
        ),
    ]


def _travel(axis: str, unit: str, nominal: float, widest: float, narrowest: float, what: str):
    return [
        PlantParam(
            f"{axis}_travel_min_{unit}",
            unit,
            -nominal,
            -widest,
            -narrowest,
            "uniform",
            f"Lower hard travel limit (end stop) of the {what}; the start position is 0.",
            randomised=False,
        ),
        PlantParam(
            f"{axis}_travel_max_{unit}",
            unit,
            nominal,
            narrowest,
            widest,
            "uniform",
            f"Upper hard travel limit (end stop) of the {what}.",
            randomised=False,
        ),
    ]


def _rod(mass: float, length: float) -> _BodyNumbers:
    """A uniform rod along x from the joint, of ``mass`` and ``length``."""
    r = LINK_RADIUS_M
    transverse = mass * (3.0 * r * r + length * length) / 12.0
    return _BodyNumbers(
        mass=mass, inertia=(0.5 * mass * r * r, transverse, transverse), ipos=(0.5 * length, 0, 0)
    )


class TwoLinkArmFamily(MultiAxisPlantFamily):
    """Two revolute joints in series, each with its own geared motor; a payload at the tip."""

    name = "two-link-arm"
    axes = ("shoulder", "elbow")
    joint_units = ("rad", "rad")
    joint_unit = "rad"
    load_param = "payload_kg"
    position_stages = True  # the mass matrix changes with the elbow angle
    # per axis: (distance, max_velocity, max_acceleration, settle_s), run together
    moves = (
        ((0.6, 2.0, 20.0, 0.15), (-0.6, 2.0, 20.0, 0.15)),
        ((0.8, 3.0, 30.0, 0.15), (-0.8, 3.0, 30.0, 0.15)),
    )
    description = (
        "Two links in series: hinge 'shoulder' at the base and hinge 'elbow' between the "
        "links, each driven by its own motor through its own gearbox (rotor inertia "
        "reflected as armature rotor_inertia_kgm2*gear_ratio^2), a payload at the tip. "
        "Angles in rad, 0 = both links stretched along x. vertical=0: mounted horizontally "
        "(a SCARA; joint axes vertical, no gravity torque); vertical=1: in a vertical plane, "
        "positive = up, gravity on both joints. The shoulder's inertia changes several-fold "
        "with the elbow angle and each joint's motion torques the other."
    )
    params = (
        PlantParam(
            "payload_kg",
            "kg",
            0.5,
            0.0,
            5.0,
            "uniform",
            "Mass of the payload at the tip of the fore link (a small sphere).",
            randomised=True,
            sample_range=(0.0, 2.0),
        ),
        PlantParam(
            "vertical",
            "1",
            0,
            0,
            1,
            "uniform",
            "Mounting: 0 = horizontal (SCARA, no gravity torque), 1 = vertical plane "
            "(gravity on both joints).",
            randomised=False,
            integer=True,
        ),
        PlantParam(
            "upper_link_mass_kg",
            "kg",
            1.0,
            0.1,
            5.0,
            "loguniform",
            "Mass of the upper link (shoulder to elbow, a uniform rod; the elbow motor's "
            "mass included).",
            randomised=False,
        ),
        PlantParam(
            "upper_link_length_m",
            "m",
            0.3,
            0.05,
            0.8,
            "loguniform",
            "Length of the upper link, shoulder axis to elbow axis.",
            randomised=False,
        ),
        PlantParam(
            "fore_link_mass_kg",
            "kg",
            0.6,
            0.05,
            3.0,
            "loguniform",
            "Mass of the fore link (elbow to tip, a uniform rod).",
            randomised=False,
        ),
        PlantParam(
            "fore_link_length_m",
            "m",
            0.25,
            0.05,
            0.8,
            "loguniform",
            "Length of the fore link, elbow axis to the payload.",
            randomised=False,
        ),
        PlantParam(
            "shoulder_gear_ratio",
            "1",
            50.0,
            5.0,
            160.0,
            "loguniform",
            "Shoulder gearbox ratio: motor revolutions per joint revolution.",
            randomised=False,
        ),
        PlantParam(
            "elbow_gear_ratio",
            "1",
            30.0,
            5.0,
            160.0,
            "loguniform",
            "Elbow gearbox ratio: motor revolutions per joint revolution.",
            randomised=False,
        ),
        *_link_friction("shoulder"),
        *_link_friction("elbow"),
        *_axis_params("shoulder", _motor_params()),
        *_axis_params("elbow", _motor_params()),
        *_travel("shoulder", "rad", 2.5, 3.1, 1.0, "shoulder (0 = upper link along x)"),
        *_travel("elbow", "rad", 2.5, 3.0, 1.0, "elbow (0 = links in line)"),
    )

    def _skeleton(self, spec: mujoco.MjSpec) -> None:
        base = _add_body(spec.worldbody, "base")
        base.mass = 0.0
        upper = _add_body(base, "upper_link")
        upper.add_joint(name="shoulder", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, -1, 0])
        _add_geom(upper, "upper_link", mujoco.mjtGeom.mjGEOM_CAPSULE, _X_TO_Z)
        fore = _add_body(upper, "fore_link")
        fore.add_joint(name="elbow", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, -1, 0])
        _add_geom(fore, "fore_link", mujoco.mjtGeom.mjGEOM_CAPSULE, _X_TO_Z)
        payload = _add_body(fore, "payload")
        _add_geom(payload, "payload", mujoco.mjtGeom.mjGEOM_SPHERE)

    def _multi_numbers(self, v: Mapping[str, Any]) -> _MultiNumbers:
        l1, l2, m_p = v["upper_link_length_m"], v["fore_link_length_m"], v["payload_kg"]
        sphere = 0.4 * m_p * PAYLOAD_RADIUS_M * PAYLOAD_RADIUS_M
        joints = {}
        for axis in self.axes:
            n = v[f"{axis}_gear_ratio"]
            joints[axis] = _JointNumbers(
                armature=v[f"{axis}_rotor_inertia_kgm2"] * n * n,
                damping=v[f"{axis}_viscous_friction_nms"],
                frictionloss=v[f"{axis}_coulomb_friction_nm"],
                range=(v[f"{axis}_travel_min_rad"], v[f"{axis}_travel_max_rad"]),
            )
        return _MultiNumbers(
            bodies={
                "base": _BodyNumbers(mass=0.0, inertia=(0.0, 0.0, 0.0)),
                "upper_link": _rod(v["upper_link_mass_kg"], l1),
                "fore_link": dataclasses.replace(
                    _rod(v["fore_link_mass_kg"], l2), pos=(l1, 0.0, 0.0)
                ),
                "payload": _BodyNumbers(
                    mass=m_p, inertia=(sphere, sphere, sphere), pos=(l2, 0.0, 0.0)
                ),
            },
            body_quats={"base": _VERTICAL_BASE if v["vertical"] else _HORIZONTAL_BASE},
            joints=joints,
            geoms={
                "upper_link": _GeomNumbers((0.5 * l1, 0.0, 0.0), (LINK_RADIUS_M, 0.5 * l1, 0.0)),
                "fore_link": _GeomNumbers((0.5 * l2, 0.0, 0.0), (LINK_RADIUS_M, 0.5 * l2, 0.0)),
                "payload": _GeomNumbers((0.0, 0.0, 0.0), (PAYLOAD_RADIUS_M, 0.0, 0.0)),
            },
            gears={a: float(v[f"{a}_gear_ratio"]) for a in self.axes},
            peak_efforts={
                a: v[f"{a}_torque_constant_nm_per_a"] * v[f"{a}_peak_current_a"] for a in self.axes
            },
        )

    def _axis_transmission(self, v: Mapping[str, Any], axis: str) -> tuple[float, float]:
        n = v[f"{axis}_gear_ratio"]
        return n, v[f"{axis}_encoder_counts_per_rev"] * n / (2.0 * math.pi)

    @staticmethod
    def mass_matrix(values: Mapping[str, Any], elbow_rad: float) -> np.ndarray:
        """The joint-space inertia (kg*m^2, armature included) in closed form.

        The textbook two-link result with rods of mass ``m1, m2`` and lengths ``l1, l2``
        (centres at half length, transverse moments ``m*(3r^2 + l^2)/12`` about their
        centres), a point payload ``m_p`` (plus its sphere's moment) at the tip:

            M11 = a + 2 b cos(q2),  M12 = M21 = c + b cos(q2),  M22 = c  (+ armatures)

        with ``c = I2 + m2 (l2/2)^2 + m_p l2^2 + I_p``, ``b = (m2 l2/2 + m_p l2) l1`` and
        ``a = I1 + m1 (l1/2)^2 + (m2 + m_p) l1^2 + c``. It depends on the elbow angle only.

        Args:
            values: A complete set of ``two-link-arm`` parameters.
            elbow_rad: The elbow angle (rad).
        """
        m1, l1 = values["upper_link_mass_kg"], values["upper_link_length_m"]
        m2, l2 = values["fore_link_mass_kg"], values["fore_link_length_m"]
        m_p = values["payload_kg"]
        r = LINK_RADIUS_M
        i1 = m1 * (3.0 * r * r + l1 * l1) / 12.0
        i2 = m2 * (3.0 * r * r + l2 * l2) / 12.0
        i_p = 0.4 * m_p * PAYLOAD_RADIUS_M**2
        c = i2 + m2 * (l2 / 2) ** 2 + m_p * l2 * l2 + i_p
        b = (m2 * l2 / 2 + m_p * l2) * l1
        a = i1 + m1 * (l1 / 2) ** 2 + (m2 + m_p) * l1 * l1 + c
        cos2 = math.cos(elbow_rad)
        arm = [values[f"{x}_rotor_inertia_kgm2"] * values[f"{x}_gear_ratio"] ** 2
               for x in ("shoulder", "elbow")]  # fmt: skip
        return np.array(
            [[a + 2 * b * cos2 + arm[0], c + b * cos2], [c + b * cos2, c + arm[1]]], dtype=float
        )


# --- X-Y stage ----------------------------------------------------------------------------


def _stage_axis(axis: str, carriage: tuple[float, float, float], drive: int) -> list[PlantParam]:
    """The parameters of one stage axis (either drive; the other's are kept, unused)."""
    what = f"{axis.upper()} axis"
    return [
        PlantParam(
            f"{axis}_drive",
            "1",
            drive,
            0,
            1,
            "uniform",
            f"Drive of the {what}: 0 = rotary motor and ball screw, 1 = linear motor "
            "(direct drive, linear scale).",
            randomised=False,
            integer=True,
        ),
        PlantParam(
            f"{axis}_carriage_mass_kg",
            "kg",
            *carriage,
            "loguniform",
            f"Moving mass of the {what}'s own carriage (table, nut or forcer), without what "
            "it carries.",
            randomised=False,
        ),
        PlantParam(
            f"{axis}_screw_lead_m",
            "m",
            0.01,
            0.002,
            0.04,
            "loguniform",
            f"Ball-screw lead of the {what}: travel per motor revolution (drive 0).",
            randomised=False,
        ),
        PlantParam(
            f"{axis}_force_constant_n_per_a",
            "N/A",
            30.0,
            5.0,
            200.0,
            "loguniform",
            f"Force constant of the {what}'s linear motor (drive 1).",
            randomised=False,
        ),
        PlantParam(
            f"{axis}_scale_counts_per_m",
            "counts/m",
            1e6,
            1e4,
            1e8,
            "loguniform",
            f"Resolution of the {what}'s linear scale, counts per metre (drive 1).",
            randomised=False,
        ),
        PlantParam(
            f"{axis}_viscous_friction_ns_per_m",
            "N*s/m",
            10.0,
            0.1,
            500.0,
            "loguniform",
            f"Viscous friction of the {what}'s guides (and screw), at its carriage.",
            randomised=True,
            sample_range=(0.1, 100.0),
        ),
        PlantParam(
            f"{axis}_coulomb_friction_n",
            "N",
            5.0,
            0.1,
            50.0,
            "loguniform",
            f"Coulomb friction force of the {what}'s guides (and screw), at its carriage.",
            randomised=True,
            sample_range=(0.1, 20.0),
        ),
        *_axis_params(axis, _motor_params(rotor_note=", including the screw (drive 0)")),
        *_travel(axis, "m", 0.2, 1.0, 0.02, f"{what} carriage"),
    ]


class XYStageFamily(MultiAxisPlantFamily):
    """A horizontal X-Y stage: the X carriage carries the Y axis, which carries the payload."""

    name = "xy-stage"
    axes = ("x", "y")
    joint_units = ("m", "m")
    joint_unit = "m"
    load_param = "payload_kg"
    position_stages = False  # slides: constant mass matrix, no gravity along either axis
    moves = (
        ((0.1, 0.5, 5.0, 0.1), (-0.1, 0.5, 5.0, 0.1)),
        ((0.05, 0.4, 5.0, 0.1), (-0.05, 0.4, 5.0, 0.1)),
    )
    description = (
        "A horizontal X-Y stage: slide 'x' moves the X carriage, which carries the whole Y "
        "axis; slide 'y' moves the Y carriage with the payload. Positions in m. Each axis is "
        "a rotary motor with a ball screw (drive 0: force 2*pi*T/screw_lead_m, rotor inertia "
        "as armature rotor_inertia_kgm2*(2*pi/screw_lead_m)^2, encoder on the motor) or a "
        "linear motor (drive 1: force = force_constant_n_per_a * current, a linear scale). "
        "X moves x_carriage + y_carriage + payload; Y moves y_carriage + payload; gravity "
        "acts on neither."
    )
    params = (
        PlantParam(
            "payload_kg",
            "kg",
            2.0,
            0.0,
            30.0,
            "uniform",
            "Mass of the payload on the Y carriage.",
            randomised=True,
            sample_range=(0.0, 10.0),
        ),
        *_stage_axis("x", (5.0, 1.0, 30.0), DRIVE_BALL_SCREW),
        *_stage_axis("y", (2.0, 0.5, 15.0), DRIVE_LINEAR_MOTOR),
    )

    def _skeleton(self, spec: mujoco.MjSpec) -> None:
        x = _add_body(spec.worldbody, "x_carriage")
        x.add_joint(name="x", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
        _add_geom(x, "x_carriage", mujoco.mjtGeom.mjGEOM_BOX)
        y = _add_body(x, "y_carriage")
        y.add_joint(name="y", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 1, 0])
        _add_geom(y, "y_carriage", mujoco.mjtGeom.mjGEOM_BOX)
        payload = _add_body(y, "payload")
        _add_geom(payload, "payload", mujoco.mjtGeom.mjGEOM_BOX)

    def _multi_numbers(self, v: Mapping[str, Any]) -> _MultiNumbers:
        xs, ys, ps = (0.15, 0.3, 0.02), (0.1, 0.1, 0.02), (0.04, 0.04, 0.04)
        joints, gears, peaks = {}, {}, {}
        for axis in self.axes:
            ratio, _ = self._axis_transmission(v, axis)
            screw = v[f"{axis}_drive"] == DRIVE_BALL_SCREW
            joints[axis] = _JointNumbers(
                armature=v[f"{axis}_rotor_inertia_kgm2"] * ratio * ratio if screw else 0.0,
                damping=v[f"{axis}_viscous_friction_ns_per_m"],
                frictionloss=v[f"{axis}_coulomb_friction_n"],
                range=(v[f"{axis}_travel_min_m"], v[f"{axis}_travel_max_m"]),
            )
            gears[axis] = ratio if screw else 1.0
            peaks[axis] = self._axis_constant(v, axis) * v[f"{axis}_peak_current_a"]
        m_x, m_y, m_p = v["x_carriage_mass_kg"], v["y_carriage_mass_kg"], v["payload_kg"]
        return _MultiNumbers(
            bodies={
                "x_carriage": _BodyNumbers(mass=m_x, inertia=_box_inertia(m_x, xs)),
                "y_carriage": _BodyNumbers(
                    mass=m_y, inertia=_box_inertia(m_y, ys), pos=(0.0, 0.0, xs[2] + ys[2])
                ),
                "payload": _BodyNumbers(
                    mass=m_p, inertia=_box_inertia(m_p, ps), pos=(0.0, 0.0, ys[2] + ps[2])
                ),
            },
            body_quats={},
            joints=joints,
            geoms={
                "x_carriage": _GeomNumbers((0.0, 0.0, 0.0), xs),
                "y_carriage": _GeomNumbers((0.0, 0.0, 0.0), ys),
                "payload": _GeomNumbers((0.0, 0.0, 0.0), ps),
            },
            gears=gears,
            peak_efforts=peaks,
        )

    def _axis_transmission(self, v: Mapping[str, Any], axis: str) -> tuple[float, float]:
        if v[f"{axis}_drive"] == DRIVE_BALL_SCREW:
            lead = v[f"{axis}_screw_lead_m"]
            return 2.0 * math.pi / lead, v[f"{axis}_encoder_counts_per_rev"] / lead
        return 1.0, float(v[f"{axis}_scale_counts_per_m"])

    def _axis_constant(self, v: Mapping[str, Any], axis: str) -> float:
        if v[f"{axis}_drive"] == DRIVE_BALL_SCREW:
            return float(v[f"{axis}_torque_constant_nm_per_a"])
        return float(v[f"{axis}_force_constant_n_per_a"])


MULTI_PLANTS: dict[str, MultiAxisPlantFamily] = {
    f.name: f for f in (TwoLinkArmFamily(), XYStageFamily())
}
"""The multi-axis plant families by name: ``"two-link-arm"``, ``"xy-stage"``."""


# --- what the motors can move -------------------------------------------------------------

MULTI_GRID_POINTS = 9
"""Positions per axis at which a multi-axis plant's inertia and bias forces are evaluated
(every combination of the axes' positions is visited: 81 configurations for two axes)."""


def _axis_visited(start: float, moves: tuple[Any, ...]) -> np.ndarray:
    points, q = [start], start
    for m in moves:
        points.append(np.linspace(q, q + float(m.distance), MULTI_GRID_POINTS))
        q += float(m.distance)
    return np.unique(np.hstack(points))


def required_peak_efforts(
    family: MultiAxisPlantFamily | str,
    values: Mapping[str, Any] | None = None,
    moves: tuple[tuple[Any, ...], ...] | None = None,
    *,
    plant: MultiAxisPlant | None = None,
) -> tuple[Any, ...]:
    """The peak motor effort each axis needs when every axis runs its moves at once.

    Per axis ``k`` (each term at the motor, N*m or N for a linear motor, divided by the
    actuator gear), the worst over every combination of the positions the axes visit:

    * inertia: ``sum_j |M_kj| * a_j``, the joint-space inertia row (``mj_fullM``, armature
      included) times every axis's largest ``max_acceleration``: its own acceleration and
      the coupling of the others' (the elbow's acceleration torques the shoulder);
    * gravity: the largest ``|qfrc_bias_k|`` at the peak velocities of every sign
      combination (gravity plus the Coriolis and centrifugal forces of the other axes);
    * Coulomb (``dof_frictionloss``) and viscous (``dof_damping`` at the peak velocity).

    Args:
        family: A multi-axis family or its name.
        values: Some or all parameters (missing ones nominal).
        moves: Per axis, a sequence of moves (``servogym.sim.MoveSpec``); ``None``: the
            family's :meth:`~MultiAxisPlantFamily.default_moves`.
        plant: A compiled plant of the family to reuse (edited in place and reset).

    Returns:
        One :class:`~servogym.plants.Need` per axis, in axis order (``family`` is
        ``"<family>/<axis>"``).
    """
    fam = MULTI_PLANTS[family] if isinstance(family, str) else family
    mv = fam.default_moves() if moves is None else tuple(tuple(m) for m in moves)
    if len(mv) != fam.n_axes:
        raise ValueError(
            f"moves must give one sequence of moves per axis of {fam.name!r} "
            f"({fam.n_axes}: {', '.join(fam.axes)}); got {len(mv)}"
        )
    if plant is None:
        plant = fam.build(values)
    else:
        plant.set_params(fam.validate(values))
    model, data = plant.model, plant.data
    ios = plant.ios
    acc = np.array([max(abs(float(m.max_acceleration)) for m in axis) for axis in mv])
    vel = np.array(
        [
            max(
                min(
                    abs(float(m.max_velocity)),
                    math.sqrt(abs(float(m.distance) * m.max_acceleration)),
                )
                for m in axis
            )
            for axis in mv
        ]
    )
    grids = [_axis_visited(io.start_qpos, axis) for io, axis in zip(ios, mv, strict=True)]
    full = np.zeros((model.nv, model.nv))
    n = fam.n_axes
    inertia = np.zeros(n)
    bias = np.zeros(n)
    signs = [np.array(s) for s in np.ndindex(*(3,) * n)]
    for config in np.stack(np.meshgrid(*grids, indexing="ij"), -1).reshape(-1, n):
        mujoco.mj_resetData(model, data)
        for io, q in zip(ios, config, strict=True):
            data.qpos[io.qpos_adr] = q
        mujoco.mj_forward(model, data)
        mujoco.mj_fullM(model, data, full)
        for k, io in enumerate(ios):
            row = sum(abs(full[io.qvel_adr, j.qvel_adr]) * acc[i] for i, j in enumerate(ios))
            inertia[k] = max(inertia[k], row)
        for s in signs:
            for i, io in enumerate(ios):
                data.qvel[io.qvel_adr] = (s[i] - 1) * vel[i]
            mujoco.mj_forward(model, data)
            for k, io in enumerate(ios):
                bias[k] = max(bias[k], abs(float(data.qfrc_bias[io.qvel_adr])))
    plant.reset()
    return _needs(plant, inertia, bias, vel)


def _needs(plant: MultiAxisPlant, inertia: Any, bias: Any, speed: Any) -> tuple[Any, ...]:
    """Per axis, the :class:`~servogym.plants.Need` of joint-space peaks (N*m or N at the
    joint): each term divided by the actuator gear, friction from the model."""
    from servogym.plants._feasibility import PEAK_HEADROOM, Need

    model, fam = plant.model, plant.family
    out = []
    for k, io in enumerate(plant.ios):
        gear = float(model.actuator_gear[io.ctrl_index, 0])
        out.append(
            Need(
                family=f"{fam.name}/{fam.axes[k]}",
                inertia_nm=float(inertia[k]) / gear,
                gravity_nm=float(bias[k]) / gear,
                coulomb_nm=float(model.dof_frictionloss[io.qvel_adr]) / gear,
                viscous_nm=float(model.dof_damping[io.qvel_adr]) * float(speed[k]) / gear,
                peak_nm=io.peak_torque_nm,
                headroom=PEAK_HEADROOM,
            )
        )
    return tuple(out)


COMMAND_WINDOW_S = 0.005
"""Half-width of the central differences :func:`commanded_efforts` takes of a commanded
trajectory (s): wide enough that one count of quantisation moves the acceleration by a few
per cent on the default machines (4 counts / (5 ms)^2 over about 1e6 counts per unit), narrow
enough to keep a trapezoid's acceleration plateau."""


def commanded_efforts(
    plant: MultiAxisPlant,
    trajectories: Any,
    dt: float,
    *,
    window_s: float = COMMAND_WINDOW_S,
) -> tuple[Any, ...]:
    """The peak motor effort each axis needs to follow commanded joint trajectories.

    Where :func:`required_peak_efforts` bounds a need from move specifications, this reads
    it off the commanded positions themselves (the coordinated moves and contours of a
    multi-axis task): velocity and acceleration by central differences over ``window_s``
    either side, then per axis ``k``, each term the worst over the samples and at the
    motor (divided by the actuator gear):

    * inertia: ``|(M a)_k|`` (``mj_fullM``, armature included, times every axis's
      acceleration: the coupling of the others' included, with its sign);
    * gravity: ``|qfrc_bias_k|`` at the commanded position and velocity (gravity plus the
      Coriolis and centrifugal forces);
    * Coulomb (``dof_frictionloss``) and viscous (``dof_damping`` at the peak velocity).

    Args:
        plant: A compiled multi-axis plant (its current parameters; reset on return).
        trajectories: One array per task, ``(n_ticks, n_axes)`` joint positions (rad or m)
            at the servo ticks.
        dt: The servo period (s).
        window_s: Half-width of the differences (s); at least one tick.

    Returns:
        One :class:`~servogym.plants.Need` per axis, in axis order.
    """
    model, data = plant.model, plant.data
    ios = plant.ios
    n = len(ios)
    h = max(1, round(window_s / dt))
    stride = max(1, h // 2)
    full = np.zeros((model.nv, model.nv))
    dofs = [io.qvel_adr for io in ios]
    inertia, bias, speed = np.zeros(n), np.zeros(n), np.zeros(n)
    mujoco.mj_resetData(model, data)  # the other joints at rest; each sample sets the axes'
    for q in trajectories:
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != n:
            raise ValueError(f"each trajectory must be (n_ticks, {n}); got {q.shape}")
        # hold the ends: the machine rests before and after the commanded motion
        padded = np.concatenate([np.repeat(q[:1], h, 0), q, np.repeat(q[-1:], h, 0)])
        vel = (padded[2 * h :] - padded[: -2 * h]) / (2 * h * dt)
        acc = (padded[2 * h :] - 2 * q + padded[: -2 * h]) / (h * dt) ** 2
        speed = np.maximum(speed, np.max(np.abs(vel), axis=0))
        for i in range(0, len(q), stride):
            for k, io in enumerate(ios):
                data.qpos[io.qpos_adr] = q[i, k]
                data.qvel[io.qvel_adr] = vel[i, k]
            mujoco.mj_forward(model, data)
            mujoco.mj_fullM(model, data, full)
            m_a = full[np.ix_(dofs, dofs)] @ acc[i]
            inertia = np.maximum(inertia, np.abs(m_a))
            bias = np.maximum(bias, np.abs(data.qfrc_bias[dofs]))
    plant.reset()
    return _needs(plant, inertia, bias, speed)


def worst_sampled_efforts(family: MultiAxisPlantFamily | str) -> tuple[Any, ...]:
    """Per axis, the largest need over every corner of the default sampling box.

    The box: each randomised parameter at the low or high end of its default sampling
    range, the others nominal (the need is monotone in every randomised parameter of the
    two families, so its largest value over the box is at a corner).
    """
    import itertools

    fam = MULTI_PLANTS[family] if isinstance(family, str) else family
    box = fam.sample_bounds()
    plant = fam.build()
    worst: list[Any] = [None] * fam.n_axes
    for corner in itertools.product(*[sorted(set(r)) for r in box.values()]):
        needs = required_peak_efforts(fam, dict(zip(box, corner, strict=True)), plant=plant)
        for k, need in enumerate(needs):
            if worst[k] is None or need.total_nm > worst[k].total_nm:
                worst[k] = need
    return tuple(worst)


def multi_feasibility_table_markdown() -> str:
    """The table of docs/plants.md, "Multi-axis plants": per family and axis, the peak need
    of the nominal plant, of the other mounting or drives, and of the worst corner of the
    default sampling box (:func:`required_peak_efforts`, :func:`worst_sampled_efforts`)."""
    lines = [
        "| Family | Case | Axis | Peak need at the motor (N*m; N for a linear motor) | Of the "
        "motor's peak |",
        "|---|---|---|---|---|",
    ]
    for fam in MULTI_PLANTS.values():
        if isinstance(fam, TwoLinkArmFamily):
            other = ("vertical (vertical=1)", {"vertical": 1})
        else:
            other = ("X linear motor, Y ball screw", {"x_drive": 1, "y_drive": 0})
        cases = [
            ("nominal", required_peak_efforts(fam)),
            (other[0], required_peak_efforts(fam, other[1])),
            ("worst corner of the sampled ranges", worst_sampled_efforts(fam)),
        ]
        for case, needs in cases:
            for axis, n in zip(fam.axes, needs, strict=True):
                lines.append(
                    f"| {fam.name} | {case} | {axis} | {n.total_nm:.3g} (inertia "
                    f"{n.inertia_nm:.3g}, gravity and Coriolis {n.gravity_nm:.3g}, Coulomb "
                    f"{n.coulomb_nm:.3g}, viscous {n.viscous_nm:.3g}) | {n.fraction:.0%} |"
                )
    return "\n".join(lines)
