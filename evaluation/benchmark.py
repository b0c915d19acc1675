"""Time the kinematic backend per sample and control step: ``python -m evaluation.benchmark``.

For each registered controller (and for a policy that does nothing, which times the backend
alone) it runs ``samples`` regulation samples in lockstep for ``steps`` steps, best of
``repeats``, and prints microseconds per sample-step. The figures in docs/evaluation.md come
from this command.
"""

from __future__ import annotations

import argparse
import functools
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from evaluation.backends import simulate_kinematic
from evaluation.jobs import policy_context
from evaluation.samples import generate_samples
from snac_gym.policies.registry import available_policies, make_policy
from snac_gym.sampling import SampleSpace


class NullPolicy:
    """Commands zero; offers the batch protocol too (times the backend alone)."""

    def __init__(self) -> None:
        self.internals: dict[str, Any] = {}

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset."""

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Nothing to reset."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(6)

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs_batch), 6))


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
    parser.add_argument("--samples", type=int, default=50)
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    context = policy_context("ur10", 1.0 / 125.0, "reach")
    rows = [
        ("backend alone, batch protocol", NullPolicy, True),
        ("backend alone, per-sample act", NullPolicy, False),
    ]
    rows += [
        (f"{name}, per-sample act", functools.partial(make_policy, name, context), True)
        for name in available_policies()
    ]
    for label, make, use_batch in rows:
        try:
            micros = time_per_sample_step(make, args.samples, args.steps, args.repeats, use_batch)
        except Exception as exc:  # noqa: BLE001 - a controller that cannot run is reported, not fatal
            print(f"{label:40s} not timed: {type(exc).__name__}: {exc}")
            continue
        print(f"{label:40s} {micros:6.1f} µs per sample-step")


if __name__ == "__main__":  # pragma: no cover
    main()
