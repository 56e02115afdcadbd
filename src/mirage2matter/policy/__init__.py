"""Visuomotor behaviour-cloning policies trained on our LeRobot datasets (issue 16, part 3).

Plain torch, not the ``lerobot`` package: LeRobot 0.6 needs Python >= 3.12 (this stack is pinned to 3.11 by
Genesis and pycolmap), torch < 2.12 and numpy < 2.3, and it cannot be installed here. Its ACT / Diffusion
Policy also assume pretrained ImageNet ResNets, and nothing can be downloaded here. Our datasets stay
LeRobot datasets: a user with LeRobot trains on them there and plugs the result back in through
:func:`load_policy_callable` (``"module:function"``, obs -> action).

- :func:`load_episodes` reads datasets into memory (:mod:`.data`);
- :func:`train_policy` trains :class:`~.model.VisuomotorPolicy` with :class:`PolicyTrainConfig` (:mod:`.train`);
- :func:`load_policy` opens the result as a :class:`Policy`, ``obs -> action`` (:mod:`.infer`).

Speed on this 2-core CPU (torch 2.13, 2 threads, machine otherwise quiet), defaults (96 px, batch 64, two
cameras, K = 10): 4.3-4.8 training steps/s = 280-310 samples/s, augmentation included; reading a dataset
costs ~5 ms per frame (both cameras decoded and resized). 300 episodes x 40 frames therefore load in about a
minute and see ~29 epochs in the default 20-minute budget. On grasp_banana (3 episodes) 300 steps take the
L1 of normalised action chunks from 0.81 to 0.05.
"""

from ..lazy import lazy_names
from .config import AugmentConfig, PolicyTrainConfig
from .data import (
    DatasetMeta,
    Demonstrations,
    PolicyError,
    chunk_indices,
    dataset_meta,
    load_episodes,
    normalization_stats,
)

# The torch-backed names are imported on first use: the command line and the stages read the configs above
# without loading torch.
_LAZY = {
    "CallablePolicy": "infer", "ChunkedPolicy": "infer", "Policy": "infer", "PolicyEnsemble": "infer",
    "load_ensemble": "infer", "load_policy": "infer", "load_policy_callable": "infer",
    "open_policies": "infer", "open_policy": "infer", "ModelSpec": "model", "VisuomotorPolicy": "model",
    "PolicyTrainer": "train", "train_policy": "train",
}  # fmt: skip

__getattr__ = lazy_names(__name__, _LAZY)

__all__ = [
    "AugmentConfig",
    "CallablePolicy",
    "ChunkedPolicy",
    "DatasetMeta",
    "Demonstrations",
    "ModelSpec",
    "Policy",
    "PolicyEnsemble",
    "PolicyError",
    "PolicyTrainConfig",
    "PolicyTrainer",
    "VisuomotorPolicy",
    "chunk_indices",
    "dataset_meta",
    "load_ensemble",
    "load_episodes",
    "load_policy",
    "load_policy_callable",
    "normalization_stats",
    "open_policies",
    "open_policy",
    "train_policy",
]
