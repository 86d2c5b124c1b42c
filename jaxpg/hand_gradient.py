"""The REINFORCE gradient of the default network, derived by hand: the fast path.

`loss_and_grad` computes the book's loss and its gradient for `policies.PolicyNetwork` from
every step's signals at once, summed over time in a loop that stops at the last alive step, for
runs on trailing axes; any other policy or loss is differentiated by JAX (`jaxpg.iteration`)."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxpg import fastmath, losses, policies, rollout, sums
from jaxpg.types import Array, Params

# The loop's carry: the loss's total and each layer's (kernel, bias) totals, per episode.
_Totals = tuple[Array, list[tuple[Array, Array]]]


def reinforce_loss(policy_params: Params, network: policies.PolicyNetwork,
                   transitions: rollout.Transition, advantages: Array) -> Array:
    """Mean over the alive steps of -advantage * log pi(a|s), by JAX's ordinary operations.

    Its gradient is the book's: the gradient of the binary cross-entropy between P(left) and the
    action taken, weighted by the normalised return and averaged over every step of every episode.

    Args:
      policy_params: the `PolicyNetwork`'s parameters, with R runs on trailing axes (kernels
        `[K, N, *runs]`).
      network: the `PolicyNetwork`.
      transitions: the episodes, `[T, E, *runs]` leading axes (obs `[T, E, *runs, 4]`).
      advantages: float `[T, E, *runs]`, each step's weight.

    Returns:
      The loss `[*runs]`.
    """
    logits = policies.forward(policy_params, transitions.obs, network.activation)
    terms = advantages * losses.log_prob(logits, transitions.action)
    return -sums.invariant_mean(terms, (0, 1), transitions.alive)


def loss_and_grad(policy_params: Params, network: policies.PolicyNetwork,
                  transitions: rollout.Transition, advantages: Array,
                  hidden: Array | None = None) -> tuple[Array, Params]:
    """`reinforce_loss` and its gradient: every step's share at once, added up over time in a loop.

    Each dense layer's input and output cotangent come for every step at once; a loop up to the
    last alive step adds their outer products per episode in time order, and the E episodes are
    summed at the end in a fixed order (`sums.invariant_sum`), so that a run rounds the same alone
    as in a sweep. A run alone (no run axis) pads its episodes to whole vectors of
    `rollout.LANES` with episodes of no alive step (all zeros). With finite parameters the padding
    changes no sum: a padded episode's totals stay +0 (a total starts at +0 and adding zeros keeps
    it), `sums.invariant_sum` pads the episode axis with zeros anyway, and the count of alive
    steps is taken before the padding. The step signals take `[K, T, E, *runs]` floats per layer,
    which `jaxpg.budget` counts.

    Args:
      policy_params: as for `reinforce_loss`.
      network: the `PolicyNetwork`.
      transitions: as for `reinforce_loss`.
      advantages: as for `reinforce_loss`.
      hidden: optional, for `"elu"` layers: the hidden layers' activations at each step as the
        rollout recorded them, `[sum(hidden), T, E, *runs]` (`policies.HiddenRecordingPolicy`),
        read rather than computed again.

    Returns:
      (loss `[*runs]`, gradient shaped as `policy_params`).
    """
    run_shape = advantages.shape[2:]
    # Counted before any padding: the same sum as the normalisation's, which XLA computes once.
    count = jnp.maximum(sums.invariant_sum(transitions.alive.astype(advantages.dtype), (0, 1)), 1)
    alone = _alone(advantages.shape)
    if alone:
        transitions, advantages, hidden = _padded_episodes(transitions, advantages, hidden,
                                                           rollout.LANES)
    weights = jnp.where(transitions.alive, advantages, 0.0)
    layers = policy_params["params"]
    names = [f"Dense_{i}" for i in range(len(layers))]
    terms, inputs, cotangents = _step_signals(policy_params, network, transitions, weights,
                                              hidden)
    # A run alone's signals come without its run axes, which its totals get back at the end.
    runs = 0 if alone else len(run_shape)

    # Summed over time per episode; steps after every episode ended weigh nothing. A step is a few
    # multiply-adds on small accumulators, which XLA runs one after another (docs/performance.md).
    def add_step(t: Array, totals: _Totals) -> _Totals:
        """`totals` with step `t` of every episode added."""

        def at(array: Array, axis: int) -> Array:
            """Step `t` of `array`, whose time axis is `axis`."""
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

    def over_episodes(total: Array) -> Array:
        """-`[..., E, *runs]` summed over E, per alive step: `[..., *run_shape]`."""
        total = sums.invariant_sum(total, total.ndim - runs - 1)
        return -total.reshape(total.shape[:total.ndim - runs] + run_shape) / count

    loss, layer_totals = jax.tree.map(over_episodes, totals)
    grads = {"params": {name: {"kernel": kernel, "bias": bias}
                        for name, (kernel, bias) in zip(names, layer_totals)}}
    return loss, grads


def _alone(shape: tuple[int, ...]) -> bool:
    """Whether `[T, E, *runs]` is a run alone: no run axes, or run axes of one entry."""
    return math.prod(shape[2:]) == 1


def _padded_episodes(transitions: rollout.Transition, advantages: Array, hidden: Array | None,
                     multiple: int) -> tuple[rollout.Transition, Array, Array | None]:
    """Episodes `[T, E, ...]`, their advantages and any recorded hidden activations
    `[N, T, E, ...]`, padded to a multiple of `multiple` episodes.

    The padding is episodes of no alive step, all zeros.
    """
    extra = -advantages.shape[1] % multiple

    def pad(leaf: Array, axis: int = 1) -> Array:
        """`leaf` with `extra` episodes of zeros appended on its episode `axis`."""
        return jnp.pad(leaf, [(0, 0)] * axis + [(0, extra)] + [(0, 0)] * (leaf.ndim - axis - 1))

    return (jax.tree.map(pad, transitions), pad(advantages),
            None if hidden is None else pad(hidden, 2))


def _step_signals(policy_params: Params, network: policies.PolicyNetwork,
                  transitions: rollout.Transition, weights: Array, hidden: Array | None
                  ) -> tuple[Array, list[Array], list[Array]]:
    """Every step's weighted log-probability and each dense layer's input and output cotangent.

    They are `[T, E, *runs]`, `[K, T, E, *runs]` and `[N, T, E, *runs]`, computed at once, from
    the recorded `hidden` activations where given. The
    cotangents are the gradient with respect to zero offsets on each layer's output. A run
    alone computes them over its steps and episodes as one axis, and returns them without run
    axes (`[T, E]`, `[K, T, E]`, `[N, T, E]`): XLA vectorises over the last axis, which a run axis
    of size one would be, and gives such arrays other layouts than the loop over them takes.
    """
    shape = weights.shape
    obs, action = transitions.obs, transitions.action
    alone = _alone(shape)
    if alone:
        policy_params = _without_runs(policy_params, len(shape) - 2)
        obs, action, weights = (obs.reshape(-1, obs.shape[-1]), action.reshape(-1),
                                weights.reshape(-1))
        hidden = None if hidden is None else hidden.reshape(hidden.shape[0], -1)
    layers_hidden = None if hidden is None else policies.hidden_layers(hidden, network)

    def forward(offsets: list[Array]) -> tuple[Array, list[Array]]:
        """The log-probability of each action taken, and each layer's inputs."""
        logits, inputs = policies.forward_layers(policy_params, obs, network.activation, offsets,
                                                 layers_hidden)
        return losses.log_prob(logits, action, fastmath.log_sigmoid), inputs

    layers = policy_params["params"]
    offsets = [jnp.zeros((layers[f"Dense_{i}"]["bias"].shape[0], *weights.shape), weights.dtype)
               for i in range(len(layers))]
    log_prob, vjp, inputs = jax.vjp(forward, offsets, has_aux=True)
    (cotangents,) = vjp(weights)
    signals = (weights * log_prob, inputs, cotangents)
    if alone:  # back to [..., T, E]
        signals = jax.tree.map(lambda leaf: leaf.reshape(*leaf.shape[:-1], *shape[:2]), signals)
    return signals


def _without_runs(policy_params: Params, runs: int) -> Params:
    """The parameters of a run alone without their `runs` trailing run axes, all of size one."""
    return jax.tree.map(lambda leaf: leaf.reshape(leaf.shape[:leaf.ndim - runs]), policy_params)
