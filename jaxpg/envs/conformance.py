"""The parity harness: jaxpg's CartPole against Gymnasium's classic_control `CartPoleEnv`.

Gymnasium plays episodes in float64 (its own `CartPoleEnv` behind its own TimeLimit) while jaxpg,
batched over all episodes, takes the same actions. Two comparisons run side by side:

- re-synced: before every step jaxpg starts from Gymnasium's float64 state (rounded to jaxpg's
  dtype), so each compared step carries one step's rounding only. States must agree within
  `tolerance` (1e-6 in float32, 1e-12 in float64; relative above magnitude 1), and rewards,
  terminated and truncated exactly, except where Gymnasium's new state lies within a few float
  spacings (of jaxpg's dtype) of a threshold: there, rounding alone can put the two on different
  sides of the strict comparison, so such a step is counted apart, as "near threshold", and not as
  a failure. Truncation depends on the step count only and is never excused.
- free-running: jaxpg follows its own trajectory under the same actions. The dynamics are chaotic,
  so rounding differences grow until the trajectories part; where that first happens is reported
  for information and never fails the check.

Actions mix a stabilizing controller with random pushes, at a rate that goes from 0 in the first
episode to 1 in the last, so that the episodes cover truncation, the cart leaving the track and the
pole falling.

Whole episodes, too, under explicit Euler: the basic policy plays the same episodes (from
Gymnasium's `reset(seed=seed + i)`) in jaxpg and in Gymnasium, each on its own observations
(`evaluate` with either backend), and every episode's return must be identical, but where the two
first differ (in the action chosen or the episode's end) while their states still agree within
the free-running tolerance: rounding alone then put an angle on either side of 0, or a state on
either side of a threshold. Its episodes last a few dozen steps there, which rounding rarely
parts: about 1 in 1000 episodes of `heavy-cart-gravity`. Semi-implicit Euler conserves energy:
the same policy then keeps the pole up for hundreds of steps, past where any two implementations
part (even jaxpg in float64, whose sine is not numpy's), so there only the steps are compared.
Besides the presets' variants, three physics settings change every physical field of
`CartPoleParams`, as Gymnasium's `CartPoleEnv` attributes of the same names.
"""

import dataclasses
from collections.abc import Collection
from typing import Any

import gymnasium
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt

from jaxpg import envs
from jaxpg.envs import cartpole, parity
from jaxpg.envs.parity import Outcome
from jaxpg.evaluation import (
    evaluate,
    gymnasium_reset_states,
    make_gymnasium_env,
)
from jaxpg.policies import basic_policy
from jaxpg.validation import check_int

COMPONENTS = ("x", "x_dot", "theta", "theta_dot")
MAX_EPISODES = 2**16  # per variant, an upper bound for `compare_with_gymnasium`

# jaxpg's float dtype: float32 or float64, as a dtype or its scalar type.
FloatDType = np.dtype[Any] | type[np.floating]

# Each variant overrides these fields of the base `env_params`.
VARIANTS: dict[str, dict[str, Any]] = {
    "v0": {"max_steps": 200},
    "v1": {"max_steps": 500},
    "euler": {"integrator": "euler"},
    "semi-implicit": {"integrator": "semi-implicit"},
    "sutton_barto_reward": {"sutton_barto_reward": True},
    # Non-default physics: derived masses and lengths, stronger forces, shorter steps, a narrower
    # track and a tighter angle (the cart leaves the track more often than the pole falls).
    "long-heavy-pole": {"masspole": 0.5, "length": 1.0},
    "heavy-cart-gravity": {"gravity": 15.0, "masscart": 2.0, "force_mag": 15.0},
    "short-steps-narrow": {"tau": 0.01, "x_threshold": 1.0, "theta_threshold_radians": 0.1},
}

# Float spacings (of jaxpg's dtype, at the threshold) within which a termination may go either way:
# the float32 state is within about one spacing of the float64 one after a step, and the threshold
# itself is rounded to float32 by half a spacing.
THRESHOLD_SPACINGS = 4

# CartPole as `parity.step_gymnasium` and `parity.step_jaxpg` step it: each step from a state set
# on Gymnasium's env as if no earlier step had terminated (or it would reward 0 and warn).
TASK = parity.Task(cartpole, cartpole.CartPoleState,
                   restart=lambda env: setattr(env, "steps_beyond_terminated", None))


def tolerance_for(dtype: FloatDType) -> float:
    """The largest per-step state error allowed for jaxpg computing in `dtype`.

    Args:
      dtype: float32 or float64.

    Returns:
      1e-6 for float32, 1e-12 otherwise.
    """
    return 1e-6 if np.dtype(dtype) == np.float32 else 1e-12


def jaxpg_dtype() -> np.dtype[Any]:
    """The float dtype jaxpg computes in now: float32, or float64 under `jax_enable_x64`."""
    return np.dtype(jnp.result_type(float))


@dataclasses.dataclass(frozen=True)
class StepStats:
    """How jaxpg's steps compared with Gymnasium's from the same states and actions."""

    tolerance: float  # the largest per-step state error allowed (`tolerance_for`)
    steps: int = 0  # steps compared
    # Per component, the largest |jaxpg - gym| / max(1, |gym|).
    max_error: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    terminated: int = 0  # steps Gymnasium terminated (coverage)
    truncated: int = 0  # steps Gymnasium truncated (coverage)
    reward_mismatches: int = 0  # steps whose rewards differed, away from a threshold
    terminated_mismatches: int = 0  # steps whose terminations differed, away from a threshold
    truncated_mismatches: int = 0  # steps whose truncations differed
    near_threshold: int = 0  # reward or terminated differed within rounding of a threshold

    @property
    def ok(self) -> bool:
        """Whether every error is within the tolerance and no step mismatched."""
        return (
            max(self.max_error) <= self.tolerance
            and self.reward_mismatches == 0
            and self.terminated_mismatches == 0
            and self.truncated_mismatches == 0
        )

    def merge(self, other: "StepStats") -> "StepStats":
        """The statistics of both batches of steps together."""
        counts = {f.name: getattr(self, f.name) + getattr(other, f.name)
                  for f in dataclasses.fields(self) if f.name not in ("tolerance", "max_error")}
        return dataclasses.replace(
            self, max_error=tuple(map(max, self.max_error, other.max_error)), **counts
        )


def relative_error(values: npt.ArrayLike, reference: np.ndarray) -> np.ndarray:
    """`|values - reference| / max(1, |reference|)`, elementwise: absolute below magnitude 1.

    Args:
      values: `[N, 4]` states, of any float dtype (compared in float64).
      reference: `[N, 4]` float64 states.

    Returns:
      `[N, 4]` float64 errors.
    """
    values = np.asarray(values, np.float64)
    return np.abs(values - reference) / np.maximum(1.0, np.abs(reference))


def near_threshold(
    values: np.ndarray, env_params: cartpole.CartPoleParams, dtype: FloatDType
) -> np.ndarray:
    """Whether |x| or |theta| lies within `THRESHOLD_SPACINGS` float spacings of its threshold.

    Args:
      values: `[N, 4]` float64 states.
      env_params: whose `x_threshold` and `theta_threshold_radians` count.
      dtype: the dtype whose spacing counts (jaxpg's).

    Returns:
      `[N]` bool.
    """
    near = np.zeros(len(values), dtype=bool)
    for column, threshold in ((0, env_params.x_threshold), (2, env_params.theta_threshold_radians)):
        window = THRESHOLD_SPACINGS * np.spacing(np.dtype(dtype).type(threshold))
        near |= np.abs(np.abs(values[:, column]) - float(threshold)) <= window
    return near


def compare(
    jaxpg_outcome: Outcome,
    gym_outcome: Outcome,
    env_params: cartpole.CartPoleParams,
    dtype: FloatDType,
    mask: np.ndarray | None = None,
) -> StepStats:
    """`StepStats` of jaxpg's steps against Gymnasium's, over the rows where `mask` is True.

    Args:
      jaxpg_outcome: jaxpg's N steps (`step_jaxpg`).
      gym_outcome: Gymnasium's N steps from the same states and actions (`step_gymnasium`).
      env_params: the physics of both, whose thresholds `near_threshold` reads.
      dtype: jaxpg's float dtype, which sets the tolerance and the spacings near a threshold.
      mask: optional `[N]` bool: the steps to compare (default: all).

    Returns:
      `StepStats` of the steps compared.
    """
    if mask is not None:
        jaxpg_outcome = Outcome(*(a[mask] for a in jaxpg_outcome))
        gym_outcome = Outcome(*(a[mask] for a in gym_outcome))
    error = relative_error(jaxpg_outcome.values, gym_outcome.values)
    near = near_threshold(gym_outcome.values, env_params, dtype)
    reward_differs = jaxpg_outcome.reward != gym_outcome.reward
    terminated_differs = jaxpg_outcome.terminated != gym_outcome.terminated
    return StepStats(
        tolerance=tolerance_for(dtype),
        steps=len(error),
        max_error=tuple(float(e) for e in error.max(axis=0, initial=0.0)),
        terminated=int(gym_outcome.terminated.sum()),
        truncated=int(gym_outcome.truncated.sum()),
        reward_mismatches=int((reward_differs & ~near).sum()),
        terminated_mismatches=int((terminated_differs & ~near).sum()),
        truncated_mismatches=int((jaxpg_outcome.truncated != gym_outcome.truncated).sum()),
        near_threshold=int(((reward_differs | terminated_differs) & near).sum()),
    )


def step_jaxpg(
    values: npt.ArrayLike,
    times: npt.ArrayLike,
    actions: npt.ArrayLike,
    env_params: cartpole.CartPoleParams,
) -> Outcome:
    """jaxpg's step from each of N states, as one compiled batch in jaxpg's dtype
    (`parity.step_jaxpg` of `TASK`).

    Args:
      values: `[N, 4]` states (rounded to jaxpg's dtype).
      times: `[N]` steps already taken in each episode.
      actions: `[N]` 0 or 1.
      env_params: the physics, checked by `cartpole.check_params`.

    Returns:
      `Outcome` of `[N]` steps.
    """
    cartpole.check_params(env_params)
    return parity.step_jaxpg(TASK, env_params, np.asarray(values), np.asarray(times),
                             np.asarray(actions))


def step_gymnasium(
    gym_env: gymnasium.Env, values: np.ndarray, times: np.ndarray, actions: np.ndarray
) -> Outcome:
    """Gymnasium's step from each of N states set on one `make_gymnasium_env` environment
    (`parity.step_gymnasium` of `TASK`).

    The float64 state goes into `CartPoleEnv.state` (its `steps_beyond_terminated` cleared) and
    the step count into the TimeLimit, so `CartPoleEnv.step` and `TimeLimit.step` themselves
    decide everything.

    Args:
      gym_env: an environment of `make_gymnasium_env`, its TimeLimit outermost.
      values: `[N, 4]` states.
      times: `[N]` steps already taken in each episode.
      actions: `[N]` 0 or 1.

    Returns:
      `Outcome` of `[N]` steps, the states in float64.
    """
    return parity.step_gymnasium(TASK, gym_env, values, times, actions)


def stabilizing_actions(obs: np.ndarray) -> np.ndarray:
    """A PD controller on the pole angle `[N, 4] -> [N]`: on its own it balances for 500 steps.

    Args:
      obs: `[N, 4]` observations.

    Returns:
      `[N]` int32 actions, 1 (push right) where the pole leans or turns right.
    """
    return (obs[:, 2] + 0.3 * obs[:, 3] > 0).astype(np.int32)


@dataclasses.dataclass(frozen=True)
class VariantReport:
    """Conformance of one variant over its episodes."""

    name: str  # the variant, a key of `VARIANTS`
    episodes: int  # episodes played
    stats: StepStats  # re-synced steps
    diverged: int  # episodes whose free-running trajectory parted from Gymnasium's
    first_divergence: int | None  # the earliest step count at which one parted
    median_divergence: float | None  # the median step count at which they parted
    equal_returns: int | None  # the basic policy's episodes with identical returns in both, or
    # parted while still together; None where they are not compared (semi-implicit Euler)

    @property
    def ok(self) -> bool:
        """Whether every re-synced step agreed, and every episode's return where compared."""
        return self.stats.ok and self.equal_returns in (None, self.episodes)


@dataclasses.dataclass(frozen=True)
class Report:
    """Conformance of every variant run."""

    variants: tuple[VariantReport, ...]  # in the order they were run
    dtype: str  # jaxpg's float dtype, "float32" or "float64"
    tolerance: float  # the largest per-step state error allowed
    divergence_tolerance: float  # the error at which a free-running trajectory counts as parted

    @property
    def ok(self) -> bool:
        """Whether every variant is `ok`."""
        return all(v.ok for v in self.variants)

    def format(self) -> str:
        """A text table, one row per variant, and a verdict (`parity.format_table`)."""
        rows = [[v.name, v.episodes, v.stats.steps, v.stats.terminated, v.stats.truncated,
                 *(f"{e:.2e}" for e in v.stats.max_error), v.stats.reward_mismatches,
                 v.stats.terminated_mismatches, v.stats.truncated_mismatches,
                 v.stats.near_threshold, v.diverged, _or_dash(v.first_divergence),
                 _or_dash(v.median_divergence), _fraction(v.equal_returns, v.episodes),
                 "yes" if v.ok else "NO"]
                for v in self.variants]
        return parity.format_table(
            [f"jaxpg ({self.dtype}) vs Gymnasium CartPoleEnv (float64), re-synced every step:",
             f"max per-step error (relative above 1) must be <= {self.tolerance:g}; mismatches "
             "of reward / terminated / truncated must be 0",
             "(near: reward or terminated differed where Gymnasium's state is within "
             f"{THRESHOLD_SPACINGS} {self.dtype} spacings of a threshold; not a failure).",
             f"Free-running, informational: episodes whose trajectory parted (error > "
             f"{self.divergence_tolerance:g} or different termination), at which step.",
             "Returns: the basic policy's episodes, each played in both, whose returns are "
             "identical, or that part while their states agree within the free-running "
             "tolerance; all must be (under explicit Euler)."],
            [("variant", -20), ("episodes", 8), ("steps", 7), ("term", 5), ("trunc", 5),
             *((c, 9) for c in COMPONENTS), ("reward", 6), ("term", 4), ("trunc", 5),
             ("near", 4), ("diverged", 8), ("first", 5), ("median", 6), ("returns", 7),
             ("ok", 3)],
            rows, self.ok)


def _or_dash(value: float | None) -> str:
    """`value` formatted with `g`, or "-" for None."""
    return "-" if value is None else f"{value:g}"


def _fraction(count: int | None, total: int) -> str:
    """"count/total", or "-" for no count."""
    return "-" if count is None else f"{count}/{total}"


def check(
    env: str = "CartPole-v1", episodes: int | None = None, states: int | None = None,
    seed: int = 0,
) -> "Report | parity.Report":
    """One task's conformance against Gymnasium: CartPole's episodes or another's drawn states.

    Args:
      env: a Gymnasium id of `jaxpg.envs.MODULES`.
      episodes: CartPole's episodes per variant (`compare_with_gymnasium`, default 100); for
        CartPole only.
      states: another task's states drawn per variant (`parity.check`, default 10^4); not for
        CartPole.
      seed: a non-negative integer.

    Returns:
      `Report` (CartPole) or `parity.Report`; each has `ok` and `format()`.

    Raises:
      ValueError: one line naming the argument, for an unknown `env`, a count of the other kind
        of task or out of range, or `seed` out of range.
    """
    if not isinstance(env, str) or env not in envs.MODULES:
        raise ValueError(f"env: allowed {', '.join(envs.MODULES)}; got {env!r}")
    if envs.MODULES[env] is cartpole:
        if states is not None:
            raise ValueError("states: CartPole's conformance plays whole episodes (episodes)")
        return compare_with_gymnasium(100 if episodes is None else episodes, seed,
                                      cartpole.PRESETS[env])
    if episodes is not None:
        raise ValueError(f"episodes: {env}'s conformance steps drawn states (states), "
                         "not episodes")
    return parity.check(env, 10_000 if states is None else states, seed)


def compare_with_gymnasium(
    episodes: int = 100,
    seed: int = 0,
    env_params: cartpole.CartPoleParams | None = None,
    variants: str | Collection[str] | None = None,
    divergence_tolerance: float = 1e-3,
) -> Report:
    """Plays `episodes` episodes of each variant in Gymnasium and jaxpg and compares every step.

    Args:
      episodes: episodes per variant; episode i starts from Gymnasium's `reset(seed=seed + i)`.
      seed: a non-negative integer; also seeds the random actions.
      env_params: the base `CartPoleParams` the variants modify (default `cartpole.V1`). A subclass
        must be a `flax.struct.dataclass` too, to be passed into compiled code.
      variants: a name or names from `VARIANTS` (default: all).
      divergence_tolerance: error at which a free-running trajectory counts as parted.

    Returns:
      `Report`; `report.ok` is False if any re-synced step disagrees.

    Raises:
      ValueError: one line naming the argument, for `episodes` or `seed` out of range, physics
        that `cartpole.check_params` refuses, or an unknown variant or none.
    """
    check_int("episodes", episodes, 1, MAX_EPISODES)
    check_int("seed", seed, 0, 2**32)
    env_params = cartpole.V1 if env_params is None else env_params
    cartpole.check_params(env_params)
    variants = tuple(VARIANTS) if variants is None else (
        (variants,) if isinstance(variants, str) else tuple(variants))
    unknown = [name for name in variants if name not in VARIANTS]
    if unknown or not variants:
        raise ValueError(
            f"variants: allowed {', '.join(VARIANTS)}; got {', '.join(unknown) or 'none'}"
        )
    dtype = jaxpg_dtype()
    reports = tuple(
        _run_variant(name, env_params.replace(**VARIANTS[name]), episodes, seed, dtype,
                     divergence_tolerance)
        for name in variants
    )
    return Report(reports, dtype.name, tolerance_for(dtype), divergence_tolerance)


def _run_variant(
    name: str,
    env_params: cartpole.CartPoleParams,
    episodes: int,
    seed: int,
    dtype: np.dtype[Any],
    divergence_tolerance: float,
) -> VariantReport:
    """`VariantReport` of `episodes` episodes played in both, stepping all episodes together."""
    gym_env = make_gymnasium_env(env_params)
    gym_values = gymnasium_reset_states(episodes, seed, env_params)  # [E, 4] float64
    free_values = gym_values.astype(dtype)  # jaxpg's own trajectory
    rng = np.random.default_rng(seed)
    random_rate = np.linspace(0.0, 1.0, episodes)
    alive = np.ones(episodes, dtype=bool)
    parted_at = np.zeros(episodes, dtype=np.int64)  # 0: not (yet) parted
    stats = StepStats(tolerance_for(dtype))
    times = np.zeros(episodes, dtype=np.int32)
    while alive.any():
        obs = gym_values.astype(np.float32)  # what a policy sees in Gymnasium
        actions = np.where(rng.random(episodes) < random_rate, rng.integers(0, 2, episodes),
                           stabilizing_actions(obs)).astype(np.int32)
        # The re-synced and the free-running steps as one batch of 2E.
        both = step_jaxpg(np.concatenate([gym_values, free_values]), np.tile(times, 2),
                          np.tile(actions, 2), env_params)
        synced = Outcome(*(a[:episodes] for a in both))
        free = Outcome(*(a[episodes:] for a in both))
        stepped = step_gymnasium(gym_env, gym_values[alive], times[alive], actions[alive])
        gym_out = Outcome(gym_values.copy(), np.zeros(episodes), np.zeros(episodes, bool),
                          np.zeros(episodes, bool))  # the episodes that ended stay as they are
        for whole, part in zip(gym_out, stepped, strict=True):
            whole[alive] = part
        stats = stats.merge(compare(synced, gym_out, env_params, dtype, mask=alive))
        times += 1
        parts = alive & (parted_at == 0) & (
            (relative_error(free.values, gym_out.values).max(axis=1) > divergence_tolerance)
            | (free.terminated != gym_out.terminated)
        )
        parted_at[parts] = times[parts]
        alive &= ~(gym_out.terminated | gym_out.truncated)
        gym_values, free_values = gym_out.values, free.values
    parted = parted_at[parted_at > 0]
    equal_returns: int | None = None
    if env_params.integrator == "euler":
        ours, theirs = episode_returns(env_params, episodes, seed)
        equal = ours == theirs
        # An episode whose returns differ counts where the two part within the tolerance: the
        # policy's choice flipped between trajectories still together (its angle within rounding
        # of 0), or an end came on one side of a threshold only.
        equal[~equal] = [
            _parted_together(env_params, gymnasium_reset_states(1, seed + int(i), env_params)[0],
                             divergence_tolerance)
            for i in np.flatnonzero(~equal)]
        equal_returns = int(equal.sum())
    return VariantReport(
        name, episodes, stats, len(parted),
        int(parted.min()) if len(parted) else None,
        float(np.median(parted)) if len(parted) else None,
        equal_returns,
    )


def _parted_together(env_params: cartpole.CartPoleParams, start: np.ndarray,
                     tolerance: float) -> bool:
    """Whether the basic policy's episode from the float64 state `start` `[4]`, played in jaxpg
    and in Gymnasium each on its own trajectory, first differs (in the action chosen or in the
    episode's end) where the two states still agree within `tolerance` (`relative_error`)."""
    gym_env = make_gymnasium_env(env_params)
    theirs = np.array(start, np.float64)
    ours = theirs.astype(jaxpg_dtype())
    for t in range(int(env_params.max_steps)):
        action = int(basic_policy(jnp.asarray(ours)))
        if action != int(basic_policy(jnp.asarray(theirs.astype(np.float32)))):
            break
        time, act = np.array([t]), np.array([action])
        mine = step_jaxpg(ours[None], time, act, env_params)
        gyms = step_gymnasium(gym_env, theirs[None], time, act)
        ours, theirs = mine.values[0], gyms.values[0]
        ends = (gyms.terminated[0], gyms.truncated[0])
        if ends != (mine.terminated[0], mine.truncated[0]):
            break
        if any(ends):
            return False  # played alike to the end: the returns differ otherwise
    else:
        return False
    return bool(relative_error(ours, theirs).max() <= tolerance)


def episode_returns(
    env_params: cartpole.CartPoleParams, episodes: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """The returns of the basic policy's episodes in jaxpg and in Gymnasium.

    Episode i starts from Gymnasium's `reset(seed=seed + i)` and runs to `env_params.max_steps`.

    Args:
      env_params: scalar physics and episode settings.
      episodes: E, how many.
      seed: the seed of the first episode.

    Returns:
      (`[E]` returns in jaxpg, `[E]` returns in Gymnasium), float64.
    """
    def play(**backend: Any) -> np.ndarray:
        """The returns `[E]` of `evaluate` with the arguments `backend`."""
        return evaluate(basic_policy, episodes, int(env_params.max_steps), env_params, seed,
                        **backend).returns

    return (play(init_states=gymnasium_reset_states(episodes, seed, env_params)),
            play(backend="gymnasium"))
