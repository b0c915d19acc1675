"""A certified bound on ‖J(θ)‖₂ over every configuration of an arm, by branch and bound, shipped per arm.

The lower bounds price a motion at Lₖ ≥ ‖J‖₂ along it (docs/lower-bounds.md). Far from θ₀ that is a global constant;
``Kinematics.position_lipschitz_bound`` (the summed link lengths: 2.52 m/rad for the UR10) is far above the true
supremum of σ_max(J) (1.53 on 20 000 random UR10 poses), and the bound scales with it.

**Branch and bound.** σ_max(J) does not depend on the first joint (it turns the whole arm about an axis fixed in the
base, J(θ) = R(θ₁)J(0, θ₂, …)) nor on a joint whose column is zero (the end effector on its axis), so its supremum is
over the other joints, each over a full turn (σ_max is 2π-periodic in a revolute angle; the joint limits are left
out, which only raises a supremum). On a box with centre c and half-widths h,

    σ_max(J(θ)) ≤ σ_max(J(c)) + Σₐ Mₐhₐ,   Mₐ ≥ sup ‖∂J/∂θₐ‖_F   (Weyl; :func:`joint_variation_bounds`).

A box whose right side is within ``tolerance`` of the largest σ_max met at a centre is closed, the others are halved
along their largest Mₐhₐ; the largest right side of a closed box is certified (σ_max is computed to ~1e-15
relative, raised here by 1e-12). For the UR10 at tolerance 0.05: 1.581, from 72 million Jacobians (about a minute).

**Shipped.** That is too dear for a run, so ``tools/ship_jacobian_bounds.py`` computes it once per UR model and
writes ``snac_gym/data/jacobian_bounds.json``, each value with a key of the geometry it holds for
(:func:`geometry_key`); :func:`jacobian_norm_bound` uses it only for an arm of that exact geometry, else the summed
link lengths. tests/control/test_jacobian_bound.py checks each shipped value against the current models.
"""

from __future__ import annotations

import functools
import hashlib
import json
from importlib import resources
from typing import Any

import numpy as np

#: Joint models whose Jacobian column is zⱼ × (p − oⱼ) with a fixed unit axis (one coordinate each).
REVOLUTE_JOINTS = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}
#: Boxes per free joint the search starts with.
_GRID = 6
#: Configurations per batch of Jacobians.
_BATCH = 200_000
#: The shipped bounds (package data).
SHIPPED = "data/jacobian_bounds.json"


def joint_variation_bounds(kinematics: Any) -> np.ndarray | None:
    """Mₐ ≥ sup_θ ‖∂J/∂θₐ‖_F per joint, base first, for a chain of revolute joints (else ``None``).

    Column b of J is J_b = z_b × (p − o_b). Differentiating (rotating about joint a moves everything after it):
    ∂J_b/∂θ_a = z_a × J_b if joint a comes before joint b, z_b × J_a otherwise, so ‖∂J_b/∂θ_a‖ ≤ c_max(a,b) with
    c_b ≥ sup ‖J_b‖: c_b = the summed lengths of the fixed offsets from joint b to the end effector (as in
    :meth:`~snac_gym.model.kinematics.Kinematics.position_lipschitz_bound`), and for the joint carrying the end effector
    exactly ‖axis × offset‖ (the distance of p from its axis never changes). Hence Mₐ = (Σ_b c_max(a,b)²)^½.
    """
    model = kinematics.model
    joint_name, offset = kinematics.ee_mount()
    joint = int(model.getJointId(joint_name))
    chain: list[float] = []  # c_b from the end effector back to the base
    reach = float(np.linalg.norm(offset))
    while joint > 0:
        axis = REVOLUTE_JOINTS.get(model.joints[joint].shortname())
        if axis is None or model.joints[joint].nq != 1:
            return None
        if not chain:  # the end effector's own joint: p − oⱼ is the fixed offset, turning about the axis
            chain.append(float(np.linalg.norm(np.delete(np.asarray(offset, dtype=float), axis))))
        else:
            chain.append(reach)
        reach += float(np.linalg.norm(model.jointPlacements[joint].translation))
        joint = int(model.parents[joint])
    lengths = np.array(chain[::-1])  # base first
    return np.sqrt([(a + 1) * lengths[a] ** 2 + float(np.sum(lengths[a + 1 :] ** 2)) for a in range(len(lengths))])


def certified_jacobian_norm(kinematics: Any, tolerance: float) -> tuple[float, float, int]:
    """The branch and bound of the module docstring: ``(certified sup σ_max(J), largest σ_max met, Jacobians)``.

    Raises:
        ValueError: If the arm is not a chain of revolute joints, or ``tolerance`` is not positive.
    """
    variation = joint_variation_bounds(kinematics)
    if variation is None:
        raise ValueError("a branch and bound over the joints needs a chain of revolute joints")
    if not tolerance > 0.0:
        raise ValueError(f"tolerance must be positive, got {tolerance!r}")
    free = [a for a in range(1, len(variation)) if variation[a] > 0.0]
    weights, joints = variation[free], kinematics.n_joints

    def sigma(centres: np.ndarray) -> np.ndarray:
        q = np.zeros((len(centres), joints))
        q[:, free] = centres
        out = np.empty(len(centres))
        for i in range(0, len(q), _BATCH):
            _, jac = kinematics.forward_and_jacobian_batch(q[i : i + _BATCH])
            out[i : i + _BATCH] = np.sqrt(np.linalg.eigvalsh(jac @ np.swapaxes(jac, 1, 2))[:, -1])
        return out * (1.0 + 1e-12)  # raised by far more than its rounding

    axes = [(np.arange(_GRID) + 0.5) / _GRID * 2.0 * np.pi - np.pi] * len(free)
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(free))
    halves = np.full_like(centres, np.pi / _GRID)
    best, certified, evaluated = -np.inf, -np.inf, 0
    while len(centres):
        values = sigma(centres)
        evaluated += len(centres)
        best = max(best, float(values.max()))
        upper = values + halves @ weights
        closed = upper <= best + tolerance
        if closed.any():
            certified = max(certified, float(upper[closed].max()))
        centres, halves = centres[~closed], halves[~closed]
        rows = np.arange(len(centres))
        split = np.argmax(halves * weights, axis=1)
        halves[rows, split] /= 2.0
        offset = np.zeros_like(halves)
        offset[rows, split] = halves[rows, split]
        centres, halves = np.concatenate([centres - offset, centres + offset]), np.concatenate([halves, halves])
    return certified, best, evaluated


def geometry_key(kinematics: Any) -> str:
    """A hash of what σ_max(J) depends on: every joint's type and placement, and the end effector's mount."""
    model = kinematics.model
    digest = hashlib.sha256()
    for joint in range(1, model.njoints):
        digest.update(model.joints[joint].shortname().encode())
        digest.update(np.ascontiguousarray(model.jointPlacements[joint].homogeneous, dtype=float).tobytes())
        digest.update(int(model.parents[joint]).to_bytes(4, "little"))
    name, offset = kinematics.ee_mount()
    digest.update(name.encode())
    digest.update(np.ascontiguousarray(offset, dtype=float).tobytes())
    return digest.hexdigest()


@functools.lru_cache(maxsize=1)
def shipped_bounds() -> dict[str, dict[str, Any]]:
    """The shipped bounds by geometry key (``{}`` if the file is absent)."""
    path = resources.files("snac_gym").joinpath(SHIPPED)
    if not path.is_file():
        return {}
    entries = json.loads(path.read_text(encoding="utf-8"))["bounds"]
    return {entry["geometry"]: entry for entry in entries}


def jacobian_norm_bound(kinematics: Any) -> float:
    """L ≥ ‖J(θ)‖₂ for every θ: the shipped branch-and-bound value where this arm's geometry is the one it was
    computed for, capped by the summed link lengths (``position_lipschitz_bound``), which hold for every arm."""
    lengths = float(kinematics.position_lipschitz_bound())
    entry = shipped_bounds().get(geometry_key(kinematics))
    return min(lengths, float(entry["bound"])) if entry is not None else lengths


__all__ = [
    "REVOLUTE_JOINTS", "SHIPPED", "certified_jacobian_norm", "geometry_key", "jacobian_norm_bound",
    "joint_variation_bounds", "shipped_bounds",
]  # fmt: skip
