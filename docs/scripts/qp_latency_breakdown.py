"""Where one ``act`` of ``pink`` and ``mink`` spends its time: the parts of the libraries' ``solve_ik``, timed alone.

On the UR10 tracking env after 50 closed-loop steps from seed 1, each part is called alone (best of 5 ×
2000 calls, ``timeit``, on one core): the configuration update (forward kinematics), ``solve_ik``'s
limit check, the task's (H, c), each limit's inequality rows, ``build_ik`` (all of them stacked),
qpsolvers' ``solve_problem`` with daqp, daqp's own ``solve`` on the same arrays, and the whole ``act``
with the library's ``solve_ik`` (``assembly="library"``); then the parts of the default
``assembly="direct"`` (the same QP written down from the library's Jacobian, the box as daqp's simple
bounds) and its whole ``act``. DLS's ``act`` is timed beside them.

    python docs/scripts/qp_latency_breakdown.py
"""

from __future__ import annotations

import os
import timeit
from ctypes import c_int

import gymnasium as gym
import numpy as np
from snac_gym.baselines.qp_ik import SOLVER, SOLVER_SETTINGS

import snac_gym  # noqa: F401  (registers the envs)
from snac_gym.policies import make_policy


def _time(call, number: int = 2000) -> float:
    return min(timeit.repeat(call, number=number, repeat=5)) / number * 1e6


def main() -> None:
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    import daqp
    import qpsolvers

    env = gym.make("snac_gym/UR10EllipseTrack-v0", physics="kinematic")
    policies = {name: make_policy(name, env, assembly="library") for name in ("pink", "mink")}
    direct = {name: make_policy(name, env) for name in ("pink", "mink")}
    policies["dls"] = make_policy("dls", env)
    obs, _ = env.reset(seed=1)
    for _ in range(50):
        obs, *_ = env.step(policies["dls"].act(obs))
    print(f"{'part':52s} {'pink µs':>8s} {'mink µs':>8s}")
    rows: dict[str, list[float]] = {}
    for name in ("pink", "mink"):
        policy = policies[name]
        library = __import__(name)
        configuration, task, limits = policy._configuration, policy._task, policy._limits
        configuration.update(policy.measured_q(obs))
        task.error = policy.task_error(obs)
        problem = library.build_ik(configuration, [task], policy.dt, damping=policy.regularisation, limits=limits)
        H, f, G, h, *_ = problem.unpack_as_dense()
        lower, sense = np.full(len(h), -1e30), np.zeros(len(h), dtype=c_int)
        q = policy.measured_q(obs)
        parts = {
            "configuration.update(q) (kinematics)": lambda: configuration.update(q),
            "configuration.check_limits() (in solve_ik)": lambda: configuration.check_limits(safety_break=False),
            "the task's (H, c)": lambda: task.compute_qp_objective(configuration),
            "ConfigurationLimit rows": lambda: limits[0].compute_qp_inequalities(configuration, policy.dt),
            "VelocityLimit rows": lambda: limits[1].compute_qp_inequalities(configuration, policy.dt),
            "build_ik (objective + all rows, stacked)": lambda: library.build_ik(
                configuration, [task], policy.dt, damping=policy.regularisation, limits=limits
            ),
            "qpsolvers.solve_problem(..., 'daqp')": lambda: qpsolvers.solve_problem(
                problem, solver=SOLVER, **SOLVER_SETTINGS
            ),
            "daqp.solve alone": lambda: daqp.solve(H, f, G, h, lower, sense, **SOLVER_SETTINGS),
            "the whole act(obs), library solve_ik": lambda: policy.act(obs),
        }
        fast = direct[name]
        jacobian = fast.task_jacobian(q)
        hessian, gradient = jacobian.T @ jacobian, fast._task.gain * fast.task_error(obs) @ jacobian
        lower_box, upper_box = fast.box(q)
        parts.update(
            {
                "direct: kinematics and the task's Jacobian": lambda: fast.task_jacobian(q),
                "direct: H = JᵀJ + (λ² + ε) I": lambda: jacobian.T @ jacobian + fast._regularisation_eye,
                "direct: the box (both limits)": lambda: fast.box(q),
                "direct: daqp.solve with the box as bounds": lambda: daqp.solve(
                    hessian, gradient, fast._no_rows, upper_box, lower_box, fast._sense, **SOLVER_SETTINGS
                ),
                "the whole act(obs), direct (the default)": lambda: fast.act(obs),
            }
        )
        for label, call in parts.items():
            rows.setdefault(label, []).append(_time(call))
    for label, (pink, mink) in rows.items():
        print(f"{label:52s} {pink:8.1f} {mink:8.1f}")
    print(f"{'dls act(obs), for comparison':52s} {_time(lambda: policies['dls'].act(obs)):8.1f}")


if __name__ == "__main__":
    main()
