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

import contextlib
import math
import multiprocessing
import shutil
import signal
from dataclasses import dataclass
from datetime import datetime, timezone
from functools import partial
from pathlib import Path
from typing import Any, Callable

import gymnasium as gym

from snac_gym.common import startup
from snac_gym.common.extras import require
from snac_gym.common.outputs import removed_if_left_empty, write_whole
from snac_gym.common.progress import ProgressLines
from snac_gym.envs import make_task_env
from snac_gym.ppo.cloning import load_actor
from snac_gym.ppo.config import env_arguments
from snac_gym.ppo.curves import plot_training_curves, read_evaluations, read_training_log, training_curves_figure
from snac_gym.ppo.envs import PPOTrainingWrapper, RewardSpec
from snac_gym.ppo.evaluation import better, evaluate_policy_file
from snac_gym.ppo.features import FeatureSpec
from snac_gym.ppo.policy_file import PolicyFile
from snac_gym.ppo.run_folder import (
    CHECKSUM_FILE,
    EVALUATION_COLUMNS,
    MODEL_FILE,
    NORMALIZE_FILE,
    POLICY_FILE,
    TrainingRun,
    check_checkpoint,
    new_config,
    package_versions,
    resumed_config,
    write_json,
)

__all__ = [
    "CHECKSUM_FILE",
    "EVALUATION_COLUMNS",
    "MODEL_FILE",
    "NORMALIZE_FILE",
    "POLICY_FILE",
    "LinearSchedule",
    "TrainingResult",
    "build_model",
    "build_vec_env",
    "evaluate_policy_file",
    "make_training_env",
    "package_versions",
    "plot_training_curves",
    "read_evaluations",
    "read_training_log",
    "train_ppo",
    "training_curves_figure",
]


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
    for module in ("torch", "stable_baselines3"):
        require(module, "rl", "train-ppo (stable-baselines3 and torch)")


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
    """A fresh SB3 PPO for ``config`` on ``venv`` (its actor from ``config["init_from"]`` when that is set)."""
    # the rl extra
    import torch
    from stable_baselines3 import PPO

    ppo = dict(config["ppo"])
    schedule = ppo.pop("learning_rate_schedule", "constant")
    rate = float(ppo.pop("learning_rate"))
    net_arch = ppo.pop("net_arch")
    activation = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[ppo.pop("activation", "tanh")]
    log_std_init = float(ppo.pop("log_std_init", 0.0))
    model = PPO(
        "MlpPolicy",
        venv,
        learning_rate=LinearSchedule(rate) if schedule == "linear" else rate,
        policy_kwargs={"net_arch": net_arch, "activation_fn": activation, "log_std_init": log_std_init},
        seed=int(config["seed"]),
        device="cpu",
        verbose=0,
        **ppo,
    )
    if config.get("init_from"):  # the actor of a policy file, e.g. a behaviour clone (snac_gym.ppo.cloning)
        load_actor(model, PolicyFile.load(config["init_from"]))
    return model


def _evaluate_checkpoint(
    run: TrainingRun, model: Any, venv: Any, log: Callable[[str], None], lines: Any, total: int
) -> dict[str, float]:
    """Checkpoint ``model``, evaluate it, keep it as ``best/`` if it beats the best so far, log a line
    (and put the success rate in the progress ``lines``, when there are any)."""
    timesteps = int(model.num_timesteps)
    policy_path = run.save("checkpoint", model, venv)
    if run.config["evaluation"].get("keep_checkpoints", False):  # every evaluated policy, for learning curves
        kept = run.out / "checkpoints" / f"{timesteps:09d}.npz"
        kept.parent.mkdir(exist_ok=True)
        shutil.copyfile(policy_path, kept)
    scores = evaluate_policy_file(policy_path, run.config)
    is_best = better(scores, run.state["best"])
    row = {"timesteps": timesteps, "wall_time_s": round(run.wall_time(), 1), **scores, "is_best": int(is_best)}
    if is_best:
        run.state["best"] = row
        run.save("best", model, venv, {"evaluation": row})
    run.append_evaluation(row)
    run.write_state(timesteps, "running")
    if lines is not None:
        lines.detail = f"success {100 * scores['success_rate']:.1f} % at {timesteps} timesteps"
    log(
        f"[{run.config['task']}] {timesteps}/{total} steps, {row['wall_time_s'] / 60:.1f} min: success "
        f"{100 * scores['success_rate']:.1f}%, mean cost {scores['mean_cost']:.4g}, median final error "
        f"{1000 * scores['median_final_error_m']:.2f} mm{'  (best)' if is_best else ''}"
    )
    return scores


def _start_line(config: dict[str, Any], model: Any, total: int, out: Path) -> str:
    """What a training segment says as it starts: the timesteps it reaches, and why where they are more than asked."""
    envs = f"{config['vec_env']['n_envs']} {config['vec_env'].get('kind', 'dummy')} envs"
    start = f"training PPO on {config['task']} for {total} timesteps"
    if total == int(config["timesteps"]):
        return f"{start} ({envs}, seed {config['seed']}) into {out}"
    return (
        f"{start}: {config['timesteps']} asked, rounded up to whole rollouts of {model.n_steps} steps of each of the "
        f"{envs} (seed {config['seed']}), into {out}"
    )


def planned_timesteps(model: Any, target: int) -> int:
    """The timesteps ``model.learn`` reaches on its way to ``target``: PPO collects whole rollouts of ``n_steps``
    steps of each of its ``n_envs`` envs, so it stops at the first rollout's end at or past ``target``."""
    done, rollout = int(model.num_timesteps), int(model.n_steps) * int(model.n_envs)
    return done + math.ceil(max(0, target - done) / rollout) * rollout


def _next_evaluation(timesteps: int, due: int, every: int) -> int:
    """The next multiple-of-``every`` evaluation point after ``timesteps`` (skipping those already passed)."""
    behind = timesteps - due + 1
    return due + every * max(1, math.ceil(behind / every))


def _first_evaluation(run: TrainingRun, timesteps: int, every: int, evaluate: Callable[[], None]) -> int:
    """The first evaluation point after ``timesteps``, where a (resumed) segment starts.

    A run interrupted (or killed) during an evaluation saved its checkpoint at that evaluation's
    timesteps without its row: ``evaluate`` runs it first, so that a resumed run keeps every row.
    """
    due = timesteps // every * every
    if due > 0 and max(run.evaluated_timesteps(), default=-1) < due:
        evaluate()
    return due + every


def _make_callback(
    run: TrainingRun, venv: Any, log: Callable[[str], None], progress: Callable[[str], None] | None, total: int
) -> Any:
    """The callback of ``model.learn``; ``total``: the timesteps the run will reach (:func:`planned_timesteps`)."""
    from stable_baselines3.common.callbacks import BaseCallback  # the rl extra

    every = int(run.config["evaluation"]["every_timesteps"])
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
            scores = _evaluate_checkpoint(run, self.model, venv, log, self.lines, total)
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
    init_from: str | Path | None = None,
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
        init_from: A policy file whose actor the new model starts from (default: the config's ``init_from``).
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
    overrides = {"timesteps": timesteps, "seed": seed, "n_envs": n_envs, "vec_env": vec_env, "init_from": init_from}
    # Everything the input decides is checked before torch is imported or anything is made.
    config = resumed_config(out, task, overrides) if resume else new_config(out, task, config_path, overrides)
    before = _paths_under(out)
    # a resumed run rewrites these two before its first timestep (its config, a state saying "running")
    kept = {path: path.read_bytes() for path in (out / "config.json", out / "state.json") if resume and path.exists()}
    # The folders made for a new run (a file or /dev/null refused here, as evaluate refuses it) are removed again if
    # it ends with nothing in them: refused, or stopped before its first timestep once what it wrote is removed.
    with removed_if_left_empty(out):
        try:
            return _train(out, config, resume, log, progress)
        except _NotStarted as stopped:  # a signal or a refusal before the first timestep: the folder as it was
            _remove_all_but(out, before)
            for path, data in kept.items():
                write_whole(path, partial(Path.write_bytes, data=data))
            raise stopped.cause from None


class _NotStarted(Exception):
    """A stop signal came, or the input was refused, before training began (``cause``: the signal's
    ``KeyboardInterrupt``, or the ``ValueError`` of what only building the model can check: a policy file of
    ``init_from`` that is not one, or whose layers do not fit)."""

    def __init__(self, cause: KeyboardInterrupt | ValueError) -> None:
        super().__init__()
        self.cause = cause


def _paths_under(folder: Path) -> set[Path] | None:
    """What ``folder`` holds now (``None``: it does not exist)."""
    return set(folder.rglob("*")) if folder.exists() else None


def _remove_all_but(folder: Path, kept: set[Path] | None) -> None:
    """Remove what was made under ``folder`` since :func:`_paths_under` gave ``kept`` (a new ``folder`` itself, and the
    folders made above it, are :func:`~snac_gym.common.outputs.removed_if_left_empty`'s)."""
    made = sorted(set(folder.rglob("*")) - (kept or set()), key=lambda path: len(path.parts), reverse=True)
    for path in made:
        if path.is_dir() and not path.is_symlink():
            with contextlib.suppress(OSError):  # not empty: something not ours is in it
                path.rmdir()
        else:
            path.unlink(missing_ok=True)


def _open_run(out: Path, config: dict[str, Any], resume: bool) -> tuple[TrainingRun, Any]:
    """The rl extra imported, the run's config written and its training envs made (``Any``: an SB3 VecEnv)."""
    _require_sb3()
    # the rl extra (checked just above, after the input)
    import torch

    startup.imports_done()
    if resume:
        check_checkpoint(out / "checkpoint")
    else:
        config["versions"] = package_versions()
    write_json(out / "config.json", config)
    torch.set_num_threads(1)  # small MLP: one thread is fastest and leaves the other cores to the envs
    return TrainingRun(out, config), build_vec_env(config)


def _load_or_build_model(out: Path, config: dict[str, Any], resume: bool, inner: Any) -> tuple[Any, Any]:
    """The normalised envs and the PPO model: the checkpoint's (``resume``) or a new one (``Any``: SB3's types)."""
    # the rl extra, imported by _open_run
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    if resume:
        checkpoint = out / "checkpoint"
        venv = VecNormalize.load(str(checkpoint / NORMALIZE_FILE), inner)
        venv.training = True
        return venv, PPO.load(checkpoint / MODEL_FILE, env=venv, device="cpu")
    venv = _normalized(inner, config)
    return venv, build_model(config, venv)


def _train(
    out: Path,
    config: dict[str, Any],
    resume: bool,
    log: Callable[[str], None],
    progress: Callable[[str], None] | None,
) -> TrainingResult:
    """:func:`train_ppo` once its input is checked; a signal or a refusal before the first timestep raises
    :class:`_NotStarted`."""
    try:
        inner = None
        run, inner = _open_run(out, config, resume)
        venv, model = _load_or_build_model(out, config, resume, inner)
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
        total = planned_timesteps(model, int(config["timesteps"]))
        log(_start_line(config, model, total, out))
        callback = _make_callback(run, venv, log, progress, total)
    except (KeyboardInterrupt, ValueError) as exc:
        if inner is not None:
            with contextlib.suppress(Exception):  # the envs' processes, if any were started
                inner.close()
        raise _NotStarted(exc) from None
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


def _result(run: TrainingRun, status: str, timesteps: int) -> TrainingResult:
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
