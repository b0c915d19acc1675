"""The README's and docs' tables of environments, spaces, robots and controllers, written from the registries.

Every block between ``<!-- tables:NAME -->`` and ``<!-- /tables:NAME -->`` in the files of :data:`TARGETS` is the
text :data:`BLOCKS` writes from what is registered: the Gymnasium ids (``snac_gym.envs.REGISTERED_IDS``), the
spaces of a made env of each id family in both versions, the robots (``snac_gym.model.robots``) and the controllers
(``snac_gym.policies.available_policies``). A controller or id family registered without a line of prose here
stops the script, naming it, and so does prose for one no longer registered: nothing registered is missing from
the tables and nothing unregistered is listed.

Usage:
    python tools/tables.py            # write every block
    python tools/tables.py --check    # exit 1 naming each block that differs (tests/integration/test_tables.py)
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.envs import REGISTERED_IDS
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import all_robots, get_robot
from snac_gym.model.ur_models import E_SERIES_URDF_DIR
from snac_gym.policies import available_policies

ROOT = Path(__file__).resolve().parents[1]
#: The files whose tables blocks are written here.
TARGETS = (ROOT / "README.md", ROOT / "docs" / "environments.md")
_BLOCK = re.compile(r"(<!-- tables:(?P<name>[a-z0-9-]+) -->\n)(?P<body>.*?)(<!-- /tables:(?P=name) -->)", re.S)
#: The robot whose ids the tables show (the paper's); its spaces stand for every robot's.
SHOWN = "ur10"
#: What each id family is, by its name with ``<Robot>`` for the robot part.
FAMILIES = {
    "<Robot>Reach": "regulation to a fixed target (the paper's Section III)",
    "<Robot>EllipseTrack": "tracking a point on an ellipse (Section IV)",
    "<Robot>ReachGoal": "the same, goal-conditioned (`Dict` observation, for HER)",
    "<Robot>EllipseTrackGoal": "the same, goal-conditioned",
    "<Robot>ReachGoalCoarse": "goal reach sized as panda-gym's PandaReach: nominal start, goals in a 30 cm cube",
    "<Robot>ReachGoalCoarseCartesian": "the same, the action the tool's velocity, as panda-gym's",
}
#: The controllers: what each is, where it comes from, its page. Every registered name has a row.
CONTROLLERS = {
    "snac": ("single network adaptive critic, the paper's weight law (eqs. 15, 19, 31–38)", "this paper", "snac.md"),
    "snac-hjb": ("the same critic, tuned by the HJB residual; converges to the optimum", "this project", "snac.md"),
    "snac-adaptive": (
        "`snac-hjb` on a Jacobian identified on line from the measured position: adapts to a wrong arm model",
        "this project",
        "model-error.md",
    ),
    "snac-irl": (
        "a critic learned from measured data alone by off-policy integral RL",
        "Jiang, Jiang 2012",
        "irl.md",
    ),
    "lqr": ("frozen-Jacobian LQR, the optimum of eq. 6 with J frozen", "reference", "baselines.md"),
    "mpc": (
        "receding-horizon MPC on the evaluator's cost: the closed-loop optimum one can run",
        "this project",
        "mpc.md",
    ),
    "rnn": ("dual recurrent network", "Li, Zhang, Jin 2017", "baselines.md"),
    "svf": ("closed-loop IK with the singular-value-filtered inverse", "Colomé, Torras 2012", "baselines.md"),
    "dls": ("damped least squares", "textbook", "baselines.md"),
    "joint-goal": (
        "straight joint-space motion to the in-limit IK solution nearest the start; keeps the joint limits",
        "this project",
        "baselines.md",
    ),
    "ppo": (
        "stable-baselines3 PPO trained on the HJB cost on Table I's cuboid, acting through the model's J⁺; "
        "shipped (runs on NumPy)",
        "this project",
        "ppo.md",
    ),
    "ppo-workspace": (
        "PPO on the arm's whole reach, correcting `joint-goal`; withdrawn (never beat `joint-goal`): no file ships",
        "this project",
        "ppo.md",
    ),
    "pink": (
        "QP differential IK on Pinocchio (daqp): position and velocity limits as constraints",
        "Caron et al.",
        "qp-ik.md",
    ),
    "mink": ("the same QP on MuJoCo's kinematics", "Zakka et al.", "qp-ik.md"),
}


def family(env_id: str) -> str:
    """``snac_gym/PandaReachGoal-v1`` → ``<Robot>ReachGoal``."""
    registered = REGISTERED_IDS[env_id]
    name = env_id.removeprefix("snac_gym/").rsplit("-v", 1)[0]
    prefix = get_robot(registered.robot).env_prefix
    return "<Robot>" + name.removeprefix(prefix)


def families() -> dict[str, list[str]]:
    """The registered ids by family, in registration order.

    Raises:
        SystemExit: Naming a family with no prose in :data:`FAMILIES`, or prose for one not registered.
    """
    grouped: dict[str, list[str]] = {}
    for env_id in REGISTERED_IDS:
        grouped.setdefault(family(env_id), []).append(env_id)
    _same_names("id family", set(grouped), set(FAMILIES))
    return {name: grouped[name] for name in FAMILIES}


def _same_names(kind: str, registered: set[str], described: set[str]) -> None:
    if registered - described:
        raise SystemExit(f"tools/tables.py: no prose for the {kind} {sorted(registered - described)}; add it")
    if described - registered:
        raise SystemExit(f"tools/tables.py: the {kind} {sorted(described - registered)} is not registered")


def _make(name: str, version: int) -> Any:
    prefix = get_robot(SHOWN if "Coarse" not in name else "panda").env_prefix
    return gym.make(f"snac_gym/{name.replace('<Robot>', prefix)}-v{version}", physics="kinematic")


def _length(metres: float) -> str:
    return f"{metres * 100:g} cm" if metres >= 0.01 else f"{metres * 1000:g} mm"


def envs() -> str:
    """The id families: task, success, episode, whether an episode ends on success."""
    robots = all_robots()
    grouped = families()
    lines = [
        '| ids (`<Robot>`: a prefix of the robot table) | task | success (`info["is_success"]`) | default '
        "episode | ends on success (`-v1` / `-v0`) |",
        "|---|---|---|---|---|",
    ]
    for name, ids in grouped.items():
        made = [_make(name, version) for version in (1, 0)]
        base = made[0].unwrapped
        steps = made[0].spec.max_episode_steps
        ends = " / ".join("yes" if env.unwrapped.terminate_on_success else "no" for env in made)
        ids_text = f"`snac_gym/{name}-v1`, `-v0`"
        lines.append(
            f"| {ids_text} | {FAMILIES[name]} | ‖e‖ ≤ {_length(base.success_tolerance)} | "
            f"{steps} steps = {steps * base.dt:g} s | {ends} |"
        )
        for env in made:
            env.close()
    total = sum(len(ids) for ids in grouped.values())
    lines.append("")
    lines.append(
        f"{total} ids: {len(grouped)} families × {len(robots)} robots × 2 versions, e.g. "
        f"`snac_gym/{get_robot(SHOWN).env_prefix}Reach-v1`, `snac_gym/PandaReachGoalCoarseCartesian-v1`."
    )
    return "\n".join(lines) + "\n"


def _action(space: gym.spaces.Box, limits: np.ndarray) -> str:
    dims = "m" if space.shape[0] == limits.shape[0] else str(space.shape[0])
    if np.all(space.low == -1) and np.all(space.high == 1):
        bounds = "−1, 1"
    elif np.allclose(space.high, limits) and np.allclose(space.low, -limits):
        bounds = "−ū, ū"  # rad/s
    else:
        raise SystemExit(f"tools/tables.py: an action space neither normalized nor the velocity limits: {space}")
    unit = " (rad/s)" if bounds == "−ū, ū" else (" (a = u/ū)" if dims == "m" else " (tool velocity / 1.25 m/s)")
    return f"`Box({bounds}, ({dims},), {space.dtype})`{unit}"


def _observation(space: gym.Space, m: int) -> str:
    if isinstance(space, gym.spaces.Dict):
        dtypes = {str(part.dtype) for part in space.values()}
        inner = space["observation"]
        infinite = np.flatnonzero(~np.isfinite(inner.high))
        if infinite.size == 0:
            bounds = "finite"
        elif infinite.tolist() == list(range(m, 2 * m)):
            bounds = "θ̇ ±inf"
        else:
            raise SystemExit(f"tools/tables.py: unexpected infinite bounds {infinite.tolist()} in {inner}")
        return f"`Dict` of {'/'.join(sorted(dtypes))}, {bounds}"
    assert isinstance(space, gym.spaces.Box)
    finite = np.isfinite(space.high)
    bounds = "finite" if finite.all() else ("±inf" if not finite.any() else "partly ±inf")
    return f"`Box` {space.dtype}, {bounds}"


def spaces() -> str:
    """Each family's action and observation spaces in both versions, as the registered envs give them."""
    lines = [
        "| ids | `-v1` action | `-v1` observation | `-v0` action | `-v0` observation |",
        "|---|---|---|---|---|",
    ]
    for name in families():
        cells = []
        for version in (1, 0):
            env = _make(name, version)
            base = env.unwrapped
            inner = getattr(base, "env", base)  # a goal env's task env holds the limits
            cells += [
                _action(env.action_space, inner.velocity_limits),
                _observation(env.observation_space, inner.kinematics.n_joints),
            ]
            env.close()
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _urdf_source(urdf: str) -> str:
    if urdf.startswith(str(E_SERIES_URDF_DIR)):
        return "this package (UR's DH parameters)"
    return "example-robot-data" if not Path(urdf).is_absolute() else "a file"


def robots() -> str:
    """The registered robots: name, arm, joints, id prefix, frames, URDF."""
    lines = [
        "| `robot=` | arm | joints | id prefix | controlled frame in | URDF from |",
        "|---|---|---|---|---|---|",
    ]
    for robot in all_robots():
        joints = Kinematics(robot.name).n_joints
        lines.append(
            f"| `{robot.name}` | {robot.description or robot.name} | {joints} | `{robot.env_prefix}` | "
            f"`{robot.ee_frame}` in `{robot.base_frame}` | {_urdf_source(robot.urdf)} |"
        )
    return "\n".join(lines) + "\n"


def robots_line() -> str:
    """The registered robots in one sentence: ``robot=`` name, arm, joints and id prefix."""
    parts = []
    for robot in all_robots():
        joints = Kinematics(robot.name).n_joints
        parts.append(f"`{robot.name}` ({robot.description or robot.name}, {joints} joints, `{robot.env_prefix}…` ids)")
    return f"{len(parts)} robots (`robot=`): " + ", ".join(parts) + ".\n"


def controllers(link: Callable[[str], str]) -> Callable[[], str]:
    """The registered controllers, each with its line of :data:`CONTROLLERS`; ``link`` maps a docs page to the
    target file's link to it."""

    def write() -> str:
        names = available_policies()
        _same_names("controller", set(names), set(CONTROLLERS))
        lines = ["| name | what | from | details |", "|---|---|---|---|"]
        for name in CONTROLLERS:  # the order of the prose: the paper's first
            what, source, page = CONTROLLERS[name]
            lines.append(f"| `{name}` | {what} | {source} | [{page.removesuffix('.md')}]({link(page)}) |")
        return "\n".join(lines) + "\n"

    return write


#: Block name → writer, per target file name.
BLOCKS: dict[str, dict[str, Callable[[], str]]] = {
    "README.md": {
        "envs": envs,
        "spaces": spaces,
        "robots": robots_line,
        "controllers": controllers(lambda page: f"docs/{page}"),
    },
    "environments.md": {"spaces": spaces},
}


def rendered(text: str, path: Path, cache: dict[str, str]) -> str:
    writers = BLOCKS[path.name]

    def replace(match: re.Match[str]) -> str:
        name = match["name"]
        if name not in writers:
            raise SystemExit(f"{path}: no writer for the block {name!r}")
        key = f"{path.name}:{name}"
        if key not in cache:
            cache[key] = writers[name]()
        return match[1] + cache[key] + match[4]

    return _BLOCK.sub(replace, text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 naming each stale block")
    args = parser.parse_args(argv)
    stale = []
    cache: dict[str, str] = {}
    for path in TARGETS:
        text = path.read_text(encoding="utf-8")
        found = {m["name"] for m in _BLOCK.finditer(text)}
        missing = set(BLOCKS[path.name]) - found
        if missing:
            print(f"{path.relative_to(ROOT)}: no block for {sorted(missing)}", file=sys.stderr)
            stale.append(path)
            continue
        new = rendered(text, path, cache)
        if new == text:
            continue
        if args.check:
            old_blocks = {m["name"]: m["body"] for m in _BLOCK.finditer(text)}
            new_blocks = {m["name"]: m["body"] for m in _BLOCK.finditer(new)}
            for name in sorted(n for n in new_blocks if new_blocks[n] != old_blocks.get(n)):
                print(f"{path.relative_to(ROOT)}: {name} is stale; run python tools/tables.py", file=sys.stderr)
            stale.append(path)
        else:
            path.write_text(new, encoding="utf-8")
            print(f"wrote {path.relative_to(ROOT)}")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
