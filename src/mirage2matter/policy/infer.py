"""Deploying a policy: ``load_policy(dir) -> Policy``, a callable ``obs -> action [A]``; ``load_ensemble(dirs) ->
PolicyEnsemble``, several trained policies whose chunks are combined (averaged, or their medoid); and user
callables.

Observations have exactly the keys of our datasets: ``observation.images.<camera>`` (uint8 [H, W, 3], any
size: the camera's whole image, cropped inside about its centre to the training frames' aspect and resized with the
training's area filter) and ``observation.state`` (float [S]). The network
predicts K actions per observation; a :class:`ChunkedPolicy` either runs it every step and averages all predictions
made for the current step (ACT's temporal ensembling: weights exp(-m i), i = 0 the oldest, so the executed
trajectory stays smooth while each new observation still pulls it), or re-plans every n steps and executes
the chunk open-loop in between. ``reset()`` between episodes.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .data import IMAGE_PREFIX, STATE_KEY, DatasetMeta, PolicyError, camera_frame, resize_area
from .model import ModelSpec, VisuomotorPolicy
from .train import CHECKPOINT_FILE, CHECKPOINT_FORMAT, POLICY_FILE, resolve_device

__all__ = [
    "CallablePolicy",
    "ChunkedPolicy",
    "Policy",
    "PolicyEnsemble",
    "load_ensemble",
    "load_policy",
    "load_policy_callable",
    "open_policies",
    "medoid",
    "open_policy",
]

ENSEMBLE_COMBINES = ("mean", "medoid")


class ChunkedPolicy:
    """``policy(obs) -> action`` float32 [A] (unnormalised, the dataset's units) from K-step action chunks that
    :meth:`predict_chunk` makes (a subclass's); how the chunks are executed:

    replan_every     None: temporal ensembling, a chunk is predicted every step; n: predict one every n steps and
                     execute its actions in between (1 <= n <= K)
    ensemble_decay   m of the ensembling weights exp(-m i); 0 averages all predictions equally
    """

    spec: ModelSpec
    meta: DatasetMeta
    source: Path

    def _set_execution(self, replan_every: int | None, ensemble_decay: float) -> None:
        if replan_every is not None and not 1 <= replan_every <= self.spec.chunk:
            raise PolicyError(f"{self.source}: replan_every must be in [1, {self.spec.chunk}] (the policy's chunk "
                              f"length), got {replan_every}")  # fmt: skip
        if ensemble_decay < 0:
            raise PolicyError(f"ensemble_decay must be >= 0, got {ensemble_decay}")
        self.replan_every = replan_every
        self.ensemble_decay = float(ensemble_decay)
        self.reset()

    @property
    def action_dim(self) -> int:
        return self.spec.action_dim

    @property
    def observation_keys(self) -> tuple[str, ...]:
        return (*[IMAGE_PREFIX + c for c in self.meta.cameras], STATE_KEY)

    def reset(self) -> None:
        """Forget the previous episode's predictions (call before each episode)."""
        self._t = 0
        self._chunks: deque[tuple[int, np.ndarray]] = deque(maxlen=self.spec.chunk)  # (step made, [K, A])

    def predict_chunk(self, obs: Mapping[str, Any]) -> np.ndarray:
        """float32 [K, A] the actions for this step and the K-1 after it (unnormalised)."""
        raise NotImplementedError

    def __call__(self, obs: Mapping[str, Any]) -> np.ndarray:
        t = self._t
        self._t += 1
        if self.replan_every is not None:
            if not self._chunks or t - self._chunks[-1][0] >= self.replan_every:
                self._chunks.append((t, self.predict_chunk(obs)))
            t0, chunk = self._chunks[-1]
            return chunk[t - t0].astype(np.float32)
        self._chunks.append((t, self.predict_chunk(obs)))
        # the chunks still covering step t, oldest first (the deque holds the last K, each covers K steps)
        preds = np.stack([c[t - t0] for t0, c in self._chunks if t - t0 < len(c)])
        w = np.exp(-self.ensemble_decay * np.arange(len(preds)))
        return ((w[:, None] * preds).sum(0) / w.sum()).astype(np.float32)


class Policy(ChunkedPolicy):
    """A policy that :func:`train_policy` wrote: its network, the robot it was trained for and its statistics."""

    def __init__(
        self,
        model: VisuomotorPolicy,
        meta: DatasetMeta,
        stats: Mapping[str, np.ndarray],
        source: Path,
        device: torch.device,
        replan_every: int | None = None,
        ensemble_decay: float = 0.1,
        frame_sizes: Mapping[str, Sequence[int] | None] | None = None,
    ) -> None:
        self.model = model.eval()
        # the training frames' (width, height) per camera: a live image is cropped to their aspect first (None: a
        # policy saved before they were recorded, or trained on frames of several shapes: the image is squashed)
        self.frame_sizes = {c: tuple(s) if s else None for c, s in (frame_sizes or {}).items()}
        self.spec = model.spec
        self.meta = meta
        self.source = source
        self.device = device
        f = lambda k: np.asarray(stats[k], np.float32)
        self._s_mean, self._s_std = f("state_mean"), f("state_std")
        self._a_mean, self._a_std = f("action_mean"), f("action_std")
        self._set_execution(replan_every, ensemble_decay)

    @property
    def action_std(self) -> np.ndarray:
        """float32 [A]: the training data's per-entry action spread (the unit of the training loss)."""
        return self._a_std

    def check_matches(
        self,
        robot_type: str | None = None,
        state_names: Sequence[str] | None = None,
        action_names: Sequence[str] | None = None,
        fps: int | None = None,
        cameras: Sequence[str] | None = None,
    ) -> None:
        """Raise PolicyError naming the checkpoint when it was trained for another robot, rate or cameras."""
        m = self.meta
        bad = []
        if robot_type is not None and m.robot_type is not None and robot_type != m.robot_type:
            bad.append(f"robot_type {m.robot_type!r}, not {robot_type!r}")
        if state_names is not None and tuple(state_names) != m.state_names:
            bad.append(f"observation.state {len(m.state_names)} {list(m.state_names)}, not "
                       f"{len(state_names)} {list(state_names)}")  # fmt: skip
        if action_names is not None and tuple(action_names) != m.action_names:
            bad.append(f"action {len(m.action_names)} {list(m.action_names)}, not "
                       f"{len(action_names)} {list(action_names)}")  # fmt: skip
        if fps is not None and int(fps) != m.fps:
            bad.append(f"{m.fps} Hz, not {fps} Hz")
        if cameras is not None and (missing := [c for c in m.cameras if c not in cameras]):
            bad.append(f"camera(s) {missing} the robot does not have (it has {list(cameras)})")
        if bad:
            raise PolicyError(f"{self.source}: this policy was trained for " + "; ".join(bad)
                              + ". Train one on datasets of this robot (m2m generate, then train-policy)")  # fmt: skip

    # -- observations -> network inputs
    def _inputs(self, obs: Mapping[str, Any]) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        if not isinstance(obs, Mapping):
            raise PolicyError(f"an observation must be a dict with keys {list(self.observation_keys)}, got "
                              f"{type(obs).__name__}")  # fmt: skip
        missing = [k for k in self.observation_keys if k not in obs]
        if missing:
            raise PolicyError(f"the observation lacks {missing} (it has {sorted(obs)}); {self.source} needs "
                              f"{list(self.observation_keys)}")  # fmt: skip
        s = self.spec.image_size
        images = {}
        for cam in self.meta.cameras:
            im = np.asarray(obs[IMAGE_PREFIX + cam])
            if im.ndim != 3 or im.shape[2] != 3 or im.dtype != np.uint8:
                raise PolicyError(f"{IMAGE_PREFIX + cam} must be uint8 [H, W, 3], got {im.dtype} {list(im.shape)}")
            im = camera_frame(im, self.frame_sizes.get(cam))
            x = torch.from_numpy(resize_area(im, s).transpose(2, 0, 1).copy()).float().div_(255.0)
            images[cam] = x[None].to(self.device).contiguous(memory_format=torch.channels_last)
        state = np.asarray(obs[STATE_KEY], np.float32).reshape(-1)
        if state.shape[0] != self.spec.state_dim or not np.isfinite(state).all():
            raise PolicyError(f"{STATE_KEY} must be {self.spec.state_dim} finite numbers "
                              f"({list(self.meta.state_names)}), got {np.asarray(obs[STATE_KEY]).shape}")  # fmt: skip
        st = torch.from_numpy((state - self._s_mean) / self._s_std)[None].to(self.device)
        return images, st

    @torch.no_grad()
    def predict_chunk(self, obs: Mapping[str, Any]) -> np.ndarray:
        """float32 [K, A] the actions for this step and the K-1 after it (unnormalised)."""
        images, state = self._inputs(obs)
        out = self.model(images, state)[0].float().cpu().numpy()
        return out * self._a_std + self._a_mean

class PolicyEnsemble(ChunkedPolicy):
    """Several policies trained for the same robot, rate, cameras and chunk length (e.g. the same recipe from
    different seeds), run as one: at each prediction the members' chunks (unnormalised) are combined into one, which
    is executed as one policy's. Seeds of one recipe disagree most where each is unsure; the combination is steadier
    than any one of them (measured on the sample: see the README's closed-loop section).

    combine   "mean": the members' chunks averaged; "medoid": the one member's chunk nearest all the others (sum of
              distances in action-std units; three members or more). The mean of two 7-joint arm motions that
              reach one place on different arm branches, or two grasps either side of an object, reaches neither;
              the medoid is always one member's own motion, the one the others agree with most.
    """

    def __init__(self, members: Sequence[Policy], replan_every: int | None = None,
                 ensemble_decay: float = 0.1, combine: str = "mean") -> None:  # fmt: skip
        if len(members) < 2:
            raise PolicyError(f"an ensemble needs two or more policies, got {len(members)}")
        if combine not in ENSEMBLE_COMBINES:
            raise PolicyError(f"ensemble combine must be one of {', '.join(ENSEMBLE_COMBINES)}, got {combine!r}")
        if combine == "medoid" and len(members) < 3:
            raise PolicyError(f"a medoid ensemble needs three or more policies (of two, neither is nearer the "
                              f"other), got {len(members)}; use mean, or add a member")  # fmt: skip
        self.combine = combine
        first = members[0]
        for m in members[1:]:
            differs = [name for name, a, b in (("robot", first.meta.robot_type, m.meta.robot_type),
                                               ("state", first.meta.state_names, m.meta.state_names),
                                               ("action", first.meta.action_names, m.meta.action_names),
                                               ("rate", first.meta.fps, m.meta.fps),
                                               ("cameras", first.meta.cameras, m.meta.cameras),
                                               ("chunk length", first.spec.chunk, m.spec.chunk)) if a != b]  # fmt: skip
            if differs:
                raise PolicyError(f"{m.source} cannot join an ensemble with {first.source}: its "
                                  f"{', '.join(differs)} differ; ensemble policies trained on the same robot's "
                                  "datasets with the same --chunk")  # fmt: skip
        self.members = list(members)
        self.spec, self.meta = first.spec, first.meta
        self.source = first.source
        self._set_execution(replan_every, ensemble_decay)

    @property
    def action_std(self) -> np.ndarray:
        """float32 [A]: the first member's training-data action spread (the unit its loss and errors are in)."""
        return self.members[0].action_std

    def check_matches(self, *args: Any, **kwargs: Any) -> None:
        for m in self.members:
            m.check_matches(*args, **kwargs)

    def predict_chunk(self, obs: Mapping[str, Any]) -> np.ndarray:
        chunks = np.stack([m.predict_chunk(obs) for m in self.members])  # [M, K, A]
        if self.combine == "mean":
            return chunks.mean(0).astype(np.float32)
        return chunks[medoid(chunks / self.action_std)].astype(np.float32)


def medoid(chunks: np.ndarray) -> int:
    """Index of the member of ``chunks`` [M, K, A] with the least summed Euclidean distance to the others (over all
    K x A values; the first of equals)."""
    flat = chunks.reshape(len(chunks), -1).astype(np.float64)
    d = np.linalg.norm(flat[:, None] - flat[None], axis=-1)  # [M, M]
    return int(np.argmin(d.sum(1)))


def _checkpoint_file(path: Path) -> Path:
    if path.is_dir():
        for name in (POLICY_FILE, CHECKPOINT_FILE):
            if (path / name).is_file():
                return path / name
        raise PolicyError(f"{path} holds no {POLICY_FILE}: train a policy into it first (m2m train-policy "
                          "--out-dir ...) or pass the folder that train-policy wrote")  # fmt: skip
    if not path.is_file():
        raise PolicyError(f"policy checkpoint {path} not found: pass the folder that m2m train-policy wrote")
    return path


def load_policy(
    checkpoint_dir: str | Path,
    device: str = "auto",
    replan_every: int | None = None,
    ensemble_decay: float | None = None,
    robot_type: str | None = None,
    state_names: Sequence[str] | None = None,
    action_names: Sequence[str] | None = None,
    fps: int | None = None,
    cameras: Sequence[str] | None = None,
) -> Policy:
    """Open a policy that :func:`train_policy` wrote (its folder, or the ``policy.pt`` in it; a run still
    training gives its last ``checkpoint.pt`` weights via ``policy.pt`` only once finished). The robot
    arguments, when given, must match what it was trained on (else PolicyError naming the file)."""
    path = _checkpoint_file(Path(checkpoint_dir))
    hint = "re-train it (m2m train-policy) or pass the folder that m2m train-policy wrote"
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise PolicyError(f"{path} does not load as a policy checkpoint ({type(e).__name__}: "
                          f"{str(e).splitlines()[0] if str(e) else ''}); {hint}") from None  # fmt: skip
    if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
        got = blob.get("format") if isinstance(blob, dict) else type(blob).__name__
        raise PolicyError(f"{path} is not a {CHECKPOINT_FORMAT} checkpoint (format {got!r}); {hint}. "
                          "A LeRobot checkpoint runs through load_policy_callable('module:function')")  # fmt: skip
    if "weights" not in blob:
        raise PolicyError(f"{path} is a training checkpoint of an unfinished run (no deployable weights yet): "
                          f"run m2m train-policy again to finish it, then load {POLICY_FILE}")  # fmt: skip
    try:
        meta = DatasetMeta.from_json(blob["meta"])
        spec = ModelSpec.from_json(blob["spec"])
        stats = {k: v.numpy() for k, v in blob["stats"].items()}
        model = VisuomotorPolicy(spec)
        model.load_state_dict(blob["weights"])
    except Exception as e:
        raise PolicyError(f"{path}: the checkpoint's contents do not fit its model ({type(e).__name__}: "
                          f"{str(e).splitlines()[0] if str(e) else ''}); {hint}") from None  # fmt: skip
    if len(meta.state_names) != spec.state_dim or len(meta.action_names) != spec.action_dim:
        raise PolicyError(f"{path}: state/action names do not match the network's sizes; {hint}")
    dev = resolve_device(device)
    model = model.to(dev).to(memory_format=torch.channels_last)
    if ensemble_decay is None:
        ensemble_decay = float(blob.get("inference", {}).get("ensemble_decay", 0.1))
    policy = Policy(model, meta, stats, path, dev, replan_every, ensemble_decay, blob.get("frame_sizes"))
    policy.check_matches(robot_type, state_names, action_names, fps, cameras)
    return policy


def load_ensemble(checkpoint_dirs: Sequence[str | Path], device: str = "auto", replan_every: int | None = None,
                  ensemble_decay: float | None = None, combine: str = "mean", **robot: Any) -> PolicyEnsemble:
    """Open several policies as one :class:`PolicyEnsemble` (each as :func:`load_policy` opens it; the robot
    arguments are checked against every member). ``ensemble_decay`` defaults to the first member's."""
    members = [load_policy(d, device=device, ensemble_decay=ensemble_decay, **robot) for d in checkpoint_dirs]
    decay = members[0].ensemble_decay if members else 0.1
    return PolicyEnsemble(members, replan_every=replan_every, ensemble_decay=decay, combine=combine)


class CallablePolicy:
    """A user's ``obs -> action`` callable behind the same interface (``reset()`` is passed on when it has one);
    each action is checked: finite, and ``action_dim`` long when that is known."""

    def __init__(self, fn: Callable[[Mapping[str, Any]], Any], name: str, action_dim: int | None = None) -> None:
        self.fn, self.name, self.action_dim = fn, name, action_dim

    def reset(self) -> None:
        reset = getattr(self.fn, "reset", None)
        if callable(reset):
            reset()

    def __call__(self, obs: Mapping[str, Any]) -> np.ndarray:
        out = self.fn(obs)
        if isinstance(out, torch.Tensor):
            out = out.detach().cpu().numpy()
        a = np.asarray(out, np.float32).reshape(-1)
        if self.action_dim is not None and a.shape[0] != self.action_dim:
            raise PolicyError(f"policy {self.name} returned {a.shape[0]} action values; the robot takes "
                              f"{self.action_dim}: make it return the dataset's action vector")  # fmt: skip
        if not np.isfinite(a).all():
            raise PolicyError(f"policy {self.name} returned NaN/Inf in its action")
        return a


def load_policy_callable(ref: str, action_dim: int | None = None) -> CallablePolicy:
    """``"package.module:function"`` (or ``"path/to/file.py:function"``) -> that ``obs -> action`` callable,
    wrapped. Use it for policies we did not train, e.g. a LeRobot checkpoint behind a few lines of your own."""
    mod_name, sep, attr = ref.rpartition(":")
    if not sep or not mod_name or not attr:
        raise PolicyError(f"policy {ref!r}: expected 'module:function' (e.g. my_pkg.policies:act_policy)")
    try:
        if mod_name.endswith(".py"):
            file = Path(mod_name)
            if not file.is_file():
                raise PolicyError(f"policy {ref!r}: {file} not found")
            spec = importlib.util.spec_from_file_location(f"_m2m_user_policy_{file.stem}", file)
            assert spec is not None and spec.loader is not None
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(mod_name)
    except PolicyError:
        raise
    except Exception as e:
        raise PolicyError(f"policy {ref!r}: importing {mod_name} failed ({type(e).__name__}: {e}); check the "
                          "name and that it is importable (on PYTHONPATH)") from None  # fmt: skip
    fn = module
    for part in attr.split("."):
        fn = getattr(fn, part, None)
        if fn is None:
            raise PolicyError(f"policy {ref!r}: {mod_name} has no attribute {attr!r}")
    if not callable(fn):
        raise PolicyError(f"policy {ref!r}: {attr} is not callable; it must take an observation dict and "
                          "return an action")  # fmt: skip
    return CallablePolicy(fn, ref, action_dim)


def open_policies(checkpoint_dirs: Sequence[str | Path], device: str = "cpu") -> Policy | PolicyEnsemble:
    """One trained policy, or several as one ensemble (a generation's takeover, ``datagen.config.Takeover``)."""
    if len(checkpoint_dirs) == 1:
        return load_policy(checkpoint_dirs[0], device=device)
    return load_ensemble(checkpoint_dirs, device=device)


def open_policy(ref: str | Path, **kwargs: Any) -> Policy | CallablePolicy:
    """A trained policy's folder or file, or a ``module:function`` callable (anything with a ':' that is not
    an existing path). ``kwargs`` go to :func:`load_policy` (robot checks, device, execution), and
    ``action_dim`` to a callable's output check."""
    if ":" in str(ref) and not Path(ref).exists():
        return load_policy_callable(str(ref), kwargs.get("action_dim"))
    kwargs.pop("action_dim", None)
    return load_policy(ref, **kwargs)
