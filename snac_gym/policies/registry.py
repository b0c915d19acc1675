"""Policies by name: ``make_policy("snac", env)``.

Built-in policies are listed here as import paths so that importing snac-gym stays light
(PPO pulls in torch only when asked for). Another package registers its own policy
without touching this one through the entry-point group ``snac_gym.policies``::

    [project.entry-points."snac_gym.policies"]
    mypolicy = "mypackage.module:MyPolicy"

A registered object is called as ``factory(env, **kwargs)`` and must return a
:class:`~snac_gym.policies.base.Policy`.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import Any, Callable

from snac_gym.policies.units import for_env

ENTRY_POINT_GROUP = "snac_gym.policies"

_BUILTIN: dict[str, str] = {
    "snac": "snac_gym.policies.snac:SNACPolicy",
    "snac-hjb": "snac_gym.policies.snac_hjb:SNACHJBPolicy",
    "snac-adaptive": "snac_gym.policies.snac_adaptive:SNACAdaptivePolicy",
    "snac-irl": "snac_gym.policies.snac_irl:SNACIRLPolicy",
    "dls": "snac_gym.baselines.dls:DLSPolicy",
    "joint-goal": "snac_gym.baselines.joint_goal:JointGoalPolicy",
    "svf": "snac_gym.baselines.svf:SVFPolicy",
    "rnn": "snac_gym.baselines.rnn:RNNPolicy",
    "lqr": "snac_gym.baselines.lqr:LQRPolicy",
    "mpc": "snac_gym.baselines.mpc:MPCPolicy",
    "pink": "snac_gym.baselines.pink_ik:PinkPolicy",
    "mink": "snac_gym.baselines.mink_ik:MinkPolicy",
    "ppo": "snac_gym.ppo.policy:PPOPolicy",
    "ppo-workspace": "snac_gym.ppo.policy:WorkspacePPOPolicy",
}
_FACTORIES: dict[str, Callable[..., Any]] = {}


def register_policy(name: str, factory: Callable[..., Any] | str, *, overwrite: bool = False) -> None:
    """Register ``factory`` (a callable or an ``"module:attr"`` string) under ``name``."""
    if not name or not name.replace("_", "").replace("-", "").isalnum():
        raise ValueError(f"policy name must be alphanumeric (with - or _), got {name!r}")
    if not overwrite and (name in _FACTORIES or name in _BUILTIN):
        raise ValueError(f"a policy named {name!r} is already registered")
    if isinstance(factory, str):
        _FACTORIES.pop(name, None)
        _BUILTIN[name] = factory
    else:
        _BUILTIN.pop(name, None)
        _FACTORIES[name] = factory


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def available_policies() -> list[str]:
    """Names accepted by :func:`make_policy`, built-ins and entry points together."""
    return sorted(set(_BUILTIN) | set(_FACTORIES) | set(_entry_points()))


def policy_factory(name: str) -> Callable[..., Any]:
    """The class (or factory) registered as ``name``, without building a policy.

    Raises:
        ValueError: If no policy is registered under ``name``.
    """
    return _resolve(name)


def _resolve(name: str) -> Callable[..., Any]:
    if name in _FACTORIES:
        return _FACTORIES[name]
    if name in _BUILTIN:
        module, _, attr = _BUILTIN[name].partition(":")
        builtin: Callable[..., Any] = getattr(importlib.import_module(module), attr)
        return builtin
    eps = _entry_points()
    if name in eps:
        plugin: Callable[..., Any] = eps[name].load()
        return plugin
    raise ValueError(f"unknown policy {name!r}; available: {', '.join(available_policies()) or 'none'}")


def make_policy(name: str, env: Any, **kwargs: Any) -> Any:
    """Build the policy registered as ``name`` for ``env``.

    The controllers compute in physical units (float64 observations, u in rad/s). For an env that
    scales them (a -v1 id: float32 observations, the normalized action a = u / ū) the policy comes
    wrapped in :class:`~snac_gym.policies.units.EnvUnitsPolicy`, so that ``act(obs)`` takes the env's
    observation and returns the env's action; its ``policy`` attribute is the controller itself.
    A -v0 env or a :class:`~snac_gym.policies.base.PolicyContext` gets the controller unwrapped.

    Args:
        name: A name from :func:`available_policies`.
        env: The env the policy will drive (a snac-gym env, wrapped or not, or a
            :class:`~snac_gym.policies.base.PolicyContext`).
        **kwargs: Passed to the policy's constructor (gains, seeds, ...).

    Raises:
        ValueError: If no policy is registered under ``name``.
    """
    return for_env(_resolve(name)(env, **kwargs), env)
