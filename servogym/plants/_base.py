"""Plant parameters, plant families and compiled plant instances.

A :class:`PlantFamily` is a MuJoCo servo plant with named physical parameters (SI units, a
nominal value, a legal range, a sampling distribution). :meth:`PlantFamily.build` compiles one
:class:`Plant`; :meth:`Plant.set_params` then turns it into any other instance of the family by
editing the compiled ``mujoco.MjModel`` in place (``mj_setConst`` + ``mj_resetData``), with no
recompilation and no new allocation, so an episode loop can re-randomise the plant cheaply.

Every family is built the same way: a fixed topology (bodies, joints, visual geoms, one motor
actuator; :meth:`PlantFamily._skeleton`) and the numbers that depend on the parameters
(:meth:`PlantFamily._numbers`). The numbers reach the model by two independent paths: written
into the ``MjSpec`` and compiled (:meth:`PlantFamily.build`), or written into the compiled
model's arrays (:meth:`Plant.set_params`). ``tests/plants`` checks that both paths give
bit-identical trajectories.
"""

from __future__ import annotations

import abc
import dataclasses
import difflib
import math
import numbers
from collections.abc import Iterable, Mapping
from typing import Any

import mujoco
import numpy as np

DEFAULT_TIMESTEP_S = 250e-6
"""Physics timestep of a freshly built plant, in seconds (the runner usually overrides it)."""

TIMESTEP_MIN_S = 1e-8
"""Smallest legal physics timestep, in seconds."""

TIMESTEP_MAX_S = 1e-3
"""Largest legal physics timestep, in seconds (every family is tested stable at 700 us)."""

COMMAND_MIN = -32768
"""Smallest chip motor command (signed 16 bit)."""

COMMAND_MAX = 32767
"""Largest chip motor command (signed 16 bit)."""

COMMAND_FULL_SCALE = 32768
"""Commands per peak current: command ``c`` asks for ``c / 32768 * peak_current_a`` amperes."""

GRAVITY_MPS2 = 9.81
"""Gravitational acceleration of every plant, in m/s^2 (MuJoCo's default)."""


_STATE_SIG = mujoco.mjtState.mjSTATE_INTEGRATION
"""What ``Plant.set_params(keep_state=True)`` saves: everything integration needs."""


class PlantParameterError(ValueError):
    """A plant parameter is unknown, of the wrong type, or outside its family's legal range."""


def _fmt(x: float | int) -> str:
    """Shortest text that reads back as exactly ``x`` (``3e-05``, ``0.2``, ``131072``)."""
    if isinstance(x, numbers.Integral):
        return str(int(x))
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


@dataclasses.dataclass(frozen=True)
class PlantParam:
    """One physical parameter of a plant family.

    Attributes:
        name: Physics name with a unit suffix, e.g. ``load_inertia_kgm2``, ``payload_kg``.
        unit: The SI unit, e.g. ``"kg*m^2"``, ``"N*m*s/rad"``, ``"1"`` for a pure number.
        nominal: The value of the nominal plant (``PlantFamily.nominal()``).
        low: Smallest legal value (inclusive). The legal range is also the realistic range:
            it is what the family documents, samples and accepts; values outside it are
            rejected, not extrapolated.
        high: Largest legal value (inclusive).
        distribution: ``"uniform"`` or ``"loguniform"`` (needs ``low > 0``): how
            :meth:`PlantFamily.sample` draws the value.
        doc: One line saying what the parameter is.
        randomised: Whether :meth:`PlantFamily.sample` draws it by default; ``False`` means
            it is a datasheet value kept at its current setting (nominal unless given).
        integer: Whether the value is an integer count (e.g. ``encoder_counts_per_rev``).
        sample_range: The part of the legal range :meth:`PlantFamily.sample` draws from by
            default, ``(low, high)``; ``None``: the whole legal range. Set where part of the
            legal range is more than the family's default motor can move with the default
            moves (docs/plants.md, "What the motor can move"), so that default draws are
            always movable; a ``plant_range`` (``--plant-range``) overrides it.
    """

    name: str
    unit: str
    nominal: float
    low: float
    high: float
    distribution: str
    doc: str
    randomised: bool
    integer: bool = False
    sample_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.distribution not in ("uniform", "loguniform"):
            raise ValueError(
                f"PlantParam {self.name}: distribution must be 'uniform' or 'loguniform'; "
                f"got distribution={self.distribution!r}."
            )
        if not self.low <= self.nominal <= self.high:
            raise ValueError(
                f"PlantParam {self.name}: nominal must satisfy low <= nominal <= high; "
                f"got {self.low=}, {self.nominal=}, {self.high=}."
            )
        if self.distribution == "loguniform" and not self.low > 0:
            raise ValueError(
                f"PlantParam {self.name}: a loguniform parameter needs low > 0; got {self.low=}."
            )
        if self.sample_range is not None:
            s_lo, s_hi = self.sample_range
            if not self.low <= s_lo <= self.nominal <= s_hi <= self.high:
                raise ValueError(
                    f"PlantParam {self.name}: sample_range must satisfy low <= sample_range[0] "
                    f"<= nominal <= sample_range[1] <= high; got {self.low=}, "
                    f"{self.sample_range=}, {self.nominal=}, {self.high=}."
                )

    @property
    def sample_low(self) -> float:
        """Lowest value :meth:`PlantFamily.sample` draws by default."""
        return self.low if self.sample_range is None else self.sample_range[0]

    @property
    def sample_high(self) -> float:
        """Highest value :meth:`PlantFamily.sample` draws by default."""
        return self.high if self.sample_range is None else self.sample_range[1]

    @property
    def type_name(self) -> str:
        """``"int"`` or ``"float"``."""
        return "int" if self.integer else "float"

    @property
    def range_text(self) -> str:
        """The legal range as error messages state it, e.g. ``0.5 <= payload_kg <= 10``."""
        return f"{_fmt(self.low)} <= {self.name} <= {_fmt(self.high)}"

    def validate(self, value: Any, *, family: str = "") -> float | int:
        """Return ``value`` as a Python float (int for integer parameters), or raise.

        Args:
            value: The value to check, in ``self.unit``.
            family: Name of the plant family, used in the message.

        Raises:
            PlantParameterError: if the value is not a real number (an integer for integer
                parameters), is not finite, or lies outside ``low .. high``.
        """
        where = f" for the {family!r} plant family" if family else ""
        kind = "an integer" if self.integer else "a real number"
        wanted = numbers.Integral if self.integer else numbers.Real
        if isinstance(value, bool) or not isinstance(value, wanted):
            raise PlantParameterError(
                f"{self.name} must be {kind} with {self.range_text} ({self.unit}){where}; "
                f"got {self.name}={value!r} of type {type(value).__name__}."
            )
        out = int(value) if self.integer else float(value)
        if not (math.isfinite(out) and self.low <= out <= self.high):
            raise PlantParameterError(
                f"{self.name} must satisfy {self.range_text} ({self.unit}), the legal range"
                f"{where}; got {self.name}={value!r}."
            )
        return out


@dataclasses.dataclass(frozen=True)
class AxisIO:
    """What the closed-loop runner needs from a plant, as plain numbers.

    The runner closes the loop: encoder counts from ``qpos[qpos_adr]``
    (:func:`~servogym.plants.encoder_counts`), chip command to current
    (:func:`~servogym.plants.amplifier_current`), current times
    ``torque_constant_nm_per_a`` written to ``ctrl[ctrl_index]`` as the motor torque in N*m.

    Attributes:
        qpos_adr: Address in ``MjData.qpos`` of the measured joint (the joint the motor drives
            and whose position the motor encoder reads).
        qvel_adr: Address in ``MjData.qvel`` of the same joint.
        ctrl_index: Index in ``MjData.ctrl`` of the motor actuator. ``ctrl`` is the motor
            shaft torque in N*m; the actuator gear maps it to the joint (for a ball screw the
            force is ``torque * 2*pi / screw_lead_m``).
        counts_per_unit: Encoder counts per joint unit (per rad for a hinge, per m for a slide):
            ``encoder_counts_per_rev * motor_rad_per_unit / (2*pi)``.
        motor_rad_per_unit: Motor shaft angle per joint unit, in rad per joint unit: 1 for a
            direct drive, the gear ratio for a gearbox, ``2*pi / screw_lead_m`` for a ball
            screw.
        travel_min: Lower hard travel limit of the measured joint, in joint units (rad or m).
        travel_max: Upper hard travel limit, in joint units. A runner declares the episode
            diverged unless ``travel_min <= qpos <= travel_max``, written that way so that a
            NaN (a diverged simulation; plants do not auto-reset) also fails it.
        amp_amps_per_count: Amperes per command count, ``peak_current_a / 32768``, in A.
        peak_current_a: Amplifier saturation current, in A.
        torque_constant_nm_per_a: Motor torque constant, in N*m/A.
        current_bandwidth_hz: Current-loop bandwidth in Hz; 0 means an ideal current loop.
        start_qpos: Position of the measured joint after :meth:`Plant.reset`, in joint units.
    """

    qpos_adr: int
    qvel_adr: int
    ctrl_index: int
    counts_per_unit: float
    motor_rad_per_unit: float
    travel_min: float
    travel_max: float
    amp_amps_per_count: float
    peak_current_a: float
    torque_constant_nm_per_a: float
    current_bandwidth_hz: float
    start_qpos: float

    @property
    def peak_torque_nm(self) -> float:
        """Motor torque at peak current, in N*m."""
        return self.peak_current_a * self.torque_constant_nm_per_a


# --- the numbers a family derives from its parameter values -------------------------------


@dataclasses.dataclass(frozen=True)
class _BodyNumbers:
    """Inertial properties and placement of one body (all in the parent's frame, SI)."""

    mass: float
    inertia: tuple[float, float, float]
    ipos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class _JointNumbers:
    """Passive properties of one joint (SI, in the joint's units)."""

    armature: float
    damping: float
    frictionloss: float
    range: tuple[float, float]
    stiffness: float = 0.0


@dataclasses.dataclass(frozen=True)
class _GeomNumbers:
    """Placement and size of one visual geom."""

    pos: tuple[float, float, float]
    size: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class _Numbers:
    """Every model number that depends on the parameter values."""

    bodies: dict[str, _BodyNumbers]
    joints: dict[str, _JointNumbers]
    geoms: dict[str, _GeomNumbers]
    gear: float
    peak_torque_nm: float


def _set_coef(element: Any, attr: str, value: float) -> None:
    """Set a joint's linear damping/stiffness (an array with polynomial terms in MuJoCo 4)."""
    old = getattr(element, attr)
    if np.ndim(old):
        setattr(element, attr, [value] + [0.0] * (len(old) - 1))
    else:
        setattr(element, attr, value)


# Names shared by every family's skeleton.
MOTOR_JOINT = "motor"
MOTOR_ACTUATOR = "motor"


class PlantFamily(abc.ABC):
    """A family of MuJoCo servo plants with physical parameters.

    Subclasses define the topology (:meth:`_skeleton`), the model numbers
    (:meth:`_numbers`), and the transmission (:meth:`_transmission`).

    Attributes:
        name: Registry key, e.g. ``"two-mass"``.
        description: One paragraph saying what the plant is.
        params: The parameters, in a fixed order (the sampling order).
        joint_unit: Unit of the measured joint: ``"rad"`` or ``"m"``.
        load_param: The parameter that is the axis's load (an inertia or a payload mass),
            which ``servogym check`` varies.
        position_stages: Whether the servo loop's RK4 must recompute the position-dependent
            quantities (mass matrix, kinematics, gravity torque) at every stage. ``False``
            (the default) is exact only for plants whose forces do not depend on position
            except through joint springs: a constant mass matrix and a constant gravity
            force (tests/sim/test_convergence.py checks every family against the reference).
    """

    name: str
    description: str
    joint_unit: str
    params: tuple[PlantParam, ...]
    load_param: str = ""
    position_stages: bool = False

    def __init__(self) -> None:
        self._by_name = {p.name: p for p in self.params}
        if len(self._by_name) != len(self.params):
            raise ValueError(f"duplicate parameter names in plant family {self.name}")

    def __repr__(self) -> str:
        return f"<PlantFamily {self.name!r}: {', '.join(self._by_name)}>"

    # --- parameters -----------------------------------------------------------------------

    def param(self, name: str) -> PlantParam:
        """The parameter called ``name``.

        Raises:
            PlantParameterError: if the family has no such parameter (the message lists the
                closest names).
        """
        try:
            return self._by_name[name]
        except KeyError:
            raise PlantParameterError(self._unknown_message(name)) from None

    def _unknown_message(self, name: str) -> str:
        close = difflib.get_close_matches(str(name), list(self._by_name), n=3)
        hint = f" Did you mean {', '.join(close)}?" if close else ""
        return (
            f"plant family {self.name!r} has no parameter {name!r}; its parameters are "
            f"{', '.join(self._by_name)}.{hint}"
        )

    def nominal(self) -> dict[str, float | int]:
        """Every parameter's nominal value, in parameter order."""
        return {p.name: p.nominal for p in self.params}

    def randomised(self) -> list[str]:
        """Names of the parameters :meth:`sample` draws by default."""
        return [p.name for p in self.params if p.randomised]

    def validate(self, values: Mapping[str, Any] | None = None) -> dict[str, float | int]:
        """Check parameter values and return a complete set.

        The legal range of each parameter is its documented realistic range for this family
        (``PlantParam.low .. PlantParam.high``); values outside it are rejected.

        Args:
            values: Some or all parameters, each in its ``unit``; missing ones take their
                nominal value.

        Returns:
            Every parameter, in parameter order, as Python floats (ints for integer
            parameters).

        Raises:
            PlantParameterError: for an unknown name (with close matches) or an illegal value
                (naming the parameter, the value and the legal range).
        """
        values = {} if values is None else values
        if not isinstance(values, Mapping):
            raise PlantParameterError(
                f"values must be a mapping of parameter name to value for the {self.name!r} "
                f"plant family; got values of type {type(values).__name__}."
            )
        for name in values:
            if name not in self._by_name:
                raise PlantParameterError(self._unknown_message(name))
        out = self.nominal()
        for name, value in values.items():
            out[name] = self._by_name[name].validate(value, family=self.name)
        return out

    def validate_ranges(
        self,
        ranges: Mapping[str, Any] | None,
        *,
        option: str = "plant_range",
        fixed: Iterable[str] = (),
    ) -> dict[str, tuple[float, float]]:
        """Check parameter ranges (``{"payload_kg": (0.5, 2.0)}``) and return them as numbers.

        Args:
            ranges: ``name -> (low, high)``, each end in the parameter's unit.
            option: How the caller calls the ranges, for the messages (``--plant-range``).
            fixed: Names held at a fixed value (``plant_values``), which cannot also vary.

        Returns:
            ``name -> (low, high)`` in parameter order, floats (ints for integer parameters).

        Raises:
            PlantParameterError: for an unknown name (with close matches), an end that is not
                a number, ``low > high``, an end outside the legal range (each message names
                the option, the value and the legal range), or a name also in ``fixed``.
        """
        ranges = {} if ranges is None else ranges
        if not isinstance(ranges, Mapping):
            raise PlantParameterError(
                f"{option} must be a mapping of parameter name to (low, high) for the "
                f"{self.name!r} plant family; got {type(ranges).__name__}."
            )
        fixed = set(fixed)
        out: dict[str, tuple[float, float]] = {}
        for name, pair in ranges.items():
            if name not in self._by_name:
                raise PlantParameterError(f"{option}: {self._unknown_message(name)}")
            p = self._by_name[name]
            legal = f"inside the legal range {p.range_text} ({p.unit})"
            if (
                isinstance(pair, str | bytes)
                or not isinstance(pair, Iterable)
                or len(pair := tuple(pair)) != 2
            ):
                raise PlantParameterError(
                    f"{option} {name} must be a pair (low, high) {legal}; got {name}={pair!r}."
                )
            lo, hi = (
                int(x) if p.integer and isinstance(x, float) and x.is_integer() else x for x in pair
            )
            try:
                lo, hi = (p.validate(x, family=self.name) for x in (lo, hi))
            except PlantParameterError:
                raise PlantParameterError(
                    f"{option} {name}={_fmt_end(lo)}:{_fmt_end(hi)} must lie {legal}, both ends "
                    f"{'integers' if p.integer else 'real numbers'}."
                ) from None
            if lo > hi:
                raise PlantParameterError(
                    f"{option} {name}={_fmt(lo)}:{_fmt(hi)} must have low <= high, {legal}."
                )
            if name in fixed:
                raise PlantParameterError(
                    f"{option} {name}={_fmt(lo)}:{_fmt(hi)}: {name} is also held at a fixed "
                    "value (plant_values, --plant-param); give it a value or a range, not both."
                )
            out[name] = (lo, hi)
        return {p.name: out[p.name] for p in self.params if p.name in out}

    def sample_bounds(
        self,
        scale: float = 1.0,
        *,
        randomise: Iterable[str] | None = None,
        ranges: Mapping[str, tuple[float, float]] | None = None,
    ) -> dict[str, tuple[float, float]]:
        """The range :meth:`sample` draws each parameter from, ``name -> (low, high)``.

        Args:
            scale: As in :meth:`sample`.
            randomise: As in :meth:`sample`.
            ranges: As in :meth:`sample` (validated with :meth:`validate_ranges`).
        """
        _check_scale(scale)
        ranges = self.validate_ranges(ranges)
        out = {}
        for p, lo, hi in self._drawn(randomise, ranges):
            nom = min(max(p.nominal, lo), hi)
            if p.distribution == "loguniform":
                a, n, b = math.log(lo), math.log(nom), math.log(hi)
                low, high = math.exp(n - scale * (n - a)), math.exp(n + scale * (b - n))
            else:
                low, high = nom - scale * (nom - lo), nom + scale * (hi - nom)
            out[p.name] = (min(max(low, lo), hi), min(max(high, lo), hi))
        return out

    def _drawn(
        self, randomise: Iterable[str] | None, ranges: Mapping[str, tuple[float, float]]
    ) -> list[tuple[PlantParam, float, float]]:
        """The parameters drawn, in parameter order, each with the range it is drawn from."""
        names = self.randomised() if randomise is None else list(randomise)
        for name in names:
            self.param(name)
        names = set(names) | set(ranges)
        return [
            (p, *ranges.get(p.name, (p.sample_low, p.sample_high)))
            for p in self.params
            if p.name in names
        ]

    def sample(
        self,
        rng: np.random.Generator,
        scale: float = 1.0,
        *,
        randomise: Iterable[str] | None = None,
        base: Mapping[str, Any] | None = None,
        ranges: Mapping[str, tuple[float, float]] | None = None,
    ) -> dict[str, float | int]:
        """Draw a plant instance.

        Each randomised parameter is drawn from its ``distribution`` over a range that
        shrinks towards the nominal value with ``scale``: ``nominal - scale * (nominal -
        low) .. nominal + scale * (high - nominal)`` (in log space for ``"loguniform"``),
        where ``low .. high`` is the parameter's range in ``ranges`` if given, else its
        default sampling range (``PlantParam.sample_range``: the legal range, or the part of
        it the default motor can move), and the nominal value is taken clipped into it.
        Parameters are drawn in parameter order, one ``rng.uniform`` call each, so the same
        generator state gives the same values.

        Args:
            rng: The random generator (``np.random.default_rng(seed)``).
            scale: Fraction of the sampling range to sample, ``0 <= scale <= 1``: 1 samples
                the whole range, 0 gives the nominal value (useful for curricula).
            randomise: Names of the parameters to draw, instead of the family's default
                (:meth:`randomised`).
            base: Values of the parameters that are not drawn (default: nominal).
            ranges: ``name -> (low, high)``: draw these parameters (randomised or not) from
                this part of their legal range (:meth:`validate_ranges`).

        Returns:
            Every parameter, validated, in parameter order.

        Raises:
            TypeError: if ``rng`` is not a ``numpy.random.Generator``.
            ValueError: if ``scale`` is outside ``0 <= scale <= 1``.
            PlantParameterError: for an unknown name in ``randomise``, ``base`` or
                ``ranges``, or an illegal range.
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(
                "rng must be a numpy.random.Generator (np.random.default_rng(seed)); "
                f"got rng of type {type(rng).__name__}."
            )
        _check_scale(scale)
        drawn = self._drawn(randomise, self.validate_ranges(ranges))
        out = self.validate(base)
        for p, lo, hi in drawn:
            out[p.name] = _draw(p, rng, float(scale), lo, hi)
        return out

    # --- building -------------------------------------------------------------------------

    def build(
        self, values: Mapping[str, Any] | None = None, *, timestep_s: float = DEFAULT_TIMESTEP_S
    ) -> Plant:
        """Compile a plant instance.

        Args:
            values: Some or all parameters (missing ones nominal); see :meth:`validate`.
            timestep_s: Physics timestep in seconds, ``1e-8 <= timestep_s <= 1e-3``.

        Returns:
            The compiled plant, reset to its start position.
        """
        full = self.validate(values)
        timestep_s = _check_timestep(timestep_s)
        spec = self._make_spec(full, timestep_s)
        model = spec.compile()
        return Plant(self, full, spec, model)

    def _make_spec(self, values: Mapping[str, Any], timestep_s: float) -> mujoco.MjSpec:
        spec = mujoco.MjSpec()
        spec.modelname = self.name
        spec.compiler.degree = False  # hinge ranges in radians
        spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
        spec.compiler.autolimits = False
        spec.option.timestep = timestep_s
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.gravity = [0.0, 0.0, -GRAVITY_MPS2]
        # No contacts (the geoms are visual only). No auto-reset: MuJoCo would silently reset
        # a diverged simulation to qpos0; the runner must see the NaN and stop instead. No
        # refsafe: the constraints' time constants are physical values that must not change
        # with the integration step (FRICTION_SOLREF), or no integration would converge.
        spec.option.disableflags |= (
            mujoco.mjtDisableBit.mjDSBL_CONTACT
            | mujoco.mjtDisableBit.mjDSBL_AUTORESET
            | mujoco.mjtDisableBit.mjDSBL_REFSAFE
        )
        self._skeleton(spec)
        for joint in spec.joints:
            limited = joint.name == MOTOR_JOINT
            joint.limited = mujoco.mjtLimited(int(limited))  # only the motor joint has stops
            joint.solref_limit = list(LIMIT_SOLREF)
            joint.solref_friction = list(FRICTION_SOLREF)
            joint.solimp_friction = list(FRICTION_SOLIMP)
        for geom in spec.geoms:
            geom.contype = 0
            geom.conaffinity = 0
        spec.add_actuator(
            name=MOTOR_ACTUATOR,
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            target=MOTOR_JOINT,
            ctrllimited=mujoco.mjtLimited.mjLIMITED_TRUE,
        )
        _write_spec(spec, self._numbers(values))
        return spec

    @abc.abstractmethod
    def _skeleton(self, spec: mujoco.MjSpec) -> None:
        """Add the bodies (explicit inertial), joints and visual geoms, all named.

        The measured joint is called ``"motor"``; every body gets ``explicitinertial``. The
        numbers that depend on parameters are written afterwards by :func:`_write_spec`.
        """

    @abc.abstractmethod
    def _numbers(self, values: Mapping[str, Any]) -> _Numbers:
        """Every model number that depends on the (validated, complete) parameter values."""

    @abc.abstractmethod
    def _transmission(self, values: Mapping[str, Any]) -> tuple[float, float]:
        """Motor shaft angle per joint unit (rad per joint unit) and encoder counts per unit."""

    def counts_per_unit(self, values: Mapping[str, Any] | None = None) -> float:
        """Encoder counts per joint unit of an instance (nominal values where not given)."""
        return float(self._transmission({**self.nominal(), **(values or {})})[1])

    def _axis_io(self, model: mujoco.MjModel, values: Mapping[str, Any]) -> AxisIO:
        joint = model.joint(MOTOR_JOINT)
        ratio, counts_per_unit = self._transmission(values)
        peak = float(values["peak_current_a"])
        return AxisIO(
            qpos_adr=int(joint.qposadr[0]),
            qvel_adr=int(joint.dofadr[0]),
            ctrl_index=int(model.actuator(MOTOR_ACTUATOR).id),
            counts_per_unit=counts_per_unit,
            motor_rad_per_unit=ratio,
            travel_min=float(joint.range[0]),
            travel_max=float(joint.range[1]),
            amp_amps_per_count=peak / COMMAND_FULL_SCALE,
            peak_current_a=peak,
            torque_constant_nm_per_a=float(values["torque_constant_nm_per_a"]),
            current_bandwidth_hz=float(values["current_bandwidth_hz"]),
            start_qpos=float(model.qpos0[joint.qposadr[0]]),
        )


LIMIT_SOLREF = (0.002, 1.0)
"""``solref`` of the travel-limit constraint: time constant (s) and damping ratio, fixed
(``refsafe`` is off, so it does not change with the timestep)."""


FRICTION_SOLREF = (320e-6, 1.0)
"""``solref`` of the Coulomb-friction (``frictionloss``) constraint: time constant (s) and
damping ratio. The regularised friction is a fast velocity mode of rate about
``2 / time constant``; 320 us is twice the longest substep of the default integration
(``servogym.sim.MAX_SUBSTEP_S``), what MuJoCo's ``refsafe`` would impose there, and is fixed
so that every integration step size simulates the same friction."""

FRICTION_SOLIMP = (0.999, 0.9999, 0.001, 0.5, 2.0)
"""``solimp`` of the Coulomb-friction constraint. With MuJoCo's default (0.9, 0.95, ...) the
nominal rotary plant creeps at 0.04 rad/s (900 counts/s) under half its Coulomb torque; with
this, and ``FRICTION_SOLREF``, at most a few counts/s for every nominal plant at 700 us."""


def _draw(
    p: PlantParam, rng: np.random.Generator, scale: float, low: float, high: float
) -> float | int:
    """One draw of ``p`` over ``scale`` of ``low .. high`` (see :meth:`PlantFamily.sample`)."""
    centre = min(max(p.nominal, low), high)
    if p.distribution == "loguniform":
        lo, nom, hi = math.log(low), math.log(centre), math.log(high)
        x = math.exp(rng.uniform(nom - scale * (nom - lo), nom + scale * (hi - nom)))
    else:
        nom = centre
        x = float(rng.uniform(nom - scale * (nom - low), nom + scale * (high - nom)))
    if scale == 0.0:
        x = centre  # exactly, after the same one draw (exp(log(x)) need not be x)
    x = min(max(x, low), high)  # exp(log(x)) may round just outside the range
    return round(x) if p.integer else x


def _check_scale(scale: Any) -> None:
    if isinstance(scale, bool) or not isinstance(scale, numbers.Real) or not 0 <= scale <= 1:
        raise ValueError(f"scale must satisfy 0 <= scale <= 1; got scale={scale!r}.")


def _fmt_end(x: Any) -> str:
    """A range end as the user gave it: a number in its shortest form, anything else repr."""
    if isinstance(x, numbers.Real) and not isinstance(x, bool):
        return _fmt(x)
    return repr(x)


def parse_plant_ranges(
    items: Iterable[str] | None, family: PlantFamily | None = None, option: str = "--plant-range"
) -> dict[str, tuple[float, float]]:
    """``NAME=LO:HI`` texts (``--plant-range payload_kg=0.5:2``) as ``name -> (lo, hi)``.

    Args:
        items: The texts, one range each.
        family: Validate against this family (:meth:`PlantFamily.validate_ranges`) when given.
        option: The option's name, for the messages.

    Raises:
        PlantParameterError: for malformed text, a repeated name, an end that is not a number
            (and, with ``family``, everything :meth:`PlantFamily.validate_ranges` refuses),
            each in one line naming the option and the value.
    """
    out: dict[str, tuple[float, float]] = {}
    for item in items or ():
        name, sep, rest = str(item).partition("=")
        lo_text, colon, hi_text = rest.partition(":")
        name = name.strip()
        if not sep or not colon or not name or ":" in hi_text:
            raise PlantParameterError(
                f"{option} must be NAME=LOW:HIGH (e.g. {option} payload_kg=0.5:2); got {item!r}."
            )
        ends = []
        for text in (lo_text, hi_text):
            try:
                ends.append(float(text))
            except ValueError:
                raise PlantParameterError(
                    f"{option} {name}= needs two numbers LOW:HIGH in the parameter's unit; "
                    f"got {item!r} ({text.strip()!r} is not a number)."
                ) from None
        if name in out:
            raise PlantParameterError(
                f"{option} {name} is given twice ({_fmt(out[name][0])}:{_fmt(out[name][1])} and "
                f"{rest.strip()}); give each parameter one range."
            )
        out[name] = (ends[0], ends[1])
    if family is not None:
        out = family.validate_ranges(out, option=option)
    return out


def _check_timestep(timestep_s: Any) -> float:
    if (
        isinstance(timestep_s, bool)
        or not isinstance(timestep_s, numbers.Real)
        or not TIMESTEP_MIN_S <= timestep_s <= TIMESTEP_MAX_S
    ):
        raise ValueError(
            f"timestep_s must satisfy {TIMESTEP_MIN_S:g} <= timestep_s <= {TIMESTEP_MAX_S:g} "
            f"(seconds); got timestep_s={timestep_s!r}."
        )
    return float(timestep_s)


# --- the two paths from numbers to a model ------------------------------------------------


def _write_spec(spec: mujoco.MjSpec, n: _Numbers) -> None:
    """Write the numbers into the spec (the path through the compiler)."""
    for name, b in n.bodies.items():
        body = spec.body(name)
        body.mass = b.mass
        body.inertia = list(b.inertia)
        body.ipos = list(b.ipos)
        body.pos = list(b.pos)
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
    actuator = spec.actuator(MOTOR_ACTUATOR)
    actuator.gear = [n.gear, 0.0, 0.0, 0.0, 0.0, 0.0]
    actuator.ctrlrange = [-n.peak_torque_nm, n.peak_torque_nm]


def _write_model(model: mujoco.MjModel, n: _Numbers) -> None:
    """Write the numbers into the compiled model's arrays (the in-place path)."""
    for name, b in n.bodies.items():
        i = model.body(name).id
        model.body_mass[i] = b.mass
        model.body_inertia[i] = b.inertia
        model.body_ipos[i] = b.ipos
        model.body_pos[i] = b.pos
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
    i = model.actuator(MOTOR_ACTUATOR).id
    model.actuator_gear[i, 0] = n.gear
    model.actuator_ctrlrange[i] = (-n.peak_torque_nm, n.peak_torque_nm)


def _set_statistics(model: mujoco.MjModel) -> None:
    """Recompute the mass statistics the compiler derives but ``mj_setConst`` leaves alone.

    ``stat.meaninertia`` scales the constraint solver's tolerance, so it must follow the
    masses for an edited model to step exactly like a compiled one. Same summation order as
    MuJoCo's compiler: the mean of the joint-space inertia diagonal at ``qpos0``
    (``dof_M0``), and the mean mass of the bodies other than the world.
    """
    total = 0.0
    for value in model.dof_M0:
        total += float(value)
    model.stat.meaninertia = total / model.nv
    total = 0.0
    for value in model.body_mass[1:]:
        total += float(value)
    model.stat.meanmass = total / (model.nbody - 1)


class Plant:
    """One compiled plant instance, edited in place between episodes.

    Attributes:
        family: The :class:`PlantFamily` it belongs to.
        values: The current parameter values (a complete, validated dict; do not edit it,
            call :meth:`set_params`).
        spec: The ``mujoco.MjSpec`` it was compiled from, kept up to date by
            :meth:`set_params` (``spec.compile()`` gives a fresh model of the current
            instance).
        model: The compiled ``mujoco.MjModel``; the same object for the plant's lifetime.
        data: The ``mujoco.MjData``; the same object for the plant's lifetime.
        io: The :class:`AxisIO` of the current instance.
    """

    def __init__(
        self,
        family: PlantFamily,
        values: dict[str, float | int],
        spec: mujoco.MjSpec,
        model: mujoco.MjModel,
    ) -> None:
        self.family = family
        self.values = dict(values)
        self.spec = spec
        self.model = model
        self.data = mujoco.MjData(model)
        self.io = family._axis_io(model, self.values)
        self._state_buffer = np.zeros(mujoco.mj_stateSize(model, _STATE_SIG))
        self.reset()

    def __repr__(self) -> str:
        return f"<Plant {self.family.name!r} timestep_s={self.model.opt.timestep:g}>"

    @property
    def timestep_s(self) -> float:
        """The physics timestep, in seconds."""
        return float(self.model.opt.timestep)

    def set_params(
        self, values: Mapping[str, Any] | None = None, *, keep_state: bool = False, **kw: Any
    ) -> None:
        """Change the plant instance in place, then reset it (or keep its state).

        Parameters not given keep their current values. The compiled model's arrays (masses,
        inertias, damping, friction, stiffness, ranges, gear, ...) are overwritten, then
        ``mujoco.mj_setConst`` recomputes the derived constants and ``mujoco.mj_resetData``
        puts the plant at its start position. Nothing is recompiled or reallocated: ``model``,
        ``data`` and their arrays stay the same objects. ``io`` is recomputed.

        Args:
            values: Parameters to change, each in its unit.
            keep_state: Instead of resetting, put the full integration state (position,
                velocity, actuator state, controls, the solver's warm start, time) back as it
                was: a payload picked up at rest, in the middle of a sequence of moves.
            **kw: More parameters to change, by name (``payload_kg=3.0``).

        Raises:
            PlantParameterError: for an unknown name or an illegal value; the plant is left
                unchanged.
        """
        updates = dict(values or {})
        updates.update(kw)
        full = self.family.validate({**self.values, **updates})
        numbers_ = self.family._numbers(full)
        if keep_state:
            mujoco.mj_getState(self.model, self.data, self._state_buffer, _STATE_SIG)
        _write_spec(self.spec, numbers_)
        _write_model(self.model, numbers_)
        mujoco.mj_setConst(self.model, self.data)
        _set_statistics(self.model)
        self.values = full
        self.io = self.family._axis_io(self.model, full)
        self.reset()
        if keep_state:
            mujoco.mj_setState(self.model, self.data, self._state_buffer, _STATE_SIG)
            mujoco.mj_forward(self.model, self.data)

    def set_timestep(self, dt_s: float) -> None:
        """Set the physics timestep (the runner uses the chip's servo period / substeps).

        Does not reset the plant.

        Args:
            dt_s: Timestep in seconds, ``1e-8 <= dt_s <= 1e-3``.
        """
        dt_s = _check_timestep(dt_s)
        self.model.opt.timestep = dt_s
        self.spec.option.timestep = dt_s

    def reset(self) -> None:
        """Reset the state (``mujoco.mj_resetData``): at rest at ``io.start_qpos``, zero ctrl."""
        mujoco.mj_resetData(self.model, self.data)
