"""How far PyBullet's velocity motors sag under gravity, and what it does to a demo (docs/physics.md).

Part 1: each UR arm at the paper's θ₀, one small constant command (the LQR's last command of the UR3e's reach
demo, 10⁻⁴ to 4·10⁻³ rad/s) held for 500 control periods; the worst |θ̇ − u| at the end, as the env builds the arm,
then with 200 solver iterations and a residual threshold of 10⁻¹², then without gravity (as the MuJoCo arm's gravity
compensation and a real arm's controller have it), then with the motors solved directly (``pybullet_solver="dantzig"``,
the -v1 ids' default); and the mean wall time of a period each way. Part 2: the reach and track demos with lqr on
each UR arm (the paper's reference scaled to the arm, ``snac-gym demo --robot R --controller lqr``) in each engine,
PyBullet with each solver: the final error. Part 3: the UR10 reach env under the smooth random command of ``snac-gym
bench --tracking`` (five seeds, 1000 periods each) with each solver: how far it departs from the exact model.

    python docs/scripts/pybullet_gravity_sag.py
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import pybullet as p

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym import make_policy
from snac_gym.apps.bench import tracking_errors
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import UR_MODELS
from snac_gym.physics.bullet import PyBulletArm
from snac_gym.references import PAPER_Q0
from snac_gym.tasks import get_task

COMMAND = np.array([0.00037, -0.00024, -0.00419, -0.00215, 0.00069, 0.0])  # rad/s
#: Name: (the arm's ``solver``, PyBullet's engine parameters, gravity in m/s²).
SETTINGS: dict[str, tuple[str, dict[str, float], float]] = {
    "as built (-v0)": ("pgs", {}, 9.81),
    "200 iterations, residual 1e-12": ("pgs", {"numSolverIterations": 200, "solverResidualThreshold": 1e-12}, 9.81),
    "no gravity": ("pgs", {}, 0.0),
    "dantzig (-v1)": ("dantzig", {}, 9.81),
}
#: The demos' engines: (``physics``, ``pybullet_solver``).
ENGINES = (("pybullet", "pgs"), ("pybullet", "dantzig"), ("mujoco", "pgs"), ("kinematic", "pgs"))


def sag(robot: str, setting: str) -> tuple[float, float]:
    """The worst |θ̇ − u| at the end, and the mean wall time of a control period (µs)."""
    solver, parameters, gravity = SETTINGS[setting]
    arm = PyBulletArm(Kinematics(robot), 1.0 / 125.0, 3, meshes=False, solver=solver)
    client = arm.sim.client
    p.setPhysicsEngineParameter(physicsClientId=client, **parameters)
    p.setGravity(0.0, 0.0, -gravity, physicsClientId=client)
    arm.reset(np.array(PAPER_Q0))
    start = time.perf_counter()
    for _ in range(500):
        arm.apply(COMMAND)
    period = (time.perf_counter() - start) / 500 * 1e6
    _, qdot = arm.joint_state()
    arm.close()
    return float(np.abs(qdot - COMMAND).max()), period


def demo_error(robot: str, task: str, physics: str, solver: str) -> float:
    spec = get_task(task)
    env = gym.make(
        spec.env_id_for(robot),
        physics=physics,
        pybullet_solver=solver,
        max_episode_steps=spec.horizon_steps(1.0 / 125.0),
    )
    policy = make_policy("lqr", env)
    obs, info = env.reset(seed=0, options=spec.demo_options(robot))
    policy.reset(seed=0)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        done = terminated or truncated
    env.close()
    return float(info["error_norm"])


def main() -> None:
    print("| arm | " + " | ".join(f"max abs(θ̇ − u), {name} (rad/s; µs per period)" for name in SETTINGS) + " |")
    print("|---|" + "---|" * len(SETTINGS))
    for robot in UR_MODELS:
        cells = [sag(robot, name) for name in SETTINGS]
        print(f"| {robot} | " + " | ".join(f"{error:.1e}; {period:.0f}" for error, period in cells) + " |")
    print()
    tasks = ("reach", "track")
    names = " / ".join(physics if physics != "pybullet" else f"PyBullet {solver}" for physics, solver in ENGINES)
    print("| arm | " + " | ".join(f"{task} final ‖e‖ (mm): {names}" for task in tasks) + " |")
    print("|---|---|---|")
    for robot in UR_MODELS:
        cells = [" / ".join(f"{demo_error(robot, task, *engine) * 1e3:.3f}" for engine in ENGINES) for task in tasks]
        print(f"| {robot} | " + " | ".join(cells) + " |")
    print()
    print(
        "| UR10Reach-v0, smooth command | max abs(θ̇ − u) (rad/s) | max abs(θ − θ_kin) (rad) | end-effector drift (mm) |"
    )
    print("|---|---|---|---|")
    for solver in ("pgs", "dantzig"):
        rows = [
            tracking_errors("snac_gym/UR10Reach-v0", "pybullet", "smooth", seed, solver=solver) for seed in range(5)
        ]
        worst = {key: max(row[key] for row in rows) for key in rows[0]}
        print(
            f"| {solver} | {worst['max_velocity_error']:.2e} | {worst['max_joint_drift']:.2e} | "
            f"{worst['ee_drift'] * 1e3:.3g} |"
        )


if __name__ == "__main__":
    main()
