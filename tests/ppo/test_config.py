"""The whole-workspace PPO configs (snac_gym/ppo/configs/workspace/) are valid and differ from the shipped
ones only in where the samples come from (docs/ppo.md, "Training on the whole workspace")."""

import json
from pathlib import Path

import pytest

from snac_gym.ppo.config import default_config_path, env_arguments, resolve_config

FOLDER = Path(__file__).resolve().parents[2] / "snac_gym" / "ppo" / "configs" / "workspace"


@pytest.mark.parametrize("task", ["reach", "track"])
def test_workspace_config_is_the_shipped_one_on_the_whole_reach(task):
    path = FOLDER / f"{task}.json"
    config = resolve_config(task, path)
    shipped = json.loads(default_config_path(task).read_text())
    ours = json.loads(path.read_text())
    assert ours["env"] == {**shipped["env"], "sample_space": "workspace"}
    differing = {key for key in shipped if shipped[key] != ours[key]}
    assert differing == {"env", "description"}
    assert env_arguments(config)["sample_space"] is not None
