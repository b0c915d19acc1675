"""The batched vector env's side of Gymnasium's :class:`~gymnasium.vector.SyncVectorEnv` conventions: the
per-sub-env seeds, the reset mask, and the infos of a step that autoresets some sub-envs.

Kept apart from :mod:`snac_gym.envs.vector` because they are SyncVectorEnv's rules, not the kinematic episodes':
the vector env must follow them to match a SyncVectorEnv of single envs episode for episode.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["merge_reset_infos", "reset_mask", "seed_list"]


def seed_list(seed: int | Sequence[int | None] | None, count: int) -> list[int | None]:
    """Per-sub-env seeds as :class:`~gymnasium.vector.SyncVectorEnv` derives them: ``seed + i``."""
    if seed is None:
        return [None] * count
    if isinstance(seed, (int, np.integer)):
        return [int(seed) + i for i in range(count)]
    seeds = list(seed)
    if len(seeds) != count:
        raise ValueError(
            f"If seeds are passed as a list the length must match num_envs={count} but got length={len(seeds)}."
        )
    return seeds


def reset_mask(options: dict[str, Any] | None, count: int) -> np.ndarray:
    """``options.pop("reset_mask")`` checked as SyncVectorEnv checks it (all True without one)."""
    if options is None or "reset_mask" not in options:
        return np.ones(count, dtype=bool)
    mask = options.pop("reset_mask")
    if not isinstance(mask, np.ndarray) or mask.shape != (count,) or mask.dtype != np.bool_:
        raise ValueError(f"options['reset_mask'] must be a bool numpy array of shape ({count},), got {mask!r}")
    if not mask.any():
        raise ValueError("options['reset_mask'] must contain at least one True value")
    return mask


def merge_reset_infos(step: dict[str, Any], reset: dict[str, Any], resetting: np.ndarray) -> dict[str, Any]:
    """The step infos with the autoreset sub-envs' rows replaced by their reset infos.

    As in SyncVectorEnv: a key only a step gives is masked off for those rows (and dropped if
    no row has it); a key both give takes the reset value; reset-only keys are added.
    """
    merged: dict[str, Any] = {}
    for key, value in step.items():
        if key.startswith("_"):
            continue
        if key in reset:
            value[resetting] = reset[key][resetting]
            merged[key], merged[f"_{key}"] = value, step[f"_{key}"]
        else:
            mask = step[f"_{key}"] & ~resetting
            if mask.any():
                value[resetting] = 0  # SyncVectorEnv's filler where a sub-env lacks the key
                merged[key], merged[f"_{key}"] = value, mask
    for key, value in reset.items():
        if not key.startswith("_") and key not in merged:
            merged[key], merged[f"_{key}"] = value, reset[f"_{key}"]
    return merged
