"""CartPole frames drawn with numpy alone (no pygame, no display), and GIF/MP4 writing.

`render_frame` reproduces Gymnasium's `CartPoleEnv.render()`: the same 600 x 400 canvas, geometry
and colours, and the same pixel rules as pygame's `gfxdraw` filled polygon and filled circle
(SDL_gfx's scanline fill on vertices truncated to integers). Only the one-pixel anti-aliased
outline that pygame draws around each shape is left out, so frames agree with Gymnasium's on all
but the pixels along those outlines.
"""

import functools
import pathlib
from typing import Any

import jax
import numpy as np
import numpy.typing as npt

from jaxpg import atomic_files, budget, cartpole, rollout
from jaxpg.atomic_files import StrPath
from jaxpg.cartpole import CartPoleParams, CartPoleState
from jaxpg.types import HostArray, Policy
from jaxpg.validation import check_finite, check_int

Colour = tuple[int, int, int]  # red, green, blue, each 0 to 255

SCREEN_WIDTH = 600
SCREEN_HEIGHT = 400
CART_COLOUR: Colour = (0, 0, 0)
POLE_COLOUR: Colour = (202, 152, 101)
AXLE_COLOUR: Colour = (129, 132, 203)
TRACK_COLOUR: Colour = (0, 0, 0)

# Gymnasium's drawing constants, in pixels; y grows upwards until the final flip.
_POLE_WIDTH = 10.0
_CART_WIDTH = 50.0
_CART_HEIGHT = 30.0
_CART_Y = 100  # the track, through the middle of the cart
_AXLE_OFFSET = _CART_HEIGHT / 4.0


def render_frame(state: CartPoleState | npt.ArrayLike, env_params: CartPoleParams = cartpole.V1
                 ) -> HostArray:
    """Draws the cart and pole as Gymnasium's `render()` does in `rgb_array` mode.

    Args:
      state: a `CartPoleState`, or values `[4]` or `[B, 4]` (x, x_dot, theta, theta_dot).
      env_params: `CartPoleParams`; `x_threshold` sets the scale and `length` the pole's length.

    Returns:
      uint8 RGB image `[400, 600, 3]`, or `[B, 400, 600, 3]` for a batch of states.

    Raises:
      ValueError: for values of another shape, or values that are not finite.
    """
    if isinstance(state, cartpole.CartPoleState):
        state = state.to_array()
    values = np.asarray(state, dtype=np.float64)
    if values.ndim not in (1, 2) or values.shape[-1] != 4:
        raise ValueError(
            f"state: expected a CartPoleState or an array of shape [4] or [B, 4], "
            f"got shape {values.shape}"
        )
    check_finite("state", values)
    batch = values.reshape(-1, 4)
    frames = np.full((len(batch), SCREEN_HEIGHT, SCREEN_WIDTH, 3), 255, dtype=np.uint8)  # white
    scale = SCREEN_WIDTH / (2 * float(env_params.x_threshold))
    pole_length = scale * 2 * float(env_params.length)
    # A cart far off screen is drawn just off screen: the same image, in safe integer ranges.
    cart_xs = np.clip(batch[:, 0] * scale + SCREEN_WIDTH / 2.0, -SCREEN_WIDTH, 2 * SCREEN_WIDTH)
    for frame, cart_x, theta in zip(frames, cart_xs, batch[:, 2]):
        _draw(frame, cart_x, theta, pole_length)
    return frames if values.ndim == 2 else frames[0]


def _draw(frame: HostArray, cart_x: float, theta: float, pole_length: float) -> None:
    """Draws one scene onto the white `frame` `[H, W, 3]`, in Gymnasium's order."""
    # pygame draws with y upwards and flips the image at the end; draw through a flipped view.
    surface = frame[::-1]
    left, right = cart_x - _CART_WIDTH / 2, cart_x + _CART_WIDTH / 2
    bottom, top = _CART_Y - _CART_HEIGHT / 2, _CART_Y + _CART_HEIGHT / 2
    _fill_polygon(surface, [left, left, right, right], [bottom, top, top, bottom], CART_COLOUR)

    half = _POLE_WIDTH / 2
    corners_x = np.array([-half, -half, half, half])
    corners_y = np.array([-half, pole_length - half, pole_length - half, -half])
    # pygame's Vector2.rotate_rad(-theta): a clockwise turn for a positive (rightward) angle.
    cos, sin = np.cos(-theta), np.sin(-theta)
    pole_x = corners_x * cos - corners_y * sin + cart_x
    pole_y = corners_x * sin + corners_y * cos + _CART_Y + _AXLE_OFFSET
    _fill_polygon(surface, pole_x, pole_y, POLE_COLOUR)

    _fill_circle(surface, int(cart_x), int(_CART_Y + _AXLE_OFFSET), int(half), AXLE_COLOUR)
    surface[_CART_Y] = TRACK_COLOUR  # a black line across the whole width


def _fill_polygon(surface: HostArray, xs: npt.ArrayLike, ys: npt.ArrayLike, colour: Colour
                  ) -> None:
    """pygame's `gfxdraw.filled_polygon`: SDL_gfx's scanline fill, vectorised over rows.

    Vertices are truncated to integers (as pygame converts them); each row y between the lowest
    and highest vertex meets the edges with y1 <= y < y2 (and y1 < y <= y2 on the top row); the
    crossings, in 16.16 fixed point and sorted, pair up into spans drawn inclusively, each end
    rounded inwards by one 1/65536 step.
    """
    vx = np.trunc(np.asarray(xs, dtype=np.float64)).astype(np.int64)
    vy = np.trunc(np.asarray(ys, dtype=np.float64)).astype(np.int64)
    # Edge i runs from vertex i - 1 to vertex i, oriented upwards.
    ax, ay = np.roll(vx, 1), np.roll(vy, 1)
    upwards = ay < vy
    x1, y1 = np.where(upwards, ax, vx), np.where(upwards, ay, vy)
    x2, y2 = np.where(upwards, vx, ax), np.where(upwards, vy, ay)
    min_y, max_y = vy.min(), vy.max()
    rows = np.arange(max(min_y, 0), min(max_y, surface.shape[0] - 1) + 1)[:, None]
    if rows.size == 0:
        return
    meets = (y1 != y2) & (
        ((rows >= y1) & (rows < y2)) | ((rows == max_y) & (rows > y1) & (rows <= y2))
    )
    height = np.where(y1 == y2, 1, y2 - y1)
    crossings = (65536 * (rows - y1)) // height * (x2 - x1) + 65536 * x1
    # Sorting puts the crossings first and the edges a row misses last.
    crossings = np.sort(np.where(meets, crossings, np.iinfo(np.int64).max), axis=1)
    count = meets.sum(axis=1)
    for pair in range(len(vx) // 2):
        starts = _round_fixed(crossings[:, 2 * pair] + 1)
        ends = _round_fixed(crossings[:, 2 * pair + 1] - 1)
        drawn = count >= 2 * pair + 2
        _fill_spans(
            surface, rows[drawn, 0], np.minimum(starts, ends)[drawn],
            np.maximum(starts, ends)[drawn], colour,
        )


def _round_fixed(value: HostArray) -> HostArray:
    """SDL_gfx's rounding of a 16.16 fixed-point number to the nearest integer."""
    return (value >> 16) + ((value & 32768) >> 15)


def _fill_spans(surface: HostArray, rows: HostArray, starts: HostArray, ends: HostArray,
                colour: Colour) -> None:
    """Paints the inclusive spans `starts[i]..ends[i]` of `rows[i]`, clipped to the surface."""
    width = surface.shape[1]
    starts, ends = np.clip(starts, 0, width), np.clip(ends, -1, width - 1)
    if rows.size == 0 or ends.max() < starts.min():
        return
    lo, hi = starts.min(), ends.max() + 1
    columns = np.arange(lo, hi)
    inside = (columns >= starts[:, None]) & (columns <= ends[:, None])
    # Indexing by an array of rows copies: paint the copy, then write it back.
    region = surface[rows, lo:hi]
    region[inside] = colour
    surface[rows, lo:hi] = region


@functools.lru_cache(maxsize=8)
def _circle_half_widths(radius: int) -> HostArray:
    """Half-widths, by row offset 0..radius, of SDL_gfx's `filledCircle` (midpoint algorithm)."""
    half = [0] * (radius + 1)
    cx, cy, df, d_e, d_se = 0, radius, 1 - radius, 3, 5 - 2 * radius
    previous_cy = None
    while cx <= cy:
        # Rows +-cy are drawn (cx wide) only when cy has just changed; rows +-cx every time.
        if cy != previous_cy:
            half[cy] = max(half[cy], cx)
            previous_cy = cy
        if cx != cy:
            half[cx] = max(half[cx], cy)
        if df < 0:
            df, d_e, d_se = df + d_e, d_e + 2, d_se + 2
        else:
            df, d_e, d_se, cy = df + d_se, d_e + 2, d_se + 4, cy - 1
        cx += 1
    return np.array(half)


def _fill_circle(surface: HostArray, cx: int, cy: int, radius: int, colour: Colour) -> None:
    """pygame's `gfxdraw.filled_circle` centred on the integer pixel (cx, cy)."""
    half = _circle_half_widths(radius)
    offsets = np.arange(-radius, radius + 1)
    rows = cy + offsets
    half = half[np.abs(offsets)]
    on_surface = (rows >= 0) & (rows < surface.shape[0])
    _fill_spans(surface, rows[on_surface], (cx - half)[on_surface], (cx + half)[on_surface], colour)


def render_episode(policy: Policy, seed: int = 0, env_params: CartPoleParams = cartpole.V1,
                   max_steps: int = 500) -> HostArray:
    """Plays one episode with `policy` and draws it, from the first state to the last.

    Args:
      policy: `(obs [E, 4], u [E]) -> action [E]`, as `rollout.rollout` takes.
      seed: seeds the initial state and the policy's randomness.
      env_params: `CartPoleParams`.
      max_steps: the most steps drawn (the episode also ends when `env_params` ends it).

    Returns:
      uint8 frames `[T, 400, 600, 3]`, T <= max_steps + 1: the initial state and the state after
      each step.

    Raises:
      ValueError: for a `max_steps` below 1 or one whose frames need more memory than the
        machine's (`budget.render_bytes`), or a policy that gave an action other than 0 or 1.
    """
    check_int("max_steps", max_steps)
    budget.check_fits(budget.render_bytes(max_steps, int(env_params.max_steps)), "max_steps",
                      f"drawing an episode of at most {max_steps} steps")
    # One step more than drawn, so that the state after the last drawn step is observed too.
    episodes = rollout.rollout(jax.random.PRNGKey(seed), policy, env_params, 1, max_steps + 1)
    rollout.check_played_actions(episodes.invalid_action)
    length = min(int(episodes.lengths[0]), max_steps)
    states = np.asarray(episodes.transitions.obs[: length + 1, 0])
    return render_frame(states, env_params)


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
    with atomic_files.atomic_path(path) as tmp:
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
      ValueError: naming `name` unless `path` ends with .gif or .mp4 and a file can be created in
        its folder.
      ImportError: for MP4 without imageio-ffmpeg.
    """
    path = pathlib.Path(path)
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
    atomic_files.check_writable(path.parent, name)
    return path
