"""Frames against Gymnasium's own pygame rendering, episodes, and animation files."""

import os
import sys
import warnings

import gymnasium
import imageio.v3 as iio
import jax
import numpy as np
import pytest

from jaxpg import basic_policy, cartpole, render, rollout
from jaxpg.envs import render as drawing

# pygame without a display, and without its greeting on stdout.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

STATES = np.array([
    [0.0, 0.0, 0.0, 0.0],  # upright, centred
    [0.03, 0.5, -0.04, 0.2],  # a reset-like state
    [1.3, 0.0, 0.2, 0.0],  # off-centre, leaning right
    [-2.0, -1.0, -0.2, 1.0],  # far left, leaning left
    [2.4, 0.0, 0.1, 0.0],  # cart centred on the right edge of the image
    [-2.6, 0.0, -0.5, 0.0],  # partly off the image, fallen far
    [0.5, 0.0, np.pi / 2, 0.0],  # lying flat
])


@pytest.fixture(scope="module")
def gymnasium_frames():
    pytest.importorskip("pygame")
    env = gymnasium.make("CartPole-v1", render_mode="rgb_array")
    env.reset(seed=0)
    frames = []
    for state in STATES:
        env.unwrapped.state = state
        frames.append(env.render())
    env.close()
    return np.stack(frames)


@pytest.mark.parametrize("index", range(len(STATES)))
def test_frame_matches_gymnasium(gymnasium_frames, index):
    expected = gymnasium_frames[index]
    frame = render.render_frame(STATES[index])
    assert frame.shape == expected.shape == (400, 600, 3)
    assert frame.dtype == np.uint8
    # Only pygame's anti-aliased outlines differ: a few hundred of the 240,000 pixels.
    same = np.all(frame == expected, axis=-1)
    assert same.mean() >= 0.99
    # Every shape Gymnasium shows is there: the black cart and track, the pole, the axle.
    drawn = {drawing.CART_COLOUR, drawing.POLE_COLOUR, drawing.AXLE_COLOUR}
    assert _colours(expected) & drawn == _colours(frame) & drawn != set()


def _colours(image):
    return {tuple(int(v) for v in c) for c in np.unique(image.reshape(-1, 3), axis=0)}


@pytest.mark.parametrize("theta, side", [(0.2, 1), (-0.2, -1)])
def test_pole_leans_the_way_theta_says(theta, side):
    # Positive theta leans the pole right (as the dynamics: it falls right), by about
    # sin(0.2) * 120 = 24 pixels at its top, for a cart centred at column 300.
    pole = np.all(render.render_frame([0.0, 0.0, theta, 0.0]) == drawing.POLE_COLOUR, axis=-1)
    rows, cols = np.nonzero(pole)
    top = cols[rows < rows.min() + 5].mean()
    assert 15 < side * (top - 300) < 30


def test_batch_and_state_inputs_match_single_frames():
    batch = render.render_frame(STATES[:3])
    assert batch.shape == (3, 400, 600, 3)
    for i in range(3):
        np.testing.assert_array_equal(batch[i], render.render_frame(STATES[i]))
    state = cartpole.CartPoleState.from_array(STATES[:3])
    np.testing.assert_array_equal(render.render_frame(state), batch)
    with pytest.raises(ValueError, match="state"):
        render.render_frame(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        render.render_frame([0.0, 0.0, np.nan, 0.0])
    # Far off screen: only the track is left.
    far = render.render_frame([1e9, 0.0, 0.0, 0.0])
    assert _colours(far) == {(0, 0, 0), (255, 255, 255)}


def test_render_episode_draws_every_state_of_the_episode():
    frames = render.render_episode(basic_policy, seed=3, max_steps=500)
    episodes = rollout.rollout(jax.random.PRNGKey(3), basic_policy, cartpole.V1, 1, 501)
    length = int(episodes.lengths[0])
    assert 1 < length < 500  # the angle policy falls before the time limit
    assert frames.shape == (length + 1, 400, 600, 3)
    np.testing.assert_array_equal(frames[0], render.render_frame(episodes.transitions.obs[0, 0]))
    # The last frame is the state that ended the episode, past a threshold.
    last = np.asarray(episodes.transitions.obs[length, 0])
    assert abs(last[0]) > 2.4 or abs(last[2]) > cartpole.V1.theta_threshold_radians
    np.testing.assert_array_equal(frames[-1], render.render_frame(last))
    # Cut short: the first max_steps steps, plus the initial state.
    assert render.render_episode(basic_policy, seed=3, max_steps=5).shape[0] == 6


def _frames(count=4):
    frames = np.full((count, 40, 60, 3), 255, dtype=np.uint8)
    for t in range(count):
        frames[t, 10:20, 10 * t:10 * t + 10] = drawing.POLE_COLOUR
    return frames


def test_save_animation_writes_a_gif_atomically(tmp_path):
    path = render.save_animation(_frames(), tmp_path / "episode.gif", fps=25)
    read = iio.imread(path, index=None)
    assert read.shape[:3] == (4, 40, 60)
    np.testing.assert_array_equal(read[..., :3], _frames())
    assert iio.immeta(path, index=0)["duration"] == 40  # milliseconds at 25 frames per second
    assert [p.name for p in tmp_path.iterdir()] == ["episode.gif"]


def test_save_animation_mp4_needs_imageio_ffmpeg(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if not installed
    with pytest.raises(ImportError, match="pip install imageio-ffmpeg"):
        render.save_animation(_frames(), tmp_path / "episode.mp4")
    assert list(tmp_path.iterdir()) == []


def test_save_animation_writes_mp4_when_available(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    jax.numpy.zeros(1).block_until_ready()  # JAX started: it warns of any fork from now on
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        path = render.save_animation(render.render_frame(STATES), tmp_path / "episode.mp4")
        assert [str(w.message) for w in caught] == []  # not JAX's warning of ffmpeg's fork
        frames = iio.imread(path, index=None, plugin="FFMPEG")
    assert any("os.fork() was called" in str(w.message) for w in caught)  # (the check works)
    assert frames.shape == (len(STATES), 400, 600, 3)


def test_save_animation_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="path"):
        render.save_animation(_frames(), tmp_path / "episode.avi")
    with pytest.raises(ValueError, match="^path: cannot write in /proc"):
        render.save_animation(_frames(), "/proc/episode.gif")
    with pytest.raises(ValueError, match="^out: cannot write in .*missing"):
        render.check_animation_path(tmp_path / "missing" / "episode.gif", "out")
    (tmp_path / "folder.gif").mkdir()
    with pytest.raises(ValueError, match="^out: .*folder.gif is a directory"):
        render.check_animation_path(tmp_path / "folder.gif", "out")
    with pytest.raises(ValueError, match="^out: the name r+... is 304 bytes long"):
        render.check_animation_path(tmp_path / ("r" * 300 + ".gif"), "out")
    with pytest.raises(ValueError, match="frames"):
        render.save_animation(_frames().astype(np.float32), tmp_path / "episode.gif")
    with pytest.raises(ValueError, match="fps"):
        render.save_animation(_frames(), tmp_path / "episode.gif", fps=0)


def test_an_episode_of_actions_other_than_0_or_1_is_refused():
    with pytest.raises(ValueError, match="^policy: returned an action other than 0"):
        render.render_episode(lambda obs, u: jax.numpy.full(obs.shape[:-1], 2), max_steps=5)
