"""Time and energy of arm motions: joint torques from Pinocchio's RNEA (with the held mug as a payload on the
gripper) turned into electrical power by a DC-motor model of each servo, beside the thesis's proxy.

Servo model, output-referred, gearbox included: current I = tau / k_t, terminal voltage V = R I + k_e omega,
electrical power P = V I = R I^2 + k_e omega I. A servo's H-bridge does not return braking energy to the
supply, so negative power counts as zero. k_t, k_e and R come from the datasheet's stall torque, stall
current and no-load speed at the supply voltage (``ServoModel``). While the arm is still, the joints still
draw the copper loss of holding it against gravity, and every servo's electronics draw standby current.

The thesis estimated energy as the potential-energy-like proxy E = M_m g Δm (Eq 4.1-4.2), Δm the straight
distance from the counter to the tray; ``thesis_energy_j`` gives it for comparison.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from description import thesis
from description.servos import SERVO_MODELS
from drivers.interfaces import FloatArray
from planning.arm.model import ArmModel
from planning.motion.trajectory import JointPath


@dataclass(frozen=True, slots=True)
class EnergyBreakdown:
    """Electrical energy of a motion (joules) drawn from the supply, and the part lost in the windings."""

    total_j: float
    copper_j: float


def thesis_energy_j(
    mug_mass_kg: float, start_xy_m: tuple[float, float], goal_xy_m: tuple[float, float]
) -> float:
    """The thesis's energy proxy for one mug, F Δm with F = M_m g (Eq 4.1-4.2)."""
    return mug_mass_kg * thesis.GRAVITY_M_S2 * math.dist(start_xy_m, goal_xy_m)


class DynamicsEnergyModel:
    """Electrical energy of joint trajectories from RNEA torques and the servo motor model."""

    def __init__(self, arm: ArmModel, *, supply_v: float = thesis.SUPPLY_VOLTAGE_V) -> None:
        self.arm = arm
        self.supply_v = supply_v
        servos = arm.servo_models
        self.k_t = np.array([s.torque_constant_nm_per_a for s in servos])
        self.k_e = np.array([s.back_emf_v_s_per_rad(supply_v) for s in servos])
        self.resistance = np.array([s.winding_resistance_ohm(supply_v) for s in servos])
        # The gripper servo is not in the kinematic model but draws standby current all the same.
        gripper = SERVO_MODELS[dict(thesis.JOINT_SERVOS)["gripper"]]
        self.standby_w = supply_v * (sum(s.standby_current_a for s in servos) + gripper.standby_current_a)
        self._models: dict[tuple[float, float], tuple[pin.Model, pin.Data]] = {}

    def torques(
        self,
        q: FloatArray,
        qd: FloatArray,
        qdd: FloatArray,
        *,
        payload_kg: float = 0.0,
        payload_lateral_m: float = 0.0,
    ) -> FloatArray:
        """Joint torques (n_samples, n_joints) along sampled states, with a point-like mug held at the grasp
        point (its axis ``payload_lateral_m`` beside it)."""
        model, data = self._model(payload_kg, payload_lateral_m)
        out = np.empty_like(q)
        for i in range(len(q)):
            out[i] = pin.rnea(model, data, q[i], qd[i], qdd[i])
        return out

    def power_w(self, tau: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Supply power and copper loss (each (n_samples,)) of the arm's joint motors, standby excluded.
        Per joint P = R I^2 + k_e omega I, floored at zero (no regeneration)."""
        current = tau / self.k_t
        copper = self.resistance * current**2
        supply = np.maximum(copper + self.k_e * qd * current, 0.0)
        return np.sum(supply, axis=1), np.sum(copper, axis=1)

    def path_energy(
        self, path: JointPath, rate_hz: float, *, payload_kg: float = 0.0, payload_lateral_m: float = 0.0
    ) -> EnergyBreakdown:
        """Energy of one time-parameterised path, integrated at ``rate_hz`` (standby excluded)."""
        if path.duration == 0.0:
            return EnergyBreakdown(0.0, 0.0)
        n = max(2, math.ceil(path.duration * rate_hz) + 1)
        times = np.linspace(0.0, path.duration, n)
        q, qd, qdd = path.state_at(times)
        tau = self.torques(q, qd, qdd, payload_kg=payload_kg, payload_lateral_m=payload_lateral_m)
        supply, copper = self.power_w(tau, qd)
        return EnergyBreakdown(float(np.trapezoid(supply, times)), float(np.trapezoid(copper, times)))

    def hold_energy_j(
        self, q: FloatArray, seconds: float, *, payload_kg: float = 0.0, payload_lateral_m: float = 0.0
    ) -> float:
        """Copper loss of holding pose ``q`` against gravity for ``seconds``."""
        zero = np.zeros((1, len(q)))
        tau = self.torques(q[None, :], zero, zero, payload_kg=payload_kg, payload_lateral_m=payload_lateral_m)
        return float(np.sum(self.resistance * (tau[0] / self.k_t) ** 2)) * seconds

    def idle_energy_j(self, seconds: float) -> float:
        """Standby draw of every servo's electronics over ``seconds``."""
        return self.standby_w * max(0.0, seconds)

    def _model(self, payload_kg: float, lateral_m: float) -> tuple[pin.Model, pin.Data]:
        key = (round(payload_kg, 4), round(lateral_m, 4))
        cached = self._models.get(key)
        if cached is not None:
            return cached
        model = self.arm.model.copy()
        if payload_kg > 0:
            frame = model.frames[model.getFrameId(self.arm.tool_frame)]
            local = frame.placement.act(np.array([0.0, lateral_m, 0.0]))
            model.appendBodyToJoint(
                frame.parentJoint, pin.Inertia.FromSphere(payload_kg, 0.04), pin.SE3(np.eye(3), local)
            )
        cached = (model, model.createData())
        self._models[key] = cached
        return cached
