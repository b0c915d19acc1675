"""Why the MuJoCo arm's servos are unbounded and its joint limits are enforced on the command (docs/physics.md).

Builds the UR10's physics spec (snac_gym.physics.mujoco_model.build_physics_spec) and, from the seeded
start pose of UR10Reach-v0 (seed 0), runs the smooth random command of snac-gym bench --tracking
for 1000 steps three ways: as built, with the servo forces clamped to the URDF efforts, and with
MuJoCo's soft joint-limit constraint on instead of the command cut, driving wrist 1 at full speed
into its limit. Prints max |θ̇ − u| and the overshoot past the limit.

    python docs/scripts/mujoco_servo_choices.py
"""

from __future__ import annotations

import mujoco
import numpy as np

from snac_gym.apps.bench import random_command
from snac_gym.model.kinematics import Kinematics
from snac_gym.physics.mujoco_model import build_physics_spec
from snac_gym.sampling import SampleSpace, sample_seed_pose

DT, SUBSTEPS, STEPS = 1.0 / 125.0, 3, 1000


def velocity_error(model: mujoco.MjModel, q0: np.ndarray, commands: np.ndarray) -> float:
    data = mujoco.MjData(model)
    data.qpos[:] = q0
    worst = 0.0
    for u in commands:
        data.ctrl[:] = u
        mujoco.mj_step(model, data, SUBSTEPS)
        worst = max(worst, float(np.abs(data.qvel - u).max()))
    return worst


def limit_overshoot(model: mujoco.MjModel, kinematics: Kinematics, q0: np.ndarray, joint: int) -> float:
    """Joint ``joint`` at full speed into its upper limit for twice the time it needs: the largest overshoot."""
    data = mujoco.MjData(model)
    data.qpos[:] = q0
    u = np.zeros(kinematics.n_joints)
    u[joint] = kinematics.velocity_limits[joint]
    periods = int(2 * (kinematics.upper_limits[joint] - q0[joint]) / u[joint] / DT)
    worst = 0.0
    for _ in range(periods):
        data.ctrl[:] = u
        mujoco.mj_step(model, data, SUBSTEPS)
        worst = max(worst, float(data.qpos[joint] - kinematics.upper_limits[joint]))
    return worst


def main() -> None:
    kinematics = Kinematics("ur10")
    rng = np.random.default_rng(0)
    q0 = sample_seed_pose(kinematics, rng, SampleSpace.for_robot(kinematics))
    commands = random_command("smooth", np.random.default_rng(0), kinematics.velocity_limits, STEPS, DT)

    spec = build_physics_spec(kinematics, DT / SUBSTEPS)
    print(
        f"as built (unbounded servos):          max |θ̇ − u| = {velocity_error(spec.compile(), q0, commands):.2e} rad/s"
    )

    clamped = spec.compile()
    clamped.actuator_forcelimited[:] = 1
    efforts = np.array([float(j.find("limit").get("effort")) for j in _urdf_joints(kinematics)])
    clamped.actuator_forcerange[:] = np.column_stack([-efforts, efforts])
    print(
        f"servo forces clamped to the efforts {efforts.tolist()} N·m: max |θ̇ − u| = "
        f"{velocity_error(clamped, q0, commands):.2e} rad/s"
    )

    soft_limits = spec.compile()
    soft_limits.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    print(
        f"MuJoCo's soft limit constraint, wrist 1 at full speed into it: overshoot "
        f"{limit_overshoot(soft_limits, kinematics, q0, 3):.3f} rad past {kinematics.upper_limits[3]:.3f} rad"
    )


def _urdf_joints(kinematics: Kinematics) -> list:
    import xml.etree.ElementTree as ET

    joints = {j.get("name"): j for j in ET.fromstring(kinematics.urdf_path.read_text()).findall("joint")}
    return [joints[name] for name in kinematics.joint_names]


if __name__ == "__main__":
    main()
