"""``snac-adaptive`` with another arm's model: the UR3's kinematics driving a UR10 (the tool 0.5 m off at the median).

Two properties of docs/model-error.md, "Another arm's model", on a handful of samples:

* in the cuboid it tracks ellipses the earlier prior (0.1 m per frame) did not: the two here missed the 5 mm with it
  (mean 6.1-7.5 mm over the second half, as two more of seed 41 did), and track within it now;
* on the whole workspace, an episode that ends more than 5 cm off carries the ``diverged`` flag: the two here crawl
  near a singular pose (σ_min(J) ≈ 0.05) and only the too-slow rule catches them.
"""

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context, task_kinematics
from snac_gym.evaluation.samples import generate_samples, policy_seed

from snac_gym.model.kinematics import Kinematics
from snac_gym.policies.registry import make_policy
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

DT = 1 / 125
UR3 = "model=ur3"


def _rollouts(task, seed, indices, workspace=False, **kwargs):
    kinematics = Kinematics("ur10")
    space = SampleSpace.workspace(kinematics) if workspace else SampleSpace.for_robot(kinematics)
    samples = generate_samples(kinematics, space, seed, task, indices)
    context = policy_context("ur10", DT, task, UR3)
    return simulate_kinematic(
        context, lambda: make_policy("snac-adaptive", context, Q=[4.0, 4.0, 4.0], **kwargs), samples,
        get_task(task).horizon_steps(DT), [policy_seed(seed, task, s.index) for s in samples],
        plant=task_kinematics("ur10", task),
    )  # fmt: skip


def _second_half_mean(rollouts):
    errors = np.linalg.norm(rollouts.errors, axis=2)
    return errors[:, errors.shape[1] // 2 :].mean(axis=1)


def test_with_the_ur3s_model_it_tracks_ellipses_the_narrow_prior_missed():
    indices = [3, 23]  # two of seed 41's four cuboid ellipses that the 0.1 m prior missed (3, 16, 23, 27)
    tracked = _second_half_mean(_rollouts("track", 41, indices))
    assert (tracked <= 5e-3).all(), tracked
    narrow = _second_half_mean(_rollouts("track", 41, indices, prior_translation=0.1))
    assert (narrow > 5e-3).all(), narrow  # the test can fail: the prior is what makes the difference


def test_on_the_workspace_an_episode_that_ends_more_than_5_cm_off_is_flagged():
    far_seen = 0
    for task, indices in (("reach", [68, 0, 1]), ("track", [65, 0])):  # seed 43: the first of each crawls
        rollouts = _rollouts(task, 43, indices, workspace=True)
        final = np.linalg.norm(rollouts.errors[:, -1], axis=1)
        flags = rollouts.flags
        assert flags is not None
        far = final > 0.05
        assert not (far & ~flags["diverged"]).any(), (task, final, flags["diverged"])
        assert not flags["diverged"][~far].any()  # the others converge and are not stopped
        far_seen += int(far.sum())
    assert far_seen == 2
    unwatched = _rollouts("reach", 43, [68], workspace=True, divergence_time_to_go=1e9)
    assert np.linalg.norm(unwatched.errors[0, -1]) > 0.05 and not unwatched.flags["diverged"][0]
