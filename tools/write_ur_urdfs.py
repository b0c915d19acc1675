"""Write the e-series URDFs that snac_gym ships (snac_gym/data/urdf/), from snac_gym.model.ur_models.

example-robot-data ships the CB3 arms only; the e-series arms' URDFs are written from Universal Robots'
published DH parameters and datasheet limits. tests/model/test_ur_models.py fails when a shipped file differs
from what this writes.

    python tools/write_ur_urdfs.py
"""

from pathlib import Path

from snac_gym.model.ur_models import E_SERIES_URDF_DIR, UR_MODELS, urdf_text


def main() -> None:
    for model in UR_MODELS.values():
        if model.series == "e":
            path = E_SERIES_URDF_DIR / f"{model.name}.urdf"
            path.write_text(urdf_text(model.name))
            print(f"wrote {path.relative_to(Path.cwd()) if path.is_relative_to(Path.cwd()) else path}")


if __name__ == "__main__":
    main()
