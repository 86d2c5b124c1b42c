"""One episode played and drawn, and frames written as an animation (GIF, or MP4).

The drawing itself, of any state of the classic-control environments, is `jaxpg.envs.render`'s;
`render_frame` is here too, so that `jaxpg.render` holds all three.
"""

import pathlib
import warnings
from typing import Any

import jax
import numpy as np
import numpy.typing as npt

from jaxpg import atomic_files, budget, rollout
from jaxpg.atomic_files import StrPath
from jaxpg.envs import cartpole, render
from jaxpg.envs.render import render_frame
from jaxpg.types import HostArray, Policy
from jaxpg.validation import check_int

__all__ = ["check_animation_path", "render_episode", "render_frame", "save_animation"]


def render_episode(policy: Policy, seed: int = 0, env_params: Any = cartpole.V1,
                   max_steps: int = 500) -> HostArray:
    """Plays one episode with `policy` and draws it, from the first state to the last.

    The states drawn are those the policy observed (Acrobot's and Pendulum's angles from their
    cosines and sines), and the state after the last step.

    Args:
      policy: `(obs [E, K], u [E]) -> action [E]`, as `rollout.rollout` takes.
      seed: seeds the initial state and the policy's randomness.
      env_params: the environment's params (CartPole's by default), as `render.render_frame` takes.
      max_steps: the most steps drawn (the episode also ends when `env_params` ends it).

    Returns:
      uint8 frames `[T, H, W, 3]` (`render_frame`'s), T <= max_steps + 1: the initial state and
      the state after each step.

    Raises:
      ValueError: for params of an environment not drawn, a `max_steps` below 1 or one whose
        frames need more memory than the machine's (`budget.render_bytes`), or a policy that gave
        an action outside the environment's.
    """
    render.check_drawn(env_params)
    check_int("max_steps", max_steps)
    budget.check_fits(budget.render_bytes(max_steps, int(env_params.max_steps)), "max_steps",
                      f"drawing an episode of at most {max_steps} steps")
    # The time limit ends the episode anyway. One step more than drawn, so that the state after
    # the last drawn step is observed too.
    steps = min(max_steps, int(env_params.max_steps)) + 1
    episodes = rollout.rollout(jax.random.PRNGKey(seed), policy, env_params, 1, steps)
    rollout.check_played_actions(episodes.invalid_action, env_params)
    length = min(int(episodes.lengths[0]), max_steps)
    return render.render_observations(episodes.transitions.obs[: length + 1, 0], env_params)


def save_animation(frames: npt.ArrayLike, path: StrPath, fps: float = 50
                   ) -> pathlib.Path:
    """Writes frames as an animated GIF, or as MP4 when `path` ends with `.mp4`.

    MP4 needs the optional `imageio-ffmpeg` package. The file is replaced atomically.

    Args:
      frames: uint8 `[T, H, W, 3]`.
      path: the file to write, `.gif` or `.mp4`.
      fps: frames per second.

    Returns:
      The `pathlib.Path` written.

    Raises:
      ValueError: for frames of another shape or dtype, an fps not positive, or a path that
        `check_animation_path` rejects.
    """
    import imageio.v3 as iio

    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(
            f"frames: expected uint8 [T, H, W, 3], got {frames.dtype} {frames.shape}"
        )
    if not fps > 0:
        raise ValueError(f"fps: must be positive, got {fps}")
    path = check_animation_path(path)
    if path.suffix.lower() == ".mp4":
        # 8-pixel blocks divide 600 x 400 exactly; the default 16 would resize the frames.
        options: dict[str, Any] = {"plugin": "FFMPEG", "fps": fps, "macro_block_size": 8}
    else:
        # The duration is in milliseconds (GIF keeps hundredths); loop=0 repeats forever.
        options = {"plugin": "pillow", "duration": 1000 / fps, "loop": 0}
    with atomic_files.atomic_path(path) as tmp, warnings.catch_warnings():
        # imageio starts ffmpeg as a subprocess: the child of that fork runs ffmpeg at once, so
        # JAX's warning that a forked JAX process may deadlock does not apply.
        warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
        iio.imwrite(tmp, frames, **options)
    return path


def check_animation_path(path: StrPath, name: str = "path") -> pathlib.Path:
    """`path` as a Path that `save_animation` can write, checked before anything is drawn.

    Args:
      path: the file to write.
      name: the argument's name, which a message starts with.

    Returns:
      `path` as a `pathlib.Path`.

    Raises:
      ValueError: naming `name` unless `path` ends with .gif or .mp4, can be a file's name
        (`atomic_files.check_path_names`) and a file can be created in its folder, outside
        folders of jaxpg's results (`atomic_files.check_outside_results`), and is not a
        directory or anything else than a regular file (`atomic_files.check_replaceable`).
      ImportError: for MP4 without imageio-ffmpeg.
    """
    path = atomic_files.check_path_names(path, name)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"{name}: must end with .gif or .mp4, got {path.name!r}")
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401  (the plugin imageio needs for MP4)
        except ImportError:
            raise ImportError(
                "writing MP4 needs imageio-ffmpeg: pip install imageio-ffmpeg (or write a .gif)"
            ) from None
    if path.is_dir():
        raise ValueError(f"{name}: {path} is a directory; give the animation's file")
    atomic_files.check_replaceable(path, name)
    atomic_files.check_outside_results(path, name)
    atomic_files.check_writable(path.parent, name)
    return path
