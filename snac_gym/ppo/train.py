"""``snac-gym train-ppo``: train the PPO baseline on a snac-gym env, evaluate it, keep the best.

:func:`train_ppo` trains stable-baselines3 PPO on :class:`~snac_gym.ppo.envs.PPOTrainingWrapper`
around the task's env, with the hyperparameters of a versioned JSON config
(:mod:`snac_gym.ppo.config`). Output folder ``OUT``::

    OUT/config.json           the resolved config, command-line overrides applied, with versions
    OUT/state.json            timesteps done, wall time, best evaluation, status
    OUT/evaluations.csv       one row per periodic evaluation (success rate, mean trajectory cost, ...)
    OUT/logs/segment_<T>/     SB3 logger output of the run started at timestep T: progress.csv
                              (and TensorBoard event files when tensorboard is installed)
    OUT/checkpoint/           the latest state: model.zip (SB3 PPO, optimiser included),
                              vecnormalize.pkl (VecNormalize statistics), policy.npz (the frozen
                              policy file, see snac_gym.ppo.policy_file)
    OUT/best/                 the same three files for the best evaluation so far
    OUT/training_curves.png   success rate, mean trajectory cost and training reward vs timesteps

Every ``evaluation.every_timesteps`` steps the current policy is frozen into a policy file and
run by :class:`~snac_gym.ppo.policy.PPOPolicy` (the code path of ``make_policy("ppo")``) on
``evaluation.episodes`` episodes of the PyBullet env, reset with seeds ``evaluation.seed + i``,
and scored at each of ``evaluation.horizons_s`` (the evaluator's horizons: 4 s and 8 s for
reach, 10 s and 20 s for track). Success at a horizon: reach, final ‖e‖ ≤ ``success_error_m``;
track, mean ‖e‖ over the second half of the horizon < ``success_error_m``; an episode succeeds
if it does at every horizon. The trajectory cost is :func:`snac_gym.control.cost.trajectory_cost` over
the first horizon. The best model is the one with the highest success rate, ties broken by
the lower mean cost.

Ctrl-C (or any stop signal the caller turns into ``KeyboardInterrupt``, as the CLI does SIGTERM,
SIGHUP and SIGQUIT) stops training after saving ``checkpoint/`` (a usable ``policy.npz`` included);
``resume=True`` (``--resume``) continues from it up to the total ``timesteps``. A checkpoint is
written whole or not at all, with the sha256 of its files (``checkpoint/sha256.json``), which a
resume checks. A resume keeps every evaluation row: one whose evaluation the interruption cut is
run first. It is not bit-identical to an uninterrupted run: SB3 saves neither the random
generators nor the rollout and the training episodes in flight, so the resumed segment collects
new rollouts from fresh episodes (docs/ppo.md).
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import multiprocessing
import pickle
import platform
import shutil
import signal
import time
import zipfile
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from snac_gym import __version__
from snac_gym.common.outputs import usable_out_folder, write_error, write_text_whole, write_whole
from snac_gym.common.progress import ProgressLines
from snac_gym.control.cost import trajectory_cost
from snac_gym.envs import make_task_env
from snac_gym.model.kinematics import Kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.ppo.config import env_arguments, resolve_config, validate_config
from snac_gym.ppo.envs import PPOTrainingWrapper, RewardSpec
from snac_gym.ppo.features import FeatureSpec
from snac_gym.ppo.policy import PPOPolicy
from snac_gym.ppo.policy_file import export_policy
from snac_gym.rollout import log_array, rollout
from snac_gym.tasks import get_task

#: Env id of each task.
#: Columns of evaluations.csv (``success_rate_<h>s`` follows ``success_rate`` for each horizon h).
EVALUATION_COLUMNS = (
    "timesteps",
    "wall_time_s",
    "success_rate",
    "mean_cost",
    "mean_final_error_m",
    "median_final_error_m",
    "mean_error_2nd_half_m",
    "median_error_2nd_half_m",
    "is_best",
)
MODEL_FILE = "model.zip"
NORMALIZE_FILE = "vecnormalize.pkl"
POLICY_FILE = "policy.npz"
#: The sha256 of the three files above, written into the checkpoint folder with them.
CHECKSUM_FILE = "sha256.json"


@dataclass
class TrainingResult:
    """What a call of :func:`train_ppo` did.

    Attributes:
        out: The output folder.
        status: ``"finished"``, ``"interrupted"`` (Ctrl-C; resume with ``resume=True``) or
            ``"already-done"`` (resume found the timesteps reached).
        timesteps: Timesteps trained in total (all segments).
        wall_time_s: Wall time of all segments together, s.
        best: The best evaluation row (see :data:`EVALUATION_COLUMNS`), or ``None``.
        best_policy: ``OUT/best/policy.npz`` if an evaluation ran, else ``None``.
        checkpoint_policy: ``OUT/checkpoint/policy.npz``.
    """

    out: Path
    status: str
    timesteps: int
    wall_time_s: float
    best: dict[str, float] | None
    best_policy: Path | None
    checkpoint_policy: Path


def _require_sb3() -> None:
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError("train-ppo needs stable-baselines3 and torch: pip install 'snac-gym[rl]'") from exc


def package_versions() -> dict[str, str]:
    """Versions of snac-gym and of the training stack, stored with every run and policy file."""
    # the rl extra
    import stable_baselines3
    import torch

    return {
        "snac_gym": __version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
        "gymnasium": gym.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


class LinearSchedule:
    """Learning rate ``initial · progress_remaining`` (a module-level class, so saved models reload it)."""

    def __init__(self, initial: float) -> None:
        self.initial = float(initial)

    def __call__(self, progress_remaining: float) -> float:
        return self.initial * progress_remaining


# -- envs ----------------------------------------------------------------------------------------
def make_training_env(config: dict[str, Any]) -> gym.Env:
    """One training env of ``config`` (the task's env inside :class:`PPOTrainingWrapper`)."""
    reward = RewardSpec.from_dict(config["reward"])
    env = make_task_env(config["task"], config.get("robot", "ur10"), **env_arguments(config), **reward.env_kwargs())
    return PPOTrainingWrapper(env, FeatureSpec.from_dict(config["features"]), reward)


class _EnvFactory:
    """Picklable env constructor for ``SubprocVecEnv``; workers ignore Ctrl-C (the trainer handles it)."""

    def __init__(self, config: dict[str, Any]) -> None:
        self.config = config

    def __call__(self) -> gym.Env:
        if multiprocessing.parent_process() is not None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        import snac_gym  # noqa: F401  (registers the env ids in a fresh worker)

        return make_training_env(self.config)


def build_vec_env(config: dict[str, Any]) -> Any:
    """The vectorised training env (``n_envs`` copies, ``dummy``, ``subproc`` or ``batched``), seeded
    with ``seed + i``."""
    # the rl extra
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    vec = config["vec_env"]
    kind = vec.get("kind", "dummy")
    if kind == "batched":
        # the rl extra (PPOVecEnv is a stable_baselines3 VecEnv)
        from stable_baselines3.common.vec_env import VecMonitor

        from snac_gym.ppo.vec_env import PPOVecEnv

        venv = PPOVecEnv(config)
        venv.seed(int(config["seed"]))
        return VecMonitor(venv)  # episode returns and lengths for SB3's log (make_vec_env's Monitor does it otherwise)
    kwargs: dict[str, Any] = {"start_method": "spawn"} if kind == "subproc" else {}
    return make_vec_env(
        _EnvFactory(config),
        n_envs=int(vec.get("n_envs", 1)),
        seed=int(config["seed"]),
        vec_env_cls=SubprocVecEnv if kind == "subproc" else DummyVecEnv,
        vec_env_kwargs=kwargs,
    )


def _normalized(venv: Any, config: dict[str, Any]) -> Any:
    from stable_baselines3.common.vec_env import VecNormalize  # the rl extra

    normalize = config["normalize"]
    return VecNormalize(
        venv,
        norm_obs=bool(normalize.get("obs", True)),
        norm_reward=bool(normalize.get("reward", True)),
        clip_obs=float(normalize.get("clip_obs", 10.0)),
        gamma=float(config["ppo"]["gamma"]),
    )


def build_model(config: dict[str, Any], venv: Any) -> Any:
    """A fresh SB3 PPO for ``config`` on ``venv``."""
    # the rl extra
    import torch
    from stable_baselines3 import PPO

    ppo = dict(config["ppo"])
    schedule = ppo.pop("learning_rate_schedule", "constant")
    rate = float(ppo.pop("learning_rate"))
    net_arch = ppo.pop("net_arch")
    activation = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[ppo.pop("activation", "tanh")]
    log_std_init = float(ppo.pop("log_std_init", 0.0))
    return PPO(
        "MlpPolicy",
        venv,
        learning_rate=LinearSchedule(rate) if schedule == "linear" else rate,
        policy_kwargs={"net_arch": net_arch, "activation_fn": activation, "log_std_init": log_std_init},
        seed=int(config["seed"]),
        device="cpu",
        verbose=0,
        **ppo,
    )


# -- evaluation ----------------------------------------------------------------------------------
def evaluate_policy_file(
    policy_path: str | Path, config: dict[str, Any], episodes: int | None = None, action_scale: float = 1.0
) -> dict[str, float]:
    """Run a policy file with :class:`~snac_gym.ppo.policy.PPOPolicy` on the PyBullet env.

    Episodes ``i = 0 .. episodes−1`` are reset with seed ``evaluation.seed + i`` (random start
    pose and reference) and run for the longest of ``evaluation.horizons_s``; each horizon h is
    scored on the first h seconds of the same episode.

    Returns:
        ``success_rate`` (the fraction of episodes that succeed at every horizon),
        ``success_rate_<h>s`` per horizon, ``mean_cost`` (mean trajectory cost V over the
        first horizon), and at the last horizon ``mean_final_error_m``,
        ``median_final_error_m``, ``mean_error_2nd_half_m``, ``median_error_2nd_half_m``.
    """
    evaluation = config["evaluation"]
    task = get_task(config["task"])
    count = int(episodes if episodes is not None else evaluation["episodes"])
    threshold = float(evaluation["success_error_m"])
    # the episodes of the region trained on (the sample cuboid unless env.sample_space says otherwise)
    space = env_arguments(config).get("sample_space")
    env = make_task_env(
        task, config.get("robot", "ur10"), max_steps=10**9, **({} if space is None else {"sample_space": space})
    )
    try:
        policy = PPOPolicy(env, model_path=policy_path, action_scale=action_scale)
        dt = env.unwrapped.dt
        horizons = [float(h) for h in evaluation["horizons_s"]]
        horizon_steps = [max(1, int(round(h / dt))) for h in horizons]
        costs, successes, finals, second_halves = [], [], [], []
        for i in range(count):
            log = rollout(env, policy, seed=int(evaluation["seed"]) + i, steps=max(horizon_steps))
            errors = np.vstack([log_array(log, "e"), np.asarray(log.attrs["final_e"], dtype=float)[None]])
            norms = np.linalg.norm(errors, axis=1)
            first = horizon_steps[0]
            costs.append(float(trajectory_cost(errors[:first], log_array(log, "u")[:first], dt).total))
            finals_i = [float(norms[k]) for k in horizon_steps]
            halves_i = [float(norms[k // 2 : k].mean()) for k in horizon_steps]
            successes.append(
                [
                    bool(task.success({"final_error": final, "mean_error_2nd_half": half}, threshold))
                    for final, half in zip(finals_i, halves_i, strict=True)
                ]
            )
            finals.append(finals_i[-1])
            second_halves.append(halves_i[-1])
    finally:
        env.close()
    success = np.array(successes, dtype=bool)
    finals_a, halves_a = np.array(finals), np.array(second_halves)
    scores = {"success_rate": float(success.all(axis=1).mean())}
    for j, horizon in enumerate(horizons):
        scores[f"success_rate_{horizon:g}s"] = float(success[:, j].mean())
    scores.update(
        mean_cost=float(np.mean(costs)),
        mean_final_error_m=float(finals_a.mean()),
        median_final_error_m=float(np.median(finals_a)),
        mean_error_2nd_half_m=float(halves_a.mean()),
        median_error_2nd_half_m=float(np.median(halves_a)),
    )
    return scores


def _better(candidate: dict[str, float], best: dict[str, float] | None) -> bool:
    if best is None:
        return True
    if candidate["success_rate"] != best["success_rate"]:
        return candidate["success_rate"] > best["success_rate"]
    return candidate["mean_cost"] < best["mean_cost"]


# -- saving --------------------------------------------------------------------------------------
class _Run:
    """The output folder of one training run and what is saved into it."""

    def __init__(self, out: Path, config: dict[str, Any]) -> None:
        self.out = out
        self.config = config
        self.state_path = out / "state.json"
        self.evaluations_path = out / "evaluations.csv"
        self.state: dict[str, Any] = {"timesteps": 0, "wall_time_s": 0.0, "best": None, "status": "new", "segments": []}
        if self.state_path.exists():
            self.state.update(json.loads(self.state_path.read_text()))
        self.segment_start = time.perf_counter()
        self.wall_before = float(self.state["wall_time_s"])

    def wall_time(self) -> float:
        return self.wall_before + time.perf_counter() - self.segment_start

    def write_state(self, timesteps: int, status: str) -> None:
        self.state.update(timesteps=int(timesteps), wall_time_s=round(self.wall_time(), 1), status=status)
        _write_json(self.state_path, self.state)

    def metadata(self, model: Any) -> dict[str, Any]:
        robot = self.config.get("robot", "ur10")
        kinematics = Kinematics(robot)
        layout = ObservationLayout(kinematics.n_joints, kinematics.task_dim)
        return {
            "task": self.config["task"],
            "robot": robot,
            "layout": {"n_joints": layout.n_joints, "task_dim": layout.task_dim, "size": layout.size},
            "timesteps": int(model.num_timesteps),
            "seed": int(self.config["seed"]),
            "versions": package_versions(),
            "config": self.config,
            "exported_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "training_wall_time_s": round(self.wall_time(), 1),
        }

    def save(self, folder: str, model: Any, venv: Any, extra_metadata: dict[str, Any] | None = None) -> Path:
        """Save model, normalisation statistics and the frozen policy file into ``OUT/folder``, whole or not at all.

        The files are written into ``OUT/folder.tmp`` with their sha256 in its ``CHECKSUM_FILE``, which
        then replaces ``OUT/folder``: a run killed while saving leaves the previous folder, and a file
        altered later fails its checksum on ``--resume`` (:func:`_check_checkpoint`).
        """
        target = self.out / folder
        staging = self.out / f"{folder}.tmp"
        shutil.rmtree(staging, ignore_errors=True)
        try:
            staging.mkdir(parents=True)
            model.save(staging / MODEL_FILE)
            venv.save(str(staging / NORMALIZE_FILE))
            metadata = self.metadata(model)
            metadata.update(extra_metadata or {})
            features = FeatureSpec.from_dict(self.config["features"])
            export_policy(model, venv, metadata, features).save(staging / POLICY_FILE)
            checksums = {name: _sha256(staging / name) for name in (MODEL_FILE, NORMALIZE_FILE, POLICY_FILE)}
            _write_json(staging / CHECKSUM_FILE, {"timesteps": int(model.num_timesteps), "sha256": checksums})
            _replace_folder(staging, target)
        except OSError as exc:  # the previous checkpoint stays; the half-written one goes
            shutil.rmtree(staging, ignore_errors=True)
            raise write_error(target, exc) from exc
        return target / POLICY_FILE

    def evaluated_timesteps(self) -> list[int]:
        """The timesteps of the rows in evaluations.csv, in order."""
        return [int(row["timesteps"]) for row in read_evaluations(self.out)]

    def best_of_rows(self) -> dict[str, float] | None:
        """The best row of evaluations.csv (as :func:`_better` ranks them): state.json's ``best`` may lag
        the rows when a run was killed between writing one and the other."""
        best = None
        for row in read_evaluations(self.out):
            if _better(row, best):
                best = row
        return best

    def append_evaluation(self, row: dict[str, Any]) -> None:
        new = not self.evaluations_path.exists()
        per_horizon = [key for key in row if key.startswith("success_rate_")]
        columns = [*EVALUATION_COLUMNS[:3], *per_horizon, *EVALUATION_COLUMNS[3:]]
        with self.evaluations_path.open("a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=columns)
            if new:
                writer.writeheader()
            writer.writerow({key: row[key] for key in columns})


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _replace_folder(staging: Path, target: Path) -> None:
    """Put the complete folder ``staging`` in the place of ``target`` (two renames: at every moment one of them is
    whole)."""
    previous = target.with_name(target.name + ".old")
    shutil.rmtree(previous, ignore_errors=True)
    if target.exists():
        target.rename(previous)
    staging.rename(target)
    shutil.rmtree(previous, ignore_errors=True)


def _write_json(path: Path, data: dict[str, Any]) -> None:
    write_text_whole(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def _evaluate_checkpoint(run: _Run, model: Any, venv: Any, log: Callable[[str], None], lines: Any) -> dict[str, float]:
    """Checkpoint ``model``, evaluate it, keep it as ``best/`` if it beats the best so far, log a line
    (and put the success rate in the progress ``lines``, when there are any)."""
    timesteps = int(model.num_timesteps)
    policy_path = run.save("checkpoint", model, venv)
    if run.config["evaluation"].get("keep_checkpoints", False):  # every evaluated policy, for learning curves
        kept = run.out / "checkpoints" / f"{timesteps:09d}.npz"
        kept.parent.mkdir(exist_ok=True)
        shutil.copyfile(policy_path, kept)
    scores = evaluate_policy_file(policy_path, run.config)
    is_best = _better(scores, run.state["best"])
    row = {"timesteps": timesteps, "wall_time_s": round(run.wall_time(), 1), **scores, "is_best": int(is_best)}
    if is_best:
        run.state["best"] = row
        run.save("best", model, venv, {"evaluation": row})
    run.append_evaluation(row)
    run.write_state(timesteps, "running")
    if lines is not None:
        lines.detail = f"success {100 * scores['success_rate']:.1f} % at {timesteps} timesteps"
    total = int(run.config["timesteps"])
    log(
        f"[{run.config['task']}] {timesteps}/{total} steps, {row['wall_time_s'] / 60:.1f} min: success "
        f"{100 * scores['success_rate']:.1f}%, mean cost {scores['mean_cost']:.4g}, median final error "
        f"{1000 * scores['median_final_error_m']:.2f} mm{'  (best)' if is_best else ''}"
    )
    return scores


def _next_evaluation(timesteps: int, due: int, every: int) -> int:
    """The next multiple-of-``every`` evaluation point after ``timesteps`` (skipping those already passed)."""
    behind = timesteps - due + 1
    return due + every * max(1, math.ceil(behind / every))


def _first_evaluation(run: _Run, timesteps: int, every: int, evaluate: Callable[[], None]) -> int:
    """The first evaluation point after ``timesteps``, where a (resumed) segment starts.

    A run interrupted (or killed) during an evaluation saved its checkpoint at that evaluation's
    timesteps without its row: ``evaluate`` runs it first, so that a resumed run keeps every row.
    """
    due = timesteps // every * every
    if due > 0 and max(run.evaluated_timesteps(), default=-1) < due:
        evaluate()
    return due + every


def _make_callback(run: _Run, venv: Any, log: Callable[[str], None], progress: Callable[[str], None] | None) -> Any:
    from stable_baselines3.common.callbacks import BaseCallback  # the rl extra

    every = int(run.config["evaluation"]["every_timesteps"])
    total = int(run.config["timesteps"])
    task = run.config["task"]

    class EvaluateAndCheckpoint(BaseCallback):
        """Every ``every`` timesteps: checkpoint, evaluate the frozen policy, keep the best.

        With ``progress``, also a line of timesteps done, time and the last success rate every
        10 % of the timesteps or 10 s, whichever comes first.
        """

        def __init__(self) -> None:
            super().__init__()
            self.next_evaluation = 0
            self.last_evaluated = -1
            self.lines = ProgressLines(f"train-ppo: {task}", total, progress, unit="timesteps") if progress else None

        def _on_training_start(self) -> None:
            self.next_evaluation = _first_evaluation(run, int(self.model.num_timesteps), every, self.evaluate)

        def _on_step(self) -> bool:
            if self.lines is not None:
                self.lines.update(done=self.model.num_timesteps)
            if self.model.num_timesteps >= self.next_evaluation:
                self.evaluate()
                self.next_evaluation = _next_evaluation(self.model.num_timesteps, self.next_evaluation, every)
            return True

        def _on_training_end(self) -> None:
            if self.last_evaluated != self.model.num_timesteps:
                self.evaluate()

        def evaluate(self) -> None:
            timesteps = int(self.model.num_timesteps)
            scores = _evaluate_checkpoint(run, self.model, venv, log, self.lines)
            for key, value in scores.items():
                self.logger.record(f"eval/{key}", value)
            self.logger.dump(timesteps)
            self.last_evaluated = timesteps

    return EvaluateAndCheckpoint()


def _configure_logger(folder: Path) -> Any:
    from stable_baselines3.common.logger import configure  # the rl extra

    formats = ["csv"]
    try:
        import tensorboard  # noqa: F401

        formats.append("tensorboard")
    except ImportError:
        pass
    return configure(str(folder), formats)


# -- the entry point -----------------------------------------------------------------------------
def _resumed_config(out: Path, task: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The saved config of the run in ``out``, with the overrides a resumed run may change."""
    if overrides["seed"] is not None:
        raise ValueError("--seed has no effect with --resume: a resumed run keeps the seed it started with")
    checkpoint = out / "checkpoint"
    if not (checkpoint / MODEL_FILE).is_file() or not (out / "config.json").is_file():
        raise ValueError(f"--resume: {out} holds no checkpoint to continue (no {checkpoint / MODEL_FILE})")
    try:
        config = json.loads((out / "config.json").read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"--resume: {out / 'config.json'} is unreadable ({type(exc).__name__}: {exc})") from None
    if not isinstance(config, dict) or config.get("task") != task:
        other = config.get("task") if isinstance(config, dict) else None
        raise ValueError(f"--resume: the run in {out} trains task {other!r}, not {task!r}")
    saved = {k: v for k, v in config.items() if k not in ("config_file", "versions")}
    validate_config(saved, str(out / "config.json"))  # before the overrides are written into its sections
    if overrides["timesteps"] is not None:
        config["timesteps"] = int(overrides["timesteps"])
    if overrides["n_envs"] is not None:
        config["vec_env"]["n_envs"] = int(overrides["n_envs"])
    if overrides["vec_env"] is not None:
        config["vec_env"]["kind"] = overrides["vec_env"]
    saved = {k: v for k, v in config.items() if k not in ("config_file", "versions")}
    validate_config(saved, str(out / "config.json"))
    return config


def _check_checkpoint(checkpoint: Path) -> None:
    """Refuse a truncated, corrupt or altered checkpoint, naming the file, before any env is built for it."""
    manifest = checkpoint / CHECKSUM_FILE
    if manifest.is_file():  # runs saved before 0.2.0 have none: their zip CRCs below are all there is
        try:
            expected = json.loads(manifest.read_text())["sha256"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(
                f"--resume: the checksum file {manifest} is unreadable ({type(exc).__name__}: {exc})"
            ) from None
        for name, digest in expected.items():
            path = checkpoint / name
            if not path.is_file() or _sha256(path) != digest:
                raise ValueError(
                    f"--resume: the checkpoint file {path} does not match the sha256 written with it in {manifest}: "
                    "it was altered or damaged after the run saved it; train anew or restore it"
                )
    model = checkpoint / MODEL_FILE
    try:
        with zipfile.ZipFile(model) as archive:
            damaged = archive.testzip()  # CRC of every member: a cut or altered file fails here
        if damaged is not None:
            raise zipfile.BadZipFile(f"member {damaged} fails its CRC")
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"--resume: the checkpoint {model} is corrupt or truncated ({exc})") from None
    statistics = checkpoint / NORMALIZE_FILE
    try:
        with statistics.open("rb") as handle:
            pickle.load(handle)  # our own file, written by VecNormalize.save
    except Exception as exc:  # noqa: BLE001 - unpickling a damaged file raises almost anything
        raise ValueError(
            f"--resume: the checkpoint {statistics} is corrupt or truncated ({type(exc).__name__}: {exc})"
        ) from None


def _new_config(out: Path, task: str, config_path: str | Path | None, overrides: dict[str, Any]) -> dict[str, Any]:
    """The config of a new run in ``out`` (refused if ``out`` already holds one)."""
    # A state.json without a checkpoint is a run stopped before it saved anything: it is started anew.
    if (out / "checkpoint" / MODEL_FILE).exists():
        raise ValueError(f"{out} already holds a training run; pass --resume to continue it or choose another --out")
    return resolve_config(task, config_path, **overrides)


def train_ppo(
    task: str,
    out: str | Path,
    timesteps: int | None = None,
    seed: int | None = None,
    config_path: str | Path | None = None,
    resume: bool = False,
    n_envs: int | None = None,
    vec_env: str | None = None,
    log: Callable[[str], None] = print,
    progress: Callable[[str], None] | None = None,
) -> TrainingResult:
    """Train (or continue training) the PPO baseline for ``task``; see the module docstring.

    Args:
        task: A registered task's name.
        out: Output folder (created; must not hold another run unless ``resume``).
        timesteps: Total environment steps (default: the config's).
        seed: Seed of PPO and of the training envs (default: the config's).
        config_path: A config file (default: ``snac_gym/ppo/configs/<task>.json``).
        resume: Continue the run in ``out`` from its checkpoint, up to ``timesteps`` in total.
        n_envs: Number of parallel training envs (default: the config's).
        vec_env: ``"dummy"`` (one process) or ``"subproc"`` (one process per env).
        log: Where the lines of the run go (start, each evaluation, interruption).
        progress: Where periodic progress lines go (timesteps done, time, last success rate;
            every 10 % of the timesteps or 10 s, whichever first), or ``None`` for none.

    Raises:
        ValueError: On a bad config (naming the field, see :class:`~snac_gym.ppo.config.TrainingConfig`),
            an ``out`` that is a file or already holds a run (without ``resume``), or ``resume``
            without a checkpoint in ``out``, with a truncated one, or of another task.
        ImportError: If stable-baselines3 or torch is not installed.
    """
    out = Path(out)
    checkpoint = out / "checkpoint"
    overrides = {"timesteps": timesteps, "seed": seed, "n_envs": n_envs, "vec_env": vec_env}
    # Everything the input decides is checked before torch is imported or anything is made.
    config = _resumed_config(out, task, overrides) if resume else _new_config(out, task, config_path, overrides)
    usable_out_folder(out)  # a file or /dev/null is refused as evaluate refuses it
    _require_sb3()
    # the rl extra (checked just above, after the input)
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    if resume:
        _check_checkpoint(checkpoint)
    else:
        config["versions"] = package_versions()
    _write_json(out / "config.json", config)

    torch.set_num_threads(1)  # small MLP: one thread is fastest and leaves the other cores to the envs
    run = _Run(out, config)
    inner = build_vec_env(config)
    if resume:
        venv = VecNormalize.load(str(checkpoint / NORMALIZE_FILE), inner)
        venv.training = True
        model = PPO.load(checkpoint / MODEL_FILE, env=venv, device="cpu")
    else:
        venv = _normalized(inner, config)
        model = build_model(config, venv)
    start_timesteps = int(model.num_timesteps)
    if resume:
        run.state["best"] = run.best_of_rows()
    remaining = int(config["timesteps"]) - start_timesteps
    if remaining <= 0:
        venv.close()
        log(f"{out}: {start_timesteps} timesteps already trained (target {config['timesteps']}); nothing to do")
        return _result(run, "already-done", start_timesteps)
    model.set_logger(_configure_logger(out / "logs" / f"segment_{start_timesteps}"))
    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    run.state["segments"].append({"start_timesteps": start_timesteps, "started_at": started_at})
    run.state.pop("interrupted_by", None)
    run.write_state(start_timesteps, "running")
    log(
        f"training PPO on {config['task']} for {config['timesteps']} timesteps ({config['vec_env']['n_envs']} "
        f"{config['vec_env'].get('kind', 'dummy')} envs, seed {config['seed']}) into {out}"
    )
    callback = _make_callback(run, venv, log, progress)
    status = "finished"
    try:
        model.learn(total_timesteps=remaining, callback=callback, reset_num_timesteps=False, progress_bar=False)
    except KeyboardInterrupt as exc:  # Ctrl-C, or a stop signal the caller turned into one (the CLI's four)
        status = "interrupted"
        run.state["interrupted_by"] = getattr(exc, "signal_name", "SIGINT")
    timesteps_done = int(model.num_timesteps)
    run.save("checkpoint", model, venv)
    run.write_state(timesteps_done, status)
    try:
        venv.close()
    except (EOFError, BrokenPipeError, ConnectionResetError):  # pragma: no cover - workers gone after Ctrl-C
        pass
    if (
        status == "interrupted"
    ):  # the caller says so (status, timesteps, checkpoint); the curves wait for the finished run
        return _result(run, status, timesteps_done)
    try:
        plot_training_curves(out)
    except KeyboardInterrupt as exc:  # the run is complete and saved; only the figure is missing
        exc.kept = f"the finished run is saved in {out}/ (training_curves.png not drawn)"  # type: ignore[attr-defined]
        raise
    except Exception as exc:  # noqa: BLE001 - a missing plot must not lose a finished training run
        log(f"training curves not plotted: {exc}")
    return _result(run, status, timesteps_done)


def _result(run: _Run, status: str, timesteps: int) -> TrainingResult:
    best_policy = run.out / "best" / POLICY_FILE
    return TrainingResult(
        out=run.out,
        status=status,
        timesteps=timesteps,
        wall_time_s=float(run.state["wall_time_s"]),
        best=run.state["best"],
        best_policy=best_policy if best_policy.is_file() else None,
        checkpoint_policy=run.out / "checkpoint" / POLICY_FILE,
    )


def read_evaluations(out: str | Path) -> list[dict[str, float]]:
    """The rows of a run folder's evaluations.csv, in order (none if it has no evaluation yet)."""
    path = Path(out) / "evaluations.csv"
    if not path.exists():
        return []
    with path.open() as handle:
        return [{k: float(v) for k, v in row.items() if v != ""} for row in csv.DictReader(handle)]


def read_training_log(out: str | Path) -> tuple[list[dict[str, float]], list[dict[str, float]]]:
    """The evaluation rows and the SB3 progress rows (all segments, in order) of a run folder."""
    out = Path(out)
    evaluations = read_evaluations(out)
    progress: list[dict[str, float]] = []
    segments = sorted((out / "logs").glob("segment_*"), key=lambda p: int(p.name.split("_")[1]))
    for segment in segments:
        path = segment / "progress.csv"
        if path.exists() and path.stat().st_size:
            with path.open() as handle:
                rows = csv.DictReader(handle)
                progress += [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in rows]
    return evaluations, progress


def plot_training_curves(out: str | Path, path: str | Path | None = None, title: str | None = None) -> Path:
    """Plot success rate, mean trajectory cost and training reward against timesteps into a PNG.

    Args:
        out: A run folder of :func:`train_ppo`.
        path: Where to write (default ``OUT/training_curves.png``).
        title: Figure title (default: task and seed from ``OUT/config.json``).

    Returns:
        The path written.
    """
    import matplotlib  # only plotting needs matplotlib; the trainer does not

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    out = Path(out)
    fig = training_curves_figure(out, title)
    target = Path(path) if path is not None else out / "training_curves.png"
    target.parent.mkdir(parents=True, exist_ok=True)
    write_whole(target, lambda partial: fig.savefig(partial, dpi=110))
    plt.close(fig)
    return target


def _timesteps_axis(axis: Any) -> None:
    """Label the x axis of ``axis`` in engineering notation (``200k``, ``1.2M``) with at most 5 ticks.

    Plain integers (``100000``, ``200000``, ...) on a third of a 13-inch figure run into each other.
    """
    from matplotlib.ticker import EngFormatter, MaxNLocator  # only plotting needs matplotlib

    axis.xaxis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
    axis.xaxis.set_major_formatter(EngFormatter(sep=""))


def training_curves_figure(out: str | Path, title: str | None = None) -> Any:
    """The figure of :func:`plot_training_curves` (three panels against timesteps), not saved.

    Args:
        out: A run folder of :func:`train_ppo` (``config.json``, ``evaluations.csv``, ``logs/``).
        title: Figure title (default: task and seed from ``OUT/config.json``).

    Returns:
        The matplotlib figure; the caller closes it.
    """
    import matplotlib.pyplot as plt  # only plotting needs matplotlib

    out = Path(out)
    config = json.loads((out / "config.json").read_text())
    evaluations, progress = read_training_log(out)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    if evaluations:
        steps = [row["timesteps"] for row in evaluations]
        for key in [k for k in evaluations[0] if k.startswith("success_rate_")]:
            axes[0].plot(
                steps,
                [100 * row[key] for row in evaluations],
                lw=1,
                alpha=0.7,
                label=f"at {key.removeprefix('success_rate_')}",
            )
        axes[0].plot(
            steps,
            [100 * row["success_rate"] for row in evaluations],
            marker="o",
            ms=3,
            color="k",
            label="at every horizon",
        )
        best_rows = [row for row in evaluations if row.get("is_best")]
        if best_rows:  # the model kept in best/: the last row that improved
            best = best_rows[-1]
            axes[0].plot(
                [best["timesteps"]], [100 * best["success_rate"]], "*", ms=12, color="C3", label="kept (best/)"
            )
            axes[1].plot([best["timesteps"]], [best["mean_cost"]], "*", ms=12, color="C3")
        axes[0].legend(fontsize=8, loc="lower right")
        axes[1].plot(steps, [row["mean_cost"] for row in evaluations], marker="o", ms=3)
        axes[1].set_yscale("log")
    threshold_mm = 1000 * float(config["evaluation"]["success_error_m"])
    spec = get_task(config["task"])
    criterion = "final ‖e‖ ≤" if spec.success_measure == "final_error" else "mean ‖e‖, 2nd half ≤"
    axes[0].set(
        xlabel="timesteps", ylabel="success rate, %", ylim=(-2, 102), title=f"success ({criterion} {threshold_mm:g} mm)"
    )
    first_horizon = float(config["evaluation"]["horizons_s"][0])
    axes[1].set(xlabel="timesteps", ylabel="mean trajectory cost V", title=f"Table I cost V over {first_horizon:g} s")
    rewards = [
        (row["time/total_timesteps"], row["rollout/ep_rew_mean"])
        for row in progress
        if "rollout/ep_rew_mean" in row and "time/total_timesteps" in row
    ]
    if rewards:
        axes[2].plot(*zip(*rewards))
    else:  # runs made before the batched env was wrapped in VecMonitor logged no episode returns
        axes[2].text(0.5, 0.5, "no episode returns logged", ha="center", va="center", transform=axes[2].transAxes)
        axes[2].set_xlim(axes[0].get_xlim())
        axes[2].set_yticks([])
    reward = config.get("reward", {})
    reward_name = {"shaped": "shaped", "env": "the env's"}.get(reward.get("type", "shaped"))
    if reward_name is None:  # minus the evaluator's cost under the run's convention
        reward_name = f"−{reward.get('cost', 'hjb')} cost, Q = {float(reward.get('q_scale', 1.0)):g}·I"
    axes[2].set(xlabel="timesteps", ylabel="mean episode return", title=f"training reward ({reward_name})")
    for axis in axes:
        axis.grid(alpha=0.3)
        _timesteps_axis(axis)
    if title is None:
        title = f"PPO, task {config['task']}, seed {config['seed']}"
        if (out / "state.json").exists():
            state = json.loads((out / "state.json").read_text())
            title += f": {state['timesteps']} timesteps, {state['wall_time_s'] / 60:.1f} min wall time"
    fig.suptitle(title)
    fig.tight_layout()
    return fig
