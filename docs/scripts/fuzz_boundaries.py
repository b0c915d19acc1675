"""A fuzzing pass over the public boundaries: every input of a fixed pool, each outcome in one class.

    python docs/scripts/fuzz_boundaries.py            # the counts of docs/robustness.md
    python docs/scripts/fuzz_boundaries.py --list     # and every input that was not a clear error or a valid result

Classes (docs/robustness.md):
    clear        refused with a ValueError (CLI: exit 2) whose message names the argument
    unclear      refused with a ValueError (CLI: exit 2) that does not name it
    raw          another exception (CLI: a traceback, or an exit code other than 0 and 2)
    hang         longer than the bound (``BOUND_S``)
    accepted     taken, and the input is valid by the documented range: the correct result
    silent       taken although the input is outside the documented range
The pool mixes the wrong types (bool, str, bytes, complex, None, nested lists), non-finite and huge
numbers, wrong shapes and valid values; it is the same in every run (no randomness).
"""

from __future__ import annotations

import argparse
import math
import numbers
import signal
import tempfile
import warnings
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from snac_gym.evaluation import EvaluationConfig

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.control.cost import trajectory_cost
from snac_gym.model.model_error import ModelError
from snac_gym.policies import make_policy

BOUND_S = 20
ID = "snac_gym/UR10Reach-v0"

SCALARS: list[Any] = [
    None,
    True,
    False,
    "0.008",
    "",
    b"1",
    0.5j,
    [],
    [[1], [2, 3]],
    {"a": 1},
    float("nan"),
    float("inf"),
    -float("inf"),
    1e300,
    -1e300,
    10**18,
    -1,
    0,
    0.0,
    2.5,
    3,
    1e-320,
    np.float32(0.5),
    np.int64(4),
]


def arrays(shape: tuple[int, ...]) -> list[Any]:
    good = np.linspace(-0.3, 0.3, int(np.prod(shape))).reshape(shape)
    return [
        good,
        good.astype(np.float32),
        good[..., :-1],
        np.zeros(shape + (1,)),
        good.astype(complex) * 1j,
        good > 0,
        good.astype(str),
        np.full(shape, np.nan),
        np.full(shape, np.inf),
        np.full(shape, 1e300),
        good.tolist(),
        np.zeros(0),
        np.zeros(1),
        0.1,
        None,
        "0.1",
        [0.1] * (shape[-1] + 1),
    ]


class Hang(Exception):
    pass


def _alarm(signum: int, frame: Any) -> None:
    raise Hang


def classify(call: Callable[[], Any], names: tuple[str, ...], valid: bool) -> str:
    signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, BOUND_S)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            call()
    except Hang:
        return "hang"
    except ValueError as exc:
        return "clear" if any(name in str(exc) for name in names) else "unclear"
    except Exception:  # noqa: BLE001 - the class under test
        return "raw"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    return "accepted" if valid else "silent"


def real(value: Any, low: float = -math.inf, high: float = math.inf, whole: bool = False) -> bool:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        return False
    if whole and not float(value).is_integer():
        return False
    return math.isfinite(float(value)) and low <= float(value) <= high


def finite_array(value: Any, shape: tuple[int, ...]) -> bool:
    array = np.asarray(value) if not isinstance(value, (list, str)) or _rectangular(value) else None
    return array is not None and array.dtype.kind in "iuf" and array.shape == shape and np.isfinite(array).all()


def _rectangular(value: Any) -> bool:
    try:
        np.asarray(value, dtype=float)
        return True
    except (TypeError, ValueError):
        return False


def _short(value: Any) -> str:
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 40 else text[:37] + "..."


Case = tuple[str, Callable[[], Any], tuple[str, ...], bool]


def env_cases() -> list[Case]:
    env = gym.make(ID, physics="kinematic")
    env.reset(seed=0)
    cases = [
        (f"env.step({_short(a)})", lambda a=a: env.step(a), ("action",), finite_array(a, (6,))) for a in arrays((6,))
    ]
    for name, low, high, whole in (
        ("dt", 1e-6, 1, False),
        ("n_substeps", 1, 1000, True),
        ("max_steps", 1, 10**7, True),
        ("render_width", 1, 8192, True),
    ):
        for value in SCALARS:
            cases.append(
                (
                    f"gym.make({name}={_short(value)})",
                    lambda n=name, v=value: gym.make(ID, physics="kinematic", **{n: v}).close(),
                    (name,),
                    value is None or real(value, low, high, whole),
                )
            )
    for count in SCALARS:
        if real(count, 65, 1 << 20, whole=True):
            continue  # a valid large count only measures memory
        cases.append(
            (
                f"gym.make_vec({_short(count)})",
                lambda n=count: gym.make_vec(ID, n, vectorization_mode="vector_entry_point").close(),
                ("num_envs",),
                real(count, 1, 1 << 20, whole=True),
            )
        )
    return cases


def goal_cases() -> list[Case]:
    goal = gym.make("snac_gym/UR10ReachGoal-v0")
    goal.reset(seed=0)
    cases = []
    for desired in arrays((3,)):
        for method in ("compute_reward", "compute_terminated", "compute_truncated"):
            call = getattr(goal.unwrapped, method)
            cases.append(
                (
                    f"goal.{method}({_short(desired)})",
                    lambda c=call, d=desired: c(np.zeros(3), d, {}),
                    ("desired_goal", "one shape"),
                    finite_array(desired, (3,)),
                )
            )
    return cases


def cost_cases() -> list[Case]:
    cases = [
        (
            f"trajectory_cost(errors={_short(e)})",
            lambda e=e: trajectory_cost(e, np.zeros((4, 6)), 0.008),
            ("error", "trajectory"),
            any(finite_array(e, (4, d)) for d in range(1, 7)),
        )  # any task size
        for e in arrays((4, 3))
    ]
    cases += [
        (
            f"trajectory_cost(dt={_short(dt)})",
            lambda d=dt: trajectory_cost(np.zeros((4, 3)), np.zeros((4, 6)), d),
            ("dt",),
            real(dt) and dt > 0,
        )
        for dt in SCALARS
    ]
    return cases


def model_error_cases() -> list[Case]:
    lists = [[0.1] * 6, [0.1, 0.2, 0.3], [1e9, 0, 0], [4.0], [0.1, float("nan")]]
    valid = {
        "link_scale": lambda v: real(v, -1, 1) and v > -1,
        "joint_offset": lambda v: isinstance(v, list) and all(real(a, -math.pi, math.pi) for a in v),
        "tool_offset": lambda v: isinstance(v, list) and len(v) == 3 and all(real(a, -1, 1) for a in v),
    }
    return [
        (f"ModelError({field}={_short(value)})", lambda f=field, v=value: ModelError(**{f: v}), (field,), check(value))
        for field, check in valid.items()
        for value in (SCALARS if field == "link_scale" else SCALARS + lists)
    ]


def config_and_policy_cases() -> list[Case]:
    cases = []
    for field, low, high, whole in (
        ("samples", 1, 10**5, True),
        ("seed", 0, 2**32 - 1, True),
        ("q_scale", 5e-324, 1e308, False),
        ("workers", 1, 4, True),
    ):
        cases += [
            (
                f"EvaluationConfig({field}={_short(value)})",
                lambda f=field, v=value: EvaluationConfig(out=Path("unused"), **{f: v}).validate(),
                (field,),
                real(value, low, high, whole) and not (field == "q_scale" and value <= 0),
            )
            for value in SCALARS
        ]
    env = gym.make(ID, physics="kinematic")
    policy = make_policy("snac", env.unwrapped)
    policy.reset(seed=0)
    size = env.unwrapped.obs_layout.size
    cases += [
        (f"policy.act({_short(o)})", lambda o=o: policy.act(o), ("observation",), finite_array(o, (size,)))
        for o in arrays((size,))
    ]
    return cases


def api_cases() -> list[Case]:
    return env_cases() + goal_cases() + cost_cases() + model_error_cases() + config_and_policy_cases()


CLI_VALUES = ["nan", "inf", "-inf", "-1", "0", "0.5", "1e9", "1e300", "2.5", "abc", "", "1,2", "0x10", "True", "3", "7"]
CLI_OPTIONS = {
    "evaluate": (
        ["--export-only", "--samples", "2"],
        {
            "--seed": (0, 2**32 - 1, True),
            "--q-scale": (1e-300, 1e300, False),
            "--cuboid": None,
            "--horizon": None,
            "--model-error": None,
            "--effort-tolerance": (1e-9, 1, False),
            "--success-threshold": (0, 1, False),
            "--samples": (1, 10**5, True),
            "--workers": (1, 4, True),
            "--chunk-size": (1, 10**6, True),
        },
    ),
    "demo": (
        ["--no-plots", "--steps", "5"],
        {"--seed": (0, 2**32 - 1, True), "--model-error": None, "--robot": None, "--controller": None, "--task": None},
    ),
    "real": (
        ["--connection", "sim", "--dry-run", "--no-plots", "--steps", "3"],
        {
            "--speed-scale": (1e-9, 1, False),
            "--max-acceleration": (1e-9, 40, False),
            "--joint-margin": (0, math.pi / 2, False),
            "--max-tcp-mismatch": (1e-9, 1, False),
            "--seed": (0, 2**32 - 1, True),
            "--target": None,
            "--q0": None,
            "--task-box": None,
            "--series": None,
            "--robot": None,
        },
    ),
    "emulate-ur": (
        ["--port-base", "0", "--duration", "0"],
        {
            "--speed-scaling": (1e-9, 1, False),
            "--protective-stop-at": (0, 1e300, False),
            "--latency-spike": None,
            "--tcp-offset": None,
            "--robot": None,
            "--series": None,
        },
    ),
    "bench": (
        ["--no-panda"],
        {"--steps": (100, 99, True), "--act-calls": (100, 99, True)},
    ),  # valid counts skipped: minutes
    "train-ppo": (
        ["--task", "reach", "--resume"],
        {
            "--n-envs": (1, 1024, True),
            "--timesteps": (1, 10**12, True),
            "--seed": (0, 2**32 - 1, True),
            "--vec-env": None,
        },
    ),
}


def cli_cases(folder: Path) -> list[tuple[str, list[str], str, tuple | None]]:
    cases = []
    for command, (fixed, options) in CLI_OPTIONS.items():
        for option, bounds in options.items():
            for k, value in enumerate(CLI_VALUES):
                if command == "bench" and value in ("1e9",):
                    continue
                out = ["--out", str(folder / f"{command}{option}{k}")] if command not in ("bench", "emulate-ur") else []
                extra = ["--export-samples", str(folder / f"s{option}{k}.csv")] if command == "evaluate" else []
                cases.append((command, [command, *fixed, *out, *extra, f"{option}={value}"], option, bounds))
    return cases


def classify_cli(arguments: list[str], option: str, bounds: tuple | None) -> str:
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    value = arguments[-1].split("=", 1)[1]
    signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, BOUND_S)
    try:
        outcome = CliRunner().invoke(app, arguments, terminal_width=200)
    except Hang:
        return "hang"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    if outcome.exception is not None and not isinstance(outcome.exception, SystemExit):
        return "raw"
    text = " ".join(outcome.output.split())
    if outcome.exit_code == 2:
        if "holds no checkpoint to continue" in text:  # train-ppo --resume on an empty folder: the options were taken
            return _taken(value, bounds)
        named = (
            option in text
            or option.lstrip("-").replace("-", "_") in text
            or option.lstrip("-").replace("-", " ") in text
        )
        return "clear" if named else "unclear"
    if outcome.exit_code in (0, 4):  # 4: real's safety layer stopped the (simulated) arm, a documented end
        return _taken(value, bounds)
    return "raw"


def _taken(value: str, bounds: tuple | None) -> str:
    if bounds is None:
        return "accepted"  # a text option (a name, a list): its valid forms are the command's own tests'
    low, high, whole = bounds
    try:
        number = int(value, 10) if whole else float(value)
    except ValueError:
        return "silent"
    return "accepted" if math.isfinite(number) and low <= number <= high else "silent"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--list", action="store_true", help="also list every input that was not clear or accepted")
    args = parser.parse_args()
    api = Counter()
    flagged = []
    for boundary, call, names, valid in api_cases():
        outcome = classify(call, names, valid)
        api[outcome] += 1
        if outcome not in ("clear", "accepted"):
            flagged.append(f"API {boundary}: {outcome}")
    cli = Counter()
    with tempfile.TemporaryDirectory() as folder:
        for command, arguments, option, bounds in cli_cases(Path(folder)):
            outcome = classify_cli(arguments, option, bounds)
            cli[outcome] += 1
            if outcome not in ("clear", "accepted"):
                flagged.append(f"CLI {' '.join(arguments[:1] + arguments[-1:])}: {outcome}")
    classes = ["clear", "unclear", "raw", "hang", "accepted", "silent"]
    print("| boundary | inputs | " + " | ".join(classes) + " |")
    print("|---|---|" + "---|" * len(classes))
    for name, counts in (("API", api), ("CLI", cli)):
        print(f"| {name} | {sum(counts.values())} | " + " | ".join(str(counts[c]) for c in classes) + " |")
    if args.list:
        print("\n".join(flagged))


if __name__ == "__main__":
    main()
