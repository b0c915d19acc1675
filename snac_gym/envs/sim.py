"""A thin wrapper around one PyBullet physics client (the panda-gym split: sim / robot / task / env)."""

from __future__ import annotations

import math
import os
import sys
import tempfile
from typing import Any

import numpy as np

from snac_gym._quiet import quiet_output

with quiet_output():
    import pybullet as _pybullet

p: Any = _pybullet

#: Largest rendered image side, pixels (TinyRenderer allocates width x height buffers in C++).
MAX_IMAGE_SIDE = 8192


def check_image_size(width: Any, height: Any) -> tuple[int, int]:
    """``(width, height)`` as ints, each in [1, :data:`MAX_IMAGE_SIDE`].

    A negative size aborts the interpreter inside PyBullet (``std::bad_alloc``) and zero divides
    by zero or gives an empty image, so they are refused before they reach it.

    Raises:
        ValueError: Naming the bad side and the bound.
    """
    sides = []
    for name, value in (("render_width", width), ("render_height", height)):
        whole = isinstance(value, (int, np.integer)) or (isinstance(value, float) and value.is_integer())
        if isinstance(value, bool) or not whole or not 1 <= value <= MAX_IMAGE_SIDE:
            raise ValueError(f"{name} must be a whole number of pixels in [1, {MAX_IMAGE_SIDE}], got {value!r}")
        sides.append(int(value))
    return sides[0], sides[1]


#: Longest control period accepted, s: a velocity command held for longer is no longer the
#: paper's velocity-level control (its UR10 runs at 8 ms).
MAX_DT = 1.0


def check_timing(dt: Any, n_substeps: Any) -> tuple[float, int]:
    """``(dt, n_substeps)`` of a physics engine, checked: 0 < dt ≤ :data:`MAX_DT`, a whole n_substeps ≥ 1.

    Raises:
        ValueError: Naming the bad one.
    """
    if not (math.isfinite(dt) and 0 < dt <= MAX_DT):
        raise ValueError(f"dt must be positive, finite and at most {MAX_DT:g} s, got {dt}")
    if int(n_substeps) != n_substeps or n_substeps < 1:
        raise ValueError(f"n_substeps must be a positive integer, got {n_substeps}")
    return float(dt), int(n_substeps)


class PyBulletSim:
    """One PyBullet client that advances by a control period split into physics substeps.

    Args:
        dt: Control period in seconds: one :meth:`step` advances the world by ``dt``.
        n_substeps: Physics steps per control period (physics step ``dt / n_substeps``).
        gui: Open the PyBullet GUI (needs a display) instead of the headless DIRECT client.
        gravity: Gravity along −z, m/s².
    """

    def __init__(self, dt: float, n_substeps: int, gui: bool = False, gravity: float = 9.81) -> None:
        self.dt, self.n_substeps = check_timing(dt, n_substeps)
        if gui and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            # PyBullet would call exit() on a failed GUI connection, killing the caller.
            raise RuntimeError(
                "render_mode='human' opens the PyBullet GUI and needs a display, but DISPLAY is not set; "
                "use render_mode='rgb_array' to render headless"
            )
        with quiet_output():
            self.client = p.connect(p.GUI if gui else p.DIRECT)
        if self.client < 0:
            raise RuntimeError("could not connect to PyBullet" + (" GUI (is there a display?)" if gui else ""))
        if gui:
            p.configureDebugVisualizer(p.COV_ENABLE_GUI, 0, physicsClientId=self.client)
        # One stepSimulation call advances dt in n_substeps fixed steps: one Python call per control step.
        p.setPhysicsEngineParameter(
            fixedTimeStep=self.dt, numSubSteps=self.n_substeps,
            # The arm touches nothing (see SimulatedArm), so there are no contact pairs to order and no
            # friction cones to solve; both settings only cost time here.
            deterministicOverlappingPairs=0, enableConeFriction=0, physicsClientId=self.client,
        )
        p.setGravity(0.0, 0.0, -gravity, physicsClientId=self.client)

    def load_urdf_text(self, urdf_text: str, flags: int = 0) -> int:
        """Load a URDF given as text (a temporary file is written and removed), base fixed."""
        with tempfile.NamedTemporaryFile("w", suffix=".urdf", delete=False) as handle:
            handle.write(urdf_text)
            path = handle.name
        try:
            with quiet_output():  # merging fixed links prints a trace to stdout
                return p.loadURDF(path, useFixedBase=True, flags=flags, physicsClientId=self.client)
        finally:
            os.unlink(path)

    def step(self) -> None:
        p.stepSimulation(physicsClientId=self.client)

    def save_state(self) -> int:
        return p.saveState(physicsClientId=self.client)

    def restore_state(self, state_id: int) -> None:
        p.restoreState(stateId=state_id, physicsClientId=self.client)

    def render(self, width: int, height: int, target: np.ndarray, distance: float = 2.2) -> np.ndarray:
        """An RGB image (``(height, width, 3)`` uint8) from a camera orbiting ``target``, headless-safe.

        Raises:
            ValueError: If ``width`` or ``height`` is not in [1, :data:`MAX_IMAGE_SIDE`] (:func:`check_image_size`).
        """
        width, height = check_image_size(width, height)
        view = p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(target), distance=distance, yaw=45.0, pitch=-25.0, roll=0.0, upAxisIndex=2,
            physicsClientId=self.client,
        )
        proj = p.computeProjectionMatrixFOV(fov=50.0, aspect=width / height, nearVal=0.05, farVal=10.0, physicsClientId=self.client)
        _, _, rgba, _, _ = p.getCameraImage(
            width, height, viewMatrix=view, projectionMatrix=proj, renderer=p.ER_TINY_RENDERER, physicsClientId=self.client
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3].copy()

    def close(self) -> None:
        if self.client >= 0 and p.isConnected(self.client):
            p.disconnect(self.client)
        self.client = -1

    def __del__(self) -> None:
        # An env dropped without close() would otherwise keep its physics server (~65 MB) for the
        # life of the process: a test suite or a notebook that builds many envs runs out of memory.
        try:
            if getattr(self, "client", -1) >= 0 and p is not None and p.isConnected(self.client):
                p.disconnect(self.client)
        except Exception:  # noqa: BLE001 - interpreter shutdown may have torn pybullet down already
            pass

