"""Which controllers a run evaluates, with what arguments and effort knob: :func:`resolve_controllers`.

Step 2 of :func:`snac_gym.evaluation.runner.run_evaluation`: ``controllers``, or by default
:data:`DEFAULT_CONTROLLERS` (``all`` in the list: every registered policy), those that can be built from a
:class:`~snac_gym.policies.base.PolicyContext` (and, with effort matching, declare an ``effort_parameter``);
those of the default set or of ``all`` left out are listed in the summary with the reason. Each controller is
described by a :class:`ControllerSpec`, which the passes, the effort search and the manifest (``run.json``) read.
"""

from __future__ import annotations

import difflib
import inspect
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference.optimum import OPTIMAL
from snac_gym.evaluation.reports.summary import PAPER_TABLE_I
from snac_gym.evaluation.run_config import ControllerSpec, EvaluationConfig
from snac_gym.evaluation.store import file_sha1

from snac_gym.common.extras import MissingExtraError
from snac_gym.policies.registry import available_policies, make_policy, policy_factory

#: What a run compares when no controllers are named: Table I's three (the paper's RNN, SVF and SNAC), SNAC's
#: HJB-residual variant, the classical baselines LQR and DLS, and PPO. Their matched knobs ship with the package
#: (``snac_gym/data/calibration``), so a first run of any size matches no effort. The other registered controllers
#: are evaluated when named, or with ``all``; their effort is matched on the 1000-sample effort set first, which
#: takes minutes (MPC re-solves a trajectory problem every step; docs/evaluation.md has the figures).
DEFAULT_CONTROLLERS = ("rnn", "svf", "snac", "snac-hjb", "lqr", "dls", "ppo")
#: In ``controllers``: every registered controller (each left out, with its reason, where it cannot be evaluated).
ALL_CONTROLLERS = "all"


class _LeftOut(Exception):
    """A registered controller that cannot be evaluated in this run.

    Args:
        reason: Why (the summary's "left out" line, or the error's end).
        hint: What to do about it, appended to the error when the controller was asked for.
    """

    def __init__(self, reason: str, hint: str = "") -> None:
        super().__init__(reason)
        self.reason, self.hint = reason, hint


def _knob_value(policy: Any, knob: str) -> float | None:
    value = getattr(policy, knob, None)
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def controller_input_hashes(policies: Sequence[Any], kwargs: Mapping[str, Any]) -> dict[str, str]:
    """SHA-1 of every file a controller reads: those its policies list in ``input_files`` (a PPO
    model, shipped or not) and every constructor argument that names an existing file.

    Keys are file names (the folder is left out, so that a moved install resumes), with the path
    appended where two files share a name.
    """
    files: list[Path] = []
    for policy in policies:
        files.extend(Path(f) for f in (getattr(policy, "input_files", None) or ()))
    for value in kwargs.values():
        if isinstance(value, (str, Path)) and str(value) and Path(value).is_file():
            files.append(Path(value))
    hashes: dict[str, str] = {}
    for path in dict.fromkeys(p.resolve() for p in files):
        key = path.name if path.name not in hashes else str(path)
        hashes[key] = file_sha1(path, "controller input file")
    return hashes


def _takes_argument(name: str, argument: str) -> bool:
    """Whether the controller registered as ``name`` has a constructor argument ``argument``."""
    return argument in (_arguments(name) or ())


def _requested(controllers: Sequence[str] | None, known: set[str]) -> tuple[list[str], set[str]]:
    """The controllers to try, in order, and those named one by one (refused, not left out, where they cannot be
    evaluated): ``None`` is :data:`DEFAULT_CONTROLLERS`, :data:`ALL_CONTROLLERS` every registered one; the
    ``optimal`` reference row is not a policy (``EvaluationRun.run_optimal`` solves it)."""
    if controllers is None:
        return default_controller_order([name for name in DEFAULT_CONTROLLERS if name in known]), set()
    names: list[str] = []
    for name in controllers:
        expanded = default_controller_order(sorted(known)) if name == ALL_CONTROLLERS else [name]
        names += [each for each in expanded if each != OPTIMAL and each not in names]
    return names, {name for name in controllers if name not in (ALL_CONTROLLERS, OPTIMAL)}


def default_controller_order(names: Sequence[str]) -> list[str]:
    """Table I's rows first, in the paper's order (RNN, SVF, SNAC), then the other names sorted."""
    paper = [name for name in PAPER_TABLE_I if name in names]
    return paper + sorted(name for name in names if name not in PAPER_TABLE_I)


def _check_arguments(config: EvaluationConfig, names: Sequence[str], known: set[str]) -> None:
    """Refuse ``--param`` arguments for a controller that is not registered or not evaluated, or that its
    constructor does not take (one line naming the argument, not the constructor's TypeError)."""
    for name, given in config.controller_kwargs.items():
        option = "--param " + ", ".join(f"{name}.{key}" for key in given)
        if name not in known:
            close = difflib.get_close_matches(name, sorted(known), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else f"; registered: {', '.join(sorted(known))}"
            raise ValueError(f"{option}: no controller is registered as {name!r}{hint}")
        if name not in names:
            raise ValueError(
                f"{option}: {name!r} is not among the evaluated controllers ({', '.join(names) or 'none'}); "
                "name it in --controllers"
            )
        arguments = _arguments(name)
        unknown = [key for key in given if arguments is not None and key not in arguments]
        if unknown:
            key = unknown[0]
            close = [a for a in arguments if a.lower() == key.lower()] or difflib.get_close_matches(key, arguments, n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"its arguments: {', '.join(arguments)}"
            raise ValueError(f"--param {name}.{key}: {name!r} has no argument {key!r}; {hint}")


def _arguments(name: str) -> list[str] | None:
    """The constructor arguments ``--param`` may set on the controller registered as ``name`` (all but the env), in
    the constructor's order; ``None`` where they cannot be read (then they are checked when it is built).

    A class whose ``__init__`` takes ``**kwargs`` passes them up: its bases' arguments count too, up to one
    without ``**kwargs``.
    """
    factory = policy_factory(name)
    chain = [c for c in factory.__mro__ if "__init__" in vars(c)] if isinstance(factory, type) else [factory]
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    names: list[str] = []
    for each in chain:
        try:
            parameters = list(inspect.signature(each).parameters.values())
        except (TypeError, ValueError):
            return None
        names += [p.name for p in parameters[1:] if p.kind in kinds and p.name not in names]  # [0]: the env
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters):
            return names
    return None


def _controller_spec(config: EvaluationConfig, name: str) -> ControllerSpec:
    """Build ``name``'s policies for every task and read its knob.

    Raises:
        _LeftOut: If it cannot be built, or (with effort matching) has no scalar knob.
    """
    kwargs = dict(config.controller_kwargs.get(name, {}))
    if config.q_scale != 1.0 and "Q" not in kwargs and _takes_argument(name, "Q"):
        # The cost's Q, as a diagonal of the task dimension (a run's tasks share it: 3, or 6 for pose).
        kwargs["Q"] = [config.q_scale] * policy_context(config.robot, config.dt, config.tasks[0]).layout.task_dim
    # A controller that optimises a trajectory cost (mpc) is given the run's, as it is given Q.
    for key, value in (("cost", config.cost), ("udot_start", config.udot_start)):
        if key not in kwargs and _takes_argument(name, key):
            kwargs[key] = value
    try:
        policies = [make_policy(name, policy_context(config.robot, config.dt, task), **kwargs) for task in config.tasks]
    except MissingExtraError as exc:  # an optional dependency: the one line that names its extra
        raise _LeftOut(f"is not installed: {exc}") from exc
    except Exception as exc:
        reason = f"cannot be built from a PolicyContext with arguments {kwargs}: {type(exc).__name__}: {exc}"
        raise _LeftOut(reason) from exc
    knob = getattr(type(policies[0]), "effort_parameter", None)
    value = _knob_value(policies[0], knob) if knob else None
    if config.match_effort and (knob is None or value is None):
        reason = (
            "declares no effort_parameter (needed for --match-effort)"
            if knob is None
            else f"its effort_parameter {knob!r} is not a scalar attribute of the policy"
        )
        raise _LeftOut(reason, hint="; run it with --no-match-effort")
    return ControllerSpec(name, kwargs, knob, value, controller_input_hashes(policies, kwargs))


def resolve_controllers(config: EvaluationConfig) -> tuple[list[ControllerSpec], dict[str, str]]:
    """The controllers to evaluate, and the registered ones left out with the reason.

    A controller given arguments (``controller_kwargs``, ``--param``) counts as named: it is
    never left out silently.

    Raises:
        ValueError: If an explicitly named controller is unknown, cannot be built, or (with
            effort matching) declares no scalar ``effort_parameter``; or if arguments are given
            for a controller that is not registered or not evaluated.
    """
    known = set(available_policies())
    names, named = _requested(config.controllers, known)
    _check_arguments(config, names, known)
    if config.controllers is not None and not names:
        return [], {}
    specs: list[ControllerSpec] = []
    skipped: dict[str, str] = {}
    for name in names:
        if name not in known:
            raise ValueError(f"unknown controller {name!r}; registered: {', '.join(sorted(known))}")
        try:
            specs.append(_controller_spec(config, name))
        except _LeftOut as left_out:
            if name in named or name in config.controller_kwargs:
                raise ValueError(f"controller {name!r} {left_out.reason}{left_out.hint}") from left_out.__cause__
            skipped[name] = left_out.reason
    if not specs and not config.wants_optimal:
        raise ValueError(f"no controller to evaluate (left out: {skipped})")
    return specs, skipped


__all__ = [
    "ALL_CONTROLLERS", "DEFAULT_CONTROLLERS", "ControllerSpec", "controller_input_hashes", "default_controller_order",
    "resolve_controllers",
]  # fmt: skip
