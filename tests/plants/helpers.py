"""Shared helpers for the plant tests."""

import mujoco
import numpy as np

from servogym.plants import Plant


def rollout(plant: Plant, torque_nm: float, n_steps: int) -> np.ndarray:
    """Step the plant from its current state with a constant motor torque.

    Returns:
        ``qpos`` after every step, shape ``(n_steps, nq)``.
    """
    out = np.empty((n_steps, plant.model.nq))
    plant.data.ctrl[plant.io.ctrl_index] = torque_nm
    for k in range(n_steps):
        mujoco.mj_step(plant.model, plant.data)
        out[k] = plant.data.qpos
    return out


def holding_torque_nm(plant: Plant, qpos: float) -> float:
    """Motor torque that balances gravity with the measured joint at ``qpos``, at rest."""
    plant.reset()
    plant.data.qpos[plant.io.qpos_adr] = qpos
    mujoco.mj_forward(plant.model, plant.data)
    gear = plant.model.actuator_gear[plant.io.ctrl_index, 0]
    return float(plant.data.qfrc_bias[plant.io.qvel_adr] / gear)
