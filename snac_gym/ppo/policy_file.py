"""The file a trained PPO policy ships in, and the exact NumPy forward pass that reads it.

A *policy file* (``.npz``, written by :func:`export_policy`, read by :meth:`PolicyFile.load`)
holds everything ``act`` needs, frozen at the moment of export:

* the actor network of the SB3 ``MlpPolicy`` (hidden ``Linear`` layers with their activation,
  then the ``action_net`` layer that gives the mean of the Gaussian, i.e. the deterministic
  action), as float32 arrays ``pi_weight_<i>``, ``pi_bias_<i>``, ``action_weight``,
  ``action_bias``;
* the observation normalisation of ``VecNormalize`` (``obs_mean``, ``obs_var``, with ε and
  the clip in the metadata), applied to the features exactly as ``VecNormalize.normalize_obs``
  does;
* a JSON ``metadata`` entry: format and version, task, robot, observation layout, feature
  spec, activation, the training config, timesteps, seed, package/SB3/torch versions and a
  SHA-256 of the arrays, checked on load so a damaged file is refused rather than run.

Reading it needs NumPy only, so ``make_policy("ppo", env)`` works without torch or
stable-baselines3 installed and acts in microseconds. :func:`export_policy` needs both (it reads
a trained SB3 model); the tests check that the NumPy pass equals ``model.predict(...,
deterministic=True)`` on the normalised features.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, cast

import numpy as np

from snac_gym.common.errors import MissingPolicyFileError, PolicyFileError
from snac_gym.common.outputs import read_json_object, write_whole
from snac_gym.observation import ObservationLayout
from snac_gym.ppo.features import FeatureSpec, GoalState, action_size, command, feature_size, observation_features

FORMAT_NAME = "snac-gym-ppo-policy"
FORMAT_VERSION = 1
ACTIVATIONS = ("tanh", "relu")


def _checksum(arrays: dict[str, np.ndarray]) -> str:
    digest = hashlib.sha256()
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        digest.update(name.encode())
        digest.update(str(array.dtype).encode())
        digest.update(str(array.shape).encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def _rowwise(rows: np.ndarray, weight_t: np.ndarray) -> np.ndarray:
    """``rows @ weight_t`` as one vector-matrix product per row (``(d,)`` or ``(B, d)``)."""
    return np.matmul(rows[..., None, :], weight_t)[..., 0, :]


def _activation(name: str, values: np.ndarray) -> np.ndarray:
    return np.tanh(values) if name == "tanh" else np.maximum(values, 0.0)


@dataclass(frozen=True)
class PolicyFile:
    """A loaded policy file: frozen network, normalisation and metadata.

    Attributes:
        hidden: ``(weight (out, in), bias (out,))`` of each hidden layer, float32.
        action_layer: ``(weight (m, h), bias (m,))`` of the output layer, float32.
        activation: ``"tanh"`` or ``"relu"``.
        obs_mean, obs_var: VecNormalize running statistics of the features (float64), or
            ``None`` when the observations were not normalised.
        obs_epsilon: ε of the normalisation.
        obs_clip: Clip of the normalised features.
        features: The feature spec the network was trained with.
        metadata: Everything else (task, robot, layout, config, versions, ...).
    """

    hidden: tuple[tuple[np.ndarray, np.ndarray], ...]
    action_layer: tuple[np.ndarray, np.ndarray]
    activation: str
    obs_mean: np.ndarray | None
    obs_var: np.ndarray | None
    obs_epsilon: float
    obs_clip: float
    features: FeatureSpec
    metadata: dict[str, Any]

    # -- inference -------------------------------------------------------------------------
    def normalise(self, features: np.ndarray) -> np.ndarray:
        """Frozen ``VecNormalize.normalize_obs`` of float32 features, rounded to float32 as SB3 feeds torch."""
        if self.obs_mean is None:
            return features
        # the variance is given with the mean
        normalised = (features - self.obs_mean) / np.sqrt(cast(np.ndarray, self.obs_var) + self.obs_epsilon)
        return np.clip(normalised, -self.obs_clip, self.obs_clip).astype(np.float32)

    @cached_property
    def _layers64(self) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """The layers as float64 ``(weightᵀ, bias)``, made once."""
        layers = (*self.hidden, self.action_layer)
        return tuple((w.astype(np.float64).T.copy(), b.astype(np.float64)) for w, b in layers)

    def network_action(self, network_input: np.ndarray) -> np.ndarray:
        """The deterministic (mean) action of the actor for normalised inputs, unclipped.

        Computed in float64 from the float32 weights (it agrees with the float32 torch forward pass to ~1e-7),
        one row at a time: a matrix product over a batch lets BLAS pick kernels by the batch's size, which
        changed a row's last bits with the number of rows around it; row by row (a stacked product), a row
        of a batch is bit for bit the row alone, whatever the batch.
        """
        *hidden_layers, (weight_t, bias) = self._layers64
        hidden = np.asarray(network_input, dtype=np.float64)
        for layer_weight_t, layer_bias in hidden_layers:
            hidden = _activation(self.activation, _rowwise(hidden, layer_weight_t) + layer_bias)
        return _rowwise(hidden, weight_t) + bias

    def action(
        self, obs: np.ndarray, layout: ObservationLayout, action_scale: float = 1.0, goal: GoalState | None = None
    ) -> np.ndarray:
        """Normalised action in [−1, 1] for observations ``(d,)`` or ``(B, d)`` at effort ``action_scale``."""
        features = observation_features(obs, layout, self.features, action_scale, goal)
        return np.clip(self.network_action(self.normalise(features)), -1.0, 1.0)

    def command(
        self,
        obs: np.ndarray,
        layout: ObservationLayout,
        velocity_limits: np.ndarray,
        action_scale: float = 1.0,
        jacobians: np.ndarray | None = None,
        goal: GoalState | None = None,
    ) -> np.ndarray:
        """Joint velocities (rad/s) for observations ``(d,)`` or ``(B, d)`` (:func:`~snac_gym.ppo.features.command`).

        A task- or goal-relative policy also needs ``J(θ)`` of each observation (``(n, m)`` or ``(B, n, m)``);
        a goal-relative one its goal state.

        Raises:
            ValueError: If a task-relative policy is given no Jacobians, or a goal-relative one no goal.
        """
        action = self.action(obs, layout, action_scale, goal)
        return command(action, obs, layout, velocity_limits, self.features, action_scale, jacobians, goal)

    # -- checks ----------------------------------------------------------------------------
    @property
    def task(self) -> str:
        """The task the policy was trained on."""
        return str(self.metadata["task"])

    def check_compatible(self, task: str, layout: ObservationLayout, robot: str, source: str = "policy file") -> None:
        """Refuse to drive an env of another task, robot or observation layout.

        Raises:
            PolicyFileError: Naming what differs and what to do.
        """
        trained_task = self.metadata.get("task")
        if trained_task != task:
            raise PolicyFileError(
                f"{source} was trained for task {trained_task!r} but the env's task is {task!r}; "
                f"use the {task} policy (the default model_path) or train one with "
                f"`snac-gym train-ppo --task {task} --out DIR`"
            )
        trained_layout = self.metadata.get("layout", {})
        expected = {"n_joints": layout.n_joints, "task_dim": layout.task_dim, "size": layout.size}
        if trained_layout != expected:
            raise PolicyFileError(
                f"{source} was trained for the observation layout {trained_layout} but the env has {expected}; "
                "a PPO policy only runs on the observation it was trained on"
            )
        trained_robot = self.metadata.get("robot")
        if trained_robot != robot:
            raise PolicyFileError(f"{source} was trained on robot {trained_robot!r} but the env's robot is {robot!r}")

    # -- reading and writing ---------------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays of the file (what the checksum covers)."""
        arrays: dict[str, np.ndarray] = {}
        for i, (weight, bias) in enumerate(self.hidden):
            arrays[f"pi_weight_{i}"] = weight
            arrays[f"pi_bias_{i}"] = bias
        arrays["action_weight"], arrays["action_bias"] = self.action_layer
        if self.obs_mean is not None:
            arrays["obs_mean"] = self.obs_mean
            arrays["obs_var"] = cast(np.ndarray, self.obs_var)  # given with the mean
        return arrays

    def save(self, path: str | Path) -> Path:
        """Write the policy file (the metadata's checksum is recomputed)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = self.arrays()
        metadata = dict(self.metadata)
        metadata.update(
            format=FORMAT_NAME,
            format_version=FORMAT_VERSION,
            activation=self.activation,
            obs_epsilon=self.obs_epsilon,
            obs_clip=self.obs_clip,
            features=self.features.to_dict(),
            hidden_layers=len(self.hidden),
            normalize_obs=self.obs_mean is not None,
            checksum=_checksum(arrays),
        )
        buffer = io.BytesIO()
        # numpy's stub lets a ** dict fill allow_pickle (a bool): every key here is an array's name
        np.savez_compressed(buffer, metadata=np.array(json.dumps(metadata, sort_keys=True)), **arrays)  # type: ignore[arg-type]
        return write_whole(path, lambda partial: partial.write_bytes(buffer.getvalue()))  # never half a file

    @classmethod
    def load(cls, path: str | Path) -> "PolicyFile":
        """Read and check a policy file.

        Raises:
            MissingPolicyFileError: If ``path`` does not exist.
            PolicyFileError: If it is a folder, device or pipe, not a readable policy file of this format, or its arrays
                do not match their checksum (a damaged file).
        """
        path = Path(path)
        if path.exists() and not path.is_file():  # np.load of /dev/zero or a pipe would read for ever
            what = "a folder" if path.is_dir() else "a device, pipe or socket"
            raise PolicyFileError(f"PPO policy file {path} is {what}, not a policy file (.npz)")
        if not path.is_file():
            raise MissingPolicyFileError(
                f"PPO policy file {path} does not exist; train one with `snac-gym train-ppo` "
                "or reinstall snac-gym to restore the shipped ones"
            )
        try:
            with np.load(path, allow_pickle=False) as data:
                contents = {name: data[name] for name in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
            raise PolicyFileError(
                f"PPO policy file {path} is corrupt or not a policy file ({type(exc).__name__}: {exc})"
            ) from exc
        if "metadata" not in contents:
            raise PolicyFileError(f"PPO policy file {path} is not a {FORMAT_NAME} file: it has no metadata")
        try:
            metadata = json.loads(str(contents.pop("metadata")))
        except json.JSONDecodeError as exc:
            raise PolicyFileError(f"PPO policy file {path} is corrupt: its metadata is not JSON ({exc})") from exc
        if not isinstance(metadata, dict) or metadata.get("format") != FORMAT_NAME:
            raise PolicyFileError(f"{path} is not a {FORMAT_NAME} file")
        if metadata.get("format_version") != FORMAT_VERSION:
            raise PolicyFileError(
                f"{path} has format version {metadata.get('format_version')}; "
                f"this snac-gym reads version {FORMAT_VERSION}"
            )
        if metadata.get("checksum") != _checksum(contents):
            raise PolicyFileError(f"PPO policy file {path} is corrupt: its arrays do not match their checksum")
        try:
            features = FeatureSpec.from_dict(metadata["features"])
            n_hidden = int(metadata["hidden_layers"])
            hidden = tuple((contents[f"pi_weight_{i}"], contents[f"pi_bias_{i}"]) for i in range(n_hidden))
            action_layer = (contents["action_weight"], contents["action_bias"])
            normalised = bool(metadata["normalize_obs"])
            policy = cls(
                hidden=hidden,
                action_layer=action_layer,
                activation=str(metadata["activation"]),
                obs_mean=contents["obs_mean"] if normalised else None,
                obs_var=contents["obs_var"] if normalised else None,
                obs_epsilon=float(metadata["obs_epsilon"]),
                obs_clip=float(metadata["obs_clip"]),
                features=features,
                metadata=metadata,
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PolicyFileError(f"PPO policy file {path} is incomplete or inconsistent: {exc}") from exc
        policy.validate(str(path))
        return policy

    def check_card(self, path: str | Path) -> None:
        """Check the model card ``<stem>.json`` beside the policy file at ``path``, if there is one.

        The card (shipped beside ``models/<task>.npz``) says how the file was made; a card that
        describes another file would mislead a reader of results, so its ``file``, ``bytes``,
        ``sha256`` and ``task`` must match the policy file.

        Raises:
            PolicyFileError: If the card is unreadable or does not describe this file.
        """
        path = Path(path)
        card_path = path.with_suffix(".json")
        if not card_path.is_file():
            return
        card = read_json_object(card_path)
        if isinstance(card, str):
            raise PolicyFileError(f"PPO model card {card_path} is unreadable ({card}); fix or remove it")
        data = path.read_bytes()
        actual = {
            "file": path.name,
            "bytes": len(data),
            "sha256": hashlib.sha256(data).hexdigest(),
            "task": self.task,
        }
        wrong = [
            f"{key} {card.get(key)!r}, the file's {value!r}" for key, value in actual.items() if card.get(key) != value
        ]
        if wrong:
            raise PolicyFileError(
                f"PPO model card {card_path} does not describe {path.name}: {'; '.join(wrong)}; fix or remove the card"
            )

    def validate(self, source: str = "policy file") -> None:
        """Check the shapes chain from the features to the action.

        Raises:
            PolicyFileError: If they do not.
        """
        if self.activation not in ACTIVATIONS:
            raise PolicyFileError(f"{source}: unknown activation {self.activation!r}")
        layout = self.metadata.get("layout", {})
        try:
            observation_layout = ObservationLayout(int(layout["n_joints"]), int(layout["task_dim"]))
            width = feature_size(observation_layout, self.features)
            outputs = action_size(observation_layout, self.features)
        except (KeyError, TypeError, ValueError) as exc:
            raise PolicyFileError(f"{source}: metadata has no valid observation layout ({layout!r})") from exc
        # the variance is given with the mean
        if self.obs_mean is not None and (
            self.obs_mean.shape != (width,) or cast(np.ndarray, self.obs_var).shape != (width,)
        ):
            raise PolicyFileError(f"{source}: normalisation statistics have the wrong shape for {width} features")
        for i, (weight, bias) in enumerate((*self.hidden, self.action_layer)):
            if weight.ndim != 2 or weight.shape[1] != width or bias.shape != (weight.shape[0],):
                raise PolicyFileError(
                    f"{source}: layer {i} has shape {weight.shape}/{bias.shape}, expected (*, {width})"
                )
            width = weight.shape[0]
        if width != outputs:
            raise PolicyFileError(
                f"{source}: the network outputs {width} actions where a {self.features.action} policy has {outputs}"
            )


def export_policy(model: Any, vec_normalize: Any, metadata: dict[str, Any], features: FeatureSpec) -> PolicyFile:
    """Freeze a trained SB3 PPO ``MlpPolicy`` (and its ``VecNormalize``) into a :class:`PolicyFile`.

    Args:
        model: A ``stable_baselines3.PPO`` with an ``MlpPolicy`` (separate or shared
            ``Linear`` + activation layers and a Gaussian ``action_net``).
        vec_normalize: The training ``VecNormalize`` (its current statistics are copied), or
            ``None`` if the observations were not normalised.
        metadata: Task, robot, layout and provenance to store (see the module docstring).
        features: The feature spec the model was trained with.

    Raises:
        ValueError: If the network is not a plain MLP this exporter understands.
    """
    import torch  # the rl extra; the exported file is read without torch

    policy = model.policy
    hidden: list[tuple[np.ndarray, np.ndarray]] = []
    activation = None
    for module in policy.mlp_extractor.policy_net:
        if isinstance(module, torch.nn.Linear):
            hidden.append(
                (
                    module.weight.detach().cpu().numpy().astype(np.float32).copy(),
                    module.bias.detach().cpu().numpy().astype(np.float32).copy(),
                )
            )
        elif isinstance(module, torch.nn.Tanh):
            activation = "tanh"
        elif isinstance(module, torch.nn.ReLU):
            activation = "relu"
        else:
            raise ValueError(f"cannot export a policy network with a {type(module).__name__} layer")
    if not isinstance(policy.action_net, torch.nn.Linear):
        raise ValueError("cannot export a policy whose action_net is not one Linear layer")
    features_extractor = getattr(policy, "pi_features_extractor", policy.features_extractor)
    if type(features_extractor).__name__ != "FlattenExtractor":
        raise ValueError(f"cannot export a policy with a {type(features_extractor).__name__}")
    action_layer = (
        policy.action_net.weight.detach().cpu().numpy().astype(np.float32).copy(),
        policy.action_net.bias.detach().cpu().numpy().astype(np.float32).copy(),
    )
    normalise = vec_normalize is not None and bool(getattr(vec_normalize, "norm_obs", False))
    exported = PolicyFile(
        hidden=tuple(hidden),
        action_layer=action_layer,
        activation=activation or "tanh",
        obs_mean=np.array(vec_normalize.obs_rms.mean, dtype=np.float64) if normalise else None,
        obs_var=np.array(vec_normalize.obs_rms.var, dtype=np.float64) if normalise else None,
        obs_epsilon=float(vec_normalize.epsilon) if normalise else 1e-8,
        obs_clip=float(vec_normalize.clip_obs) if normalise else float("inf"),
        features=features,
        metadata=dict(metadata),
    )
    exported.validate("exported policy")
    return exported
