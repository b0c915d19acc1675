"""Driving B policies in lockstep: the optional batch protocol and its per-sample fallback.

**The optional batch protocol.** A policy class MAY offer, besides the per-episode
``reset(seed)`` / ``act(obs)`` of :class:`snac_gym.policies.base.Policy`::

    def reset_batch(self, seeds: Sequence[int]) -> None:
        '''Start B independent episodes; episode i behaves as reset(seed=seeds[i]).'''

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        '''(B, d) observations, row i for episode i -> (B, m) commands.'''

One object then runs all B episodes of a chunk in lockstep, which lets it vectorise its
arithmetic across samples. Row ``i`` of ``act_batch`` must equal what a fresh object reset
with ``seeds[i]`` would return from ``act`` on the same observations (up to rounding), so
results do not depend on the protocol; ``internals`` are not read in batch mode. A class that
lacks either method is run the ordinary way: one object per sample, ``act`` called per row.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np


def supports_batch(policy: Any) -> bool:
    """Whether ``policy`` (an instance or a class) offers ``reset_batch`` and ``act_batch``."""
    return callable(getattr(policy, "reset_batch", None)) and callable(getattr(policy, "act_batch", None))


class LockstepPolicies:
    """B episodes of one controller, stepped together.

    Args:
        make_policy: Builds one policy object (called once in batch mode, B times otherwise).
        seeds: Reset seed of each episode.
        use_batch: Use the batch protocol when the policy offers it (default ``True``);
            ``False`` forces the per-sample path (the tests compare the two).
    """

    def __init__(self, make_policy: Callable[[], Any], seeds: Sequence[int], use_batch: bool = True) -> None:
        self.seeds = [int(s) for s in seeds]
        first = make_policy()
        self.batched = bool(use_batch and supports_batch(first))
        if self.batched:
            self._batch_policy = first
            first.reset_batch(self.seeds)
            self._policies: list[Any] = []
        else:
            self._policies = [first] + [make_policy() for _ in self.seeds[1:]]
            for policy, seed in zip(self._policies, self.seeds, strict=True):
                policy.reset(seed=seed)

    @property
    def policy_class(self) -> type:
        """The class of the policies being driven."""
        return type(self._batch_policy if self.batched else self._policies[0])

    @property
    def critic(self) -> Any:
        """The ``critic_diagnostics`` method of a critic-based controller, else ``None``."""
        return getattr(self._batch_policy if self.batched else self._policies[0], "critic_diagnostics", None)

    def critic_weights(self) -> np.ndarray:
        """``(B, l)``: each episode's critic weights now (those its next command uses)."""
        if self.batched:
            return np.array(self._batch_policy.batch_critic_weights, dtype=float)
        return np.array([policy.critic_weights for policy in self._policies], dtype=float)

    def act(self, observations: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, d)`` (row i to episode i)."""
        if self.batched:
            return np.asarray(self._batch_policy.act_batch(observations), dtype=float)
        return np.array(
            [policy.act(obs) for policy, obs in zip(self._policies, observations, strict=True)], dtype=float
        )
