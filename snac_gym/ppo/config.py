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
* ``evaluation``: ``every_timesteps``, ``episodes``, ``horizons_s`` (the horizons each
  episode is scored at: the evaluator's, 4 s and 8 s reach, 10 s and 20 s track), ``seed``
  (first reset seed of the evaluation episodes), ``success_error_m`` (reach: final ‖e‖ at
  most this; track: mean ‖e‖ over the second half of the horizon below this).
"""

from __future__ import annotations

import copy
import json
from importlib import resources
from pathlib import Path
from typing import Any

from snac_gym.tasks import task_names

CONFIG_VERSION = 1
PACKAGE = "snac_gym.ppo"
_SECTIONS = ("env", "features", "reward", "vec_env", "normalize", "ppo", "evaluation")
_TOP_LEVEL = {"config_version", "task", "robot", "timesteps", "seed", "description", *_SECTIONS}
_PPO_KEYS = {
    "learning_rate", "learning_rate_schedule", "n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda",
    "clip_range", "ent_coef", "vf_coef", "max_grad_norm", "net_arch", "activation", "log_std_init",
}
_EVALUATION_KEYS = {"every_timesteps", "episodes", "horizons_s", "seed", "success_error_m"}


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
        config = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read PPO config {path}: {exc}") from exc
    validate_config(config, str(path))
    return config


def validate_config(config: dict[str, Any], source: str = "PPO config") -> None:
    """Check the schema of a config dict (see the module docstring).

    Raises:
        ValueError: Naming the offending key.
    """
    if not isinstance(config, dict):
        raise ValueError(f"{source}: expected a JSON object")
    if config.get("config_version") != CONFIG_VERSION:
        raise ValueError(f"{source}: config_version must be {CONFIG_VERSION}, got {config.get('config_version')!r}")
    unknown = set(config) - _TOP_LEVEL
    if unknown:
        raise ValueError(f"{source}: unknown keys {sorted(unknown)}")
    missing = [key for key in ("task", "timesteps", "seed", *_SECTIONS) if key not in config]
    if missing:
        raise ValueError(f"{source}: missing keys {missing}")
    if config["task"] not in task_names():
        raise ValueError(f"{source}: task must be one of {task_names()}, got {config['task']!r}")
    _validate_sections(config, source)


#: Enumerated settings: (section, key, default, allowed values).
_CHOICES = (
    ("vec_env", "kind", "dummy", ("dummy", "subproc", "batched")),
    ("ppo", "learning_rate_schedule", "constant", ("constant", "linear")),
    ("ppo", "activation", "tanh", ("tanh", "relu")),
)


def _validate_sections(config: dict[str, Any], source: str) -> None:
    """The keys of the ``ppo`` and ``evaluation`` sections and the enumerated settings."""
    for key, allowed in (("ppo", _PPO_KEYS), ("evaluation", _EVALUATION_KEYS)):
        extra = set(config[key]) - allowed
        if extra:
            raise ValueError(f"{source}: unknown {key} keys {sorted(extra)}")
    for section, key, default, allowed in _CHOICES:
        value = config[section].get(key, default)
        if value not in allowed:
            quoted = " or ".join(repr(v) for v in allowed)
            raise ValueError(f"{source}: {section}.{key} must be {quoted}, got {value!r}")


def resolve_config(
    task: str,
    config_path: str | Path | None = None,
    timesteps: int | None = None,
    seed: int | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
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
    config["config_file"] = str(path)
    validate_config({k: v for k, v in config.items() if k != "config_file"}, str(path))
    if config["timesteps"] < 1:
        raise ValueError(f"timesteps must be at least 1, got {config['timesteps']}")
    if config["vec_env"].get("n_envs", 1) < 1:
        raise ValueError("n_envs must be at least 1")
    return config
