"""One training iteration of R runs at once: play, discount, compute the loss's gradient, step."""

import functools
from collections.abc import Callable
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import optax

from jaxpg import (
    distributions,
    hand_gradient,
    losses,
    policies,
    replay,
    returns,
    rng,
    rollout,
    runwise,
    sums,
)
from jaxpg.train_config import (
    ELEMENTWISE_OPTIMIZERS,
    Hyperparams,
    Ranges,
    TrainConfig,
    make_optimizer,
    steps_on_gradients,
)
from jaxpg.types import Array, ArrayLike, HostArray, Params, Policy, PRNGKey

# An array inside the training program, or its value on the host (numpy) once fetched.
Values = Array | HostArray


class TrainState(NamedTuple):
    """The carry of R runs from iteration to iteration.

    Parameters and optimizer state hold the runs on their last axis, where they meet each run's
    episodes `[T, E, R]`. On the fast path (`TrainConfig.hand_gradient`) each run's parameters
    are one vector (`policies.flatten`, `[P, R]`), and so are the moments of an optimizer in
    `ELEMENTWISE_OPTIMIZERS` (Adam among them), whose step is then a few kernels rather than a
    few per weight matrix and bias. Otherwise they are `{"policy": ..., "critic": ...}` as
    `init_run` makes them, leaves `[..., R]`.

    Attributes:
      params: the runs' parameters, `[P, R]` on the fast path, else a dict of `[..., R]` leaves.
      opt_state: the runs' optimizer state, leaves `[..., R]` (a dict by network off the fast
        path).
      key: uint32 `[R, 2]`, each run's PRNG key.
    """

    params: Params
    opt_state: optax.OptState
    key: PRNGKey


class Metrics(NamedTuple):
    """Per-iteration statistics of a run: `[I]`, or `[R, I]` for R runs.

    Attributes:
      mean_return: the mean return of the iteration's episodes.
      min_return: their lowest return.
      max_return: their highest return.
      mean_length: their mean length in steps.
      loss: the loss the step minimised (with the entropy bonus, where there is one).
      grad_norm: the global L2 norm of the policy's gradient.
      extra: the loss's own metrics by name (and `entropy` with an entropy bonus).
    """

    mean_return: Values
    min_return: Values
    max_return: Values
    mean_length: Values
    loss: Values
    grad_norm: Values
    extra: dict[str, Values] = {}

    def columns(self) -> dict[str, Values]:
        """Every metric by name, the loss's own beside the others: `{name: array}`."""
        fields = {name: getattr(self, name) for name in self._fields if name != "extra"}
        return {**fields, **self.extra}


class TrainResult(NamedTuple):
    """The trained policy, its per-iteration metrics and, where asked for, its evaluation.

    Attributes:
      policy_params: the final policy parameters, leading axis `[R]` for several runs.
      metrics: `Metrics`, `[I]` leaves, or `[R, I]` for several runs.
      evaluation: the held-out `Evaluation` of the final policy, or None where none was asked for.
      critic_params: the final parameters of a loss's critic (`losses.critic`), as
        `policy_params`; None for a loss without one.
    """

    policy_params: Params
    metrics: Metrics
    evaluation: "Evaluation | None" = None
    critic_params: Params | None = None


def is_run_alone(train_state: TrainState) -> bool:
    """Whether a `TrainState` holds one run (keys `[1, 2]`).

    `iterate` then plays and computes the run without its run axis, and `AloneOrTogether` picks
    the program compiled for that.
    """
    return train_state.key.shape[0] == 1


def global_norm(tree: Params) -> Array:
    """The L2 norm of every leaf together, summed in a fixed order so that it is batch-invariant.

    Args:
      tree: a pytree of arrays.

    Returns:
      A scalar.
    """
    squares = [sums.invariant_sum(jnp.square(leaf).ravel(), 0) for leaf in jax.tree.leaves(tree)]
    return jnp.sqrt(sum(squares))



def init_run(
    config: TrainConfig, key: PRNGKey, hyperparams: Hyperparams,
    policy_params: Params | None = None, critic_params: Params | None = None,
) -> tuple[Params, optax.OptState]:
    """The initial parameters and optimizer state of one run.

    On the fast path (`TrainConfig.hand_gradient`) the parameters are the policy's as one vector
    `[P]` (`policies.flatten`); otherwise `{"policy": ...}`, with `"critic"` for a loss that has
    one (`losses.critic`), each with its own optimizer state.

    Args:
      config: the `TrainConfig`.
      key: the run's key `[2]`.
      hyperparams: the run's `Hyperparams`, scalars.
      policy_params: optional: one run's policy parameters, as `policies.init_network` gives
        them, to start the policy from.
      critic_params: optional: one run's critic parameters, to start a loss's critic from.

    Returns:
      (params, opt_state) of the run.
    """
    network, obs_size = config.network, config.env_module.OBS_SIZE
    key_init = jax.random.split(key)[1]
    if policy_params is None:
        policy_params = policies.init_network(key_init, network, obs_size)
    optimizer = make_optimizer(config, hyperparams.learning_rate)
    if config.hand_gradient:
        flat = policies.flatten(policy_params, cast(policies.PolicyNetwork, network))
        return flat, optimizer.init(flat)
    params = {"policy": policy_params}
    critic = losses.critic(config.loss)
    if critic is not None:
        params["critic"] = (policies.init_network(jax.random.fold_in(key_init, 1), critic,
                                                  obs_size)
                            if critic_params is None else critic_params)
    return params, {name: optimizer.init(leaves) for name, leaves in params.items()}


def init_runs(config: TrainConfig, keys: PRNGKey, hyperparams: Hyperparams,
              policy_params: Params | None = None,
              critic_params: Params | None = None) -> TrainState:
    """The initial `TrainState` of R runs.

    Args:
      config: the `TrainConfig`.
      keys: uint32 `[R, 2]`, the runs' keys.
      hyperparams: `Hyperparams` with `[R]` leaves.
      policy_params: optional: one run's policy parameters, which every run's policy starts from.
      critic_params: optional: one run's critic parameters, which every run's critic starts from.

    Returns:
      `TrainState` of the R runs, run axes last (keys `[R, 2]`).
    """
    params, opt_state = jax.vmap(
        lambda key, hyper: init_run(config, key, hyper, policy_params, critic_params),
        out_axes=-1)(
        keys, hyperparams)
    return TrainState(params, opt_state, jax.vmap(lambda k: jax.random.split(k)[0])(keys))


def optimizer_step(config: TrainConfig, grads: Params, opt_state: optax.OptState,
                   policy_params: Params, learning_rate: ArrayLike
                   ) -> tuple[Params, optax.OptState]:
    """One optimizer step of one run's network: on the fast path its flat parameters `[P]`,
    otherwise each network's of `learn_run`.

    Args:
      config: the `TrainConfig`.
      grads: the run's gradient, shaped as `policy_params`.
      opt_state: the run's optimizer state of that network.
      policy_params: the run's parameters of the network.
      learning_rate: the run's learning rate, a scalar.

    Returns:
      (policy_params, opt_state) after the step.
    """
    updates, opt_state = make_optimizer(config, learning_rate).update(
        grads, opt_state, policy_params)
    return optax.apply_updates(policy_params, updates), opt_state


def iterate(config: TrainConfig, train_state: TrainState, hyperparams: Hyperparams,
            records: rollout.Records | None = None
            ) -> tuple[TrainState, Metrics, rollout.Records | None]:
    """One iteration of R runs at once: play, discount, take `config.updates` optimizer steps.

    Args:
      config: the `TrainConfig`.
      train_state: `TrainState` of the R runs.
      hyperparams: `Hyperparams` with `[R]` leaves.
      records: optional, the rollout's records, which it writes over (`initial_records`, then
        each iteration's) rather than clearing new ones.

    Returns:
      (`TrainState`, `Metrics` with `[R]` leaves, the records written over `records`, None
      without them)
    """
    episodes, key, key_minibatches = _play(config, train_state, hyperparams, records)
    learn: Callable[..., tuple[Params, optax.OptState, Array, Array, dict[str, Any]]] = (
        _learn_by_hand if config.hand_gradient else _learn)
    new_params, opt_state, loss, grad_norm, extra = learn(
        config, train_state, episodes, hyperparams, key_minibatches)
    metrics = Metrics(
        # Summed in a fixed order: a continuous task's returns are not whole numbers.
        mean_return=sums.invariant_sum(episodes.returns, 0) / episodes.returns.shape[0],
        min_return=episodes.returns.min(axis=0),
        max_return=episodes.returns.max(axis=0),
        mean_length=episodes.lengths.mean(axis=0),
        loss=loss,
        grad_norm=grad_norm,
        extra=extra,
    )
    return (TrainState(new_params, opt_state, key), metrics,
            None if records is None else episodes.records)


def initial_records(config: TrainConfig, train_state: TrainState,
                    hyperparams: Hyperparams) -> rollout.Records:
    """Zeros shaped as the records `iterate` writes for these runs: its first `records`."""
    played = jax.eval_shape(functools.partial(_play, config), train_state, hyperparams, None)[0]
    return tuple(jnp.zeros(leaf.shape, leaf.dtype) for leaf in played.records)


def _play(config: TrainConfig, train_state: TrainState, hyperparams: Hyperparams,
          records: rollout.Records | None) -> tuple[rollout.Episodes, PRNGKey, PRNGKey]:
    """The runs' episodes of one iteration, written over `records` (if given), and the keys of
    the next iteration and of this one's minibatches: (episodes `[T, E, R]`, key, key)."""
    key, key_rollout = rng.split(train_state.key)
    alone = is_run_alone(train_state)
    params = _without_run_axis(train_state.params) if alone else train_state.params
    env_params = _physics(hyperparams, alone)
    if config.randomize:
        key_rollout, key_physics = rng.split(key_rollout)
        num_episodes = rollout.played_episodes(config.episodes, rollout.LANES if alone else 1)
        env_params = _randomized(config.randomize, env_params, key_physics[0] if alone
                                 else key_physics, num_episodes)
    # With one minibatch, several epochs order that minibatch's episodes by the rollout's key:
    # the order changes no term of the loss. Several minibatches draw a key of their own.
    key_minibatches = key_rollout
    if config.minibatches > 1:
        key_rollout, key_minibatches = rng.split(key_rollout)

    # Play the episodes of every run with its current policy: [T, E, R] transitions. A run alone
    # plays without its run axis, XLA vectorising over its episodes instead, in whole vectors.
    # Runs side by side record the fast path's hidden activations for its gradient; a run alone
    # computes them again there: under XLA's own setting (not the command's), its rollout rounds
    # them otherwise than the gradient, and than the same run beside others (docs/performance.md).
    # A module's pass is recorded for its gradient alone and side by side alike (`replay_plan`).
    episodes = rollout.rollout(
        key_rollout[0] if alone else key_rollout, _policy(config, params, alone, record=True),
        env_params, config.episodes, config.max_steps,
        lanes=rollout.LANES if alone else 1, records=records,
    )
    if alone:
        episodes = episodes._replace(
            transitions=jax.tree.map(lambda leaf: jnp.expand_dims(leaf, 2), episodes.transitions),
            returns=episodes.returns[:, None], lengths=episodes.lengths[:, None])
    return episodes, key, key_minibatches


def _physics(hyperparams: Hyperparams, alone: bool) -> Any:
    """Each run's physics: `[R]` leaves, scalars for a run alone."""
    return _without_run_axis(hyperparams.env) if alone else hyperparams.env


EVALUATION = 1  # folded into a run's key for its held-out episodes, a key training never draws


class Evaluation(NamedTuple):
    """Held-out returns of each run's policy `[N]` (`[R, N]` for R runs).

    Attributes:
      sampled: the returns with actions sampled as in training.
      greedy: the returns with the likelier action taken.
    """

    sampled: Values
    greedy: Values


def evaluate_runs(config: TrainConfig, train_state: TrainState, hyperparams: Hyperparams,
                  episodes: int, randomized: bool = True) -> Evaluation:
    """R runs' current policies, each on `episodes` fresh episodes of its own.

    Each run's episodes come from its key with `EVALUATION` folded in and play in its training
    physics: with `config.randomize`, each episode draws its physics from the same ranges as in
    training (from the key with `EVALUATION` folded in twice), unless `randomized` is False.

    Args:
      config: the `TrainConfig`.
      train_state: `TrainState` of the R runs.
      hyperparams: `Hyperparams` with `[R]` leaves.
      episodes: how many episodes each run plays, static.
      randomized: static: False plays the runs' physics without drawing `config.randomize`'s
        fields (the config's physics, with the run's grid values).

    Returns:
      `Evaluation` with `[R, episodes]` returns; a run plays the same episodes alone as beside
      others.
    """
    alone = is_run_alone(train_state)
    params = _without_run_axis(train_state.params) if alone else train_state.params
    keys = jax.vmap(lambda key: jax.random.fold_in(key, EVALUATION))(train_state.key)
    policy = cast(policies.NetworkPolicy, _policy(config, params, alone))
    env_params = _physics(hyperparams, alone)
    if config.randomize and randomized:
        drawn = rollout.played_episodes(episodes, rollout.LANES if alone else 1)
        key_physics = jax.vmap(lambda key: jax.random.fold_in(key, EVALUATION))(keys)
        env_params = _randomized(config.randomize, env_params,
                                 key_physics[0] if alone else key_physics, drawn)

    def returns(policy: Policy) -> Array:
        """The returns `[R, episodes]` of the runs' episodes played by `policy`."""
        played = rollout.rollout(keys[0] if alone else keys, policy, env_params, episodes,
                                 config.max_steps, lanes=rollout.LANES if alone else 1).returns
        return played[None] if alone else jnp.moveaxis(played, -1, 0)

    return Evaluation(returns(policy), returns(policy.replace(greedy=True)))


def _randomized(ranges: Ranges, env_params: Any, key: PRNGKey, episodes: int) -> Any:
    """`env_params` with each field of `ranges` drawn per episode, uniformly in [low, high).

    The drawn fields have leaves `[episodes]` for a key `[2]`, or `[episodes, R]` for R keys
    `[R, 2]`.
    """
    keys = rng.split(key, len(ranges))
    return env_params.replace(**{
        name: rng.uniform(field_key, (episodes,), low, high)
        for (name, (low, high)), field_key in zip(ranges, keys)})


def _without_run_axis(tree: Any) -> Any:
    """`tree` with the trailing run axis of its leaves, of size one, taken off."""
    return jax.tree.map(lambda leaf: leaf[..., 0], tree)


def _policy(config: TrainConfig, params: Params, alone: bool, record: bool = False) -> Policy:
    """The rollout's policy of the runs' parameters.

    It maps `(obs [E, R, K], u [E, R])` to actions `[E, R]`, without the run axes for a run alone.
    With `record`, the policy records what its gradient reads back: the fast path's hidden
    activations for runs side by side (`policies.HiddenRecordingPolicy`), a module's pass where
    the gradient replays it (`replay_plan`).
    """
    network = config.network
    if config.hand_gradient:  # parameters taken apart where the rollout's kernels use them
        network_params = policies.unflatten(params, cast(policies.PolicyNetwork, network))
        if record and not alone and policies.records_hidden(network):
            return policies.HiddenRecordingPolicy(cast(policies.PolicyNetwork, network),
                                                  network_params)
        return policies.network_policy(network, network_params)
    plan = replay_plan(config, (rollout.played_episodes(
        config.episodes, rollout.LANES if alone else 1),)) if record else None
    if plan is not None:
        return replay.ReplayPolicy(plan, params["policy"], runs=not alone,
                                   num_actions=config.num_actions)
    return policies.network_policy(network, params["policy"], runs=not alone,
                                   num_actions=config.num_actions)


@functools.lru_cache(maxsize=64)
def replay_plan(config: TrainConfig, batch: tuple[int, ...]) -> replay.Plan | None:
    """The `replay.Plan` of the policy module's pass over observations `[*batch, K]`: a step of a
    rollout `[E']` or every step of the episodes `[T, E]`. None where the gradient does not
    replay the rollout's pass: on the fast path, with more than one update an iteration, or where
    a plan fails (`replay.plan`) or records otherwise for any of the shapes a run plays and
    learns on (a step alone and beside other runs, and `[T, E]`), which is decided for all of
    them together."""
    if config.hand_gradient or config.updates != 1:
        return None
    obs_size = config.env_module.OBS_SIZE
    params = jax.eval_shape(lambda key: policies.init_network(key, config.network, obs_size),
                            jax.ShapeDtypeStruct((2,), jnp.uint32))
    floats = jnp.result_type(float)
    shapes: set[tuple[int, ...]] = {batch, (config.max_steps, config.episodes)}
    shapes |= {(rollout.played_episodes(config.episodes, lanes),) for lanes in (1, rollout.LANES)}
    plans = {shape: replay.plan(config.network.apply, params,
                                jax.ShapeDtypeStruct((*shape, obs_size), floats))
             for shape in shapes}
    every = plans[config.max_steps, config.episodes]
    if every is None or any(p is None or not replay.same_layout(p, every)
                            for p in plans.values()):
        return None
    return plans[batch]


def _learn_by_hand(
    config: TrainConfig, train_state: TrainState, episodes: rollout.Episodes,
    hyperparams: Hyperparams, keys: PRNGKey,
) -> tuple[Array, optax.OptState, Array, Array, dict[str, Values]]:
    """The fast path's step: the book's loss and its gradient by `hand_gradient.loss_and_grad`."""
    del keys  # one step on all the episodes
    network = cast(policies.PolicyNetwork, config.network)
    transitions = episodes.transitions
    # Discounted returns, normalised over every step of every episode of a run.
    advantages = returns.discount_and_normalize_masked(
        transitions.reward, transitions.alive, cast(Array, hyperparams.discount)  # traced
    )
    loss, grad_arrays = hand_gradient.loss_and_grad(
        policies.unflatten(train_state.params, network), network, transitions, advantages,
        None if episodes.policy_features is None else episodes.policy_features[0])
    grads = policies.flatten(grad_arrays, network)
    # The step runs with the runs first (`runwise.vmap_runs_first`).
    params, opt_state = runwise.vmap_runs_first(functools.partial(optimizer_step, config))(
        grads, train_state.opt_state, train_state.params, hyperparams.learning_rate)
    # Summed by parameter array: over the one vector, LLVM fuses a few of the squares into the
    # additions for one number of runs and not another.
    grad_norm = jax.vmap(global_norm, in_axes=-1)(grad_arrays)
    return params, opt_state, loss, grad_norm, {}


def _learn(
    config: TrainConfig, train_state: TrainState, episodes: rollout.Episodes,
    hyperparams: Hyperparams, keys: PRNGKey,
) -> tuple[dict[str, Params], dict[str, optax.OptState], Array, Array, dict[str, Array]]:
    """Any other policy, loss or optimizer: `learn_run` of every run, by `runwise`.

    `runwise` evaluates it with the runs on the last axis, matrix products as multiply-adds and
    every sum in a fixed order, so a run rounds alike alone (no run axis) and beside others.
    """
    alone = is_run_alone(train_state)
    transitions = episodes.transitions
    if alone:
        transitions = jax.tree.map(lambda leaf: leaf[:, :, 0], transitions)
        args = _without_run_axis((train_state.params, train_state.opt_state, hyperparams))
    else:  # the run axis last, as `runwise` takes it
        transitions = transitions._replace(obs=jnp.moveaxis(transitions.obs, -2, -1))
        args = (train_state.params, train_state.opt_state, hyperparams)
    batch = losses.Batch(
        transitions.obs, transitions.action, transitions.reward, transitions.alive,
        returns.discount_masked(transitions.reward, transitions.alive,
                                cast(Array, args[2].discount)))  # traced
    outs = runwise.runwise(functools.partial(learn_run, config), batched=not alone)(
        *args[:2], batch, args[2], keys[0] if alone else keys.T,
        None if episodes.policy_features is None else tuple(
            leaf[0] for leaf in episodes.policy_features))
    return jax.tree.map(lambda leaf: leaf[..., None], outs) if alone else outs


def learn_run(
    config: TrainConfig, params: dict[str, Params], opt_state: dict[str, optax.OptState],
    batch: losses.Batch, hyper: Hyperparams, key: PRNGKey,
    played: tuple[Array, ...] | None = None,
) -> tuple[dict[str, Params], dict[str, optax.OptState], Array, Array, dict[str, Array]]:
    """One run's optimizer steps on its loss plus the entropy bonus: `TrainConfig.updates` of them.

    The batch gains what played it (`Batch.log_prob`, `Batch.values`), held fixed; then each
    epoch steps once per minibatch of whole episodes. Each network (the policy and a loss's
    critic) is stepped by its own optimizer.

    Args:
      config: the `TrainConfig`.
      params: `{"policy": ...}`, with `"critic"` for a loss that has one.
      opt_state: each network's optimizer state, by the same names.
      batch: the run's episodes, `[T, E]`, without `log_prob` and `values`.
      hyper: the run's `Hyperparams`, scalars.
      key: the run's key `[2]` for its minibatches, used with several.
      played: optional, where `replay_plan` serves: the policy's pass as the rollout recorded it,
        each value `[T, E, n]` (`replay.ReplayPolicy`), which the loss's `apply_fn` of the policy's
        parameters on `batch.obs` replays rather than computing again.

    Returns:
      (params, opt_state, loss, grad_norm of the policy's gradient, the loss's metrics, with
      `entropy`, the mean entropy over alive steps, where `config.entropy_coef` is not 0); the
      last three averaged over the updates.
    """
    loss_fn = losses.resolve(config.loss)
    distribution = functools.partial(policies.distribution, config.network,
                                     num_actions=config.num_actions)
    critic = losses.critic(config.loss)
    if played is None:
        played_dist = distribution(params["policy"], batch.obs)
    else:
        plan = cast(replay.Plan, replay_plan(config, batch.obs.shape[:-1]))
        played_dist = distributions.from_output(replay.output(plan, played), batch.obs.shape,
                                                config.num_actions)
    batch = jax.lax.stop_gradient(batch._replace(
        log_prob=losses.log_prob(played_dist, batch.action),
        values=jnp.zeros_like(batch.reward) if critic is None
        else cast(Array, critic.apply(params["critic"], batch.obs))))

    def total(params: dict[str, Params], batch: losses.Batch) -> tuple[Array, dict[str, Array]]:
        """The loss plus the entropy bonus, and the metrics."""
        apply_fn = _once_per_input(distribution if played is None else _replaying(
            distribution, config.num_actions, plan, params["policy"], batch.obs, played))
        loss, metrics = loss_fn(params if critic else params["policy"], apply_fn, batch, hyper)
        if not config.entropy_coef:  # no run has a bonus (`programs.compiled_program`)
            return loss, metrics
        entropy = losses.masked_mean(losses.entropy(apply_fn(params["policy"], batch.obs)),
                                     batch.alive)
        return loss - hyper.entropy_coef * entropy, {**metrics, "entropy": entropy}

    def step(grads: dict[str, Params], opt_state: dict[str, optax.OptState],
             params: dict[str, Params], learning_rate: Array
             ) -> tuple[dict[str, Params], dict[str, optax.OptState]]:
        """One optimizer step of every network, each by its own optimizer (`optimizer_step`)."""
        stepped = {name: optimizer_step(config, grads[name], opt_state[name], params[name],
                                        learning_rate) for name in params}
        return ({name: new for name, (new, _) in stepped.items()},
                {name: state for name, (_, state) in stepped.items()})

    # One update on one episode, of an elementwise optimizer, steps with the runs first, as the
    # fast path does (`runwise.runs_first`): with the runs last, Adam's moments rounded otherwise
    # alone there. Not elsewhere: it slowed a 32x32 MLP's training by half, and inside the loop of
    # several updates more runs rounded otherwise alone, not fewer (docs/performance.md).
    if (config.optimizer in ELEMENTWISE_OPTIMIZERS and config.updates == 1
            and config.episodes == 1):
        step = runwise.runs_first(step)

    def update(carry: tuple[dict[str, Params], dict[str, optax.OptState]], batch: losses.Batch
               ) -> tuple[tuple[dict[str, Params], dict[str, optax.OptState]],
                          tuple[Array, Array, dict[str, Array]]]:
        """One optimizer step of every network on `batch`: (params, opt_state), (loss, grad
        norm, metrics)."""
        params, opt_state = carry
        (loss, metrics), grads = jax.value_and_grad(total, has_aux=True)(params, batch)
        params, opt_state = step(grads, opt_state, params, cast(Array, hyper.learning_rate))
        return (params, opt_state), (loss, global_norm(grads["policy"]), metrics)

    if config.updates == 1:
        (params, opt_state), (loss, grad_norm, metrics) = update((params, opt_state), batch)
        return params, opt_state, loss, grad_norm, metrics
    # A scan, not unrolled updates: each update's state reaches the next through the loop's
    # carry, in memory. Unrolled, XLA fuses one update's optimizer arithmetic into the next
    # update's kernels otherwise for a run alone than beside others, and LLVM then fuses other
    # multiplications and additions into one rounding. The update also compiles once, not once
    # per update.
    (params, opt_state), outs = jax.lax.scan(update, (params, opt_state),
                                             minibatches(config, batch, key))
    loss, grad_norm, metrics = jax.tree.map(lambda leaf: jnp.mean(leaf, axis=0), outs)
    return params, opt_state, loss, grad_norm, metrics


def minibatches(config: TrainConfig, batch: losses.Batch, key: PRNGKey) -> losses.Batch:
    """The minibatches of every epoch, in order: whole episodes, shuffled anew each epoch.

    Args:
      config: the `TrainConfig`, whose `epochs` and `minibatches` they are.
      batch: one run's episodes, `[T, E]` leading axes.
      key: the run's key `[2]`; each epoch orders the episodes by its own uniforms.

    Returns:
      `Batch` with leaves `[epochs * minibatches, T, E / minibatches, ...]`.
    """
    episodes = config.episodes // config.minibatches
    orders = jnp.argsort(rng.uniform(key, (config.epochs, config.episodes)), axis=-1)

    def split(leaf: Array) -> Array:
        """`[T, E, ...]` as `[epochs * minibatches, T, E / minibatches, ...]`."""
        shuffled = jnp.take(leaf, orders.reshape(-1), axis=1)  # [T, epochs * E, ...]
        grouped = shuffled.reshape(leaf.shape[0], -1, episodes, *leaf.shape[2:])
        return jnp.moveaxis(grouped, 1, 0)

    return jax.tree.map(split, batch)


def _replaying(distribution: losses.ApplyFn, num_actions: int | None, plan: replay.Plan,
               policy_params: Params, obs: Array, played: tuple[Array, ...]) -> losses.ApplyFn:
    """The loss's `apply_fn`: on `policy_params` and `obs`, the pass the rollout recorded in
    `played` (`replay.replayed`); on any other arguments, `distribution`, the module's own."""
    replayed = replay.replayed(plan)

    def apply(params: Params, observations: Array) -> Any:
        """The action distribution of `params` on `observations`."""
        if params is policy_params and observations is obs:
            return distributions.from_output(replayed(params, obs, played), obs.shape,
                                             num_actions)
        return distribution(params, observations)

    return apply


def _once_per_input(apply_fn: losses.ApplyFn) -> losses.ApplyFn:
    """`apply_fn(params, obs)`, computed once for the same arrays (inside one trace).

    The loss's logits and the entropy bonus's are then one forward pass, and one backward.
    """
    computed: dict[tuple[tuple[int, ...], int], tuple[Array, Params, Array]] = {}

    def apply(params: Params, obs: Array) -> Array:
        """`apply_fn(params, obs)`, computed on the first call with these arrays."""
        key = (tuple(map(id, jax.tree.leaves(params))), id(obs))
        if key not in computed:  # the inputs are kept too, so that their ids stay theirs
            computed[key] = (apply_fn(params, obs), params, obs)
        return computed[key][0]

    return apply


def check_config(config: TrainConfig) -> tuple[str, ...]:
    """Checks the policy, loss and optimizer of `config` by their shapes alone, before compiling.

    Each is traced by `jax.eval_shape`, which compiles nothing.

    Args:
      config: the `TrainConfig`.

    Returns:
      The names of the loss's metrics (`Metrics.extra`), in the order of their leaves.

    Raises:
      ValueError: naming the field at fault: an optimizer function that returns no
        `optax.GradientTransformation`, one that asks for more than the gradient, or one whose
        update returns no (updates, state) with updates of the parameters' tree and shapes; a
        policy whose logits are not floating; or a loss that returns no (scalar, dict of
        scalars).
    """
    optimizer = make_optimizer(config, 0.01)
    if not isinstance(optimizer, optax.GradientTransformation):
        raise ValueError(f"optimizer: the function must return an optax.GradientTransformation, "
                         f"got {type(optimizer).__name__}")
    if not steps_on_gradients(optimizer):
        raise ValueError("optimizer: the function's optimizer asks for more than the gradient, "
                         "its state and the parameters in its update (as optax's lbfgs does)")
    if config.hand_gradient:  # optax's own elementwise optimizer on the default network
        return ()
    params, opt_state = jax.eval_shape(
        lambda key: init_run(config, key, config.hyperparams),
        jax.ShapeDtypeStruct((2,), jnp.uint32))
    try:
        state = jax.eval_shape(optimizer.init, params)
        step = jax.eval_shape(lambda p: optimizer.update(p, optimizer.init(p), p), params)
    except Exception as error:  # the optimizer's own code, on these parameters' shapes
        raise ValueError(f"optimizer: cannot step the parameters, of shapes "
                         f"{jax.tree.map(lambda leaf: leaf.shape, params)}: "
                         f"{type(error).__name__}: {error}".splitlines()[0]) from None
    if not (isinstance(step, tuple) and len(step) == 2):
        raise ValueError(f"optimizer: its update must return (updates, state), got "
                         f"{type(step).__name__}")
    _check_alike("updates", params, step[0])
    if not all(jnp.issubdtype(leaf.dtype, jnp.floating) for leaf in jax.tree.leaves(step[0])):
        raise ValueError("optimizer: its update must return floating updates, got "
                         f"{sorted({str(leaf.dtype) for leaf in jax.tree.leaves(step[0])})}")
    _check_alike("state", state, step[1])
    floats = jnp.result_type(float)
    hyper = jax.tree.map(lambda leaf: jax.ShapeDtypeStruct((), leaf.dtype),
                         config.hyperparams.per_run())
    steps = (config.max_steps, config.episodes)
    shaped: Any = jax.ShapeDtypeStruct  # a batch of shapes, in place of arrays
    batch = losses.Batch(shaped((*steps, config.env_module.OBS_SIZE), floats),
                         shaped(steps, floats if config.num_actions is None else jnp.int32),
                         shaped(steps, floats), shaped(steps, bool), shaped(steps, floats))
    apply_fn = functools.partial(policies.distribution, config.network,
                                 num_actions=config.num_actions)
    dist = jax.eval_shape(apply_fn, params["policy"], batch.obs)
    if not all(jnp.issubdtype(leaf.dtype, jnp.floating) for leaf in jax.tree.leaves(dist)):
        raise ValueError(f"policy: the module's logits must be floating, got "
                         f"{jax.tree.leaves(dist)[0].dtype}")
    loss_fn = losses.resolve(config.loss)
    has_critic = losses.critic(config.loss) is not None
    played = batch._replace(log_prob=shaped(steps, floats), values=shaped(steps, floats))
    out = jax.eval_shape(lambda p, b, h: loss_fn(p if has_critic else p["policy"], apply_fn, b, h),
                         params, played, hyper)
    if not (isinstance(out, tuple) and len(out) == 2 and _is_scalar(out[0])
            and isinstance(out[1], dict) and all(map(_is_scalar, out[1].values()))):
        raise ValueError(f"loss: must return (a scalar loss, a dict of scalar metrics), got "
                         f"{jax.tree.map(lambda leaf: leaf.shape, out)}")
    metrics = jax.eval_shape(functools.partial(learn_run, config), params, opt_state, batch,
                             hyper, jax.ShapeDtypeStruct((2,), jnp.uint32))[-1]
    return tuple(sorted(metrics))


def _check_alike(what: str, expected: Any, got: Any) -> None:
    """Checks that the optimizer's update returned `what` ("updates" or "state") like `expected`.

    Raises:
      ValueError: naming the optimizer, with both trees' shapes.
    """
    def shape(leaf: Any) -> Any:
        """A leaf's shape, with its dtype for the state (updates are cast to the parameters')."""
        return leaf.shape if what == "updates" else (leaf.shape, str(leaf.dtype))

    shapes = [jax.tree.map(shape, tree) for tree in (expected, got)]
    # jaxlib's stubs leave PyTreeDef unresolved, so mypy cannot compare two of them.
    if (jax.tree.structure(expected) != jax.tree.structure(got)  # type: ignore[operator]
            or shapes[0] != shapes[1]):
        source = ("the parameters' tree and shapes" if what == "updates"
                  else "its init's tree, shapes and dtypes")
        raise ValueError(f"optimizer: its update must return {what} of {source}, {shapes[0]}, "
                         f"got {shapes[1]}")


def _is_scalar(leaf: Any) -> bool:
    """Whether `leaf` is an array (or shape) of no axes."""
    return hasattr(leaf, "shape") and leaf.shape == ()
