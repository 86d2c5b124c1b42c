"""Frames of Acrobot, both mountain cars and Pendulum: against Gymnasium's own pygame rendering,
against the state they draw, in episodes, and from the command line."""

import os

import gymnasium
import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpg
from jaxpg import cartpole, checkpoint, cli, envs, render
from jaxpg.envs import acrobot, continuous_mountain_car, mountain_car, pendulum
from jaxpg.envs import render as drawing

# pygame without a display, and without its greeting on stdout.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

# (Gymnasium id, attributes of Gymnasium's env and the same fields of jaxpg's params, states)
CASES = [
    ("Acrobot-v1", {}, {}, [
        [0.0, 0.0, 0.0, 0.0],  # hanging down
        [np.pi, 0.0, 0.0, 0.0],  # upright: exact quarter turns
        [np.pi / 2, 0.0, 0.0, 0.0],  # both links to the right
        [0.3, -0.5, 1.0, 1.0],
        [-2.0, 2.5, 0.0, 0.0],
    ]),
    ("Acrobot-v1", {"LINK_LENGTH_1": 1.5}, {"link_length_1": 1.5}, [[1.0, 1.0, 0.0, 0.0]]),
    ("MountainCar-v0", {}, {}, [
        [-0.5, 0.0],  # the valley's bottom
        [-1.2, 0.0],  # at the left wall
        [0.5, 0.01],  # at the goal
        [-0.9, 0.02],
    ]),
    ("MountainCar-v0", {"min_position": -1.5, "max_position": 0.7, "goal_position": 0.3},
     {"min_position": -1.5, "max_position": 0.7, "goal_position": 0.3}, [[0.0, 0.0]]),
    ("MountainCarContinuous-v0", {}, {}, [[-0.5, 0.0], [0.45, 0.0], [-1.1, 0.0]]),
    ("Pendulum-v1", {}, {}, [
        [0.0, 0.0],  # upright
        [np.pi, 0.0],  # hanging down: exact quarter turns
        [np.pi / 2, 0.0],  # to the left
        [1.0, 0.0],
        [-2.5, 0.0],
        [7.0, 1.0],  # more than a turn
    ]),
]
FRAMES = [(name, attributes, fields, state) for name, attributes, fields, states in CASES
          for state in states]
# Every colour drawn; any other colour in Gymnasium's frames is a blend of its anti-aliasing.
DRAWN = {(255, 255, 255), drawing.TRACK_COLOUR, drawing.LINK_COLOUR, drawing.JOINT_COLOUR,
         drawing.ROD_COLOUR, drawing.PIVOT_COLOUR, drawing.HILL_COLOUR, drawing.WHEEL_COLOUR,
         drawing.FLAG_COLOUR}


def _gymnasium_frame(name, attributes, state):
    env = gymnasium.make(name, render_mode="rgb_array")
    env.reset(seed=0)
    for attribute, value in attributes.items():
        setattr(env.unwrapped, attribute, value)
    env.unwrapped.state = np.array(state, dtype=np.float64)
    frame = env.render()
    env.close()
    return frame


@pytest.mark.parametrize("name, attributes, fields, state", FRAMES)
def test_frame_matches_gymnasium_but_along_its_anti_aliasing(name, attributes, fields, state):
    pytest.importorskip("pygame")
    expected = _gymnasium_frame(name, attributes, state)
    frame = render.render_frame(state, envs.MODULES[name].make_params(name, **fields))
    assert frame.shape == expected.shape
    assert frame.dtype == np.uint8
    same = np.all(frame == expected, axis=-1)
    # Gymnasium's anti-aliased outlines and curve: under 1% of the pixels (about 1,500 of
    # 240,000 for a mountain car, whose whole curve is anti-aliased; under 400 of 250,000
    # otherwise)...
    assert same.mean() > 0.99
    # ...and every other pixel is next to one of them: a shape 2 pixels off is not.
    blended = ~np.isin(_colour_codes(expected), [_code(c) for c in DRAWN])
    assert not np.any(~same & ~_grow(blended))
    # Every shape Gymnasium shows is there.
    assert _colours(expected) & DRAWN == _colours(frame)


def _code(colour):
    return (colour[0] << 16) | (colour[1] << 8) | colour[2]


def _colour_codes(image):
    image = image.astype(np.int64)
    return (image[..., 0] << 16) | (image[..., 1] << 8) | image[..., 2]


def _colours(image):
    return {tuple(int(v) for v in c) for c in np.unique(image.reshape(-1, 3), axis=0)}


def _grow(mask):
    """`mask` `[H, W]` and its 8 neighbours."""
    padded = np.pad(mask, 1)
    height, width = mask.shape
    return np.any([padded[dy:dy + height, dx:dx + width] for dy in range(3) for dx in range(3)],
                  axis=0)


@pytest.mark.parametrize("params, state_type, values, shape", [
    (acrobot.V1, acrobot.AcrobotState, [[0.1, 0.2, 0, 0], [1, 2, 0, 0]], (500, 500)),
    (mountain_car.V0, mountain_car.MountainCarState, [[-0.5, 0], [0, 0]], (400, 600)),
    (continuous_mountain_car.V0, mountain_car.MountainCarState, [[-0.5, 0], [0, 0]], (400, 600)),
    (pendulum.V1, pendulum.PendulumState, [[0.0, 0], [2, 0]], (500, 500)),
])
def test_sizes_batches_and_states(params, state_type, values, shape):
    batch = render.render_frame(values, params)
    assert batch.shape == (2, *shape, 3) and batch.dtype == np.uint8
    np.testing.assert_array_equal(batch[1], render.render_frame(values[1], params))
    np.testing.assert_array_equal(render.render_frame(state_type.from_array(values), params),
                                  batch)
    assert not np.array_equal(batch[0], batch[1])


def test_bad_states_and_params_are_refused():
    with pytest.raises(ValueError, match=r"^state: expected AcrobotState or an array of shape "
                                         r"\[4\] or \[B, 4\], got shape \(2,\)"):
        render.render_frame([0.0, 0.0], acrobot.V1)
    with pytest.raises(ValueError, match="^state: expected PendulumState for these params, "
                                         "got MountainCarState"):
        render.render_frame(mountain_car.MountainCarState.from_array([0.0, 0.0]), pendulum.V1)
    with pytest.raises(ValueError, match="^state: .*finite"):
        render.render_frame([np.inf, 0.0], mountain_car.V0)
    with pytest.raises(ValueError, match="^env"):
        render.render_frame([0.0, 0.0], "MountainCar-v0")


def _pixels(frame, colour):
    """(rows, columns) of the pixels of `colour`."""
    return np.nonzero(np.all(frame == colour, axis=-1))


@pytest.mark.parametrize("params", [mountain_car.V0, continuous_mountain_car.V0])
def test_the_car_moves_with_its_position(params):
    scale = 600 / (0.6 - -1.2)  # pixels per unit of position: 333.3
    columns = []
    for position in [-1.1, -0.7, -0.3, 0.1, 0.5]:
        rows, cols = _pixels(render.render_frame([position, 0.0], params), drawing.WHEEL_COLOUR)
        # The two wheels sit symmetrically about the car's centre, (position + 1.2) * 333.3
        # pixels from the left (-0.3: 300); each wheel's centre is truncated, a pixel at most.
        assert abs(cols.mean() - (position + 1.2) * scale) <= 1.5
        # ...and 10 pixels above the curve, at height sin(3 position) * 0.45 + 0.55 (-0.3:
        # 0.1436, 47.9 pixels) from the bottom row 399, so at row 399 - 57.9 = 341.1.
        height = 10 + (np.sin(3 * position) * 0.45 + 0.55) * scale
        assert abs(rows.mean() - (399 - height)) <= 1.5
        columns.append(cols.mean())
    assert np.all(np.diff(columns) > 100)  # 0.4 apart: 133 pixels


@pytest.mark.parametrize("params, flag", [
    (mountain_car.V0, 566),  # int((0.5 + 1.2) * 600 / 1.8) = int(566.67)
    (continuous_mountain_car.V0, 550),  # int((0.45 + 1.2) * 600 / 1.8) = int(550.0)
])
def test_the_flag_stands_at_the_goal(params, flag):
    frame = render.render_frame([-0.5, 0.0], params)
    _, cols = _pixels(frame, drawing.FLAG_COLOUR)
    assert cols.min() == flag  # the pennant starts at the pole
    assert cols.max() <= flag + 25


@pytest.mark.parametrize("values, reach", [
    # (down, up, right, left) from the first joint at (250, 250), in pixels of 500 / 4.4 = 113.6
    # a metre: the links start at the joint and reach 2 m (227.3) away from it, half their 0.2 m
    # width (11.4) to either side.
    ([0.0, 0.0, 0.0, 0.0], (227.3, 0, 11.4, 11.4)),  # hanging down
    ([np.pi / 2, 0.0, 0.0, 0.0], (11.4, 11.4, 227.3, 0)),  # theta1 turns them right...
    ([np.pi, 0.0, 0.0, 0.0], (0, 227.3, 11.4, 11.4)),  # ...and upright
    # theta2 = pi / 2 bends the second link to the right of the first: from 1 m down, 1 m right.
    ([0.0, np.pi / 2, 0.0, 0.0], (113.6 + 11.4, 0, 113.6, 11.4)),
])
def test_the_links_turn_with_their_angles(values, reach):
    rows, cols = _pixels(render.render_frame(values, acrobot.V1), drawing.LINK_COLOUR)
    drawn = (rows.max() - 250, 250 - rows.min(), cols.max() - 250, 250 - cols.min())
    # Within 2 pixels (truncation, the joints' circles drawn over the links' ends).
    np.testing.assert_allclose(drawn, reach, atol=2)


@pytest.mark.parametrize("theta, up, left", [
    (0.0, 1, 0),  # theta 0 is upright
    (np.pi / 2, 0, 1),  # a positive angle turns it anticlockwise, to the left
    (np.pi, -1, 0),
    (-np.pi / 2, 0, -1),
])
def test_the_rod_turns_with_theta(theta, up, left):
    rows, cols = _pixels(render.render_frame([theta, 0.0], pendulum.V1), drawing.ROD_COLOUR)
    # The rod's middle is half its 1 * 113.6 pixels from the axle at (250, 250).
    half = 500 / 4.4 / 2
    assert abs((250 - rows.mean()) - up * half) < 3
    assert abs((250 - cols.mean()) - left * half) < 3


def _replay(module, params, action, steps):
    """The states of an episode of one action from the params' (tiny) reset range: `[T + 1, K]`
    values, stepped one at a time."""
    _, state = module.reset(jax.random.PRNGKey(0), params)
    step = jax.jit(module.step)
    values = [state.to_array()]
    for _ in range(steps):
        _, state, _, terminated, truncated = step(state, action, params)
        values.append(state.to_array())
        if terminated or truncated:
            break
    return np.asarray(values)


@pytest.mark.parametrize("module, params, action", [
    # Reset ranges a billionth wide: every episode starts from (almost) the same state.
    (acrobot, acrobot.V1.replace(reset_low=0.3, reset_high=0.3 + 1e-9), 2),
    (mountain_car, mountain_car.V0.replace(reset_low=-0.5, reset_high=-0.5 + 1e-9,
                                           max_steps=12), 2),
    (pendulum, pendulum.V1.replace(reset_theta=1e-9, reset_theta_dot=1e-9), 1.5),
])
def test_an_episode_draws_the_states_played(module, params, action):
    def policy(obs, u):
        return jnp.full(obs.shape[:-1], action, dtype=jnp.asarray(action).dtype)

    frames = render.render_episode(policy, seed=1, env_params=params, max_steps=15)
    # MountainCar's time limit of 12 steps ends its episode first: 13 frames, else 16.
    states = _replay(module, params, action, 15)
    assert frames.shape[0] == len(states) == min(15, params.max_steps) + 1
    expected = render.render_frame(states, params)
    # The same states, but for last bits (a float32 angle from its cosine and sine).
    for frame, drawn in zip(frames, expected):
        assert np.all(frame == drawn, axis=-1).mean() > 0.999
    assert not np.array_equal(frames[0], frames[-1])  # it moved


def test_an_action_outside_the_environment_is_refused():
    with pytest.raises(ValueError, match="^policy: returned an action other than 0 to 2"):
        render.render_episode(lambda obs, u: jnp.full(obs.shape[:-1], 3), seed=0,
                              env_params=acrobot.V1, max_steps=5)


@pytest.fixture(scope="module")
def acrobot_checkpoint(tmp_path_factory):
    config = jaxpg.TrainConfig(env="Acrobot-v1", iterations=2, episodes=2, max_steps=20,
                               hidden=(4,))
    folder = str(tmp_path_factory.mktemp("acrobot"))
    checkpoint.save(folder + "/", jaxpg.train(config, seed=0).policy_params, config)
    return folder


def test_the_command_line_draws_a_checkpoint_in_its_environment(acrobot_checkpoint, tmp_path,
                                                                 capsys):
    path = tmp_path / "x.gif"
    assert cli.run_command(["render", "--policy", acrobot_checkpoint, "--out", str(path),
                            "--max-steps", "12"]) == 0
    # A policy of 2 iterations does not swing the end up within 12 steps: all 12 are drawn.
    assert iio.imread(path, index=None).shape[:3] == (13, 500, 500)
    assert "12 steps" in capsys.readouterr().out
    assert cli.run_command(["render", "--policy", acrobot_checkpoint, "--env", "CartPole-v1",
                            "--out", str(path)]) == 2
    assert "env: " in capsys.readouterr().err


@pytest.mark.parametrize("policy, params", [
    (None, cartpole.V1),  # basic: CartPole's book episode, 200 steps
    ("acrobot", acrobot.V1),  # Acrobot's time limit, 500
])
def test_the_command_line_draws_up_to_the_time_limit(policy, params, acrobot_checkpoint,
                                                     tmp_path, monkeypatch):
    calls = []

    def record(policy, seed, env_params, max_steps):
        calls.append((env_params, max_steps))
        return render.render_frame(np.zeros((2, 4)), env_params)

    monkeypatch.setattr(render, "render_episode", record)
    flags = ["--policy", acrobot_checkpoint] if policy else []
    assert cli.run_command(["render", *flags, "--out", str(tmp_path / "x.gif")]) == 0
    assert calls == [(params, envs.max_steps(params))]
    assert envs.max_steps(params) == (500 if policy else 200)
