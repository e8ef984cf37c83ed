"""A servo plugin that asks for what ``joint_aware`` and ``velocity_aware`` give (issue 55 item
6): its ``init`` learns the joint it is for (its robot type's limits and drive), its ``step``
the demand's velocity.  A PD on the velocity error ``kv (qd_d - qd)``, its torque clipped at
the joint's drive limit (``kt · max_current · |G|``); the record keeps what it was given."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from kali_daemons.servo import STATUS_OK, Handover, JointInfo, Registry, ServoAlgorithm

NAME = "aware_pd"
PARAMS = ("kp", "kv")
DTYPE = np.dtype(
    [
        ("kp", "<f8"), ("kv", "<f8"), ("period", "<f8"), ("old_position", "<f8"),
        ("limit", "<f8"), ("q_max", "<f8"), ("joint", "<i4"), ("primed", "<u4"),
        ("last_velocity_demand", "<f8"),
    ],
    align=True,
)  # fmt: skip


def init(data: Any, init_data: Mapping[str, float], dt: float, joint: JointInfo | None) -> None:
    data.kp, data.kv, data.period, data.primed = 3000.0, 150.0, dt, 0
    data.joint, data.limit, data.q_max = 0, 1e9, 0.0
    if joint is not None:  # None: the checks at registration (no arm yet)
        j, drive = joint.joint - 1, joint.rtype.drive
        data.joint = joint.joint
        data.q_max = float(joint.rtype.q_max[j])
        data.limit = float(drive.kt[j] * drive.max_current[j] * abs(drive.gear[j]))
    set_params(data, init_data)


def step(
    data: Any, demand: float, position: float, velocity_demand: float
) -> tuple[float, float, int]:
    if not data.primed:
        data.old_position, data.primed = position, 1
    v = (position - data.old_position) / data.period
    data.old_position = position
    data.last_velocity_demand = velocity_demand
    error = demand - position
    torque = data.kp * error + data.kv * (velocity_demand - v)
    return max(-data.limit, min(data.limit, torque)), error, STATUS_OK


def handover(data: Any, h: Handover) -> None:
    data.old_position, data.primed = h.position - h.velocity * data.period, 1


def set_params(data: Any, values: Mapping[str, float]) -> None:
    for key, value in values.items():
        setattr(data, key, float(value))


def get_params(data: Any) -> dict[str, float]:
    return {"kp": data.kp, "kv": data.kv}


def register(registry: Registry) -> None:
    registry.register(
        ServoAlgorithm(
            NAME, DTYPE, PARAMS, init, step, handover, set_params, get_params,
            joint_aware=True, velocity_aware=True,
        )
    )  # fmt: skip
