"""Write snac_gym/data/calibration/default_knobs.json: the main command's controllers matched to equal effort at
the evaluator's defaults, shipped so that a first run at those settings does not match them again.

    python tools/ship_calibration.py               # match anew (about 40 s on 2 cores) and rewrite the file
    python tools/ship_calibration.py --workers 1

It runs ``snac-gym evaluate --controllers snac,snac-hjb,lqr,rnn,svf,dls,ppo --recalibrate`` (the README's main
command without the reference, which no knob depends on) with the calibration cache in a fresh folder, and
stores each (task, controller)'s record with the identity it was matched for, less the code fingerprint
(:mod:`snac_gym.evaluation.effort.shipped`). tests/evaluation/effort/test_shipped.py recomputes the knob searches and
fails when the file is stale: rerun this script then, and commit the file.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from datetime import datetime, timezone
from importlib.metadata import version
from pathlib import Path

#: The README's main command's controllers (its ``optimal`` row is a reference, matched to nothing).
MAIN_CONTROLLERS = ("snac", "snac-hjb", "lqr", "rnn", "svf", "dls", "ppo")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        os.environ["SNAC_GYM_CACHE_DIR"] = str(Path(scratch) / "cache")  # read by the cache at each call
        os.environ.pop("SNAC_GYM_CALIBRATION_CACHE", None)
        from snac_gym.evaluation import EvaluationConfig, run_evaluation
        from snac_gym.evaluation.controllers import resolve_controllers
        from snac_gym.evaluation.effort.cache import calibration_folder, read_records
        from snac_gym.evaluation.effort.shipped import numerics, shipped_file, write_shipped
        from snac_gym.evaluation.runner import _calibration_identities, _checked_setting

        out = Path(scratch) / "run"
        config = EvaluationConfig(out=out, controllers=MAIN_CONTROLLERS, workers=args.workers, recalibrate=True,
                                  progress=False, plots=False)  # fmt: skip
        run_evaluation(config)
        _, space = _checked_setting(config)
        specs, _ = resolve_controllers(config)
        identities = _calibration_identities(config, space, specs)
        cached = read_records(calibration_folder(), identities)
        if cached is None:
            print("the calibrating run left no complete calibration record", file=sys.stderr)
            return 1
        records, _ = cached
        unmatched = [f"{t}/{c}: {r.note}" for (t, c), r in records.items() if r.role not in ("matched", "reference")]
        if unmatched:
            print("not shipped, some controllers are unmatched:\n  " + "\n  ".join(unmatched), file=sys.stderr)
            return 1
        searches = json.loads((out / "calibration.json").read_text())
        stamp = {
            "made_by": "python tools/ship_calibration.py",
            "made_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "versions": {**numerics(), **{name: version(name) for name in ("torch", "stable-baselines3")}},
        }
        path = write_shipped(shipped_file(), identities, records, searches, stamp)
    print(f"wrote {path} ({len(records)} knobs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
