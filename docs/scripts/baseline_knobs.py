"""Measured effect of the baselines' second knobs for docs/baselines.md: SVF's ν and σ₀, RNN's ε.

Each row is one ``snac-gym evaluate`` run (kinematic engine, seed 0, default horizons reach
12 s / track 20 s, ``--no-match-effort``, so every controller keeps its default gain K = k = 2
1/s), one knob changed from its default. The columns are those of
``docs/scripts/snac_sensitivity.py`` (V/N is the mean of ``cost``, as in ``summary.csv``).

Usage (about 6 s per row on 2 workers; runs the code of the checkout that holds this script)::

    .venv/bin/python docs/scripts/baseline_knobs.py --out /tmp/knobs --samples 200
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from snac_sensitivity import main  # noqa: E402

#: (controller, [(name, --param values, note)]). The first row of each is the defaults.
KNOBS = {
    "svf": [
        ("svf defaults", [], "ν = 10, σ₀ = 0.005 (the paper's)"),
        ("svf ν=1", ["nu=1"], ""),
        ("svf ν=3", ["nu=3"], ""),
        ("svf ν=30", ["nu=30"], ""),
        ("svf ν=100", ["nu=100"], ""),
        ("svf ν=300", ["nu=300"], "σ₀ν = 1.5 (the constructor needs σ₀ν < 2)"),
        ("svf σ₀=0.001", ["sigma0=0.001"], ""),
        ("svf σ₀=0.02", ["sigma0=0.02"], ""),
        ("svf σ₀=0.1", ["sigma0=0.1"], ""),
        ("svf σ₀=0.19", ["sigma0=0.19"], "σ₀ν = 1.9"),
    ],
    "rnn": [
        ("rnn defaults", [], "ε = 1 ms"),
        ("rnn ε=1e-4", ["epsilon=1e-4"], ""),
        ("rnn ε=1e-2", ["epsilon=1e-2"], ""),
        ("rnn ε=5e-2", ["epsilon=5e-2"], ""),
    ],
}

if __name__ == "__main__":
    controller = sys.argv.pop(1) if len(sys.argv) > 1 and sys.argv[1] in KNOBS else None
    for name in [controller] if controller else list(KNOBS):
        main(KNOBS[name], name)
        print()
