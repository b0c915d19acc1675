"""rl-zoo3 hyperparameter files for every ``-v1`` id, shipped inside the package.

One YAML file per learner (:data:`ALGOS`), in rl-zoo3's format, with an entry for every registered ``-v1`` id
(written from the registry by ``tools/write_zoo_hyperparams.py``). rl-zoo3 reads a file by its path, so the
path is what this module gives, from any folder::

    python -m rl_zoo3.train --algo tqc --env snac_gym/PandaReachGoalCoarseCartesian-v1 --gym-packages snac_gym \\
        -conf "$(python -m snac_gym.zoo tqc)"

``python -m snac_gym.zoo ALGO`` prints the file's path; :func:`hyperparams_file` returns it.
"""

from __future__ import annotations

import sys
from importlib.resources import as_file, files
from pathlib import Path

#: The learners with a shipped file: stable-baselines3's PPO, SAC and TD3, and sb3-contrib's TQC.
ALGOS = ("ppo", "sac", "td3", "tqc")


def hyperparams_file(algo: str) -> Path:
    """The shipped rl-zoo3 file of ``algo`` (a path on disk, for ``-conf``).

    Raises:
        ValueError: If ``algo`` has no file, naming those that do.
    """
    if algo not in ALGOS:
        raise ValueError(f"no rl-zoo3 hyperparameters for {algo!r}; shipped: {', '.join(ALGOS)}")
    # The package is installed as files (a wheel or an editable install), so the resource is a real file: its path
    # stays valid after the context manager closes.
    with as_file(files("snac_gym") / "data" / "zoo" / f"{algo}.yml") as path:
        return Path(path)


def main(argv: list[str] | None = None) -> int:
    """``python -m snac_gym.zoo ALGO``: print the path of ``ALGO``'s file."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print(f"usage: python -m snac_gym.zoo {{{','.join(ALGOS)}}}", file=sys.stderr)
        return 2
    try:
        print(hyperparams_file(args[0]))
    except ValueError as error:
        print(error, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
