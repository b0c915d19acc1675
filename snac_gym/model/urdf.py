"""Where a registered robot's URDF is, and its text with the ``package://`` paths resolved (Pinocchio and PyBullet
read it so)."""

from __future__ import annotations

import importlib.metadata
from functools import lru_cache
from pathlib import Path

from snac_gym.model.robots import get_robot

__all__ = ["resolved_urdf_text", "robot_urdf_path", "robots_directory"]

_PACKAGE_PREFIX = "package://example-robot-data/robots/"


@lru_cache(maxsize=1)
def robots_directory() -> Path:
    """Return the ``robots/`` folder that the ``example-robot-data`` wheel installs.

    Raises:
        RuntimeError: If the package is not installed.
    """
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as exc:  # pragma: no cover - install error
        raise RuntimeError(
            "example-robot-data is not installed; `pip install example-robot-data` provides the UR URDFs"
        ) from exc
    path = Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))
    if not path.is_dir():  # pragma: no cover - broken install
        raise RuntimeError(f"example-robot-data is installed but {path} does not exist")
    return path


def robot_urdf_path(robot: str) -> Path:
    """Path of the URDF shipped by ``example-robot-data`` for a registered ``robot`` (:mod:`snac_gym.model.robots`).

    Raises:
        ValueError: If ``robot`` is not registered.
    """
    return robots_directory() / get_robot(robot).urdf


def resolved_urdf_text(urdf_path: str | Path) -> str:
    """URDF text with ``package://example-robot-data/robots/`` mesh URIs made absolute.

    PyBullet does not resolve ROS ``package://`` URIs, so the simulator loads this text
    (written to a temporary file) instead of copying meshes into the repository.
    """
    text = Path(urdf_path).read_text()
    return text.replace(_PACKAGE_PREFIX, str(robots_directory()) + "/")
