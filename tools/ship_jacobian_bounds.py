"""Write snac_gym/data/jacobian_bounds.json: a certified sup ‖J(θ)‖₂ of every UR model, by branch and bound.

    python tools/ship_jacobian_bounds.py                  # every UR model, about a minute each here
    python tools/ship_jacobian_bounds.py --relative 0.02  # the tolerance, as a fraction of the summed link lengths

Each entry holds the bound, the tolerance it was computed to, the largest σ_max(J) met, the Jacobians it took and the
geometry key it holds for (:mod:`snac_gym.control.jacobian_bound`); the lower bounds use it for an arm of that exact
geometry only. tests/control/test_jacobian_bound.py fails when a model's geometry no longer matches its entry:
rerun this script then, and commit the file.
"""

from __future__ import annotations

import argparse
import json
import time
from importlib.metadata import version
from pathlib import Path

from snac_gym.control.jacobian_bound import SHIPPED, certified_jacobian_norm, geometry_key
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import UR_MODELS

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--relative", type=float, default=0.02, help="tolerance / summed link lengths")
    args = parser.parse_args()
    entries = []
    for robot in UR_MODELS:
        kinematics = Kinematics(robot)
        lengths = kinematics.position_lipschitz_bound()
        started = time.perf_counter()
        bound, best, evaluated = certified_jacobian_norm(kinematics, args.relative * lengths)
        seconds = time.perf_counter() - started
        print(f"{robot}: sup |J| <= {bound:.4f} (largest met {best:.4f}, link lengths {lengths:.4f}), "
              f"{evaluated / 1e6:.1f} M Jacobians, {seconds:.0f} s", flush=True)  # fmt: skip
        entries.append({
            "robot": robot, "bound": bound, "tolerance": args.relative * lengths, "largest_met": best,
            "link_lengths": lengths, "jacobians": evaluated, "geometry": geometry_key(kinematics),
        })  # fmt: skip
    out = ROOT / "snac_gym" / SHIPPED
    command = "python tools/ship_jacobian_bounds.py" + (f" --relative {args.relative}" if args.relative != 0.02 else "")
    document = {"command": command, "snac_gym": version("snac-gym"), "bounds": entries}
    out.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
