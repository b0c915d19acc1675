"""The output folder of a PPO training run (:func:`snac_gym.ppo.train.train_ppo`): its config, state and evaluation
rows, and its checkpoints, each written whole or not at all with the sha256 of its files, which a resume checks."""

from __future__ import annotations

import csv
import hashlib
import json
import pickle
import platform
import shutil
import time
import zipfile
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from snac_gym import __version__
from snac_gym.common.outputs import write_error, write_text_whole
from snac_gym.model.kinematics import Kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.ppo.config import resolve_config, validate_config
from snac_gym.ppo.curves import read_evaluations
from snac_gym.ppo.evaluation import better
from snac_gym.ppo.features import FeatureSpec
from snac_gym.ppo.policy_file import export_policy

__all__ = [
    "CHECKSUM_FILE",
    "EVALUATION_COLUMNS",
    "MODEL_FILE",
    "NORMALIZE_FILE",
    "POLICY_FILE",
    "TrainingRun",
    "check_checkpoint",
    "new_config",
    "package_versions",
    "resumed_config",
    "write_json",
]

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


class TrainingRun:
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
        write_json(self.state_path, self.state)

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
        altered later fails its checksum on ``--resume`` (:func:`check_checkpoint`).
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
            checksums = {name: sha256_of(staging / name) for name in (MODEL_FILE, NORMALIZE_FILE, POLICY_FILE)}
            write_json(staging / CHECKSUM_FILE, {"timesteps": int(model.num_timesteps), "sha256": checksums})
            replace_folder(staging, target)
        except OSError as exc:  # the previous checkpoint stays; the half-written one goes
            shutil.rmtree(staging, ignore_errors=True)
            raise write_error(target, exc) from exc
        return target / POLICY_FILE

    def evaluated_timesteps(self) -> list[int]:
        """The timesteps of the rows in evaluations.csv, in order."""
        return [int(row["timesteps"]) for row in read_evaluations(self.out)]

    def best_of_rows(self) -> dict[str, float] | None:
        """The best row of evaluations.csv (as :func:`better` ranks them): state.json's ``best`` may lag
        the rows when a run was killed between writing one and the other."""
        best = None
        for row in read_evaluations(self.out):
            if better(row, best):
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


def sha256_of(path: Path) -> str:
    """The hex sha256 of the file at ``path``."""
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def replace_folder(staging: Path, target: Path) -> None:
    """Put the complete folder ``staging`` in the place of ``target`` (two renames: at every moment one of them is
    whole)."""
    previous = target.with_name(target.name + ".old")
    shutil.rmtree(previous, ignore_errors=True)
    if target.exists():
        target.rename(previous)
    staging.rename(target)
    shutil.rmtree(previous, ignore_errors=True)


def write_json(path: Path, data: dict[str, Any]) -> None:
    """``data`` as indented JSON at ``path``, written whole."""
    write_text_whole(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def resumed_config(out: Path, task: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The saved config of the run in ``out``, with the overrides a resumed run may change."""
    if overrides["seed"] is not None:
        raise ValueError("--seed has no effect with --resume: a resumed run keeps the seed it started with")
    if overrides.get("init_from") is not None:
        raise ValueError("--init-from has no effect with --resume: a resumed run continues its own model")
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


def check_checkpoint(checkpoint: Path) -> None:
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
            if not path.is_file() or sha256_of(path) != digest:
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


def new_config(out: Path, task: str, config_path: str | Path | None, overrides: dict[str, Any]) -> dict[str, Any]:
    """The config of a new run in ``out`` (refused if ``out`` already holds one)."""
    # A state.json without a checkpoint is a run stopped before it saved anything: it is started anew.
    if (out / "checkpoint" / MODEL_FILE).exists():
        raise ValueError(f"{out} already holds a training run; pass --resume to continue it or choose another --out")
    return resolve_config(task, config_path, **overrides)
