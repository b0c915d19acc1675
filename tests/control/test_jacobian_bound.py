"""The certified sup ‖J(θ)‖₂ by branch and bound, and the shipped values (snac_gym/control/jacobian_bound.py)."""

from __future__ import annotations

import copy
import json
from importlib import resources

import numpy as np
import pytest

from snac_gym.control.jacobian_bound import (
    SHIPPED,
    certified_jacobian_norm,
    geometry_key,
    jacobian_norm_bound,
    joint_variation_bounds,
)
from snac_gym.control.lower_bounds import jacobian_variation_bound
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.ur_models import UR_MODELS


def _largest_sigma(kinematics: Kinematics, count: int, seed: int) -> float:
    """The largest σ_max(J) over random configurations of every joint (a lower bound on the supremum)."""
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, size=(count, kinematics.n_joints))
    _, jac = kinematics.forward_and_jacobian_batch(q)
    return float(np.linalg.norm(jac, ord=2, axis=(-2, -1)).max())


def test_the_branch_and_bound_is_above_every_pose_sampled_and_within_its_tolerance_of_the_best_met():
    ur10 = Kinematics("ur10")
    bound, best, evaluated = certified_jacobian_norm(ur10, 0.3)
    sampled = _largest_sigma(ur10, 50_000, 1)
    assert sampled <= best <= bound <= best + 0.3 + 1e-9
    assert bound < ur10.position_lipschitz_bound()  # below the summed link lengths it replaces (2.52)
    assert evaluated > 1000
    # the first joint and the joint that carries the end effector on its axis are not searched: their terms
    terms = joint_variation_bounds(ur10)
    assert terms is not None and terms[-1] == 0.0
    assert jacobian_variation_bound(ur10) == pytest.approx(float(np.sqrt(np.sum(terms[1:] ** 2))))


def test_every_ur_model_has_a_shipped_bound_that_holds_for_its_current_geometry():
    shipped = json.loads(resources.files("snac_gym").joinpath(SHIPPED).read_text(encoding="utf-8"))
    entries = {entry["robot"]: entry for entry in shipped["bounds"]}
    assert set(entries) == set(UR_MODELS)
    for robot, entry in entries.items():
        kinematics = Kinematics(robot)
        # the geometry the value was computed for: a model that changes makes this fail (rerun the command)
        assert entry["geometry"] == geometry_key(kinematics), f"{robot}: rerun {shipped['command']}"
        assert _largest_sigma(kinematics, 20_000, 2) <= entry["largest_met"] <= entry["bound"]
        assert entry["bound"] <= entry["largest_met"] + entry["tolerance"] + 1e-9
        assert jacobian_norm_bound(kinematics) == entry["bound"] < kinematics.position_lipschitz_bound()


def test_an_arm_of_another_geometry_gets_the_summed_link_lengths():
    ur10 = Kinematics("ur10")
    moved = copy.copy(ur10)
    moved.model = ur10.model.copy()
    placement = moved.model.jointPlacements[3].copy()
    placement.translation = placement.translation * 1.1  # a longer forearm: the shipped value need not hold
    moved.model.jointPlacements[3] = placement
    assert geometry_key(moved) != geometry_key(ur10)
    assert jacobian_norm_bound(moved) == moved.position_lipschitz_bound()
