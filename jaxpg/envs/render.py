"""Frames of every classic-control environment drawn with numpy alone (no pygame, no display).

`render_frame` reproduces the `render()` of Gymnasium's `CartPoleEnv`, `AcrobotEnv`,
`MountainCarEnv`, `Continuous_MountainCarEnv` and `PendulumEnv` in `rgb_array` mode: the same
canvas (600 x 400, or 500 x 500 for Acrobot and Pendulum), geometry and colours, and the same pixel
rules as pygame's `gfxdraw` filled polygon, filled circle and line and `draw.line` (SDL_gfx's
scanline fill on vertices truncated to integers, Bresenham's lines). Left out: the one-pixel
anti-aliased outline that pygame draws around each shape, the anti-aliasing of the mountain's curve
(drawn here as a plain one-pixel polyline), and Pendulum's arrow image of the last torque (a state
does not hold it). So frames agree with Gymnasium's on all but the pixels along those outlines and
that curve, and where Pendulum's arrow would be.
"""

import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from jaxpg import envs
from jaxpg.envs import acrobot, cartpole, continuous_mountain_car, mountain_car, pendulum
from jaxpg.envs.cartpole import CartPoleParams
from jaxpg.types import HostArray
from jaxpg.validation import check_finite

Colour = tuple[int, int, int]  # red, green, blue, each 0 to 255

SCREEN_WIDTH = 600  # CartPole's and both mountain cars' canvas
SCREEN_HEIGHT = 400
SQUARE_SIZE = 500  # Acrobot's and Pendulum's square canvas
CART_COLOUR: Colour = (0, 0, 0)
POLE_COLOUR: Colour = (202, 152, 101)
AXLE_COLOUR: Colour = (129, 132, 203)
TRACK_COLOUR: Colour = (0, 0, 0)
LINK_COLOUR: Colour = (0, 204, 204)  # Acrobot's links...
JOINT_COLOUR: Colour = (204, 204, 0)  # ...and joints
ROD_COLOUR: Colour = (204, 77, 77)  # Pendulum's rod and its round ends...
PIVOT_COLOUR: Colour = (0, 0, 0)  # ...and the axle it turns about
HILL_COLOUR: Colour = (0, 0, 0)  # the mountain cars' curve, car and flagpole
CAR_COLOUR: Colour = (0, 0, 0)
WHEEL_COLOUR: Colour = (128, 128, 128)
FLAG_COLOUR: Colour = (204, 204, 0)

# Gymnasium's drawing constants, in pixels; y grows upwards until the final flip.
_POLE_WIDTH = 10.0
_CART_WIDTH = 50.0
_CART_HEIGHT = 30.0
_CART_Y = 100  # the track, through the middle of the cart
_AXLE_OFFSET = _CART_HEIGHT / 4.0
_LINK_LENGTH_2 = 1.0  # Acrobot's second link, m: Gymnasium's LINK_LENGTH_2, not in its dynamics
_MOUNTAIN_CAR_WIDTH = 40.0
_MOUNTAIN_CAR_HEIGHT = 20.0
_CLEARANCE = 10.0  # between the curve and the car's floor
_CURVE_POINTS = 100
_EPSILON = 1e-6  # pygame's Vector2.epsilon: turns this close to a quarter turn are exact
_QUARTER_TURNS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))  # (cos, sin) of k pi / 2


class _Scene(NamedTuple):
    """How one environment is drawn."""

    state_type: Any  # its state dataclass, with `to_array`
    size: int  # K, the number of values of a state
    shape: tuple[int, int]  # the canvas, (height, width)
    # (surface [H, W, 3] with y upwards, state values [K], env_params): draws onto the surface.
    draw: Callable[[HostArray, HostArray, Any], None]
    # Observations [T, OBS_SIZE] -> the state values [T, K] they show.
    values_of_obs: Callable[[HostArray], HostArray]


def render_frame(state: Any, env_params: Any = cartpole.V1) -> HostArray:
    """Draws a state as Gymnasium's `render()` does in `rgb_array` mode.

    Args:
      state: the environment's state dataclass (`CartPoleState`, `AcrobotState`,
        `MountainCarState` or `PendulumState`), or its values (`VALUES`, e.g. x, x_dot, theta,
        theta_dot for CartPole) `[K]` or `[B, K]`.
      env_params: the environment's params, which choose the picture (CartPole's by default):
        CartPole's `x_threshold` sets the scale and `length` the pole's length; Acrobot's
        `link_length_1` the scale and the first link's length; the mountain cars' track ends the
        scale and `goal_position` the flag. Pendulum's rod is drawn 1 m long whatever its
        `length`, as Gymnasium draws it, without Gymnasium's arrow of the last torque.

    Returns:
      uint8 RGB image `[H, W, 3]` (`[400, 600, 3]`, `[500, 500, 3]` for Acrobot and Pendulum), or
      `[B, H, W, 3]` for a batch of states.

    Raises:
      ValueError: for params of another environment than these, a state of another environment,
        values of another shape, or values that are not finite.
    """
    scene = _scene(env_params)
    values = _state_values(state, scene)
    batch = values.reshape(-1, values.shape[-1])
    frames = np.full((len(batch), *scene.shape, 3), 255, dtype=np.uint8)  # white
    for frame, row in zip(frames, batch):
        # pygame draws with y upwards and flips the image at the end; draw through a flipped view.
        scene.draw(frame[::-1], row, env_params)
    return frames if values.ndim == 2 else frames[0]


def render_observations(obs: npt.ArrayLike, env_params: Any = cartpole.V1) -> HostArray:
    """Draws the states that observations show, as `render_frame` draws states.

    Args:
      obs: `[T, OBS_SIZE]` observations of the environment of `env_params` (Acrobot's and
        Pendulum's angles are read from their cosines and sines).
      env_params: as `render_frame` takes.

    Returns:
      uint8 frames `[T, H, W, 3]`.

    Raises:
      ValueError: as `render_frame` does.
    """
    scene = _scene(env_params)
    return render_frame(scene.values_of_obs(np.asarray(obs, np.float64)), env_params)


def check_drawn(env_params: Any) -> None:
    """Raises a ValueError naming `env_params` unless its environment is one drawn here."""
    _scene(env_params)


def _scene(env_params: Any) -> _Scene:
    """The scene of the environment whose params `env_params` are.

    Raises:
      ValueError: naming `env_params` for params of an environment not drawn here.
    """
    module = envs.module_of(env_params)
    if module not in _SCENES:
        raise ValueError(f"env_params: render draws {', '.join(envs.MODULES)}, got "
                         f"{type(env_params).__name__}")
    return _SCENES[module]


def _state_values(state: Any, scene: _Scene) -> HostArray:
    """A state's values as float64 `[K]` or `[B, K]`, checked.

    Raises:
      ValueError: for a state of another environment, values of another shape, or values that
        are not finite.
    """
    kind, size = scene.state_type.__name__, scene.size
    if hasattr(state, "to_array"):
        if not isinstance(state, scene.state_type):
            raise ValueError(f"state: expected {kind} for these params, got "
                             f"{type(state).__name__}")
        state = state.to_array()
    values = np.asarray(state, dtype=np.float64)
    if values.ndim not in (1, 2) or values.shape[-1] != size:
        raise ValueError(
            f"state: expected {kind} or an array of shape [{size}] or [B, {size}], "
            f"got shape {values.shape}"
        )
    check_finite("state", values)
    return values


def _draw_cartpole(surface: HostArray, values: HostArray, env_params: CartPoleParams) -> None:
    """Draws the cart and pole of values (x, x_dot, theta, theta_dot), in Gymnasium's order."""
    scale = SCREEN_WIDTH / (2 * float(env_params.x_threshold))
    pole_length = scale * 2 * float(env_params.length)
    # A cart far off screen is drawn just off screen: the same image, in safe integer ranges.
    cart_x = np.clip(values[0] * scale + SCREEN_WIDTH / 2.0, -SCREEN_WIDTH, 2 * SCREEN_WIDTH)
    theta = values[2]
    left, right = cart_x - _CART_WIDTH / 2, cart_x + _CART_WIDTH / 2
    bottom, top = _CART_Y - _CART_HEIGHT / 2, _CART_Y + _CART_HEIGHT / 2
    _fill_polygon(surface, [left, left, right, right], [bottom, top, top, bottom], CART_COLOUR)

    half = _POLE_WIDTH / 2
    # pygame's Vector2.rotate_rad(-theta), a clockwise turn for a positive (rightward) angle, to
    # its last bit but for angles that `_rotate` reduces or makes exact quarter turns.
    pole_x, pole_y = _turn([-half, -half, half, half],
                           [-half, pole_length - half, pole_length - half, -half],
                           np.cos(-theta), np.sin(-theta))
    _fill_polygon(surface, pole_x + cart_x, pole_y + _CART_Y + _AXLE_OFFSET, POLE_COLOUR)

    _fill_circle(surface, int(cart_x), int(_CART_Y + _AXLE_OFFSET), int(half), AXLE_COLOUR)
    surface[_CART_Y] = TRACK_COLOUR  # a black line across the whole width


def _draw_acrobot(surface: HostArray, values: HostArray, env_params: acrobot.AcrobotParams
                  ) -> None:
    """Draws the two links of values (theta1, theta2, dtheta1, dtheta2) and the line the free end
    must rise above, in Gymnasium's order."""
    theta1, theta2 = values[0], values[1]
    link_1 = float(env_params.link_length_1)
    scale = SQUARE_SIZE / ((link_1 + _LINK_LENGTH_2 + 0.2) * 2)
    offset = SQUARE_SIZE / 2
    half = 0.1 * scale  # half a link's width
    # Gymnasium's line: 4.4 m wide, 1 m above the first joint, whatever the links' lengths.
    _draw_polyline(surface, [-2.2 * scale + offset, 2.2 * scale + offset],
                   [1 * scale + offset] * 2, TRACK_COLOUR)
    joints = [(0.0, 0.0), (link_1 * np.sin(theta1) * scale, -link_1 * np.cos(theta1) * scale)]
    angles = [theta1 - math.pi / 2, theta1 + theta2 - math.pi / 2]
    for (x, y), angle, length in zip(joints, angles, [link_1 * scale, _LINK_LENGTH_2 * scale]):
        x, y = x + offset, y + offset
        link_x, link_y = _rotate([0, 0, length, length], [-half, half, half, -half], angle)
        _fill_polygon(surface, link_x + x, link_y + y, LINK_COLOUR)
        _fill_circle(surface, int(x), int(y), int(half), JOINT_COLOUR)


def _draw_mountain_car(surface: HostArray, values: HostArray, env_params: Any) -> None:
    """Draws the hills, the car of values (position, velocity) and the goal's flag, in
    Gymnasium's order; either mountain car's params."""
    low, high = float(env_params.min_position), float(env_params.max_position)
    scale = SCREEN_WIDTH / (high - low)
    xs = np.linspace(low, high, _CURVE_POINTS)
    # pygame's anti-aliased curve, drawn plain: the pixels nearest it, its vertices rounded.
    _draw_polyline(surface, (xs - low) * scale + 0.5, _hill_height(xs) * scale + 0.5,
                   HILL_COLOUR)

    # A car far off the track is drawn just off screen: the same image, in safe integer ranges.
    position = np.clip(values[0], 2 * low - high, 2 * high - low)
    car_x = (position - low) * scale
    car_y = _CLEARANCE + _hill_height(position) * scale
    angle = math.cos(3 * position)
    half = _MOUNTAIN_CAR_WIDTH / 2
    body_x, body_y = _rotate([-half, -half, half, half],
                             [0, _MOUNTAIN_CAR_HEIGHT, _MOUNTAIN_CAR_HEIGHT, 0], angle)
    _fill_polygon(surface, body_x + car_x, body_y + car_y, CAR_COLOUR)
    wheels_x, wheels_y = _rotate([half / 2, -half / 2], [0, 0], angle)
    for wheel_x, wheel_y in zip(wheels_x, wheels_y):
        _fill_circle(surface, int(wheel_x + car_x), int(wheel_y + car_y),
                     int(_MOUNTAIN_CAR_HEIGHT / 2.5), WHEEL_COLOUR)

    goal = float(env_params.goal_position)
    flag_x, flag_y = int((goal - low) * scale), int(_hill_height(goal) * scale)
    top = flag_y + 50
    _draw_polyline(surface, [flag_x, flag_x], [flag_y, top], HILL_COLOUR)
    _fill_polygon(surface, [flag_x, flag_x, flag_x + 25], [top, top - 10, top - 5], FLAG_COLOUR)


def _hill_height(position: npt.ArrayLike) -> HostArray:
    """Gymnasium's `_height` of the mountain cars: `sin(3 position) * 0.45 + 0.55`."""
    return np.sin(3 * np.asarray(position)) * 0.45 + 0.55


def _draw_pendulum(surface: HostArray, values: HostArray, env_params: pendulum.PendulumParams
                   ) -> None:
    """Draws the rod of values (theta, theta_dot), its round ends and the axle, in Gymnasium's
    order; `env_params` changes nothing (Gymnasium draws every pendulum alike)."""
    scale = SQUARE_SIZE / (2.2 * 2)
    offset = SQUARE_SIZE // 2
    length, half = 1 * scale, 0.2 * scale / 2
    angle = values[0] + np.pi / 2  # theta 0 points up
    rod_x, rod_y = _rotate([0, 0, length, length, length], [-half, half, half, -half, 0], angle)
    _fill_polygon(surface, rod_x[:4] + offset, rod_y[:4] + offset, ROD_COLOUR)
    _fill_circle(surface, offset, offset, int(half), ROD_COLOUR)
    _fill_circle(surface, int(rod_x[4] + offset), int(rod_y[4] + offset), int(half), ROD_COLOUR)
    _fill_circle(surface, offset, offset, int(0.05 * scale), PIVOT_COLOUR)


def _rotate(xs: npt.ArrayLike, ys: npt.ArrayLike, angle: float) -> tuple[HostArray, HostArray]:
    """pygame's `Vector2.rotate_rad(angle)` of the points (xs, ys), counter-clockwise with y up.

    As pygame does, the angle is reduced to [0, 2 pi) first, and within its `epsilon` (1e-6) of a
    quarter turn the turn is exact, so that a rod turned by pi / 2 stays on its pixel column.
    """
    angle = math.fmod(angle, 2 * math.pi)
    angle = angle + 2 * math.pi if angle < 0 else angle
    if math.fmod(angle + _EPSILON, math.pi / 2) < 2 * _EPSILON:
        cos, sin = _QUARTER_TURNS[int((angle + _EPSILON) / (math.pi / 2)) % 4]
    else:
        cos, sin = math.cos(angle), math.sin(angle)
    return _turn(xs, ys, cos, sin)


def _turn(xs: npt.ArrayLike, ys: npt.ArrayLike, cos: float, sin: float
          ) -> tuple[HostArray, HostArray]:
    """The points (xs, ys) turned by the angle of cosine `cos` and sine `sin`, as float64."""
    xs, ys = np.asarray(xs, dtype=np.float64), np.asarray(ys, dtype=np.float64)
    return xs * cos - ys * sin, xs * sin + ys * cos


def _identity(obs: HostArray) -> HostArray:
    """The state values of an environment whose observation is its state."""
    return obs


def _acrobot_values(obs: HostArray) -> HostArray:
    """Acrobot's values `[T, 4]` from observations `[T, 6]`: each angle from its cosine and sine."""
    return np.stack([np.arctan2(obs[:, 1], obs[:, 0]), np.arctan2(obs[:, 3], obs[:, 2]),
                     obs[:, 4], obs[:, 5]], axis=-1)


def _pendulum_values(obs: HostArray) -> HostArray:
    """Pendulum's values `[T, 2]` from observations `[T, 3]`: the angle from its cosine and sine."""
    return np.stack([np.arctan2(obs[:, 1], obs[:, 0]), obs[:, 2]], axis=-1)


_WIDE = (SCREEN_HEIGHT, SCREEN_WIDTH)
_SQUARE = (SQUARE_SIZE, SQUARE_SIZE)
_SCENES: dict[Any, _Scene] = {
    cartpole: _Scene(cartpole.CartPoleState, 4, _WIDE, _draw_cartpole, _identity),
    acrobot: _Scene(acrobot.AcrobotState, 4, _SQUARE, _draw_acrobot, _acrobot_values),
    mountain_car: _Scene(mountain_car.MountainCarState, 2, _WIDE, _draw_mountain_car,
                         _identity),
    continuous_mountain_car: _Scene(continuous_mountain_car.ContinuousMountainCarState, 2, _WIDE,
                                    _draw_mountain_car, _identity),
    pendulum: _Scene(pendulum.PendulumState, 2, _SQUARE, _draw_pendulum, _pendulum_values),
}


def _draw_polyline(surface: HostArray, xs: npt.ArrayLike, ys: npt.ArrayLike, colour: Colour
                   ) -> None:
    """pygame's one-pixel `draw.lines` (open), `draw.line` and `gfxdraw.vline`.

    Vertices are truncated to integers (as pygame converts them); each segment takes one pixel
    per step along its longer axis, both ends included, rounded to the nearest along the other:
    Bresenham's pixels, but where the line passes halfway between two.
    """
    vx = np.trunc(np.asarray(xs, dtype=np.float64)).astype(np.int64)
    vy = np.trunc(np.asarray(ys, dtype=np.float64)).astype(np.int64)
    dx, dy = np.diff(vx), np.diff(vy)
    steps = np.maximum(np.abs(dx), np.abs(dy))
    segment = np.repeat(np.arange(len(steps)), steps + 1)
    t = np.arange(len(segment)) - np.repeat(np.cumsum(steps + 1) - (steps + 1), steps + 1)
    n = np.maximum(steps, 1)[segment]
    # floor(t * d / n + 1/2) in integers.
    px = vx[:-1][segment] + (2 * t * dx[segment] + n) // (2 * n)
    py = vy[:-1][segment] + (2 * t * dy[segment] + n) // (2 * n)
    inside = (px >= 0) & (px < surface.shape[1]) & (py >= 0) & (py < surface.shape[0])
    surface[py[inside], px[inside]] = colour


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
