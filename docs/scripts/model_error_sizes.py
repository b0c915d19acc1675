"""How far each model error puts the tool point: median and 95th percentile of ‖f(θ) − f_model(θ)‖.

Over ``--configurations`` joint configurations drawn uniformly within the arm's joint limits
(``default_rng(0)``), for ``random=σ,seed`` at each σ and seed, and for ``model=NAME`` (another
robot's kinematics), through :func:`snac_gym.model.model_error.tool_displacement`. Prints a Markdown table.

    python docs/scripts/model_error_sizes.py [--robot ur10] [--configurations 1000] [--model ur5]
"""

from __future__ import annotations

import argparse

import numpy as np

from snac_gym.model.kinematics import Kinematics
from snac_gym.model.model_error import tool_displacement

SIGMAS = (0.001, 0.002, 0.005, 0.01)
SEEDS = (0, 1, 2)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="ur10")
    parser.add_argument("--configurations", type=int, default=1000)
    parser.add_argument("--model", action="append", help="another robot as the model (repeatable; default ur5)")
    parser.add_argument("--spec", action="append", help="a --model-error text to measure instead of the default list")
    args = parser.parse_args(argv)
    true = Kinematics(args.robot)
    qs = np.random.default_rng(0).uniform(
        true.lower_limits, true.upper_limits, size=(args.configurations, true.n_joints)
    )
    print(f"{args.robot}, {args.configurations} configurations within the joint limits\n")
    print("| `--model-error` | median (mm) | 95th percentile (mm) |")
    print("|---|---|---|")
    specs = [f"random={sigma},{seed}" for sigma in SIGMAS for seed in SEEDS]
    specs += [f"model={name}" for name in args.model or ["ur5"]]
    specs = args.spec or specs
    for spec in specs:
        distance = 1000 * tool_displacement(true, true.with_model_error(spec), qs)
        print(f"| `{spec}` | {np.median(distance):.1f} | {np.percentile(distance, 95):.1f} |")


if __name__ == "__main__":
    main()
