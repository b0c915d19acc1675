"""Write the package's rl-zoo3 files, ``snac_gym/data/zoo/{ppo,sac,td3,tqc}.yml``: an entry for every ``-v1`` id.

    python tools/write_zoo_hyperparams.py            # rewrite the files
    python tools/write_zoo_hyperparams.py --check    # exit 1 naming each file that is not what the registry gives

rl-zoo3 needs an entry per id ("Hyperparameters not found" otherwise). Three presets per learner, by id family:
the coarse reach presets (panda-gym's PandaReach sizes) take rl-zoo3's own PandaReach/FetchReach settings (SAC's
measured in docs/rl.md), the other goal ids the same with a longer budget, and the plain ids (a flat observation,
the paper's dense cost as the reward) stable-baselines3's defaults with observation normalisation. Only the SAC
coarse preset is measured; every other preset is a starting point, and its file says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gymnasium as gym

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.envs import REGISTERED_IDS
from snac_gym.zoo import ALGOS

FOLDER = Path(__file__).resolve().parents[1] / "snac_gym" / "data" / "zoo"

HEADER = """\
# rl-zoo3 hyperparameters for snac-gym's -v1 ids ({learner}), in rl-zoo3's format, one entry per registered
# -v1 id (written by `python tools/write_zoo_hyperparams.py`; do not edit by hand). Shipped in the package:
#   python -m rl_zoo3.train --algo {algo} --env snac_gym/PandaReachGoalCoarseCartesian-v1 --gym-packages snac_gym \\
#       -conf "$(python -m snac_gym.zoo {algo})"
# {status}
# Training threads: on a small machine set OMP_NUM_THREADS=1 (docs/rl.md).
"""
STATUS = {
    "sac": "The coarse reach presets' settings are rl-zoo3's PandaReach ones, measured in docs/rl.md; the other "
    "ids'\n# are a starting point, not tuned.",
}
UNTUNED = "Every preset here is a starting point, not tuned: rl-zoo3's PandaReach settings (goal ids) and\n# {plain}."

#: rl-zoo3's PandaReach / FetchReach settings, HER included (its sac.yml, tqc.yml).
HER = """\
  policy: 'MultiInputPolicy'
  buffer_size: 1000000
  batch_size: 256
  gamma: 0.95
  learning_rate: !!float 1e-3
  learning_starts: 1000
  normalize: True
  replay_buffer_class: HerReplayBuffer
  replay_buffer_kwargs: "dict(goal_selection_strategy='future', n_sampled_goal=4)"
  policy_kwargs: "dict(net_arch=[64, 64], n_critics=1)"
"""
#: stable-baselines3's off-policy defaults, observations normalised (the plain ids' observation spans metres
#: and radians per second).
OFF_POLICY_PLAIN = """\
  policy: 'MlpPolicy'
  buffer_size: 1000000
  batch_size: 256
  gamma: 0.99
  learning_rate: !!float 3e-4
  learning_starts: 10000
  normalize: True
"""
PPO_COMMON = """\
  normalize: True
  n_envs: 8
  n_steps: 512
  batch_size: 128
  gamma: 0.99
  gae_lambda: 0.95
  n_epochs: 10
  learning_rate: !!float 3e-4
  ent_coef: 0.0
  clip_range: 0.2
"""
#: Per learner: (preset body of the coarse goal ids, of the other goal ids, of the plain ids), each without
#: n_timesteps; and the plain ids' description in the header.
PRESETS = {
    "sac": (HER + "  ent_coef: 'auto'\n", HER + "  ent_coef: 'auto'\n", OFF_POLICY_PLAIN + "  ent_coef: 'auto'\n"),
    "tqc": (HER + "  ent_coef: 'auto'\n", HER + "  ent_coef: 'auto'\n", OFF_POLICY_PLAIN + "  ent_coef: 'auto'\n"),
    "td3": (
        HER + "  noise_type: 'normal'\n  noise_std: 0.1\n",
        HER + "  noise_type: 'normal'\n  noise_std: 0.1\n",
        OFF_POLICY_PLAIN + "  noise_type: 'normal'\n  noise_std: 0.1\n",
    ),
    "ppo": ("  policy: 'MultiInputPolicy'\n" + PPO_COMMON,) * 2 + ("  policy: 'MlpPolicy'\n" + PPO_COMMON,),
}
PLAIN_WORDS = {
    "sac": "stable-baselines3's defaults with normalised observations (plain ids)",
    "tqc": "stable-baselines3's SAC defaults with normalised observations (plain ids)",
    "td3": "stable-baselines3's defaults with Gaussian action noise and normalised observations (plain ids)",
    "ppo": "rl-zoo3's PyBullet-style PPO settings with normalised observations (every id)",
}
LEARNERS = {"ppo": "PPO", "sac": "SAC", "td3": "TD3", "tqc": "TQC, sb3-contrib"}
#: Steps of each preset: coarse goal, other goal, plain.
STEPS = {"ppo": (2e5, 1e6, 1e6), "sac": (3e4, 1e5, 1e6), "td3": (3e4, 1e5, 1e6), "tqc": (3e4, 1e5, 1e6)}


def v1_ids() -> list[str]:
    """Every registered ``-v1`` snac-gym id, in registration order."""
    return [env_id for env_id in REGISTERED_IDS if env_id.endswith("-v1") and env_id in gym.registry]


def _kind(env_id: str) -> int:
    """0: a coarse reach preset, 1: another goal id, 2: a plain id."""
    return 0 if "Coarse" in env_id else (1 if REGISTERED_IDS[env_id].goal else 2)


def render(algo: str) -> str:
    """The file of ``algo``: the first id of each kind holds its preset (a YAML anchor), the others merge it."""
    status = STATUS.get(algo, UNTUNED.format(plain=PLAIN_WORDS[algo]))
    lines = [HEADER.format(learner=LEARNERS[algo], algo=algo, status=status)]
    anchors = ("coarse-reach", "goal", "plain")
    seen: set[int] = set()
    ids = sorted(v1_ids(), key=_kind)
    for env_id in ids:
        kind = _kind(env_id)
        if kind in seen:
            lines.append(f"{env_id}:\n  <<: *{anchors[kind]}\n")
            continue
        seen.add(kind)
        lines.append(f"{env_id}: &{anchors[kind]}\n  n_timesteps: !!float {STEPS[algo][kind]:g}\n{PRESETS[algo][kind]}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true")
    check = parser.parse_args().check
    stale = []
    for algo in ALGOS:
        target = FOLDER / f"{algo}.yml"
        text = render(algo)
        if check:
            if not target.is_file() or target.read_text() != text:
                stale.append(target)
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text)
        print(f"wrote {target} ({len(v1_ids())} ids)")
    for target in stale:
        print(f"{target} is stale; run python tools/write_zoo_hyperparams.py")
    if stale:
        sys.exit(1)


if __name__ == "__main__":
    main()
