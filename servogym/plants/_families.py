"""The four servo plant families: rotary, two-mass, vertical-axis, arm.

Conventions shared by every family:

* The measured joint is called ``"motor"``; the encoder sits on the motor shaft and the
  single actuator (``"motor"``) takes the motor shaft torque in N*m as ``ctrl``.
* Viscous friction is the joint's ``damping``, Coulomb friction its ``frictionloss`` (a
  MuJoCo friction constraint), the hard travel limits its ``range`` (a limit constraint).
* Bodies have explicit inertials. Where a parameter is a mass, the body's inertia is the
  mass times a fixed shape factor, so the two always change together.
* Direct-drive families (``rotary``, ``two-mass``) carry the rotor inertia on the motor body;
  geared families (``vertical-axis``, ``arm``) reflect it onto the joint as ``armature``
  (rotor inertia times the square of the transmission ratio).
* Hinge axes are horizontal (along y), gravity is ``-9.81 m/s^2`` along z.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import mujoco

from servogym.plants._base import (
    MOTOR_JOINT,
    PlantFamily,
    PlantParam,
    _BodyNumbers,
    _GeomNumbers,
    _JointNumbers,
    _Numbers,
)

ROTOR_RADIUS_M = 0.02
"""Radius of the disc that stands for the rotor (sets its hidden mass, no effect on motion)."""

LOAD_RADIUS_M = 0.05
"""Radius of the disc that stands for an inertial load (sets its hidden mass only)."""

DISC_TRANSVERSE = 0.6
"""Transverse moment of a disc body as a fraction of its axial moment (shape factor)."""

_Y_TO_Z = (math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0)  # geom quat: local z along world y
_X_TO_Z = (math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0)  # geom quat: local z along world x


def _motor_params(*, rotor_note: str = "") -> list[PlantParam]:
    """The motor, amplifier and encoder parameters every family has (datasheet values)."""
    return [
        PlantParam(
            "rotor_inertia_kgm2",
            "kg*m^2",
            3e-5,
            1e-5,
            1e-4,
            "loguniform",
            "Motor rotor inertia" + rotor_note + ".",
            randomised=False,
        ),
        PlantParam(
            "torque_constant_nm_per_a",
            "N*m/A",
            0.2,
            0.05,
            0.5,
            "loguniform",
            "Motor torque constant: shaft torque per ampere.",
            randomised=False,
        ),
        PlantParam(
            "peak_current_a",
            "A",
            10.0,
            5.0,
            20.0,
            "uniform",
            "Amplifier peak current; command -32768 gives -peak_current_a.",
            randomised=False,
        ),
        PlantParam(
            "current_bandwidth_hz",
            "Hz",
            0.0,
            0.0,
            10000.0,
            "uniform",
            "Current-loop bandwidth (first-order lag); 0 means an ideal current loop.",
            randomised=False,
        ),
        PlantParam(
            "encoder_counts_per_rev",
            "counts/rev",
            131072,
            4096,
            1048576,
            "loguniform",
            "Encoder resolution on the motor shaft, in counts per motor revolution.",
            randomised=False,
            integer=True,
        ),
    ]


def _rotary_friction_params(
    viscous: tuple[float, float, float], coulomb: tuple[float, float, float], where: str
) -> list[PlantParam]:
    return [
        PlantParam(
            "viscous_friction_nms",
            "N*m*s/rad",
            *viscous,
            "loguniform",
            f"Viscous friction of the {where} (joint damping).",
            randomised=True,
        ),
        PlantParam(
            "coulomb_friction_nm",
            "N*m",
            *coulomb,
            "loguniform",
            f"Coulomb friction torque of the {where} (joint frictionloss).",
            randomised=True,
        ),
    ]


def _travel_params(
    unit: str, nominal: float, lowest: float, narrowest: float, what: str
) -> list[PlantParam]:
    return [
        PlantParam(
            f"travel_min_{unit}",
            unit,
            -nominal,
            -lowest,
            -narrowest,
            "uniform",
            f"Lower hard travel limit (end stop) of the {what}; the start position is 0.",
            randomised=False,
        ),
        PlantParam(
            f"travel_max_{unit}",
            unit,
            nominal,
            narrowest,
            lowest,
            "uniform",
            f"Upper hard travel limit (end stop) of the {what}.",
            randomised=False,
        ),
    ]


def _disc(inertia_kgm2: float, radius_m: float, pos: tuple[float, float, float]) -> _BodyNumbers:
    """A disc spinning about y with axial moment ``inertia_kgm2`` (mass from the radius)."""
    return _BodyNumbers(
        mass=2.0 * inertia_kgm2 / (radius_m * radius_m),
        inertia=(DISC_TRANSVERSE * inertia_kgm2, inertia_kgm2, DISC_TRANSVERSE * inertia_kgm2),
        pos=pos,
    )


def _add_body(parent: Any, name: str, pos: tuple[float, float, float] = (0, 0, 0)) -> Any:
    body = parent.add_body(name=name, pos=list(pos))
    body.explicitinertial = True
    return body


def _add_geom(body: Any, name: str, kind: mujoco.mjtGeom, quat=(1.0, 0.0, 0.0, 0.0)) -> None:
    body.add_geom(name=name, type=kind, quat=list(quat), size=[0.01, 0.01, 0.01])


def _hinge(body: Any, name: str, axis=(0.0, 1.0, 0.0)) -> None:
    body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(axis))


class RotaryFamily(PlantFamily):
    """Motor rotor with a rigidly coupled inertial load on a horizontal axis."""

    name = "rotary"
    load_param = "load_inertia_kgm2"
    joint_unit = "rad"
    description = (
        "Motor rotor with a rigidly coupled inertial load, horizontal axis through the centre "
        "of mass (no gravity torque). One hinge: the motor shaft angle in rad. Total inertia "
        "rotor_inertia_kgm2 + load_inertia_kgm2."
    )
    params = (
        PlantParam(
            "load_inertia_kgm2",
            "kg*m^2",
            9e-5,
            1e-6,
            3e-3,
            "loguniform",
            "Inertia of the load rigidly coupled to the rotor.",
            randomised=True,
            sample_range=(1e-6, 4e-4),
        ),
        *_rotary_friction_params((2e-5, 1e-6, 1e-3), (0.01, 1e-4, 0.1), "motor shaft"),
        *_motor_params(),
        *_travel_params("rad", 50.0, 1000.0, 1.0, "motor shaft"),
    )

    def _skeleton(self, spec: mujoco.MjSpec) -> None:
        rotor = _add_body(spec.worldbody, "rotor")
        _hinge(rotor, MOTOR_JOINT)
        _add_geom(rotor, "rotor", mujoco.mjtGeom.mjGEOM_CYLINDER, _Y_TO_Z)
        load = _add_body(rotor, "load")
        _add_geom(load, "load", mujoco.mjtGeom.mjGEOM_CYLINDER, _Y_TO_Z)

    def _numbers(self, v: Mapping[str, Any]) -> _Numbers:
        return _Numbers(
            bodies={
                "rotor": _disc(v["rotor_inertia_kgm2"], ROTOR_RADIUS_M, (0.0, 0.0, 0.0)),
                "load": _disc(v["load_inertia_kgm2"], LOAD_RADIUS_M, (0.0, 0.08, 0.0)),
            },
            joints={
                MOTOR_JOINT: _JointNumbers(
                    armature=0.0,
                    damping=v["viscous_friction_nms"],
                    frictionloss=v["coulomb_friction_nm"],
                    range=(v["travel_min_rad"], v["travel_max_rad"]),
                )
            },
            geoms={
                "rotor": _GeomNumbers((0.0, 0.0, 0.0), (ROTOR_RADIUS_M, 0.03, 0.0)),
                "load": _GeomNumbers((0.0, 0.0, 0.0), (LOAD_RADIUS_M, 0.01, 0.0)),
            },
            gear=1.0,
            peak_torque_nm=v["torque_constant_nm_per_a"] * v["peak_current_a"],
        )

    def _transmission(self, v: Mapping[str, Any]) -> tuple[float, float]:
        return 1.0, v["encoder_counts_per_rev"] / (2.0 * math.pi)


class TwoMassFamily(PlantFamily):
    """Rotor and load joined by a torsional spring and damper (a compliant shaft)."""

    name = "two-mass"
    load_param = "load_inertia_kgm2"
    joint_unit = "rad"
    description = (
        "Rotor and load joined by a torsional spring and damper (compliant coupling or "
        "shaft), horizontal axis: the plant where notch filters matter. Hinge 'motor' is the "
        "rotor angle (measured); hinge 'shaft' is the twist, load angle minus rotor angle. "
        "First resonance f = sqrt(k*(J1+J2)/(J1*J2))/(2*pi) with k = stiffness_nm_per_rad, "
        "J1 = rotor_inertia_kgm2, J2 = load_inertia_kgm2: about 100 Hz nominal, 17..318 Hz "
        "over the legal ranges."
    )
    params = (
        PlantParam(
            "load_inertia_kgm2",
            "kg*m^2",
            9e-5,
            1e-5,
            1e-3,
            "loguniform",
            "Inertia of the load at the far end of the compliant shaft.",
            randomised=True,
            sample_range=(1e-5, 9e-4),
        ),
        PlantParam(
            "stiffness_nm_per_rad",
            "N*m/rad",
            9.0,
            1.0,
            20.0,
            "loguniform",
            "Torsional stiffness of the coupling between rotor and load.",
            randomised=True,
        ),
        PlantParam(
            "shaft_damping_nms",
            "N*m*s/rad",
            5e-4,
            1e-5,
            1e-2,
            "loguniform",
            "Torsional damping of the coupling (acts on the twist rate).",
            randomised=True,
        ),
        *_rotary_friction_params((2e-5, 1e-6, 1e-3), (0.01, 1e-4, 0.1), "motor shaft"),
        *_motor_params(),
        *_travel_params("rad", 50.0, 1000.0, 1.0, "motor shaft"),
    )

    def _skeleton(self, spec: mujoco.MjSpec) -> None:
        rotor = _add_body(spec.worldbody, "rotor")
        _hinge(rotor, MOTOR_JOINT)
        _add_geom(rotor, "rotor", mujoco.mjtGeom.mjGEOM_CYLINDER, _Y_TO_Z)
        load = _add_body(rotor, "load")
        _hinge(load, "shaft")
        _add_geom(load, "load", mujoco.mjtGeom.mjGEOM_CYLINDER, _Y_TO_Z)
        _add_geom(load, "shaft", mujoco.mjtGeom.mjGEOM_CAPSULE, _Y_TO_Z)

    def _numbers(self, v: Mapping[str, Any]) -> _Numbers:
        return _Numbers(
            bodies={
                "rotor": _disc(v["rotor_inertia_kgm2"], ROTOR_RADIUS_M, (0.0, 0.0, 0.0)),
                "load": _disc(v["load_inertia_kgm2"], LOAD_RADIUS_M, (0.0, 0.15, 0.0)),
            },
            joints={
                MOTOR_JOINT: _JointNumbers(
                    armature=0.0,
                    damping=v["viscous_friction_nms"],
                    frictionloss=v["coulomb_friction_nm"],
                    range=(v["travel_min_rad"], v["travel_max_rad"]),
                ),
                "shaft": _JointNumbers(
                    armature=0.0,
                    damping=v["shaft_damping_nms"],
                    frictionloss=0.0,
                    range=(0.0, 0.0),
                    stiffness=v["stiffness_nm_per_rad"],
                ),
            },
            geoms={
                "rotor": _GeomNumbers((0.0, 0.0, 0.0), (ROTOR_RADIUS_M, 0.03, 0.0)),
                "load": _GeomNumbers((0.0, 0.0, 0.0), (LOAD_RADIUS_M, 0.01, 0.0)),
                "shaft": _GeomNumbers((0.0, -0.075, 0.0), (0.004, 0.075, 0.0)),
            },
            gear=1.0,
            peak_torque_nm=v["torque_constant_nm_per_a"] * v["peak_current_a"],
        )

    def _transmission(self, v: Mapping[str, Any]) -> tuple[float, float]:
        return 1.0, v["encoder_counts_per_rev"] / (2.0 * math.pi)

    @staticmethod
    def resonance_hz(values: Mapping[str, Any]) -> float:
        """First (free-free) resonance of the rotor-shaft-load system, in Hz.

        ``f = sqrt(k * (J1 + J2) / (J1 * J2)) / (2*pi)`` with ``k = stiffness_nm_per_rad``,
        ``J1 = rotor_inertia_kgm2`` and ``J2 = load_inertia_kgm2``.

        Args:
            values: A complete set of two-mass parameters.
        """
        k, j1, j2 = (
            values["stiffness_nm_per_rad"],
            values["rotor_inertia_kgm2"],
            values["load_inertia_kgm2"],
        )
        return math.sqrt(k * (j1 + j2) / (j1 * j2)) / (2.0 * math.pi)


CARRIAGE_SIZE_M = (0.06, 0.06, 0.02)
"""Half sizes of the carriage box (its inertia is the carriage mass times this box's factor)."""

PAYLOAD_HALF_SIZE_M = 0.04
"""Half side of the vertical axis's payload cube (its inertia scales with ``payload_kg``)."""


def _box_inertia(mass_kg: float, half: tuple[float, float, float]) -> tuple[float, float, float]:
    x, y, z = (2.0 * h for h in half)
    return (
        mass_kg * (y * y + z * z) / 12.0,
        mass_kg * (x * x + z * z) / 12.0,
        mass_kg * (x * x + y * y) / 12.0,
    )


class VerticalAxisFamily(PlantFamily):
    """Ball-screw driven slide moving against gravity, with a variable payload."""

    name = "vertical-axis"
    load_param = "payload_kg"
    joint_unit = "m"
    description = (
        "Ball-screw driven slide moving vertically against gravity, carrying a payload whose "
        "mass varies. One slide joint along z: the carriage height in m (measured by the "
        "motor encoder through the screw). Motor torque T gives force 2*pi*T/screw_lead_m; "
        "the rotor (and screw) inertia appears as armature "
        "rotor_inertia_kgm2*(2*pi/screw_lead_m)^2. Gravity needs a constant holding torque "
        "(carriage_mass_kg + payload_kg)*9.81*screw_lead_m/(2*pi): the bias the chip's Bias "
        "term exists for."
    )
    params = (
        PlantParam(
            "payload_kg",
            "kg",
            2.0,
            0.5,
            10.0,
            "loguniform",
            "Mass of the payload carried by the slide.",
            randomised=True,
        ),
        PlantParam(
            "carriage_mass_kg",
            "kg",
            1.0,
            0.2,
            5.0,
            "loguniform",
            "Mass of the carriage (slide table and nut) without payload.",
            randomised=False,
        ),
        PlantParam(
            "screw_lead_m",
            "m",
            0.01,
            0.002,
            0.04,
            "loguniform",
            "Ball-screw lead: carriage travel per motor revolution.",
            randomised=False,
        ),
        PlantParam(
            "viscous_friction_ns_per_m",
            "N*s/m",
            10.0,
            0.1,
            1000.0,
            "loguniform",
            "Viscous friction of screw and guides, at the carriage (joint damping).",
            randomised=True,
        ),
        PlantParam(
            "coulomb_friction_n",
            "N",
            10.0,
            0.5,
            100.0,
            "loguniform",
            "Coulomb friction force of screw and guides, at the carriage (joint frictionloss).",
            randomised=True,
        ),
        *_motor_params(rotor_note=", including the screw"),
        *_travel_params("m", 0.2, 1.0, 0.005, "carriage"),
    )

    def _skeleton(self, spec: mujoco.MjSpec) -> None:
        carriage = _add_body(spec.worldbody, "carriage")
        carriage.add_joint(name=MOTOR_JOINT, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1])
        _add_geom(carriage, "carriage", mujoco.mjtGeom.mjGEOM_BOX)
        payload = _add_body(carriage, "payload")
        _add_geom(payload, "payload", mujoco.mjtGeom.mjGEOM_BOX)

    def _numbers(self, v: Mapping[str, Any]) -> _Numbers:
        ratio = 2.0 * math.pi / v["screw_lead_m"]
        half = (PAYLOAD_HALF_SIZE_M,) * 3
        return _Numbers(
            bodies={
                "carriage": _BodyNumbers(
                    mass=v["carriage_mass_kg"],
                    inertia=_box_inertia(v["carriage_mass_kg"], CARRIAGE_SIZE_M),
                ),
                "payload": _BodyNumbers(
                    mass=v["payload_kg"],
                    inertia=_box_inertia(v["payload_kg"], half),
                    pos=(0.0, 0.0, CARRIAGE_SIZE_M[2] + PAYLOAD_HALF_SIZE_M),
                ),
            },
            joints={
                MOTOR_JOINT: _JointNumbers(
                    armature=v["rotor_inertia_kgm2"] * ratio * ratio,
                    damping=v["viscous_friction_ns_per_m"],
                    frictionloss=v["coulomb_friction_n"],
                    range=(v["travel_min_m"], v["travel_max_m"]),
                )
            },
            geoms={
                "carriage": _GeomNumbers((0.0, 0.0, 0.0), CARRIAGE_SIZE_M),
                "payload": _GeomNumbers((0.0, 0.0, 0.0), half),
            },
            gear=ratio,
            peak_torque_nm=v["torque_constant_nm_per_a"] * v["peak_current_a"],
        )

    def _transmission(self, v: Mapping[str, Any]) -> tuple[float, float]:
        return 2.0 * math.pi / v["screw_lead_m"], v["encoder_counts_per_rev"] / v["screw_lead_m"]


LINK_RADIUS_M = 0.01
"""Radius of the arm's link rod (for its small moment about its own axis)."""

PAYLOAD_RADIUS_M = 0.03
"""Radius of the arm's payload sphere (its inertia is ``2/5 * payload_kg * r^2``)."""


class ArmFamily(PlantFamily):
    """A geared link with a tip payload rotating in a vertical plane."""

    name = "arm"
    load_param = "payload_kg"
    joint_unit = "rad"
    position_stages = True  # the gravity torque changes with the angle
    description = (
        "A link with a payload at its tip, driven through a gearbox and rotating in a "
        "vertical plane about a horizontal axis. One hinge: the link angle in rad, 0 = "
        "horizontal, positive = up. The gravity torque at the link is "
        "-(link_mass_kg*link_length_m/2 + payload_kg*link_length_m)*9.81*cos(angle), so the "
        "holding torque changes with angle (the case for gain scheduling). Motor torque T "
        "gives gear_ratio*T at the link; the rotor inertia appears as armature "
        "rotor_inertia_kgm2*gear_ratio^2; friction is given at the link."
    )
    params = (
        PlantParam(
            "payload_kg",
            "kg",
            0.5,
            0.05,
            5.0,
            "loguniform",
            "Mass of the payload at the tip of the link (a small sphere).",
            randomised=True,
            sample_range=(0.05, 2.5),
        ),
        PlantParam(
            "link_mass_kg",
            "kg",
            0.5,
            0.05,
            5.0,
            "loguniform",
            "Mass of the link (a uniform rod).",
            randomised=False,
        ),
        PlantParam(
            "link_length_m",
            "m",
            0.3,
            0.05,
            1.0,
            "loguniform",
            "Length of the link from the joint axis to the payload.",
            randomised=False,
        ),
        PlantParam(
            "gear_ratio",
            "1",
            10.0,
            1.0,
            160.0,
            "loguniform",
            "Gearbox ratio: motor revolutions per link revolution (1 = direct drive).",
            randomised=False,
        ),
        *_rotary_friction_params((2e-3, 1e-5, 0.1), (0.1, 1e-3, 2.0), "link joint, at the link"),
        *_motor_params(),
        *_travel_params("rad", 1.5, 3.1, 0.1, "link (0 = horizontal)"),
    )

    def _skeleton(self, spec: mujoco.MjSpec) -> None:
        link = _add_body(spec.worldbody, "link")
        _hinge(link, MOTOR_JOINT, axis=(0.0, -1.0, 0.0))
        _add_geom(link, "link", mujoco.mjtGeom.mjGEOM_CAPSULE, _X_TO_Z)
        payload = _add_body(link, "payload")
        _add_geom(payload, "payload", mujoco.mjtGeom.mjGEOM_SPHERE)

    def _numbers(self, v: Mapping[str, Any]) -> _Numbers:
        m_l, m_p, length, n = (
            v["link_mass_kg"],
            v["payload_kg"],
            v["link_length_m"],
            v["gear_ratio"],
        )
        r = LINK_RADIUS_M
        transverse = m_l * (3.0 * r * r + length * length) / 12.0
        sphere = 0.4 * m_p * PAYLOAD_RADIUS_M * PAYLOAD_RADIUS_M
        return _Numbers(
            bodies={
                "link": _BodyNumbers(
                    mass=m_l,
                    inertia=(0.5 * m_l * r * r, transverse, transverse),
                    ipos=(0.5 * length, 0.0, 0.0),
                ),
                "payload": _BodyNumbers(
                    mass=m_p, inertia=(sphere, sphere, sphere), pos=(length, 0.0, 0.0)
                ),
            },
            joints={
                MOTOR_JOINT: _JointNumbers(
                    armature=v["rotor_inertia_kgm2"] * n * n,
                    damping=v["viscous_friction_nms"],
                    frictionloss=v["coulomb_friction_nm"],
                    range=(v["travel_min_rad"], v["travel_max_rad"]),
                )
            },
            geoms={
                "link": _GeomNumbers((0.5 * length, 0.0, 0.0), (r, 0.5 * length, 0.0)),
                "payload": _GeomNumbers((0.0, 0.0, 0.0), (PAYLOAD_RADIUS_M, 0.0, 0.0)),
            },
            gear=n,
            peak_torque_nm=v["torque_constant_nm_per_a"] * v["peak_current_a"],
        )

    def _transmission(self, v: Mapping[str, Any]) -> tuple[float, float]:
        n = v["gear_ratio"]
        return n, v["encoder_counts_per_rev"] * n / (2.0 * math.pi)
