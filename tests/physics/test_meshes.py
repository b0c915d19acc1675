"""The visual meshes' OBJ copies (snac_gym/physics/meshes.py): frames drawn from them are the COLLADA files' pixel for
pixel, each file is converted once and named by its content, and a file that cannot be converted the same way, or
saved, keeps its ``.dae``."""

from __future__ import annotations

import re
import shutil
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest

import snac_gym.physics.bullet as bullet
from snac_gym.model.kinematics import Kinematics, resolved_urdf_text
from snac_gym.physics import meshes

#: Every built-in arm whose URDF draws COLLADA visuals, with its reach id.
DAE_ARMS = {"ur3": "snac_gym/UR3Reach-v1", "ur10": "snac_gym/UR10Reach-v1", "panda": "snac_gym/PandaReach-v1"}


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch) -> Path:
    """An empty cache folder, and no process memo of files converted before."""
    monkeypatch.setenv("SNAC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(meshes, "_SEEN", {})
    return tmp_path / "cache" / "meshes"


def _dae_files(robot: str) -> list[str]:
    urdf = resolved_urdf_text(Kinematics(robot).urdf_path)
    return sorted(set(re.findall(r'<visual\b.*?filename="([^"]+\.dae)"', urdf, flags=re.S)))


def _frames(env_id: str) -> tuple[list[np.ndarray], list[str]]:
    """Frames of one seeded episode (at reset and after 25 steps), and the mesh files the drawn arm loaded."""
    env = gym.make(env_id, render_mode="rgb_array", render_width=240, render_height=240)
    env.reset(seed=11)
    frames = [env.render()]
    for _ in range(25):
        env.step(np.full(env.action_space.shape, 0.4, dtype=env.action_space.dtype))
    frames.append(env.render())
    base = env.unwrapped
    shapes = p.getVisualShapeData(base.arm.body.body, physicsClientId=base.sim.client)
    env.close()
    return frames, sorted({shape[4].decode() for shape in shapes})


@pytest.mark.parametrize("robot", sorted(DAE_ARMS))
def test_frames_drawn_from_the_obj_copies_are_the_dae_files_pixel_for_pixel(robot, monkeypatch):
    """The Panda's links are the case that fails if a normal is turned with its node (PyBullet turns only the
    vertices), the UR base the case of a ``<polylist>``. The copies are this test process's (written by whichever
    test drew the arm first)."""
    converted, loaded = _frames(DAE_ARMS[robot])
    folder = str(meshes.mesh_folder().resolve())
    assert loaded and all(str(Path(name).resolve()).startswith(folder) for name in loaded), loaded
    assert all(name.endswith(".obj") for name in loaded) and len(loaded) == len(_dae_files(robot)), loaded
    monkeypatch.setattr(bullet, "visual_meshes_as_obj", lambda urdf: urdf)  # PyBullet reads the .dae files
    original, loaded = _frames(DAE_ARMS[robot])
    assert loaded and all(name.endswith(".dae") for name in loaded), loaded
    for ours, theirs in zip(converted, original, strict=True):
        assert ours.shape == theirs.shape and np.array_equal(ours, theirs), int((ours != theirs).any(axis=2).sum())


def test_each_file_is_converted_once_and_named_by_its_content(fresh_cache, tmp_path):
    dae = tmp_path / "wrist3.dae"
    shutil.copy(next(f for f in _dae_files("ur10") if f.endswith("wrist3.dae")), dae)
    with warnings.catch_warnings(record=True) as caught:  # pycollada's NumPy deprecations are not the user's
        warnings.simplefilter("always")
        first = meshes.obj_for(dae)
    assert not caught, [str(warning.message) for warning in caught]
    assert first is not None and Path(first).parent == fresh_cache
    written = Path(first).stat().st_mtime_ns
    meshes._SEEN.clear()  # another process: it finds the file, and writes nothing
    assert meshes.obj_for(dae) == first and Path(first).stat().st_mtime_ns == written
    dae.write_bytes(dae.read_bytes() + b"\n")  # edited: a file of its own, the old one never read for it
    edited = meshes.obj_for(dae)
    assert edited is not None and edited != first and len(list(fresh_cache.glob("*.obj"))) == 2
    urdf = f'<robot><link name="a"><visual><geometry><mesh filename="{dae}"/></geometry></visual>'
    urdf += f'<collision><geometry><mesh filename="{dae}"/></geometry></collision></link></robot>'
    assert meshes.visual_meshes_as_obj(urdf) == urdf.replace(str(dae), edited, 1)  # the collision mesh kept


@pytest.mark.parametrize("case", ["millimetres", "y up", "not collada", "no normals", "no pycollada", "unwritable"])
def test_a_file_that_cannot_be_converted_the_same_way_or_saved_keeps_its_dae(case, fresh_cache, tmp_path, monkeypatch):
    source = Path(next(f for f in _dae_files("ur10") if f.endswith("wrist3.dae"))).read_text()
    dae = tmp_path / "mesh.dae"
    if case == "millimetres":
        source = re.sub(r"<unit [^>]*/>", '<unit meter="0.001" name="millimeter"/>', source)
    elif case == "y up":
        source = re.sub(r"<up_axis>\w+</up_axis>", "<up_axis>Y_UP</up_axis>", source)
    elif case == "not collada":
        source = "<html>not a mesh</html>"
    elif case == "no normals":
        source = re.sub(r'<input semantic="NORMAL"[^>]*/>', "", source)
    elif case == "no pycollada":
        monkeypatch.setitem(sys.modules, "collada", None)
    elif case == "unwritable":
        fresh_cache.parent.mkdir(parents=True)
        fresh_cache.write_text("a file where the folder would go")
    assert source.count("<unit ") == 1 and source.count("<up_axis>") == 1 or case == "not collada"
    dae.write_text(source)
    assert meshes.obj_for(dae) is None
    if case in ("millimetres", "y up", "no normals"):  # read, and refused by the check for that case, not by an error
        import collada

        with warnings.catch_warnings():  # pycollada's own NumPy deprecations, as in the conversion
            warnings.simplefilter("ignore")
            assert meshes.read_dae(collada.Collada(str(dae))) is None
    urdf = f'<robot><link name="a"><visual><geometry><mesh filename="{dae}"/></geometry></visual></link></robot>'
    assert meshes.visual_meshes_as_obj(urdf) == urdf
    assert not list(fresh_cache.glob("*.obj")) if fresh_cache.is_dir() else True


def test_a_write_cut_short_leaves_no_file_behind(fresh_cache, tmp_path, monkeypatch):
    dae = tmp_path / "wrist3.dae"
    shutil.copy(next(f for f in _dae_files("ur10") if f.endswith("wrist3.dae")), dae)

    def full_disk(handle, *arrays):
        handle.write("v 0 0 0\n")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(meshes, "write_obj", full_disk)
    assert meshes.obj_for(dae) is None and list(fresh_cache.iterdir()) == []
