"""Time the kinematic engine per sample and control step: ``python -m snac_gym.evaluation.execution.engine_timing``.

For each registered controller (and for a policy that does nothing, which times the engine
alone) it runs ``samples`` regulation samples in lockstep for ``steps`` steps (through the
batch protocol where the policy offers it, as the evaluator does), best of ``repeats``, and
prints microseconds per sample-step. The default batch is the evaluator's job size
(``--chunk-size``, 500). The figures in docs/evaluation.md come from this command.
"""

from __future__ import annotations

import argparse
import functools
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import generate_samples

from snac_gym.policies.base import supports_batch
from snac_gym.policies.registry import available_policies, make_policy
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace


class NullPolicy:
    """Commands a small constant velocity (so θ moves and nothing is cached); offers the batch
    protocol too: times the engine alone."""

    def __init__(self) -> None:
        self.internals: dict[str, Any] = {}

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset."""

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Nothing to reset."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.full(6, 0.01)

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        return np.full((len(obs_batch), 6), 0.01)


def time_per_sample_step(make: Callable[[], Any], samples: int, steps: int, repeats: int, use_batch: bool) -> float:
    """Best wall time of ``repeats`` lockstep runs, in µs per sample and step."""
    context = policy_context("ur10", 1.0 / 125.0, "reach")
    space = SampleSpace.for_robot(context.kinematics)
    chosen = generate_samples(context.kinematics, space, 0, "reach", range(samples))
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        simulate_kinematic(context, make, chosen, steps, list(range(samples)), use_batch=use_batch)
        best = min(best, time.perf_counter() - started)
    return best / (samples * steps) * 1e6


def main(argv: Sequence[str] | None = None) -> None:
    """Print the table (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=500)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    context = policy_context("ur10", 1.0 / 125.0, "reach")
    rows = [
        ("engine alone, batch protocol", NullPolicy, True),
        ("engine alone, per-sample act", NullPolicy, False),
    ]
    for name in available_policies():
        make = functools.partial(make_policy, name, context)
        try:
            batched = supports_batch(make())
        except Exception:  # noqa: BLE001 - reported below when it is timed
            batched = False
        rows.append((f"{name}, {'act_batch' if batched else 'per-sample act'}", make, True))
    for label, make, use_batch in rows:
        try:
            micros = time_per_sample_step(make, args.samples, args.steps, args.repeats, use_batch)
        except Exception as exc:  # noqa: BLE001 - a controller that cannot run is reported, not fatal
            print(f"{label:40s} not timed: {type(exc).__name__}: {exc}")
            continue
        print(f"{label:40s} {micros:6.1f} µs per sample-step")


if __name__ == "__main__":  # pragma: no cover
    main()
