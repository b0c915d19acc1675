"""Act latency of SNAC on the 7-DOF pose tasks (the goal: median ≤ 30 µs on one core).

Run single-threaded on one core:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 taskset -c 0 .venv/bin/python docs/scripts/pose_act_latency.py

Times ``SNACPolicy.act`` alone (one observation in, one command out; the kinematics call for J
inside it included) on observations of a real rollout, for the position task (3-D error, 6 terms),
pose regulation (6-D error, 21 terms) and pose tracking (12-D ξ, 78 terms) on the Panda.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from snac_gym.model.kinematics import Kinematics, PoseKinematics
from snac_gym.observation import ObservationLayout
from snac_gym.policies import make_policy
from snac_gym.policies.base import PolicyContext
from snac_gym.references import Ellipse, FixedTarget
from snac_gym.sampling import nominal_configuration
from snac_gym.tasks.pose import PoseEllipse, PoseTarget, register_pose_tasks

CALLS = 20000
DT = 1 / 125


def observations(kinematics, reference, count: int) -> list[np.ndarray]:
    """Observations along a DLS rollout of ``count`` steps (realistic inputs, not a fixed vector)."""
    n = kinematics.task_dim
    layout = ObservationLayout(kinematics.n_joints, n)
    error = getattr(kinematics, "task_error", None)
    task = {3: "reach", 6: "pose-reach"}[n] if not isinstance(reference, PoseEllipse) else "pose-track"
    driver = make_policy(
        "dls", PolicyContext(kinematics, DT, kinematics.velocity_limits.copy(), layout, task), gain=0.5
    )
    q = nominal_configuration(getattr(kinematics, "position", kinematics))
    out = []
    for k in range(count):
        x_d, xdot_d = reference.position_and_velocity(k * DT)
        x = kinematics.forward(q)
        obs = layout.pack(
            q, np.zeros_like(q), x, x_d, xdot_d, reference.centre, None if error is None else error(x, x_d)
        )
        out.append(obs)
        q = q + driver.act(obs) * DT
    return out


def median_act_us(kinematics, reference, task: str) -> tuple[float, int]:
    layout = ObservationLayout(kinematics.n_joints, kinematics.task_dim)
    policy = make_policy("snac", PolicyContext(kinematics, DT, kinematics.velocity_limits.copy(), layout, task))
    obs = observations(kinematics, reference, 500)
    policy.reset(seed=0)
    times = np.empty(CALLS)
    clock = time.perf_counter_ns
    for i in range(CALLS):
        o = obs[i % len(obs)]
        start = clock()
        policy.act(o)
        times[i] = clock() - start
    return float(np.median(times)) / 1e3, policy.basis.size


def main() -> None:
    register_pose_tasks()
    panda, pose = Kinematics("panda"), PoseKinematics("panda")
    cases = [
        ("position reach (3-D e)", panda, FixedTarget([0.45, 0.2, 0.3]), "reach"),
        ("pose reach (6-D e)", pose, PoseTarget([0.45, 0.2, 0.3], [np.pi, 0.0, 0.0]), "pose-reach"),
        (
            "pose track (12-D ξ)",
            pose,
            PoseEllipse(Ellipse((0.45, 0.0, 0.4), (0.1, 0.1)), (np.pi, 0.0, 0.0)),
            "pose-track",
        ),
    ]
    print(f"python {sys.version.split()[0]}, {CALLS} calls each, median of act():")
    for label, kinematics, reference, task in cases:
        micros, terms = median_act_us(kinematics, reference, task)
        print(f"  panda {label:24s} {terms:3d} critic terms  {micros:6.1f} µs")


if __name__ == "__main__":
    main()
