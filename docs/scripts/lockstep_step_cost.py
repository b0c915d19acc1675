"""What the lockstep loop's compiled steps cost against the NumPy calls they replaced, per control step, one core.

    python docs/scripts/lockstep_step_cost.py

For the evaluator's chunk of 250 samples (UR10, 6 joints, 3-D task) and for one row (a control step of one arm):

* the scaling into the velocity limits (``scale_rows_into_limits``, :func:`snac_gym.kernels.small.scale_rows`)
  against its NumPy expression (``np.max(np.abs(u) / limits)``, ``np.maximum``, ``/`` and the clip);
* the observation (:func:`snac_gym.kernels.lockstep.observations`) against seven field copies by the layout's
  slices into a new array;
* the clip of the commands with its finiteness test (:func:`snac_gym.kernels.lockstep.hold_commands`) against
  ``np.isfinite(u).all()``, ``np.minimum(np.maximum(u, −limits), limits)`` and the copy into the log.

Each pair is checked equal bit for bit first; each figure is the best of 5 repeats of 2000 calls.
"""

from __future__ import annotations

import numpy as np
from kernel_speed import best_of
from threadpoolctl import threadpool_limits

from snac_gym.kernels.compiled import read_only_view
from snac_gym.kernels.lockstep import hold_commands, observations
from snac_gym.observation import ObservationLayout
from snac_gym.policies.base import scale_rows_into_limits


def numpy_scaling(commands: np.ndarray, limits: np.ndarray) -> np.ndarray:
    scales = np.max(np.abs(commands) / limits, axis=-1, keepdims=True)
    return np.minimum(np.maximum(commands / np.maximum(scales, 1.0), -limits), limits)


def main() -> None:
    threadpool_limits(1)
    rng = np.random.default_rng(0)
    m, n = 6, 3
    layout = ObservationLayout(m, n)
    limits = read_only_view(np.array([2.0, 2.0, 3.15, 3.2, 3.2, 3.2]))
    print(f"{'step':42s} {'rows':>5s} {'compiled µs':>12s} {'NumPy µs':>9s}")
    for count in (250, 1):
        commands = rng.uniform(-2.0, 2.0, (count, m)) * limits
        fields = [rng.normal(size=(count, size)) for size in (m, m, n, n, n, n, n)]
        fields[2] = read_only_view(fields[2])  # the kinematics' positions are read-only

        def by_slices() -> np.ndarray:
            obs = np.empty((count, layout.size))
            for name, value in zip(layout.FIELDS, fields, strict=True):
                obs[:, layout.slices[name]] = value
            return obs

        held, log = np.empty((count, m)), np.empty((count, m))

        def numpy_clip() -> None:
            if not np.isfinite(commands).all():
                raise ValueError("non-finite")
            log[:] = np.minimum(np.maximum(commands, -limits), limits)

        def compiled_clip() -> None:
            if not hold_commands(read_only_view(commands), limits, held):
                raise ValueError("non-finite")

        assert scale_rows_into_limits(commands, limits).tobytes() == numpy_scaling(commands, limits).tobytes()
        assert observations(*fields).tobytes() == by_slices().tobytes()
        numpy_clip()
        compiled_clip()
        assert held.tobytes() == log.tobytes()
        for name, compiled, peer in (
            ("scaling into the velocity limits", lambda: scale_rows_into_limits(commands, limits),
             lambda: numpy_scaling(commands, limits)),
            ("observation", lambda: observations(*fields), by_slices),
            ("clip, finiteness test and log", compiled_clip, numpy_clip),
        ):  # fmt: skip
            compiled_us, peer_us = best_of(compiled, calls=2000) * 1e6, best_of(peer, calls=2000) * 1e6
            print(f"{name:42s} {count:5d} {compiled_us:12.2f} {peer_us:9.2f}")


if __name__ == "__main__":
    main()
