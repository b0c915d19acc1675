"""Write hyperparams/sac.yml: an rl-zoo3 SAC + HER entry for every registered goal-conditioned id.

    python tools/write_zoo_hyperparams.py            # rewrite the file
    python tools/write_zoo_hyperparams.py --check    # exit 1 if the file is not what the registry gives

rl-zoo3 needs an entry per id ("Hyperparameters not found" otherwise). The coarse reach presets carry the
settings measured in docs/rl.md; every other goal id gets the same settings as a starting point, with the
longer budget a millimetre goal needs, and is marked untuned.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gymnasium as gym

import snac_gym  # noqa: F401  (registers the ids)

TARGET = Path(__file__).resolve().parents[1] / "hyperparams" / "sac.yml"

HEADER = """\
# rl-zoo3 hyperparameters for snac-gym's goal envs (SAC + HER), in rl-zoo3's format, one entry per
# registered goal id (written by `python tools/write_zoo_hyperparams.py`; do not edit by hand):
#   python -m rl_zoo3.train --algo sac --env snac_gym/PandaReachGoalCoarse-v0 --gym-packages snac_gym \\
#       -conf hyperparams/sac.yml
# The coarse presets start from rl-zoo3's own PandaReach-v1 / FetchReach-v1 entries (gamma 0.95,
# lr 1e-3, batch 256, HER 'future' with 4 relabelled goals, [64, 64] networks, observations
# normalised); results and commands: docs/rl.md. The other ids (the millimetre reach and the
# tracking goals) take the same settings with a longer budget: a starting point, not tuned.
# Training threads: on a small machine set OMP_NUM_THREADS=1 (docs/rl.md).
"""

PRESET = """\
  policy: 'MultiInputPolicy'
  buffer_size: 1000000
  ent_coef: 'auto'
  batch_size: 256
  gamma: 0.95
  learning_rate: !!float 1e-3
  learning_starts: 1000
  normalize: True
  replay_buffer_class: HerReplayBuffer
  replay_buffer_kwargs: "dict(goal_selection_strategy='future', n_sampled_goal=4)"
  policy_kwargs: "dict(net_arch=[64, 64], n_critics=1)"
"""

ANCHOR = "snac_gym/PandaReachGoalCoarse-v0"


def goal_ids() -> list[str]:
    """Every registered goal-conditioned snac-gym id, in registration order."""
    return [env_id for env_id in gym.registry if env_id.startswith("snac_gym/") and "Goal" in env_id]


def render() -> str:
    ids = goal_ids()
    if ANCHOR not in ids:
        raise SystemExit(f"{ANCHOR} is not registered: the presets anchor on it")
    lines = [HEADER, f"{ANCHOR}: &coarse-reach\n  n_timesteps: !!float 30000\n{PRESET}"]
    untuned = None
    for env_id in ids:
        if env_id == ANCHOR:
            continue
        if "Coarse" in env_id:
            lines.append(f"{env_id}:\n  <<: *coarse-reach\n")
        elif untuned is None:  # the first untuned id holds their preset: the coarse settings with 100 k steps
            untuned = env_id
            lines.append(
                f"# Untuned: the coarse preset's settings with 100 k steps.\n{env_id}: &untuned\n"
                f"  n_timesteps: !!float 100000\n{PRESET}"
            )
        else:
            lines.append(f"{env_id}:\n  <<: *untuned\n")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true")
    text = render()
    if parser.parse_args().check:
        if TARGET.read_text() != text:
            print(f"{TARGET} is stale; run python tools/write_zoo_hyperparams.py")
            sys.exit(1)
        return
    TARGET.write_text(text)
    print(f"wrote {TARGET} ({len(goal_ids())} ids)")


if __name__ == "__main__":
    main()
