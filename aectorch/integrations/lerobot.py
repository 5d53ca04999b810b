"""LeRobot datasets: record aectorch trials with LeRobot's own API, and read stereo video back.

Needs the extra ``aectorch[lerobot]`` (LeRobot >= 0.4). On Python 3.11 LeRobot is at most 0.4.4,
which pins torch < 2.11, so it lives in its own virtual environment (``.venv-lerobot``, made by
``scripts/setup_lerobot.sh``); ``lerobot`` is imported only when these functions run.

**Recording** (`LeRobotRecorder`, `record_trials`, ``python -m aectorch.record``): one episode
per fixation (``env.fixation_iterations`` frames, 30 by default), so a trial is two episodes.
Frame t of an episode is iteration t of that fixation, taken when the recorded cue (by default
the learner's last: stereo, step k2, after the pursuit movement and before the vergence
movement) observes; its image pair is the two cameras (`aectorch.sim.Movement.images`):

==============================  =========  ======================================================
key                             shape      content
==============================  =========  ======================================================
``observation.images.left``     H x W x 3  left eye, uint8 (the grey image in all 3 channels)
``observation.images.right``    H x W x 3  right eye
``observation.state``           5          body shift (m), left pan, right pan, left roll,
                                           right roll (degrees)
``action``                      C          the iteration's increments of the C learned cues'
                                           movements (deg; pursuit, vergence)
``reward``                      C          the coding rewards R of the cues (parallax, stereo)
``distance_m``                  1          the true distance of the plane (the supervisor)
``trial_index``, ``fixation``   1, 1       which trial of the recording, and 0 (leftward shift)
                                           or 1 (rightward)
==============================  =========  ======================================================

The task string says which fixation it is. Images are stored as images (``use_videos=False``),
so no video codec is needed to write or read them.

**Reading** (`StereoFrames`, `stereo_batches`): any LeRobotDataset with two camera streams
becomes batches of grey ``(left, right)`` images ``[B, H, W]`` in [0, 1], what
`BinocularEncoder` takes, e.g. to pre-train or evaluate dictionaries on real robot video
(`pretrain_encoder`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from aectorch._checks import check_int, is_int
from aectorch.sim import WINDOW

__all__ = [
    "FEATURES_STATE",
    "LeRobotRecorder",
    "StereoFrames",
    "features",
    "pretrain_encoder",
    "record_trials",
    "stereo_batches",
]

#: Names of ``observation.state``'s entries.
FEATURES_STATE = ("body_shift_m", "left_pan_deg", "right_pan_deg", "left_roll_deg", "right_roll_deg")
_TASKS = ("fixate the textured plane after a leftward body shift",
          "fixate the textured plane after a rightward body shift")


def _lerobot():
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset
    except ImportError as err:
        raise ImportError(
            "aectorch.integrations.lerobot needs LeRobot: `pip install aectorch[lerobot]` in its own "
            "virtual environment (LeRobot 0.4.4 pins torch < 2.11), e.g. `bash scripts/setup_lerobot.sh` "
            "for .venv-lerobot") from err
    return LeRobotDataset


def features(height: int, width: int, cues: dict[str, str] | None = None,
             cameras: tuple[str, str] = ("left", "right")) -> dict:
    """The LeRobot ``features`` of an aectorch recording with ``height x width`` images of the two
    ``cameras`` and the learned ``cues`` (``{cue: the movement it drives}``; default the paper's
    two, `ActiveDepthEnv.CUES`)."""
    from aectorch.sim import ActiveDepthEnv

    cues = {name: movement.name for name, movement in ActiveDepthEnv.CUES.items()} if cues is None else cues
    image = {"dtype": "image", "shape": (height, width, 3), "names": ["height", "width", "channel"]}
    return {
        **{f"observation.images.{camera}": dict(image) for camera in cameras},
        "observation.state": {"dtype": "float32", "shape": (5,), "names": list(FEATURES_STATE)},
        "action": {"dtype": "float32", "shape": (len(cues),), "names": [f"{m}_increment_deg" for m in cues.values()]},
        "reward": {"dtype": "float32", "shape": (len(cues),), "names": list(cues)},
        "distance_m": {"dtype": "float32", "shape": (1,), "names": ["distance_m"]},
        "trial_index": {"dtype": "int64", "shape": (1,), "names": None},
        "fixation": {"dtype": "int64", "shape": (1,), "names": None},
    }


def _uint8_rgb(image: torch.Tensor) -> np.ndarray:
    grey = (image.detach().float().clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()
    return np.repeat(grey[..., None], 3, axis=-1)


class LeRobotRecorder:
    """Writes the fixations of some of an environment's B heads into a new LeRobotDataset.

    Give `watch` to the learner's iterations (``learner.iteration(env, watch=recorder.watch)``),
    and call `after_iteration` with each `IterationRecord`; every finished fixation of a recorded
    environment becomes an episode
    (`LeRobotDataset.add_frame` per iteration, `save_episode` at the fixation's end). Call
    `close` at the end (LeRobot's ``finalize``); fixations cut short are not saved.

    Args:
        root: the dataset folder (must not exist yet).
        env: the `ActiveDepthEnv` (its image size sizes the features).
        envs: how many of the B environments to record (the first ones; >= 1).
        cues: the learner's cues (default: all of the environment's, in its order); their
            increments and rewards are the actions and rewards.
        camera_cue: the cue whose observation gives the frame and its two cameras (default: the
            last of ``cues``: the stereo pair).
        repo_id: the dataset's name for LeRobot (``owner/name``).
        fps: the frame rate written into the metadata (the simulation has no clock; nominal).
    """

    def __init__(self, root: str | Path, env, *, envs: int = 1, repo_id: str = "aectorch/hoap3-sim",
                 fps: int = 10, cues=None, camera_cue: str | None = None) -> None:
        LeRobotDataset = _lerobot()
        root = Path(root)
        if root.exists():
            raise ValueError(f"the recording folder {str(root)!r} exists already; give a new one")
        if not (is_int(envs) and 1 <= envs <= env.num_envs):
            raise ValueError(f"envs must be an int in [1, num_envs={env.num_envs}], got {envs!r}")
        self.cues = [c for c in env.CUES if cues is None or c in cues]
        self.camera_cue = self.cues[-1] if camera_cue is None else camera_cue
        self.cameras = env.cue(self.camera_cue).images
        self.env, self.envs = env, envs
        h, w = env.window.height, env.window.width
        movements = {c: env.cue(c).name for c in self.cues}
        self.dataset = LeRobotDataset.create(repo_id, fps, features(h, w, movements, self.cameras), root=root,
                                             robot_type="hoap3-sim", use_videos=False)
        self._frames: list[list[dict]] = [[] for _ in range(envs)]
        self._trial_of = list(range(envs))  # each recorded environment's current trial number
        self._next_trial = envs
        self.episodes = 0
        self._seen: dict | None = None  # what the camera cue observed this iteration

    def watch(self, cue: str, observation: dict) -> None:
        """`JointLearner.iteration`'s ``watch``: keeps the camera cue's images and the state then."""
        if cue != self.camera_cue:
            return
        env = self.env
        self._seen = {
            "images": observation[WINDOW].detach(),
            "state": torch.cat((env.body_shift_m[:, None], env.pan_deg, env.roll_deg), dim=1).detach().clone(),
            "distance_m": env.distance_m.detach().clone(), "fixation": env.fixation, "iteration": env.iteration,
        }

    def after_iteration(self, record) -> None:
        """Add this iteration's frames; save the episodes of fixations that ended."""
        seen = self._seen
        if seen is None:
            raise RuntimeError("LeRobotRecorder.after_iteration: run the learner's iteration with "
                               "watch=recorder.watch first")
        self._seen = None
        action = torch.stack([record.cues[c].increments_deg for c in self.cues], dim=1)
        reward = torch.stack([record.cues[c].reward for c in self.cues], dim=1)
        fixation = int(seen["fixation"])
        # Episodes are whole fixations: a recording started mid-fixation (a resumed run) waits.
        recording = bool(self._frames[0]) or seen["iteration"] == 0
        images = seen["images"]
        for b in range(self.envs if recording else 0):
            self._frames[b].append({
                **{f"observation.images.{camera}": _uint8_rgb(images[b, i]) for i, camera in enumerate(self.cameras)},
                "observation.state": seen["state"][b].float().cpu().numpy(),
                "action": action[b].float().cpu().numpy(),
                "reward": reward[b].float().cpu().numpy(),
                "distance_m": seen["distance_m"][b : b + 1].float().cpu().numpy(),
                "trial_index": np.array([self._trial_of[b]], dtype=np.int64),
                "fixation": np.array([fixation], dtype=np.int64),
                "task": _TASKS[fixation],
            })
        if record.fixation_end and recording:
            for b in range(self.envs):
                for frame in self._frames[b]:
                    self.dataset.add_frame(frame)
                self.dataset.save_episode()
                self.episodes += 1
                self._frames[b] = []
        if record.trial_end and recording:
            for b in range(self.envs):
                self._trial_of[b] = self._next_trial
                self._next_trial += 1

    def close(self) -> Path:
        """Finish the dataset (LeRobot's ``finalize``); returns its folder."""
        self.dataset.finalize()
        return Path(self.dataset.root)


def record_trials(learner, env, trials: int, root: str | Path, *, learn: bool = False, greedy: bool = True,
                  repo_id: str = "aectorch/hoap3-sim", fps: int = 10, progress: bool = True) -> Path:
    """Run ``trials`` trials of every environment of ``env`` and record them all.

    The environments start new trials (``env.reset()``); with the defaults learning is frozen and
    the policies greedy, as in `aectorch.evaluation`. ``trials`` trials of B environments give
    ``2 * trials * B`` episodes of ``env.fixation_iterations`` frames.

    Returns:
        The dataset folder.
    """
    check_int(trials, "trials")
    recorder = LeRobotRecorder(root, env, envs=env.num_envs, repo_id=repo_id, fps=fps, cues=list(learner.cues))
    env.reset()
    learner.forget_transitions()
    iterations = trials * 2 * env.fixation_iterations
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=iterations, desc="recording", unit="it")
    try:
        for _ in range(iterations):
            recorder.after_iteration(learner.iteration(env, learn=learn, greedy=greedy, watch=recorder.watch))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    if not learn:
        learner.forget_transitions()
    return recorder.close()


class StereoFrames(torch.utils.data.Dataset):
    """Grey ``(left, right)`` image pairs ``[H, W]`` in [0, 1] from a LeRobotDataset's two cameras.

    Args:
        root: the dataset folder (read with ``LeRobotDataset(repo_id, root=root)``; nothing is
            downloaded).
        left, right: the two camera keys; default: the dataset's first two camera keys in sorted
            order (``observation.images.left`` / ``right`` for aectorch's recordings).
        repo_id: the name to open it under (any string for a local dataset).
    """

    def __init__(self, root: str | Path, left: str | None = None, right: str | None = None,
                 repo_id: str = "local/stereo") -> None:
        LeRobotDataset = _lerobot()
        self.dataset = LeRobotDataset(repo_id, root=root)
        cameras = sorted(self.dataset.meta.camera_keys)
        if left is None and right is None:
            if len(cameras) < 2:
                raise ValueError(f"the dataset at {str(root)!r} has {len(cameras)} camera stream(s) {cameras}; "
                                 "two are needed")
            left, right = cameras[0], cameras[1]
        for name, key in (("left", left), ("right", right)):
            if key not in cameras:
                raise ValueError(f"{name}={key!r} is not a camera of the dataset at {str(root)!r}: {cameras}")
        self.left, self.right = left, right

    def __len__(self) -> int:
        return len(self.dataset)

    @staticmethod
    def _grey(image: torch.Tensor) -> torch.Tensor:
        image = image.float()
        if image.ndim == 3 and image.shape[0] in (1, 3):  # LeRobot gives [C, H, W] in [0, 1]
            return image.mean(0) if image.shape[0] == 3 else image[0]
        raise ValueError(f"expected a [C, H, W] image with C = 1 or 3, got shape {tuple(image.shape)}")

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        item = self.dataset[index]
        return self._grey(item[self.left]), self._grey(item[self.right])


def stereo_batches(root: str | Path, batch_size: int = 32, *, left: str | None = None, right: str | None = None,
                   shuffle: bool = True, seed: int = 0, num_workers: int = 0) -> torch.utils.data.DataLoader:
    """A DataLoader of ``(left [B, H, W], right [B, H, W])`` from a LeRobotDataset (see `StereoFrames`)."""
    frames = StereoFrames(root, left, right)
    return torch.utils.data.DataLoader(frames, batch_size=batch_size, shuffle=shuffle, num_workers=num_workers,
                                       generator=torch.Generator().manual_seed(seed), drop_last=False)


def pretrain_encoder(encoder, batches, steps: int | None = None) -> list[float]:
    """Dictionary learning of a `BinocularEncoder` on stereo batches (e.g. `stereo_batches`).

    Each batch is coded and one `BinocularEncoder.learn_` step is taken. Images must be at least
    as large as the coarse scale's crop (128 x 128 by default).

    Returns:
        The mean reward (-(e^C + e^F)) of each batch, before its learning step.
    """
    rewards: list[float] = []
    for i, (left, right) in enumerate(batches):
        if steps is not None and i >= steps:
            break
        with torch.no_grad():
            out = encoder(left, right)
        rewards.append(float(out.reward.mean()))
        encoder.learn_(out)
    return rewards
