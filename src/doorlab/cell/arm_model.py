"""The lab arm's uncertain parameters as Drake systems (``station.arm``,
:class:`doorlab.config.ArmModelConfig`): the joints' friction with KUKA's friction observer,
the external torque KUKA estimates (its load data, noise) and the command's latency beyond
the cycle. C++ systems only (``SymbolicVectorSystem``, ``RandomSource``, ``MatrixGain``,
``ZeroOrderHold``, ``InverseDynamics``): nothing here runs Python per plant step.

- **Friction** (:func:`add_joint_friction`, in the station): tau_f = -(1 - w) (Fc + (Fs - Fc)
  exp(-(max(|v| - 3 v_eps, 0)/vs)^2)) tanh(v / v_eps) per joint
  (:func:`doorlab.kuka.stribeck_friction`: the decay starts once the tanh has saturated, so
  that the largest friction is the stiction, 0.995 Fs), w =
  min(1, |q_ref - q| / band) the share KUKA's friction observer cancels ("only triggered when
  there is a position difference", kuka_driver.cc's comment on its IIR filter). The torque
  is explicit (evaluated at the step's start), so the tanh's slope Fs / v_eps is kept at
  M_ii / h, half the explicit limit 2 M_ii / h (:func:`friction_regularization`).
- **External torque** (:func:`add_external_torque_estimate`, in the arm cell): KUKA's estimate
  is the measured joint torque minus its model: tau_ext = contact + (g_believed(q) -
  g_true(q)) + noise, g the gravity torques of the arm with the load data KUKA believes and
  with the gripper it carries; the noise is Gaussian, one draw per cycle
  (``RandomSource``, fixed seed). The joint torque sensors sit after the gears, so the
  joints' friction does not enter it.
- **Latency** (:func:`add_command_latency`, in the arm cell): a command applied at cycle
  t_k acts from t_k + L, L = latency + jitter x U(-1, 1) drawn per cycle. The plant's steps
  (h, dividing the cycle) see for each step the torque-weighted command over it: a step
  that L splits gets (f old + (1 - f) new), f the share of the step before t_k + L; the
  spring's torque over that step is then exactly the delayed command's (the spring is
  evaluated at the step's start).
"""

from __future__ import annotations

import numpy as np
import pydrake.symbolic as sym
from pydrake.common import RandomDistribution
from pydrake.systems.framework import DiagramBuilder, OutputPort
from pydrake.systems.primitives import (
    Adder,
    MatrixGain,
    Multiplexer,
    RandomSource,
    SymbolicVectorSystem,
    ZeroOrderHold,
)

from doorlab.constants import NUM_JOINTS
from doorlab.kuka import CYCLE_PERIOD, STRIBECK_ONSET, STRIBECK_VELOCITY

MIN_FRICTION_REGULARIZATION = 1e-4
"""Smallest v_eps [rad/s] of the friction's tanh."""
NOISE_SEED = 20260
"""The external-torque noise's seed offset (plus ``station.arm.seed``)."""
JITTER_SEED = 40520
"""The latency jitter's seed offset (plus ``station.arm.seed``)."""


def friction_regularization(stiction: np.ndarray, inertia: np.ndarray, h: float) -> np.ndarray:
    """v_eps per joint [rad/s]: the friction's slope at rest Fs / v_eps is M_ii / h, half the
    limit 2 M_ii / h above which an explicit torque makes a step unstable.

    Args:
        stiction: Fs (7,) [N m]. inertia: M_ii (7,) [kg m^2]. h: The plant's step [s].
    """
    slope = np.asarray(inertia, float) / h
    return np.maximum(np.asarray(stiction, float) / slope, MIN_FRICTION_REGULARIZATION)


def _friction_system(arm, v_eps: np.ndarray) -> SymbolicVectorSystem:
    """[q (7), v (7), q_ref (7)] -> the friction torque (7) [N m]."""
    u = sym.MakeVectorVariable(3 * NUM_JOINTS, "u")
    q, v, q_ref = u[:NUM_JOINTS], u[NUM_JOINTS : 2 * NUM_JOINTS], u[2 * NUM_JOINTS :]
    band = float(arm.friction_compensation_band)
    out = []
    for i in range(NUM_JOINTS):
        fc, fs = float(arm.coulomb_friction[i]), float(arm.stiction[i])
        gap = abs(q_ref[i] - q[i]) / band
        w = sym.min(gap, 1.0)
        eps = float(v_eps[i])
        slide = sym.max(abs(v[i]) - STRIBECK_ONSET * eps, 0.0) / STRIBECK_VELOCITY
        level = fc + (fs - fc) * sym.exp(-(slide**2))
        out.append(-(1.0 - w) * level * sym.tanh(v[i] / eps))
    return SymbolicVectorSystem(input=u, output=np.array(out))


def add_joint_friction(
    builder: DiagramBuilder,
    q: OutputPort,
    v: OutputPort,
    q_ref: OutputPort,
    arm,
    *,
    inertia: np.ndarray,
    h: float,
) -> OutputPort:
    """The joints' friction torque (7) [N m] from the arm's q, v and the applied q_ref.

    Args:
        arm: ``station.arm``. inertia: M_ii for the regularization (7,) [kg m^2].
        h: The plant's step [s].
    """
    v_eps = friction_regularization(arm.stiction, inertia, h)
    inputs = builder.AddNamedSystem("joint_friction_input", Multiplexer([NUM_JOINTS] * 3))
    for i, port in enumerate((q, v, q_ref)):
        builder.Connect(port, inputs.get_input_port(i))
    friction = builder.AddNamedSystem("joint_friction", _friction_system(arm, v_eps))
    builder.Connect(inputs.get_output_port(), friction.get_input_port())
    return friction.get_output_port()


def load_data_error(arm) -> bool:
    """Whether KUKA's load data differ from the gripper the arm carries."""
    return arm.load_mass is not None


def add_external_torque_estimate(
    builder: DiagramBuilder,
    contact: OutputPort,
    arm_state: OutputPort,
    arm,
    *,
    believed=None,
    true=None,
):
    """KUKA's external-torque estimate (7) [N m] from the true contact torques: plus the
    gravity its load data leaves out, g_believed(q) - g_true(q), and the noise.

    Returns:
        (its port, the random sources as (system, seed): seed them with
        :func:`seed_random_sources` before a run).

    Args:
        contact: The contact torques on the arm's joints (7). arm_state: [q; v] (14).
        arm: ``station.arm``. believed, true: The controller plants with KUKA's load data
            and with the gripper (needed when :func:`load_data_error`).
    """
    from pydrake.systems.controllers import InverseDynamics

    terms, sources = [contact], []
    if load_data_error(arm):
        mode = InverseDynamics.InverseDynamicsMode.kGravityCompensation
        for name, model, sign in (("believed", believed, 1.0), ("true", true, -1.0)):
            gravity = builder.AddNamedSystem(f"gravity_{name}", InverseDynamics(model, mode))
            builder.Connect(arm_state, gravity.get_input_port_estimated_state())
            gain = builder.AddNamedSystem(
                f"gravity_{name}_sign", MatrixGain(sign * np.eye(NUM_JOINTS))
            )
            builder.Connect(gravity.get_output_port(), gain.get_input_port())
            terms.append(gain.get_output_port())
    sigma = np.asarray(arm.external_torque_noise, float)
    if np.any(sigma > 0):
        noise = builder.AddNamedSystem(
            "external_torque_noise",
            RandomSource(RandomDistribution.kGaussian, NUM_JOINTS, CYCLE_PERIOD),
        )
        sources.append((noise, NOISE_SEED + int(arm.seed)))
        scale = builder.AddNamedSystem("external_torque_noise_scale", MatrixGain(np.diag(sigma)))
        builder.Connect(noise.get_output_port(), scale.get_input_port())
        terms.append(scale.get_output_port())
    if len(terms) == 1:
        return contact, sources
    total = builder.AddNamedSystem("external_torque_estimate", Adder(len(terms), NUM_JOINTS))
    for i, port in enumerate(terms):
        builder.Connect(port, total.get_input_port(i))
    return total.get_output_port(), sources


def latency_steps(time_step: float) -> int:
    """Plant steps per 5 ms cycle (the latency's blend needs a whole number)."""
    return round(CYCLE_PERIOD / time_step)


def _latency_blend(size: int, steps: int, h: float, latency: float, jitter: float):
    """[H_0, ..., H_N (size each), u] -> the command the plant steps with (size).

    H_m holds the latch's value sampled m steps after the cycle (H_0 the latch itself, H_N
    the previous cycle's); u in [-1, 1] the cycle's jitter. With L = latency + jitter u = (j +
    f) h the output is (1 - f) H_j + f H_{j+1}: the steps before t_k + L see the old command,
    the one it splits a blend, the rest the new one.
    """
    u = sym.MakeVectorVariable(size * (steps + 1) + 1, "u")
    blocks = [u[m * size : (m + 1) * size] for m in range(steps + 1)]
    L = latency + jitter * u[-1]
    x = sym.min(sym.max(L / h, 0.0), steps - 1e-9)
    out = []
    for k in range(size):
        value = blocks[steps][k]
        for j in reversed(range(steps)):
            f = x - j
            blend = (1.0 - f) * blocks[j][k] + f * blocks[j + 1][k]
            value = sym.if_then_else(x < j + 1, blend, value)
        out.append(value)
    return SymbolicVectorSystem(input=u, output=np.array(out))


def add_command_latency(
    builder: DiagramBuilder, applied: OutputPort, arm, *, time_step: float, offset: float
):
    """The applied command (size n) as the plant sees it with ``station.arm``'s latency.

    Args:
        applied: The command latch's output (q_ref, tau_ff: the blended part).
        arm: ``station.arm`` (latency > 0 or jitter > 0). time_step: h (divides 5 ms).
        offset: The cycle's events' offset [s] (:func:`doorlab.cell.arm_cell.cycle_offset`).

    Returns:
        (the delayed command's port, the holds H_1..H_N whose state the caller initializes,
        the jitter's random source as [(system, seed)]).
    """
    steps = latency_steps(time_step)
    size = applied.size()
    holds = []
    for m in range(1, steps + 1):
        hold_offset = offset + (m % steps) * time_step
        hold = builder.AddNamedSystem(
            f"command_latency_hold_{m}", ZeroOrderHold(CYCLE_PERIOD, size, offset_sec=hold_offset)
        )
        builder.Connect(applied, hold.get_input_port())
        holds.append(hold)
    parts = [applied, *(hold.get_output_port() for hold in holds)]
    inputs = builder.AddNamedSystem(
        "command_latency_input", Multiplexer([size] * (steps + 1) + [1])
    )
    for i, port in enumerate(parts):
        builder.Connect(port, inputs.get_input_port(i))
    jitter = builder.AddNamedSystem(
        "command_latency_jitter", RandomSource(RandomDistribution.kUniform, 1, CYCLE_PERIOD)
    )
    sources = [(jitter, JITTER_SEED + int(arm.seed))]
    # U(0, 1) -> U(-1, 1)
    spread = builder.AddNamedSystem(
        "command_latency_jitter_spread",
        SymbolicVectorSystem(
            input=(w := sym.MakeVectorVariable(1, "w")), output=np.array([2.0 * w[0] - 1.0])
        ),
    )
    builder.Connect(jitter.get_output_port(), spread.get_input_port())
    builder.Connect(spread.get_output_port(), inputs.get_input_port(steps + 1))
    blend = builder.AddNamedSystem(
        "command_latency",
        _latency_blend(size, steps, time_step, float(arm.latency), float(arm.latency_jitter)),
    )
    builder.Connect(inputs.get_output_port(), blend.get_input_port())
    return blend.get_output_port(), holds, sources


def seed_random_sources(sources, root_context) -> None:
    """Seeds each (RandomSource, seed) in ``root_context``: the same seed, the same draws in
    any process (a RandomSource's default seed counts the instances built before it)."""
    from pydrake.common import RandomGenerator

    for source, seed_value in sources:
        source.SetRandomContext(
            source.GetMyMutableContextFromRoot(root_context), RandomGenerator(seed_value)
        )


def latency_active(arm) -> bool:
    """Whether ``station.arm`` delays commands beyond the cycle."""
    return arm.latency > 0 or arm.latency_jitter > 0


def describe(arm) -> str:
    """``station.arm`` in one line, for pages and summaries."""
    parts = [
        "load data " + ("exact" if arm.load_mass is None else f"{arm.load_mass:g} kg"),
        "friction "
        + (
            "none"
            if not arm.friction()
            else f"Fs {max(arm.stiction):g} / Fc {max(arm.coulomb_friction):g} N m (largest)"
        ),
        "latency "
        + (
            f"{1e3 * arm.latency:g} ms"
            + (f" +- {1e3 * arm.latency_jitter:g}" if arm.latency_jitter else "")
        ),
    ]
    noise = max(arm.external_torque_noise)
    if noise > 0:
        parts.append(f"external-torque noise {noise:g} N m")
    return ", ".join(parts)
