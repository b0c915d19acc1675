"""Training configuration of ``snac-gym train-ppo``: versioned JSON files, not code.

The shipped configs live in ``snac_gym/ppo/configs/<task>.json``. Their keys:

* ``config_version``: version of this schema (:data:`CONFIG_VERSION`).
* ``task``: ``reach`` or ``track``; ``robot``: ``ur10`` (``ur3``/``ur5`` work as well).
* ``timesteps``, ``seed``: defaults of ``--timesteps`` and ``--seed``.
* ``env``: arguments of the training env (``max_steps``, ``terminate_on_success``).
* ``features``: :class:`~snac_gym.ppo.features.FeatureSpec`; ``reward``:
  :class:`~snac_gym.ppo.envs.RewardSpec`.
* ``vec_env``: ``n_envs`` and ``kind`` (``dummy``: all envs in this process; ``subproc``:
  one process per env, across cores; ``batched``: the ``n_envs`` episodes stepped at once on
  the exact kinematic model, :class:`~snac_gym.ppo.vec_env.PPOVecEnv`, thousands of them in
  one process).
* ``normalize``: ``obs``, ``reward`` (VecNormalize), ``clip_obs``.
* ``ppo``: stable-baselines3 PPO arguments (``learning_rate`` with ``learning_rate_schedule``
  ``constant`` or ``linear``, ``n_steps``, ``batch_size``, ``n_epochs``, ``gamma``,
  ``gae_lambda``, ``clip_range``, ``ent_coef``, ``vf_coef``, ``max_grad_norm``, ``net_arch``
  (``{"pi": [...], "vf": [...]}``), ``activation`` (``tanh``/``relu``), ``log_std_init``).
* ``init_from`` (optional): a policy file whose actor the new model starts from (its hidden and output
  layers; the critic starts fresh), e.g. a behaviour clone (:mod:`snac_gym.ppo.cloning`); a path relative to
  the working directory; ``--init-from FILE`` on the command line. A resumed run continues its own model.
* ``evaluation``: ``every_timesteps``, ``episodes``, ``horizons_s`` (the horizons each
  episode is scored at: the evaluator's, 4 s and 8 s reach, 10 s and 20 s track), ``seed``
  (first reset seed of the evaluation episodes), ``success_error_m`` (reach: final ‖e‖ at
  most this; track: mean ‖e‖ over the second half of the horizon below this).

:func:`validate_config` reads a config into :class:`TrainingConfig` (one frozen dataclass per
section, every field with its type and range), so that a bad value is refused before any env,
model or folder is made, in one line naming the field's dotted path (``ppo.batch_size``) and the
values it takes. Unknown keys are refused (a typo would otherwise fall back to a default), and
so are ``env`` keywords that the task's env constructor does not take. The run keeps the config
as the JSON dict it was read from (``OUT/config.json``, the policy files' metadata).
"""

from __future__ import annotations

import copy
import inspect
import json
import math
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar, cast

import gymnasium as gym

from snac_gym.common.errors import ConfigError
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import robot_names
from snac_gym.physics.base import check_timing
from snac_gym.ppo.envs import REWARD_TYPES
from snac_gym.ppo.features import ACTION_KINDS, FEATURE_VERSION, FeatureSpec
from snac_gym.sampling import REGIONS as SAMPLE_REGIONS
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task, task_names

CONFIG_VERSION = 1
PACKAGE = "snac_gym.ppo"
T = TypeVar("T")
#: A config file is a few kB; a bound keeps a device such as /dev/zero from being read for ever.
MAX_CONFIG_BYTES = 1_000_000


def default_config_path(task: str) -> Path:
    """The shipped config file of ``task``."""
    if task not in task_names():
        raise ValueError(f"task must be one of {task_names()}, got {task!r}")
    return Path(str(resources.files(PACKAGE).joinpath("configs", f"{task}.json")))


def load_config(path: str | Path) -> dict[str, Any]:
    """Read and check a training config.

    Raises:
        ValueError: If the file is not valid JSON, has another ``config_version``, lacks a
            section or holds unknown keys.
    """
    path = Path(path)
    try:
        if not path.is_file() or path.stat().st_size > MAX_CONFIG_BYTES:
            raise ValueError(f"not a regular file of at most {MAX_CONFIG_BYTES} bytes")
        config = json.loads(path.read_text())
    except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise ValueError(f"cannot read PPO config {path}: {exc}") from None
    validate_config(config, str(path))
    return config


def validate_config(config: dict[str, Any], source: str = "PPO config") -> TrainingConfig:
    """Read a config dict into :class:`TrainingConfig`, checking every field's type and range.

    Raises:
        ConfigError: A ``ValueError`` naming ``source`` and the offending field's dotted path
            and allowed range (unknown keys and env keywords included).
    """
    try:
        section = read_section(TrainingConfig, config)
        FeatureSpec.from_dict(config["features"])  # the action kind and the feature version agree
        return section
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def resolve_config(
    task: str,
    config_path: str | Path | None = None,
    timesteps: int | None = None,
    seed: int | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
    init_from: str | Path | None = None,
) -> dict[str, Any]:
    """The config a run uses: the file (default: the task's shipped one) with command-line overrides.

    Raises:
        ValueError: If the file is invalid or was written for another task.
    """
    path = Path(config_path) if config_path is not None else default_config_path(task)
    config = copy.deepcopy(load_config(path))
    if config["task"] != task:
        raise ValueError(f"PPO config {path} is for task {config['task']!r}, not {task!r}")
    if timesteps is not None:
        config["timesteps"] = int(timesteps)
    if seed is not None:
        config["seed"] = int(seed)
    if n_envs is not None:
        config["vec_env"]["n_envs"] = int(n_envs)
    if vec_env is not None:
        config["vec_env"]["kind"] = vec_env
    if init_from is not None:
        config["init_from"] = str(init_from)
    validate_config(config, str(path))  # the overrides too
    if config.get("init_from") and not Path(config["init_from"]).is_file():  # before anything is made
        raise ValueError(f"{path}: init_from {config['init_from']!r} is not a policy file")
    config["config_file"] = str(path)
    return config


# -- the schema ----------------------------------------------------------------------------------
#: SB3 seeds NumPy's global generator with the seed (``np.random.seed``: 0 to 2**32 − 1).
MAX_SEED = 2**32 - 1
#: Widest hidden layer accepted: 4096 units already make a 16 M-weight layer; wider is a typo.
MAX_LAYER_WIDTH = 4096
#: Longest evaluation horizon, s: the evaluator's bound (``snac_gym.evaluation.run_config``), 125 000 steps.
MAX_HORIZON_S = 1000.0

Check = Callable[[Any, str], Any]


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _interval(low: float | None, high: float | None, open_low: bool) -> str:
    if low is None:
        return "(finite)"
    if high is None:
        return f"{'>' if open_low else '≥'} {low:g}"
    return f"in {'(' if open_low else '['}{low:g}, {high:g}]"


def integer(low: int, high: int | None = None) -> Check:
    """An integer (not a bool, not 2.0) in ``[low, high]``."""

    def check(value: Any, path: str) -> int:
        if not (
            isinstance(value, int) and not isinstance(value, bool) and low <= value and (high is None or value <= high)
        ):
            bounds = f"≥ {low}" if high is None else f"in [{low}, {high}]"
            raise ConfigError(f"{path} must be an integer {bounds}, got {value!r}")
        return value

    return check


def number(low: float | None, high: float | None = None, open_low: bool = False) -> Check:
    """A finite number in ``[low, high]`` (``(low, high]`` with ``open_low``; any with ``low=None``)."""

    def check(value: Any, path: str) -> float:
        inside = (
            _is_number(value)
            and (low is None or (value > low if open_low else value >= low))
            and (high is None or value <= high)
        )
        if not inside:
            raise ConfigError(f"{path} must be a number {_interval(low, high, open_low)}, got {value!r}")
        return float(value)

    return check


def _json_object(value: Any, path: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ConfigError(f"{path} must be a JSON object, got {value!r}")
    return dict(value)


def boolean(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"{path} must be true or false, got {value!r}")
    return value


def text(value: Any, path: str) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"{path} must be a string, got {value!r}")
    return value


def choice(*allowed: Any) -> Check:
    def check(value: Any, path: str) -> Any:
        if value not in allowed:
            raise ConfigError(f"{path} must be {' or '.join(repr(v) for v in allowed)}, got {value!r}")
        return value

    return check


def sequence(item: Check, length: int | None = None, min_length: int = 1) -> Check:
    """A JSON list of ``length`` (or at least ``min_length``) items, each checked by ``item``."""

    def check(value: Any, path: str) -> tuple[Any, ...]:
        if not isinstance(value, list) or len(value) != (length or len(value)) or len(value) < min_length:
            size = f"{length}" if length else f"at least {min_length}"
            raise ConfigError(f"{path} must be a list of {size} items, got {value!r}")
        return tuple(item(entry, f"{path}[{i}]") for i, entry in enumerate(value))

    return check


def _layers(value: Any, path: str) -> tuple[int, ...]:
    return sequence(integer(1, MAX_LAYER_WIDTH), min_length=0)(value, path)


def net_arch(value: Any, path: str) -> Any:
    """SB3's ``net_arch``: ``{"pi": [...], "vf": [...]}`` or one list shared by both."""
    if isinstance(value, list):
        return _layers(value, path)
    if not isinstance(value, dict) or set(value) != {"pi", "vf"}:
        raise ConfigError(f'{path} must be {{"pi": [widths], "vf": [widths]}} or a list of widths, got {value!r}')
    return {key: _layers(value[key], f"{path}.{key}") for key in ("pi", "vf")}


def spec(kind: Check | type, default: Any = MISSING) -> Any:
    """A schema field: its check (or nested section) and, when optional, its default."""
    return field(default=default, metadata={"check": kind})


def read_section(cls: type[T], data: Any, path: str = "") -> T:
    """``data`` read into the dataclass ``cls``: unknown keys, missing keys, types and ranges checked.

    Raises:
        ConfigError: Naming the first offending field by its dotted path.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{path or 'the config'} must be a JSON object, got {data!r}")
    known = {item.name: item for item in fields(cls)}  # type: ignore[arg-type]
    for key in data:
        if key not in known:
            where = f"the {path} section" if path else "a config"
            raise ConfigError(f"unknown key {_join(path, key)}: {where} takes {', '.join(known)}")
    values: dict[str, Any] = {}
    for name, item in known.items():
        if name not in data:
            if item.default is MISSING:
                raise ConfigError(f"missing key {_join(path, name)}")
            continue
        kind = item.metadata["check"]
        values[name] = (
            read_section(cast("type[Any]", kind), data[name], _join(path, name))  # a section's dataclass: a class
            if is_dataclass(kind)
            else kind(data[name], _join(path, name))
        )
    return cls(**values)


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


@dataclass(frozen=True)
class FeaturesSection:
    """``features``: :class:`~snac_gym.ppo.features.FeatureSpec`."""

    error_scale_coarse: float = spec(number(0, open_low=True), 0.1)
    error_scale_fine: float = spec(number(0, open_low=True), 0.01)
    velocity_scale: float = spec(number(0, open_low=True), 0.1)
    position_centre: tuple[float, ...] = spec(sequence(number(None), length=3), (-0.675, 0.15, 0.425))
    position_scale: float = spec(number(0, open_low=True), 0.3)
    action_fraction: float = spec(number(0, 1, open_low=True), 0.5)
    action_scale_range: tuple[float, ...] = spec(sequence(number(0, open_low=True), length=2), (0.5, 4.0))
    action: str = spec(choice(*ACTION_KINDS), "task-relative")
    gain_max: float = spec(number(0, open_low=True), 4.0)
    damping: float = spec(number(0, open_low=True), 0.01)
    joint_gain: float = spec(number(0, open_low=True), 2.0)
    version: int = spec(choice(*ACTION_KINDS.values()), FEATURE_VERSION)

    def __post_init__(self) -> None:
        low, high = self.action_scale_range
        if low > high:
            raise ConfigError(f"features.action_scale_range must be [low, high] with low ≤ high, got [{low}, {high}]")


@dataclass(frozen=True)
class RewardSection:
    """``reward``: :class:`~snac_gym.ppo.envs.RewardSpec` (weights of penalties are not negative)."""

    type: str = spec(choice(*REWARD_TYPES), "shaped")
    distance_weight: float = spec(number(0), 10.0)
    precision_bonus: float = spec(number(0), 1.0)
    precision_scale: float = spec(number(0, open_low=True), 0.01)
    action_penalty: float = spec(number(0), 0.01)
    smoothness_penalty: float = spec(number(0), 0.0)
    cost: str = spec(choice("table1", "hjb"), "hjb")
    q_scale: float = spec(number(0, open_low=True), 1.0)
    udot_start: str = spec(choice("rest", "first"), "rest")
    limit_penalty: float = spec(number(0), 0.0)


@dataclass(frozen=True)
class VecEnvSection:
    """``vec_env``: how many training envs, and how they are stepped."""

    n_envs: int = spec(integer(1, 1024), 1)  # more would only exhaust memory (10⁸ hung, then MemoryError)
    kind: str = spec(choice("dummy", "subproc", "batched"), "dummy")


@dataclass(frozen=True)
class NormalizeSection:
    """``normalize``: SB3 ``VecNormalize``."""

    obs: bool = spec(boolean, True)
    reward: bool = spec(boolean, True)
    clip_obs: float = spec(number(0, open_low=True), 10.0)


@dataclass(frozen=True)
class PPOSection:
    """``ppo``: SB3 PPO arguments; an omitted one takes SB3's default (the defaults here)."""

    learning_rate: float = spec(number(0, open_low=True))
    net_arch: Any = spec(net_arch)
    learning_rate_schedule: str = spec(choice("constant", "linear"), "constant")
    n_steps: int = spec(integer(1), 2048)
    batch_size: int = spec(integer(2), 64)  # SB3 normalises advantages per batch: one sample is refused
    n_epochs: int = spec(integer(1), 10)
    gamma: float = spec(number(0, 1), 0.99)
    gae_lambda: float = spec(number(0, 1), 0.95)
    clip_range: float = spec(number(0, open_low=True), 0.2)
    ent_coef: float = spec(number(0), 0.0)
    vf_coef: float = spec(number(0), 0.5)
    max_grad_norm: float = spec(number(0, open_low=True), 0.5)
    activation: str = spec(choice("tanh", "relu"), "tanh")
    log_std_init: float = spec(number(None), 0.0)


@dataclass(frozen=True)
class EvaluationSection:
    """``evaluation``: the periodic evaluation of the frozen policy."""

    every_timesteps: int = spec(integer(1))
    episodes: int = spec(integer(1))
    horizons_s: tuple[float, ...] = spec(sequence(number(0, MAX_HORIZON_S, open_low=True)))
    seed: int = spec(integer(0))
    success_error_m: float = spec(number(0, open_low=True))
    keep_checkpoints: bool = spec(boolean, False)


@dataclass(frozen=True)
class TrainingConfig:
    """A training config read and checked (see the module docstring); ``env`` is checked against the env's
    constructor."""

    config_version: int = spec(choice(CONFIG_VERSION))
    task: str = spec(text)
    timesteps: int = spec(integer(1))
    seed: int = spec(integer(0, MAX_SEED))
    env: dict[str, Any] = spec(_json_object)
    features: FeaturesSection = spec(FeaturesSection)
    reward: RewardSection = spec(RewardSection)
    vec_env: VecEnvSection = spec(VecEnvSection)
    normalize: NormalizeSection = spec(NormalizeSection)
    ppo: PPOSection = spec(PPOSection)
    evaluation: EvaluationSection = spec(EvaluationSection)
    robot: str = spec(text, "ur10")
    description: str = spec(text, "")
    init_from: str = spec(text, "")

    def __post_init__(self) -> None:
        if self.task not in task_names():
            raise ConfigError(f"task must be one of {' or '.join(repr(t) for t in task_names())}, got {self.task!r}")
        if self.robot not in robot_names():
            raise ConfigError(f"robot must be one of {', '.join(sorted(robot_names()))}, got {self.robot!r}")
        if self.ppo.n_steps * self.vec_env.n_envs < 2:  # SB3's rollout buffer needs two samples
            raise ConfigError("ppo.n_steps × vec_env.n_envs must be ≥ 2, got 1")
        _check_env_keywords(self.task, self.env)
        if self.reward.type == "cost" and {"reward_type", "cost", "Q", "R"} & set(self.env):
            raise ConfigError("reward.type 'cost' sets the env's reward_type, cost, Q and R: leave them out of env")


#: Checks of the env constructor's arguments by annotation; every numeric one (dt, n_substeps,
#: max_steps, success_tolerance, render sizes) is a positive quantity. Others are the env's to check.
_ANNOTATION_CHECKS: dict[str, Check] = {
    "int": integer(1),
    "float": number(0, open_low=True),
    "bool": boolean,
    "str": text,
}


def env_keywords(task: str) -> dict[str, inspect.Parameter]:
    """The keyword arguments the env of ``task`` takes (``robot`` and ``task`` are the config's own keys)."""
    import snac_gym  # noqa: F401  (registers the env ids)

    entry = gym.spec(get_task(task).env_id).entry_point
    creator = gym.envs.registration.load_env_creator(entry) if isinstance(entry, str) else entry
    parameters = inspect.signature(cast("Callable[..., Any]", creator)).parameters  # snac-gym ids have one
    named = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return {name: p for name, p in parameters.items() if p.kind in named and name not in ("robot", "task")}


def env_arguments(config: dict[str, Any]) -> dict[str, Any]:
    """The env keyword arguments of a resolved ``config``: its ``env`` section, with ``sample_space``
    (``"cuboid"``: the robot's sample cuboid, the default; ``"workspace"``: anywhere the arm reaches,
    every IK branch, as ``snac-gym evaluate --sample-space workspace``) made a
    :class:`~snac_gym.sampling.SampleSpace`."""
    arguments = dict(config["env"])
    region = arguments.pop("sample_space", None)
    if region == "workspace":
        arguments["sample_space"] = SampleSpace.workspace(Kinematics(config.get("robot", "ur10")))
    return arguments


def _check_env_keywords(task: str, env: dict[str, Any]) -> None:
    accepted = env_keywords(task)
    region = env.get("sample_space")
    if region is not None and region not in SAMPLE_REGIONS:
        raise ConfigError(f"env.sample_space must be one of {', '.join(SAMPLE_REGIONS)}, got {region!r}")
    for key, value in env.items():
        if key == "sample_space":
            continue
        if key not in accepted:
            raise ConfigError(f"unknown env keyword env.{key}: the {task} env takes {', '.join(accepted)}")
        annotation = str(accepted[key].annotation).replace(" ", "")
        optional = annotation.endswith("|None")
        check = _ANNOTATION_CHECKS.get(annotation.removesuffix("|None"))
        if check is not None and not (optional and value is None):
            check(value, f"env.{key}")
    # The engines' own timing check, with its bounds (n_substeps ≤ 1000: 10⁹ would hang the first step)
    timing = {key: env[key] for key in ("dt", "n_substeps") if env.get(key) is not None}
    try:
        check_timing(timing.get("dt", 0.008), timing.get("n_substeps", 1))
    except ValueError as exc:
        raise ConfigError(f"env.{exc}") from None
