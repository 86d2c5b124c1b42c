"""REINFORCE on CartPole: the book's training loop, compiled.

One iteration plays `episodes` episodes of at most `max_steps` steps with the current policy,
discounts and normalises the rewards, and takes one optimizer step on the REINFORCE loss.
Iterations of many runs together (each run on the last axis of every array) are one compiled
program, so that many seeds and hyperparameter settings train at once.

The host calls that program for up to `ITERATIONS_PER_CALL` iterations at a time and shows
progress as they complete: the program needs no callback into Python, and a program without
callbacks can be kept in JAX's persistent compilation cache, so a second process does not compile
again.
"""

import concurrent.futures
import dataclasses
import functools
import inspect
import math
import os
import threading
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxpg import cartpole, executables, policies, progress, returns, rng, rollout, sums


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Settings of a training run: the book's by default.

    `learning_rate` and `discount` are hyperparameters that a sweep vmaps over; every other field
    fixes the program's shapes or structure.
    """

    # Fix the program.
    iterations: int = 150
    episodes: int = 10  # per update
    max_steps: int = 200  # per episode
    hidden: tuple[int, ...] = (5,)
    activation: str = "elu"
    optimizer: str = "adam"  # any optax optimizer taking a `learning_rate`
    env: str | cartpole.CartPoleParams = "CartPole-v1"
    solved_return: float = 195.0  # the mean return that counts as solved
    # Vmappable.
    learning_rate: float = 0.01
    discount: float = 0.95

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(self.hidden))
        for name in ("iterations", "episodes", "max_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}: must be a positive integer, got {value!r}")
        policies.check_network(self.hidden, self.activation)
        check_optimizer(self.optimizer)
        check_hyperparams(self.learning_rate, self.discount)
        self.env_params  # validates

    @property
    def env_params(self):
        if isinstance(self.env, cartpole.CartPoleParams):
            cartpole.check_params(self.env)
            return self.env
        return cartpole.make_params(self.env)

    @property
    def network(self):
        return policies.PolicyNetwork(hidden=self.hidden, activation=self.activation)

    @property
    def hyperparams(self):
        return Hyperparams(self.learning_rate, self.discount)


class Hyperparams(NamedTuple):
    """The settings a sweep vmaps over: scalars, or `[R]` arrays for R runs."""

    learning_rate: jax.Array
    discount: jax.Array


def check_hyperparams(learning_rate, discount):
    """Raises a ValueError unless every learning rate is positive and every discount in (0, 1]."""
    # numpy, not jnp: building a TrainConfig must not start JAX (jax.distributed comes first).
    for lr in np.atleast_1d(np.asarray(learning_rate)).tolist():
        if not lr > 0:
            raise ValueError(f"learning_rate: must be positive, got {lr}")
    for d in np.atleast_1d(np.asarray(discount)).tolist():
        if not 0 < d <= 1:
            raise ValueError(f"discount: must be in (0, 1], got {d}")


def _optimizer_factories():
    """optax's optimizers: the functions whose first parameter is `learning_rate`."""
    factories = {}
    for name in dir(optax):
        fn = getattr(optax, name)
        if name.startswith("_") or not inspect.isfunction(fn):
            continue
        try:
            params = list(inspect.signature(fn).parameters)
        except (TypeError, ValueError):
            continue
        if params[:1] == ["learning_rate"]:
            factories[name] = fn
    return factories


OPTIMIZERS = _optimizer_factories()


def check_optimizer(name):
    if name not in OPTIMIZERS:
        raise ValueError(
            f"optimizer: unknown {name!r}; allowed: optax optimizers such as adam, sgd, rmsprop "
            f"({len(OPTIMIZERS)} in all: {', '.join(sorted(OPTIMIZERS))})"
        )


class TrainState(NamedTuple):
    """The carry of R runs from iteration to iteration.

    Each run's parameters are one vector (`policies.flatten`), and so are the moments of an
    optimizer in `ELEMENTWISE_OPTIMIZERS` (Adam among them): its step is then a few kernels rather
    than a few per weight matrix and bias, which XLA compiles sooner. Parameters and optimizer
    state hold the runs on their last axis (parameters `[P, R]`), where they meet each run's
    episodes `[T, E, R]`; the keys are `[R, 2]`.
    """

    policy_params: jax.Array
    opt_state: optax.OptState
    key: jax.Array


class Metrics(NamedTuple):
    """Per-iteration statistics of a run: `[I]`, or `[R, I]` for R runs."""

    mean_return: jax.Array
    min_return: jax.Array
    max_return: jax.Array
    mean_length: jax.Array
    loss: jax.Array
    grad_norm: jax.Array


class TrainResult(NamedTuple):
    """The trained policy and its per-iteration metrics (leading axis `[R]` for several runs)."""

    policy_params: dict
    metrics: Metrics


def reinforce_loss(policy_params, network, transitions, advantages):
    """Mean over the alive steps of -advantage * log pi(a|s); `[R]` for R runs on trailing axes.

    Its gradient is the book's: the gradient of the binary cross-entropy between P(left) and the
    action taken, weighted by the normalised return and averaged over every step of every episode.
    """
    logits = policies.forward(policy_params, transitions.obs, network.activation)
    terms = advantages * policies.log_prob(logits, transitions.action)
    return -sums.invariant_mean(terms, (0, 1), transitions.alive)


def loss_and_grad(policy_params, network, transitions, advantages):
    """`reinforce_loss` and its gradient: every step's share at once, added up over time in a loop.

    A dense layer's kernel gradient is, step by step, the outer product of the layer's input and
    the cotangent of its output. Both come for every step of every episode in one vectorised pass
    (the cotangents as the gradient with respect to zero offsets on each layer's output). A loop
    up to the last step that any episode is alive in then adds the outer products up per episode,
    in time order, and the E episodes are summed at the end in a fixed order: a run rounds the
    same alone as in a sweep. A loop step is a few multiply-adds on small accumulators
    `[K, N, E, R]`, few enough kernels for XLA to run them one after another rather than schedule
    them as a graph. A run alone has no run axis, so XLA vectorises the loop over its episodes:
    they are padded with episodes of no alive step (all zeros) to whole vectors of
    `rollout.LANES`, which made 1 seed train about 40 % sooner. With finite parameters the padding
    changes no sum: a padded episode's totals stay +0 (a total, starting at +0, is never -0, so
    adding zeros keeps it), `sums.invariant_sum` pads the episode axis with zeros anyway, and the
    count of alive steps is taken before the padding.
    The step signals take `[K, T, E, R]` floats per layer, which a sweep's memory budget counts.

    Returns:
      (loss, gradient): `[R]` and `policy_params`-shaped, for R runs on trailing axes.
    """
    run_shape = advantages.shape[2:]
    # Counted before any padding: the same sum as the normalisation's, which XLA computes once.
    count = jnp.maximum(sums.invariant_sum(transitions.alive.astype(advantages.dtype), (0, 1)), 1)
    alone = _alone(advantages.shape)
    if alone:
        transitions, advantages = _padded_episodes(transitions, advantages, rollout.LANES)
    weights = jnp.where(transitions.alive, advantages, 0.0)
    layers = policy_params["params"]
    names = [f"Dense_{i}" for i in range(len(layers))]
    terms, inputs, cotangents = _step_signals(policy_params, network, transitions, weights)
    # A run alone's signals come without its run axes, which its totals get back at the end.
    runs = 0 if alone else len(run_shape)

    # Summed over time per episode; steps after every episode ended weigh nothing.
    def add_step(t, totals):
        def at(array, axis):
            return jax.lax.dynamic_index_in_dim(array, t, axis, keepdims=False)

        loss_total, layer_totals = totals
        added = [(kernel + at(x, 1)[:, None] * at(d, 1)[None], bias + at(d, 1))
                 for (kernel, bias), x, d in zip(layer_totals, inputs, cotangents)]
        return loss_total + at(terms, 0), added

    episode_shape = terms.shape[1:]
    zeros = (jnp.zeros(episode_shape, weights.dtype),
             [(jnp.zeros((x.shape[0], d.shape[0], *episode_shape), weights.dtype),
               jnp.zeros((d.shape[0], *episode_shape), weights.dtype))
              for x, d in zip(inputs, cotangents)])
    any_alive = jnp.any(transitions.alive, axis=tuple(range(1, weights.ndim)))  # [T]
    lived = jnp.max(jnp.where(any_alive, np.arange(1, weights.shape[0] + 1), 0))
    totals = jax.lax.fori_loop(0, lived, add_step, zeros)

    def over_episodes(total):  # -[..., E, *runs] summed over E, per alive step, [..., *run_shape]
        total = sums.invariant_sum(total, total.ndim - runs - 1)
        return -total.reshape(total.shape[:total.ndim - runs] + run_shape) / count

    loss, layer_totals = jax.tree.map(over_episodes, totals)
    grads = {"params": {name: {"kernel": kernel, "bias": bias}
                        for name, (kernel, bias) in zip(names, layer_totals)}}
    return loss, grads


def is_run_alone(train_state):
    """Whether a `TrainState` holds one run (keys `[1, 2]`): `iterate` then plays and computes
    it without its run axis, and `AloneOrTogether` picks the program compiled for that."""
    return train_state.key.shape[0] == 1


def _alone(shape):
    """Whether `[T, E, *runs]` is a run alone: no run axes, or run axes of one entry."""
    return math.prod(shape[2:]) == 1


def _padded_episodes(transitions, advantages, multiple):
    """Episodes `[T, E, ...]` and their advantages, padded with episodes of no alive step (all
    zeros) to a multiple of `multiple` episodes."""
    extra = -advantages.shape[1] % multiple

    def pad(leaf):
        return jnp.pad(leaf, [(0, 0), (0, extra)] + [(0, 0)] * (leaf.ndim - 2))

    return jax.tree.map(pad, transitions), pad(advantages)


def _step_signals(policy_params, network, transitions, weights):
    """Every step's weighted log-probability `[T, E, *runs]`, and each dense layer's input
    features `[K, T, E, *runs]` and output cotangent `[N, T, E, *runs]`, computed at once.

    The cotangents are the gradient with respect to zero offsets on each layer's output. A run
    alone computes them over its steps and episodes as one axis, and returns them without run
    axes (`[T, E]`, `[K, T, E]`, `[N, T, E]`): XLA vectorises over the last axis, which a run axis
    of size one would be, and gives such arrays other layouts than the loop over them takes.
    """
    shape = weights.shape
    obs, action = transitions.obs, transitions.action
    alone = _alone(shape)
    if alone:
        policy_params = _without_runs(policy_params, len(shape) - 2)
        obs, action, weights = obs.reshape(-1, obs.shape[-1]), action.reshape(-1), weights.reshape(-1)

    def forward(offsets):
        logits, inputs = policies.forward_layers(policy_params, obs, network.activation, offsets)
        return policies.log_prob(logits, action), inputs

    layers = policy_params["params"]
    offsets = [jnp.zeros((layers[f"Dense_{i}"]["bias"].shape[0], *weights.shape), weights.dtype)
               for i in range(len(layers))]
    log_prob, vjp, inputs = jax.vjp(forward, offsets, has_aux=True)
    (cotangents,) = vjp(weights)
    signals = (weights * log_prob, inputs, cotangents)
    if alone:  # back to [..., T, E]
        signals = jax.tree.map(lambda leaf: leaf.reshape(*leaf.shape[:-1], *shape[:2]), signals)
    return signals


def _without_runs(policy_params, runs):
    """The parameters of a run alone without their `runs` trailing run axes, all of size one."""
    return jax.tree.map(lambda leaf: leaf.reshape(leaf.shape[:leaf.ndim - runs]), policy_params)


def global_norm(tree):
    """The L2 norm of every leaf together, summed in a fixed order so that it is batch-invariant."""
    squares = [sums.invariant_sum(jnp.square(leaf).ravel(), 0) for leaf in jax.tree.leaves(tree)]
    return jnp.sqrt(sum(squares))


def make_optimizer(config, learning_rate):
    return OPTIMIZERS[config.optimizer](learning_rate=learning_rate)


# Optimizers that update each parameter from its own history alone. They step a run's parameters
# as the one vector they are kept in, in a few kernels; any other optimizer steps each parameter
# array as optax defines it (lamb's and lars's trust ratios, adafactor's factored moments, ...).
# `tests/test_reinforce.py` checks every name here against the per-array update.
ELEMENTWISE_OPTIMIZERS = frozenset({
    "adabelief", "adadelta", "adagrad", "adam", "adamax", "adamaxw", "adamw", "adan", "amsgrad",
    "lion", "optimistic_adam_v2", "optimistic_gradient_descent", "radam", "rmsprop", "rprop", "sgd",
    "sign_sgd", "signum", "yogi",
})


def _optimizer_view(config):
    """(to, back): a run's flat parameters `[P]` (or gradient) as its optimizer takes them."""
    if config.optimizer in ELEMENTWISE_OPTIMIZERS:
        return (lambda flat: flat), (lambda flat: flat)
    network = config.network
    return (functools.partial(policies.unflatten, network=network),
            functools.partial(policies.flatten, network=network))


def init_run(config, key, hyperparams):
    """The initial policy parameters `[P]` (`policies.flatten`) and optimizer state of one run."""
    network = config.network
    policy_params = policies.flatten(
        policies.init_network(jax.random.split(key)[1], network), network)
    to_optimizer, _ = _optimizer_view(config)
    opt_state = make_optimizer(config, hyperparams.learning_rate).init(to_optimizer(policy_params))
    return policy_params, opt_state


def init_runs(config, keys, hyperparams):
    """The initial `TrainState` of R runs, from their keys `[R, 2]` and `Hyperparams` `[R]`."""
    policy_params, opt_state = jax.vmap(functools.partial(init_run, config), out_axes=-1)(
        keys, hyperparams
    )
    return TrainState(policy_params, opt_state, jax.vmap(lambda k: jax.random.split(k)[0])(keys))


def optimizer_step(config, grads, opt_state, policy_params, learning_rate):
    """One optimizer step of one run, on its flat parameters and gradient `[P]`:
    (policy_params `[P]`, opt_state)."""
    to_optimizer, back = _optimizer_view(config)
    params = to_optimizer(policy_params)
    updates, opt_state = make_optimizer(config, learning_rate).update(
        to_optimizer(grads), opt_state, params)
    return back(optax.apply_updates(params, updates)), opt_state


def iterate(config, train_state, hyperparams):
    """One REINFORCE iteration of R runs at once: play, discount, normalise, step the optimizer.

    Args:
      config: the `TrainConfig`.
      train_state: `TrainState` of the R runs.
      hyperparams: `Hyperparams` with `[R]` leaves.

    Returns:
      (`TrainState`, `Metrics` with `[R]` leaves)
    """
    network = config.network
    key, key_rollout = rng.split(train_state.key)

    # Play the episodes of every run with its current policy: [T, E, R] transitions. A run alone
    # plays without its run axis, XLA vectorising over its episodes instead, in whole vectors.
    alone = is_run_alone(train_state)
    flat = train_state.policy_params[:, 0] if alone else train_state.policy_params

    def policy(obs, u):  # parameters taken apart where the rollout's kernels use them
        return policies.network_policy(network, policies.unflatten(flat, network))(obs, u)

    episodes = rollout.rollout(
        key_rollout[0] if alone else key_rollout, policy,
        config.env_params, config.episodes, config.max_steps,
        lanes=rollout.LANES if alone else 1,
    )
    if alone:
        episodes = rollout.Episodes(
            jax.tree.map(lambda leaf: jnp.expand_dims(leaf, 2), episodes.transitions),
            episodes.returns[:, None], episodes.lengths[:, None])
    transitions = episodes.transitions

    # Discounted returns, normalised over every step of every episode of a run.
    advantages = returns.discount_and_normalize_masked(
        transitions.reward, transitions.alive, hyperparams.discount
    )

    # One optimizer step on the REINFORCE loss.
    loss, grad_arrays = loss_and_grad(policies.unflatten(train_state.policy_params, network),
                                      network, transitions, advantages)
    grads = policies.flatten(grad_arrays, network)
    # The step runs with the runs first: on the last axis, XLA's vectorised and scalar loops
    # round a run's update differently for different numbers of runs.
    runs_first = functools.partial(jax.tree.map, lambda leaf: jnp.moveaxis(leaf, -1, 0))
    runs_last = functools.partial(jax.tree.map, lambda leaf: jnp.moveaxis(leaf, 0, -1))
    policy_params, opt_state = runs_last(jax.vmap(functools.partial(optimizer_step, config))(
        *runs_first((grads, train_state.opt_state, train_state.policy_params)),
        hyperparams.learning_rate,
    ))

    metrics = Metrics(
        mean_return=episodes.returns.mean(axis=0),
        min_return=episodes.returns.min(axis=0),
        max_return=episodes.returns.max(axis=0),
        mean_length=episodes.lengths.mean(axis=0),
        loss=loss,
        # Summed by parameter array: over the one vector, LLVM fuses a few of the squares into
        # the additions for one number of runs and not another.
        grad_norm=jax.vmap(global_norm, in_axes=-1)(grad_arrays),
    )
    return TrainState(policy_params, opt_state, key), metrics


ITERATIONS_PER_CALL = 10  # iterations a call of the program runs at most
MEAN_RETURN = Metrics._fields.index("mean_return")


class Program(NamedTuple):
    """The compiled training of R runs at once, for one `TrainConfig`: `executables.Stored`
    functions (`iterate` an `AloneOrTogether` of two), which `run` prepares before it calls them."""

    network: policies.PolicyNetwork  # whose parameters TrainState.policy_params holds, flat
    init: Callable  # (keys [R, 2], Hyperparams [R]) -> TrainState [R]
    # (TrainState [R], Hyperparams [R], count: int32 scalar) -> (TrainState [R], Metrics' fields
    # stacked [ITERATIONS_PER_CALL, len(Metrics._fields), R]): `count` iterations (at most
    # ITERATIONS_PER_CALL), whose metrics fill the first `count` rows; one array per call.
    iterate: Callable  # an `AloneOrTogether`


def compiled_program(config):
    """The jitted `Program` of `config`; `iterate` consumes (donates) the state it is given.

    Its functions keep their compiled programs on disk while `executables.enable` is in effect.

    Configs that differ only in how many iterations run, or in what counts as solved, share one.
    """
    return _program(dataclasses.replace(config, iterations=1, solved_return=0.0))


# Initialising runs once: it is compiled for speed of compilation, not of running, without
# XLA's CPU fusion emitters (about 0.1 s sooner).
INIT_OPTIONS = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
# The iteration of a block of several runs asks for 512-bit vectors (XLA's default is 256), for
# speed: 1024 seeds trained in 3.70 and 4.30 s instead of 5.50 and 5.69 s, the same bits. A block
# of one run does not, for its bits: with its loop compiled whole (`jaxpg.flags`), 512-bit vectors
# round some of its episodes differently from the same run's beside others (8 of the book's seeds
# 0 to 15).
TOGETHER_OPTIONS = {"xla_cpu_prefer_vector_width": 512}


class AloneOrTogether(NamedTuple):
    """A function whose first argument is a `TrainState`, as two `executables.Stored` functions
    compiled with different options: `alone` for a run alone (a block of one run), `together` for
    several runs. It calls, prepares, lowers or traces the one for its arguments."""

    alone: executables.Stored
    together: executables.Stored

    def _for(self, train_state):
        return self.alone if is_run_alone(train_state) else self.together

    def __call__(self, *args):
        return self._for(args[0])(*args)

    def prepare(self, *args):
        return self._for(args[0]).prepare(*args)

    def lower(self, *args):
        return self._for(args[0]).lower(*args)

    def eval_shape(self, *args):
        return self._for(args[0]).eval_shape(*args)


@functools.lru_cache(maxsize=32)
def _program(config):
    def jit_iterate(options):
        return jax.jit(functools.partial(_iterate_stacked, config), donate_argnums=0,
                       compiler_options=options)

    return Program(
        config.network,
        executables.Stored(
            jax.jit(functools.partial(init_runs, config), compiler_options=INIT_OPTIONS),
            "init", config),
        AloneOrTogether(executables.Stored(jit_iterate(None), "iterate_alone", config),
                        executables.Stored(jit_iterate(TOGETHER_OPTIONS), "iterate", config)),
    )


def _iterate_stacked(config, train_state, hyperparams, count):
    def one(i, carry):
        train_state, history = carry
        train_state, metrics = iterate(config, train_state, hyperparams)
        return train_state, jax.lax.dynamic_update_index_in_dim(history, jnp.stack(metrics), i, 0)

    history = jnp.zeros((ITERATIONS_PER_CALL, len(Metrics._fields),
                         *hyperparams.learning_rate.shape), jnp.result_type(float))
    return jax.lax.fori_loop(0, jnp.minimum(count, ITERATIONS_PER_CALL), one,
                             (train_state, history))


def calls(iterations):
    """`(first iteration, count)` of each program call that trains for `iterations` iterations."""
    return [(start, min(ITERATIONS_PER_CALL, iterations - start))
            for start in range(0, iterations, ITERATIONS_PER_CALL)]


CPU_BLOCK = 16  # runs a CPU trains together at most: one vector of them (`rollout.LANES`)
# Runs per core that train alone rather than in a block: a run alone vectorises over its episodes,
# and 2 runs alone per core trained in 0.10 to 0.12 s, a block of 4 in 0.13 to 0.15 s.
ALONE_PER_CORE = 2


def usable_cores():
    """The cores this process may run on (all of them where the OS does not say)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def cpu_blocks(num_runs):
    """The blocks in which a CPU trains `num_runs` runs, one thread per core: `(start, stop)` of
    each, and the size every block is padded to, with copies of its own runs.

    Up to `ALONE_PER_CORE` runs per core train alone, a block each. More train in blocks of at
    most `CPU_BLOCK` runs whose sizes differ by at most one, as many as a multiple of the usable
    cores, so that every core trains and all finish together, padded to a whole vector of floats:
    4, 8 or 16 runs. XLA vectorises over the runs in whole vectors and loops over the rest one by
    one: a block of 15 runs trained three times as long as one of 16, of 3 runs twice as long as
    one of 8. One size, one program to compile.
    """
    cores = usable_cores()
    if num_runs <= ALONE_PER_CORE * cores:
        return [(run, run + 1) for run in range(num_runs)], 1
    num_blocks = -(-num_runs // (CPU_BLOCK * cores)) * cores
    bounds = [i * num_runs // num_blocks for i in range(num_blocks + 1)]
    largest = -(-num_runs // num_blocks)
    size = max(4, 1 << (largest - 1).bit_length())
    return list(zip(bounds[:-1], bounds[1:])), size


def run(program, iterations, parts, on_iteration=None):
    """Trains each part's runs for `iterations` iterations, every part on its own device.

    On a CPU a part trains in `cpu_blocks`, spread over one thread per core: XLA runs such small
    programs on the thread that calls them, and a small block stops its rollout as soon as its own
    episodes have ended. Runs train alike in any batch, so the blocks and their copies of runs
    change nothing in the results. The programs of every part's blocks are compiled first, side
    by side (`prepare`).

    Args:
      program: from `compiled_program`.
      iterations: how many times to iterate.
      parts: a list of (keys `[R_p, 2]`, `Hyperparams` `[R_p]`), each on the device that trains it.
      on_iteration: optional `(iteration, mean_returns [sum of R_p]) -> None`, called on the host
        for every iteration in order, while later ones are already training.

    Returns:
      One `TrainResult` per part, with numpy leaves `[R_p, ...]` and metrics `[R_p, iterations]`.
    """
    blocks, owners, owned = [], [], []  # owned: how many of a block's runs are its part's
    for index, part in enumerate(parts):
        for block, runs in part_blocks(part):
            blocks.append(block)
            owners.append(index)
            owned.append(runs)
    prepare(program, blocks)
    schedule = calls(iterations)
    history = [[None] * len(blocks) for _ in schedule]
    finals = [None] * len(blocks)
    num_workers = min(len(blocks), usable_cores())
    finished = [0] * len(schedule)  # workers that dispatched each call
    failed = []  # workers that raised
    progress_made = threading.Condition()

    def train_blocks(indices):
        try:
            states = {i: program.init(*blocks[i]) for i in indices}
            for call, (_, count) in enumerate(schedule):
                for i in indices:
                    states[i], history[call][i] = program.iterate(
                        states[i], blocks[i][1], np.int32(count))
                with progress_made:
                    finished[call] += 1
                    progress_made.notify_all()
            for i in indices:
                finals[i] = jax.device_get(states[i])
        except BaseException:
            with progress_made:
                failed.append(indices)
                progress_made.notify_all()
            raise

    with concurrent.futures.ThreadPoolExecutor(num_workers) as pool:
        workers = [pool.submit(train_blocks, range(w, len(blocks), num_workers))
                   for w in range(num_workers)]
        for call, (start, count) in enumerate(schedule if on_iteration is not None else []):
            with progress_made:
                progress_made.wait_for(lambda: finished[call] == num_workers or failed)
            if finished[call] < num_workers:
                break  # a worker failed; its error is raised below
            shown = np.concatenate([np.asarray(m)[:count, MEAN_RETURN, :runs]
                                    for m, runs in zip(history[call], owned)], axis=-1)
            for offset, mean_returns in enumerate(shown):
                on_iteration(start + offset, mean_returns)
        for worker in workers:
            worker.result()

    results = []
    for index in range(len(parts)):
        mine = [i for i, owner in enumerate(owners) if owner == index]
        metrics = jax.device_get([[history[c][i] for i in mine] for c in range(len(schedule))])
        rows = np.concatenate([  # [I, fields, R_p]
            np.concatenate([m[..., :owned[i]] for m, i in zip(call, mine)], axis=-1)[:count]
            for call, (_, count) in zip(metrics, schedule)])
        stacked = Metrics(*np.moveaxis(rows, 0, -1))
        params = policies.unflatten(
            np.concatenate([finals[i].policy_params[:, :owned[i]] for i in mine], axis=-1),
            program.network)
        results.append(TrainResult(jax.tree.map(lambda leaf: np.moveaxis(leaf, -1, 0), params),
                                   stacked))
    return results


def prepare(program, blocks):
    """Starts compiling (or loading) `program` for `blocks`, a list of (keys `[R, 2]`,
    `Hyperparams` `[R]`), and returns the `concurrent.futures.Future`s of their programs.

    This thread traces and lowers `iterate` for each block first, then `init`; other threads
    compile each program as soon as it is lowered. `iterate`'s compile, the longest, so runs while
    `init` is traced and compiled.
    """
    iterates = [program.iterate.prepare(_state_like(program, keys, hyperparams), hyperparams,
                                        np.int32(1)) for keys, hyperparams in blocks]
    return iterates + [program.init.prepare(*block) for block in blocks]


def _state_like(program, keys, hyperparams):
    """The `TrainState` that `program.init(keys, hyperparams)` returns, as shapes placed as its
    arrays will be: committed to the keys' device where the keys are. Read from `init`'s program
    where it is at hand (kept on disk), traced otherwise."""
    init = program.init.loaded(keys, hyperparams)
    shapes = program.init.eval_shape(keys, hyperparams) if init is None else init.out_info
    sharding = keys.sharding if isinstance(keys, jax.Array) and keys.committed else None
    return jax.tree.map(
        lambda leaf: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, sharding=sharding), shapes)


def device_blocks(num_runs, device):
    """The blocks in which `device` trains `num_runs` runs, as `cpu_blocks` gives them: in
    `cpu_blocks` on a CPU, the runs whole in one block elsewhere."""
    if device.platform != "cpu":
        return [(0, num_runs)], num_runs
    return cpu_blocks(num_runs)


def part_blocks(part):
    """A part's runs as `run` trains them (`device_blocks`): `(inputs, runs)` of each block, whose
    first `runs` runs are the part's and the rest copies of them, where the block needs them."""
    keys = part[0]
    device = next(iter(keys.devices())) if isinstance(keys, jax.Array) else jax.devices()[0]
    bounds, size = device_blocks(keys.shape[0], device)

    def block(start, stop):
        full = stop - start == size
        runs = slice(start, stop) if full else np.resize(np.arange(start, stop), size)
        return jax.tree.map(lambda leaf: leaf[runs], part)

    return [(block(start, stop), stop - start) for start, stop in bounds]


def run_keys(seeds):
    """One PRNG key per seed, `[R, 2]` uint32: `jax.random.PRNGKey(seed)`, made on the host.

    Threefry's key of a 32-bit seed is its high word (0) and the seed itself.
    """
    seeds = np.asarray(seeds, dtype=np.uint32)
    return np.stack([np.zeros_like(seeds), seeds], axis=-1)


def train(config=TrainConfig(), seed=0, show_progress=True):
    """Trains one policy with REINFORCE.

    Returns:
      `TrainResult`: the final `policy_params` and `Metrics` with `[iterations]` leaves.
    """
    if not isinstance(config, TrainConfig):
        raise ValueError(f"config: expected a TrainConfig, got {type(config).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        raise ValueError(f"seed: must be an integer in [0, 2**32), got {seed!r}")
    hyperparams = jax.tree.map(lambda v: np.asarray([v], np.float32), config.hyperparams)
    with progress.bar(config.iterations, enabled=show_progress) as on_iteration:
        (result,) = run(
            compiled_program(config), config.iterations, [(run_keys([seed]), hyperparams)],
            on_iteration,
        )
    return jax.tree.map(lambda leaf: leaf[0], result)
