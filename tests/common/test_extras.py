"""Importing an optional dependency: no stray child processes."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SPY = r"""
import subprocess, sys
started = []
original = subprocess.Popen.__init__
def spy(self, args, *rest, **options):
    started.append(args)
    return original(self, args, *rest, **options)
subprocess.Popen.__init__ = spy
from snac_gym.common.extras import require
mujoco = require("mujoco", "mujoco", "physics='mujoco'")
import glfw
print(len(started), glfw.get_version() >= (3, 0, 0), hasattr(mujoco, "Renderer"))
"""


def test_importing_mujoco_starts_no_process_to_find_glfw():
    """pyGLFW, told no library, runs a Python child per candidate to read its version: slow on a busy
    machine, and a stop signal during it left that child printing a traceback after the command ended."""
    pytest.importorskip("mujoco")
    pytest.importorskip("glfw")
    if not sys.platform.startswith("linux"):
        pytest.skip("pyGLFW searches for its library on Linux only")
    env = {key: value for key, value in os.environ.items() if key != "PYGLFW_LIBRARY"}
    done = subprocess.run([sys.executable, "-c", SPY], capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["0", "True", "True"]  # no child; the bundled GLFW 3 loaded; MuJoCo's renderer there


def test_a_glfw_library_the_user_names_is_kept(monkeypatch):
    from snac_gym.common import extras

    monkeypatch.setenv("PYGLFW_LIBRARY", "/opt/mine/libglfw.so")
    extras._name_the_glfw_library()
    assert os.environ["PYGLFW_LIBRARY"] == "/opt/mine/libglfw.so"
