"""The learners table of docs/rl.md: PPO, SAC, TD3 and TQC trained on the UR10's reach and ellipse-tracking -v1 ids
with the shipped rl-zoo3 hyperparameters, then scored by the evaluator against the per-sample optimum.

    python docs/scripts/learners.py --out runs/learners --steps 15000 --seeds 0,1,2

One job per (learner, task, seed): train for ``--steps`` environment steps, save the model under
``OUT/LEARNER_TASK_SEED/``, then score it with :func:`snac_gym.evaluation.runner.run_evaluation` (the evaluator's
kinematic engine, its success rule and its cost, the ``optimal`` reference on the same samples) and write
``scores.csv`` there. A job whose ``scores.csv`` exists is skipped, and one whose model exists is only scored, so
the same command resumes. ``--workers N`` runs N jobs at once on local processes, ``--ray ADDRESS`` (or ``local``)
on a Ray cluster (the evaluator's executors). Then ``learners_report.py`` aggregates the scores (rliable's IQM and
stratified-bootstrap intervals, the performance profile) into ``OUT/table.md``, ``OUT/runs.csv`` and the figure.

Training: the hyperparameters are the entry of the env id in ``snac_gym/data/zoo/ALGO.yml``, read as rl-zoo3 reads
them (``normalize`` wraps the envs in ``VecNormalize`` with the entry's γ, ``noise_type``/``noise_std`` give
Gaussian action noise, ``policy_kwargs`` is evaluated); the env is the -v1 id on the kinematic engine with the
reward minus the scored cost (``reward_type="cost"``, :data:`COST`), one torch thread per job.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
import yaml

import snac_gym  # noqa: F401 - registers the ids
from snac_gym.control.cost import CostConvention
from snac_gym.policies.base import PolicyContext
from snac_gym.zoo import hyperparams_file

#: The learners: stable-baselines3's PPO, SAC and TD3, sb3-contrib's TQC (the files of snac_gym/data/zoo).
LEARNERS = ("ppo", "sac", "td3", "tqc")
#: The tasks and their -v1 ids (the UR10, the default cuboid sample space).
TASKS = {"reach": "snac_gym/UR10Reach-v1", "track": "snac_gym/UR10EllipseTrack-v1"}
#: The cost trained on and scored by: the HJB cost at Q = 4·I (``snac-gym evaluate --cost hjb --q-scale 4``).
COST = CostConvention("hjb", q_scale=4.0)
#: The seed of the held-out evaluation samples (no page of the docs uses it).
EVAL_SEED = 62
#: What the evaluator runs with the model: its engine, its horizons, no effort matching.
ENV_KWARGS: dict[str, Any] = {"physics": "kinematic", "reward_type": "cost", "cost": COST}
#: The name the trained model is registered under for the evaluator (in the job's own process).
POLICY_NAME = "zoo-learner"


@dataclass(frozen=True)
class Job:
    """One (learner, task, seed) run: its training budget, its scoring and its folder ``out/LEARNER_TASK_SEED``."""

    learner: str
    task: str
    seed: int
    steps: int
    samples: int
    eval_seed: int
    out: str

    @property
    def folder(self) -> Path:
        return Path(self.out) / f"{self.learner}_{self.task}_{self.seed}"

    @property
    def env_id(self) -> str:
        return TASKS[self.task]


def zoo_hyperparams(learner: str, env_id: str) -> dict[str, Any]:
    """The entry of ``env_id`` in the shipped rl-zoo3 file of ``learner`` (YAML merge keys resolved)."""
    entries = yaml.safe_load(hyperparams_file(learner).read_text())
    if env_id not in entries:
        raise ValueError(f"{hyperparams_file(learner)} has no entry for {env_id}")
    return dict(entries[env_id])


def algorithm(learner: str) -> Any:
    """The stable-baselines3 (or sb3-contrib) class of ``learner``."""
    # torch and stable-baselines3 load on first use: the CLI's checks and the report run without them
    import sb3_contrib
    import stable_baselines3

    classes = {"ppo": stable_baselines3.PPO, "sac": stable_baselines3.SAC, "td3": stable_baselines3.TD3}
    return classes.get(learner, sb3_contrib.TQC)


def build(learner: str, env_id: str, seed: int, overrides: dict[str, Any] | None = None) -> tuple[Any, Any]:
    """The untrained model and its (normalised) training env, from the zoo entry as rl-zoo3 builds them.

    Returns:
        ``(model, venv)``; ``venv`` is the ``VecNormalize`` when the entry normalises, else the plain ``VecEnv``.
    """
    # stable-baselines3 loads on first use (see algorithm)
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.noise import NormalActionNoise
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    params = {**zoo_hyperparams(learner, env_id), **(overrides or {})}
    params.pop("n_timesteps", None)
    policy = params.pop("policy")
    normalize = params.pop("normalize", False)
    n_envs = int(params.pop("n_envs", 1))
    # make_vec_env's way without its render_mode (the kinematic arm has no scene): Monitor, then env i seeded seed + i
    envs = DummyVecEnv([lambda: Monitor(gym.make(env_id, **ENV_KWARGS)) for _ in range(n_envs)])
    envs.seed(seed)
    venv: Any = envs
    if normalize:
        venv = VecNormalize(envs, **({"gamma": params["gamma"]} if "gamma" in params else {}))
    if isinstance(params.get("policy_kwargs"), str):
        params["policy_kwargs"] = eval(params["policy_kwargs"])  # rl-zoo3's format: "dict(net_arch=[64, 64])"
    noise_type = params.pop("noise_type", None)
    noise_std = params.pop("noise_std", None)
    if noise_type is not None:
        if noise_type.strip() != "normal":
            raise ValueError(f"{learner} on {env_id}: only normal action noise is read, got {noise_type!r}")
        n_actions = int(np.prod(venv.action_space.shape))
        params["action_noise"] = NormalActionNoise(np.zeros(n_actions), float(noise_std) * np.ones(n_actions))
    model = algorithm(learner)(policy, venv, seed=seed, device="cpu", verbose=0, **params)
    return model, venv


def train(job: Job, overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """Train ``job``'s model for ``job.steps`` steps and save ``model.zip`` (and ``vecnormalize.pkl``) in its folder.

    Returns:
        The training's wall and CPU seconds and the steps it took (also written to ``train.json``).
    """
    import torch  # with stable-baselines3 (see algorithm)

    torch.set_num_threads(1)  # small networks: one thread (docs/rl.md, Threads)
    job.folder.mkdir(parents=True, exist_ok=True)
    model, venv = build(job.learner, job.env_id, job.seed, overrides)
    wall, cpu = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=job.steps)
    timing = {"train_wall_s": time.perf_counter() - wall, "train_cpu_s": time.process_time() - cpu}
    timing["timesteps"] = int(model.num_timesteps)  # PPO rounds up to whole rollouts (n_envs × n_steps)
    if hasattr(venv, "obs_rms"):
        venv.save(str(job.folder / "vecnormalize.pkl"))
    model.save(job.folder / "model.zip")  # last: its presence marks a finished training
    (job.folder / "train.json").write_text(json.dumps({**asdict(job), **timing}, indent=1) + "\n")
    venv.close()
    return timing


def observation_bounds(env_id: str) -> tuple[np.ndarray, np.ndarray]:
    """The float64 bounds a -v1 env clips its observation into (``observation_clip``)."""
    probe = gym.make(env_id, physics="kinematic")
    try:
        low, high = getattr(probe.unwrapped, "observation_clip")  # a snac-gym env's (gymnasium's Env has none)
    finally:
        probe.close()
    return np.asarray(low), np.asarray(high)


def env_observation(obs: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The -v1 env's observation of the physical one (a -v0 env's, the evaluator's): clipped, float32."""
    return np.asarray(np.clip(np.asarray(obs, dtype=np.float64), low, high).astype(np.float32))


class ZooPolicy:
    """A trained model as an evaluator controller: the evaluator's observation (physical units) turned into the
    -v1 env's (clipped into its bounds, float32), normalised with the saved statistics, the deterministic action
    a ∈ [−1, 1] mapped back to u = a·ū (rad/s). Offers the batch protocol (one forward pass per step for all samples).

    Args:
        env: The evaluator's :class:`~snac_gym.policies.base.PolicyContext` (or a -v0 env).
        model_dir: The job folder (``model.zip``, ``vecnormalize.pkl``).
        learner: The learner's name (:data:`LEARNERS`).
        env_id: The -v1 id it was trained on (its observation bounds).
    """

    def __init__(self, env: Any, model_dir: str, learner: str, env_id: str) -> None:
        import torch  # with stable-baselines3 (see algorithm)

        torch.set_num_threads(1)
        context = PolicyContext.from_env(env)
        self.velocity_limits = np.asarray(context.velocity_limits, dtype=np.float64)
        self.low, self.high = observation_bounds(env_id)
        folder = Path(model_dir)
        self.model = algorithm(learner).load(folder / "model.zip", device="cpu")
        stats = folder / "vecnormalize.pkl"
        self.normalizer = pickle.loads(stats.read_bytes()) if stats.exists() else None
        self.internals: dict[str, Any] = {}

    def reset(self, seed: int | None = None) -> None:
        self.internals = {}

    def reset_batch(self, seeds: Sequence[int]) -> None:
        self.internals = {}

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands (B, n) in rad/s for the evaluator's observations (B, d)."""
        obs = env_observation(obs_batch, self.low, self.high)
        if self.normalizer is not None:
            obs = self.normalizer.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=True)
        return np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * self.velocity_limits

    def act(self, obs: np.ndarray) -> np.ndarray:
        commands: np.ndarray = self.act_batch(np.asarray(obs)[None])[0]
        return commands


def score(job: Job) -> pd.DataFrame:
    """Score ``job``'s saved model with the evaluator on ``job.samples`` samples of seed ``job.eval_seed``.

    Returns:
        One row per sample (also ``scores.csv``): ``success`` (the evaluator's rule, joint limits included),
        ``cost`` (its HJB cost at Q = 4·I), ``reference_cost`` (the ``optimal`` row's on the same sample),
        ``ratio`` (their quotient, failures at their actual cost), ``reference_success``.
    """
    # the evaluator loads on first use (see algorithm)
    from snac_gym.evaluation.run_config import EvaluationConfig
    from snac_gym.evaluation.runner import run_evaluation

    from snac_gym.policies import register_policy

    register_policy(POLICY_NAME, ZooPolicy, overwrite=True)
    shutil.rmtree(job.folder / "evaluation", ignore_errors=True)  # an interrupted scoring's: scored anew
    kwargs = {"model_dir": str(job.folder), "learner": job.learner, "env_id": job.env_id}
    config = EvaluationConfig(
        out=job.folder / "evaluation",
        tasks=(job.task,),
        controllers=(POLICY_NAME, "optimal"),
        samples=job.samples,
        seed=job.eval_seed,
        match_effort=False,
        cost=COST.cost,
        q_scale=COST.q_scale,
        udot_start=COST.udot_start,
        controller_kwargs={POLICY_NAME: kwargs},
        progress=False,
        plots=False,
    )
    results = run_evaluation(config)
    rows = results.set_index(["controller", "sample"]).sort_index()
    learned, reference = rows.loc[POLICY_NAME], rows.loc["optimal"]
    column = f"cost_{COST.cost}"
    scores = pd.DataFrame(
        {
            "learner": job.learner,
            "task": job.task,
            "seed": job.seed,
            "sample": learned.index,
            "success": learned["success"].astype(bool).to_numpy(),
            "cost": learned[column].to_numpy(),
            "reference_cost": reference.loc[learned.index, column].to_numpy(),
            "reference_success": reference.loc[learned.index, "success"].astype(bool).to_numpy(),
        }
    )
    scores["ratio"] = scores["cost"] / scores["reference_cost"]
    scores.to_csv(job.folder / "scores.csv", index=False)
    return scores


def run_job(job: Job) -> dict[str, Any]:
    """Train (unless ``model.zip`` exists) and score (unless ``scores.csv`` exists) one job; its summary line."""
    done = job.folder / "scores.csv"
    if done.exists():
        scores, action = pd.read_csv(done), "kept"
    else:
        action = "scored" if (job.folder / "model.zip").exists() else "trained and scored"
        if action == "trained and scored":
            train(job)
        scores = score(job)
    timing = json.loads((job.folder / "train.json").read_text()) if (job.folder / "train.json").exists() else {}
    return {
        "job": job.folder.name,
        "action": action,
        "success": float(scores["success"].mean()),
        "median_ratio": float(scores["ratio"].median()),
        "train_cpu_s": timing.get("train_cpu_s", float("nan")),
    }


def jobs_of(args: argparse.Namespace) -> list[Job]:
    """Every job of the command, seed by seed (an interrupted run has whole seeds first)."""
    return [
        Job(learner, task, seed, args.steps, args.samples, args.eval_seed, str(args.out))
        for seed in args.seeds
        for learner in args.learners
        for task in args.tasks
    ]


def pending(jobs: Sequence[Job]) -> list[Job]:
    """The jobs without ``scores.csv`` (the rest are finished: resuming skips them)."""
    return [job for job in jobs if not (job.folder / "scores.csv").exists()]


def _names(text: str, allowed: Sequence[str], what: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in allowed]
    if unknown or not names:
        raise ValueError(
            f"unknown {what} {', '.join(map(repr, unknown)) or repr(text)}; choose from {', '.join(allowed)}"
        )
    return names


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The options; ``ValueError`` (one line) for a learner, task or seed list that is not valid."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/learners"), help="jobs' folders and the report")
    parser.add_argument("--learners", default=",".join(LEARNERS), help=f"comma-separated, of {', '.join(LEARNERS)}")
    parser.add_argument("--tasks", default=",".join(TASKS), help=f"comma-separated, of {', '.join(TASKS)}")
    parser.add_argument("--seeds", default="0,1,2", help="training seeds, comma-separated")
    parser.add_argument("--steps", type=int, default=15_000, help="environment steps of every run (docs/rl.md: why)")
    parser.add_argument("--samples", type=int, default=100, help="held-out evaluator samples per task")
    parser.add_argument("--eval-seed", type=int, default=EVAL_SEED, help="seed of the held-out samples")
    parser.add_argument("--workers", type=int, default=1, help="local processes (one job each)")
    parser.add_argument("--ray", default=None, metavar="ADDRESS", help="run the jobs on Ray: 'local' or an address")
    parser.add_argument("--figure", type=Path, default=None, help="the profile figure (default OUT/profile.png)")
    parser.add_argument("--data", type=Path, default=None, help="also write the report's tables to this folder")
    parser.add_argument("--report-only", action="store_true", help="aggregate the finished jobs, train nothing")
    args = parser.parse_args(argv)
    args.learners = _names(args.learners, LEARNERS, "learner")
    args.tasks = _names(args.tasks, tuple(TASKS), "task")
    try:
        args.seeds = [int(seed) for seed in args.seeds.split(",")]
    except ValueError:
        raise ValueError(f"--seeds must be integers separated by commas, got {args.seeds!r}") from None
    if args.steps < 1 or args.samples < 1 or args.workers < 1:
        raise ValueError("--steps, --samples and --workers must be at least 1")
    return args


def run(jobs: Sequence[Job], workers: int = 1, ray_address: str | None = None) -> list[dict[str, Any]]:
    """Run ``jobs`` on the evaluator's executors (serial, local processes or Ray); a line per finished job."""
    from snac_gym.evaluation.execution.executors import open_executor  # the evaluator's executors (see algorithm)

    if ray_address and __name__ != "__main__":  # Ray ships the jobs' code by value: workers need not import this file
        from ray import cloudpickle  # the ray extra, only with --ray

        cloudpickle.register_pickle_by_value(sys.modules[__name__])
    lines: list[dict[str, Any]] = []
    with open_executor(workers, ray_address) as executor:
        for index, line in executor.run(run_job, list(jobs)):
            print(f"[{len(lines) + 1}/{len(jobs)}] {jobs[index].folder.name}: {json.dumps(line)}", flush=True)
            lines.append(line)
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = parse_args(argv)
    except ValueError as error:
        print(f"learners.py: {error}", file=sys.stderr)
        return 2
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    jobs = jobs_of(args)
    todo = [] if args.report_only else pending(jobs)
    print(f"{len(jobs)} jobs, {len(jobs) - len(todo)} finished already, {len(todo)} to run", flush=True)
    if todo:
        run(todo, args.workers, args.ray)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import learners_report  # the report beside this script (matplotlib, rliable): after the runs

    return learners_report.report(args.out, [job.folder for job in jobs], args.figure, args.data)


if __name__ == "__main__":
    sys.exit(main())
