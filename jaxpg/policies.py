"""Policies: the book's hand-coded angle policy and the flax policy networks.

A policy, as `rollout` uses it, maps a batch of observations `[E, K]` and uniforms `u [E]` in
[0, 1) to actions `[E]`: on CartPole 0 pushes left, 1 pushes right. A policy module's output is
an action distribution (`jaxpg.distributions`): the logit of P(push left) on CartPole, n logits on
another discrete environment, a mean and a log standard deviation on a continuous one.
"""

import functools
import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Self

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxpg import distributions, fastmath, runwise, sums
from jaxpg.types import Action, Observation, Params, PRNGKey
from jaxpg.validation import check_choice, is_int

# The shape of each parameter of a `PolicyNetwork`: {"params": {"Dense_i": {"bias", "kernel"}}}.
ParameterShapes = dict[str, dict[str, dict[str, tuple[int, ...]]]]

ACTIVATIONS = {
    "elu": nn.elu,
    "relu": nn.relu,
    "tanh": nn.tanh,
    "sigmoid": nn.sigmoid,
    "gelu": nn.gelu,
    "selu": nn.selu,
    "swish": nn.swish,
    "softplus": nn.softplus,
}

# `forward`'s activations, whose arrays lie alike for a run alone and in a block: the built-in
# network's rollouts, evaluation and hand-derived gradient. A module's (`PolicyNetwork`'s own
# `apply`, differentiated by `runwise`) keep `jax.nn`'s: alone, `runwise` lays its arrays out
# otherwise than in a block, and LLVM contracts a polynomial's multiply-adds otherwise.
_FORWARD_ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    **ACTIVATIONS, "elu": fastmath.elu}


def basic_policy(obs: Observation, u: jax.Array | None = None) -> Action:
    """0 (push left) if the pole angle is negative, else 1.

    Args:
      obs: observations of any batch shape, `[..., 4]`.
      u: ignored: the policy is deterministic.

    Returns:
      int32 actions `[...]`.
    """
    del u  # deterministic
    return jnp.where(obs[..., 2] < 0, 0, 1).astype(jnp.int32)


def check_network(hidden: Sequence[int], activation: str) -> None:
    """Checks the layer sizes and the activation of a `PolicyNetwork`.

    Raises:
      ValueError: naming `hidden` unless every size is a positive integer, or `activation`
        unless it is one of `ACTIVATIONS`.
    """
    check_choice("activation", activation, ACTIVATIONS)
    if not isinstance(hidden, tuple | list) or any(
            not is_int(h) or h < 1 for h in hidden):
        raise ValueError(f"hidden: must be a tuple of positive layer sizes (none: a linear "
                         f"policy), got {hidden!r}")


class PolicyNetwork(nn.Module):
    """Dense(hidden) -> activation -> ... -> Dense(outputs): the logit of P(push left) `[...]`, or
    the logits of n actions `[..., n]`.

    Weights start Glorot-uniform and biases at zero, as Keras's Dense does. Its own `apply` is
    flax's dense layers, which the trainer differentiates as any module's (`jaxpg.runwise`);
    `forward` computes the same logits, to rounding, for the fast path, rollouts and evaluation,
    also for many runs' parameters at once.

    Attributes:
      hidden: the sizes of the hidden layers; none for a linear policy.
      activation: the name of the activation after each hidden layer, one of `ACTIVATIONS`.
      outputs: 1 for CartPole's one logit `[...]`; n for the logits of n actions `[..., n]`.
    """

    hidden: Sequence[int] = (5,)
    activation: str = "elu"
    outputs: int = 1

    @nn.compact
    def __call__(self, obs: Observation) -> jax.Array:
        """The logits `[...]` (`[..., n]`) for observations `[..., K]`."""
        features = obs
        for size in self.hidden:
            features = ACTIVATIONS[self.activation](_dense(size)(features))
        out = _dense(self.outputs)(features)
        return out[..., 0] if self.outputs == 1 else out


class GaussianNetwork(nn.Module):
    """A `PolicyNetwork` of one output for the mean of a continuous action, and a learned log
    standard deviation, one parameter starting at 0: (mean, log std) `[..., 2]`.

    Attributes:
      hidden: the sizes of the mean's hidden layers.
      activation: their activation, one of `ACTIVATIONS`.
    """

    hidden: Sequence[int] = (5,)
    activation: str = "elu"

    @nn.compact
    def __call__(self, obs: Observation) -> jax.Array:
        """(mean, log std) `[..., 2]` for observations `[..., K]`."""
        mean = PolicyNetwork(self.hidden, self.activation)(obs)
        log_std = self.param("log_std", nn.initializers.zeros, ())
        return jnp.stack([mean, jnp.broadcast_to(log_std, mean.shape)], axis=-1)


def _dense(features: int) -> nn.Dense:
    """A dense layer of `features` outputs, Glorot-uniform weights and zero biases."""
    return nn.Dense(features, kernel_init=nn.initializers.glorot_uniform())


def forward(policy_params: Params, obs: Observation, activation: str) -> jax.Array:
    """The logits `[...]` of `PolicyNetwork` for observations `[..., 4]`.

    Features lead (`[4, ...]`, not `[..., 4]`), so that XLA vectorises over the batch rather than
    over four or five features. Parameters may carry trailing run axes `[R]` (kernels `[K, N, R]`)
    against observations `[..., R, 4]`: every run's weights then meet its own observations, on the
    fastest-varying axis.

    Args:
      policy_params: the parameters of a `PolicyNetwork`, `{"params": {"Dense_i": ...}}`.
      obs: observations `[..., 4]`, or `[..., R, 4]` for R runs' parameters.
      activation: the network's activation, a key of `ACTIVATIONS`.

    Returns:
      The logits of P(push left) `[...]` (`[..., R]`).
    """
    return forward_layers(policy_params, obs, activation)[0]


def forward_layers(policy_params: Params, obs: Observation, activation: str,
                   offsets: Sequence[jax.Array] | None = None,
                   hidden: Sequence[jax.Array] | None = None
                   ) -> tuple[jax.Array, list[jax.Array]]:
    """`forward`'s logits and the input features `[K, ...]` of each dense layer.

    Args:
      policy_params: as for `forward`.
      obs: as for `forward`.
      activation: as for `forward`.
      offsets: optional: one per layer, shaped like its output features `[N, ...]`, added to the
        layers' outputs: the gradient with respect to them is the cotangent of each layer's output.
      hidden: optional, for `"elu"`: the hidden layers' activations `[N, ...]`, computed before
        (`HiddenRecordingPolicy`): taken as they are, with `elu`'s derivative from them
        (`fastmath.elu_of_value`), rather than computed again.

    Returns:
      (logits `[...]`, the input features of each layer, `[K, ...]` each, features first).
    """
    layers = policy_params["params"]
    features = jnp.moveaxis(obs, -1, 0)
    inputs = []
    for i in range(len(layers)):
        if i:
            features = (_FORWARD_ACTIVATIONS[activation](features) if hidden is None
                        else fastmath.elu_of_value(features, hidden[i - 1]))
        inputs.append(features)
        layer = layers[f"Dense_{i}"]
        features = dense(features, layer["kernel"], layer["bias"])
        if offsets is not None:
            features = features + offsets[i]
    return features[0], inputs


def _along(weights: jax.Array, x: jax.Array) -> jax.Array:
    """`weights` `[N, *runs]` shaped to broadcast against one feature of `x` `[K, *batch, *runs]`:
    `[N, 1, ..., 1, *runs]`."""
    runs = weights.ndim - 1
    return weights.reshape(weights.shape[0], *(1,) * (x.ndim - 1 - runs), *weights.shape[1:])


@jax.custom_vjp
def dense(x: jax.Array, kernel: jax.Array, bias: jax.Array) -> jax.Array:
    """Output features `[N, ...]`: `sum_k x[k] * kernel[k] + bias`, for input features `[K, ...]`.

    The policy's matrices are tiny: written as K multiply-adds over whole batches they fuse with
    the activations and the physics around them instead of becoming one small matrix-multiply call
    per layer and step. The gradient sums over the batch in a fixed order (`sums.invariant_sum`),
    so it rounds the same for a run alone as for a run in a sweep.

    Args:
      x: input features `[K, *batch]`, or `[K, *batch, *runs]`.
      kernel: `[K, N]`, or `[K, N, *runs]`.
      bias: `[N]`, or `[N, *runs]`.

    Returns:
      Output features `[N, *batch]` (`[N, *batch, *runs]`).
    """
    out = x[0] * _along(kernel[0], x)
    for k in range(1, x.shape[0]):
        out = out + x[k] * _along(kernel[k], x)
    return out + _along(bias, x)


def _dense_fwd(x: jax.Array, kernel: jax.Array, bias: jax.Array
               ) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """`dense`'s output and the residuals (x, kernel) its gradient needs."""
    return dense(x, kernel, bias), (x, kernel)


def _dense_bwd(residuals: tuple[jax.Array, jax.Array], grad: jax.Array
               ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The cotangents of (x, kernel, bias) from that of `dense`'s output `[N, ...]`."""
    x, kernel = residuals
    runs = kernel.ndim - 2
    batch = tuple(range(x.ndim - 1 - runs))  # the batch axes once the feature axis is last
    x_last = jnp.moveaxis(x, 0, len(batch))  # [*batch, K, *runs]
    grad_last = jnp.moveaxis(grad, 0, len(batch))  # [*batch, N, *runs]
    grad_x = grad[0] * _along(kernel[:, 0], grad)
    for n in range(1, grad.shape[0]):
        grad_x = grad_x + grad[n] * _along(kernel[:, n], grad)
    products = x_last[..., :, None, *(slice(None),) * runs] * jnp.expand_dims(grad_last, len(batch))
    return (
        grad_x,
        sums.invariant_sum(products, batch),
        sums.invariant_sum(grad_last, batch),
    )


dense.defvjp(_dense_fwd, _dense_bwd)


def init_network(key: PRNGKey, network: nn.Module, obs_size: int = 4) -> Params:
    """Initial `policy_params` of a policy module (a `PolicyNetwork` or any other).

    Args:
      key: PRNG key.
      network: the module, initialised by `network.init` on one observation `[obs_size]`.
      obs_size: K, the size of the environment's observations (CartPole's 4 by default).

    Returns:
      Its parameters, without run axes.
    """
    return network.init(key, jnp.zeros((obs_size,)))


def parameter_shapes(network: PolicyNetwork) -> ParameterShapes:
    """The shape of each parameter of `init_network(key, network)`, under the same keys."""
    sizes = (4, *network.hidden, 1)
    return {"params": {f"Dense_{i}": {"bias": (n,), "kernel": (k, n)}
                       for i, (k, n) in enumerate(zip(sizes[:-1], sizes[1:]))}}


def _shape_leaves(network: PolicyNetwork
                  ) -> tuple[list[tuple[int, ...]], jax.tree_util.PyTreeDef]:
    """The parameter shapes of `network` in `jax.tree.leaves` order, and their tree structure."""
    return jax.tree.flatten(parameter_shapes(network), is_leaf=lambda x: isinstance(x, tuple))


def flatten(policy_params: Params, network: PolicyNetwork) -> jax.Array:
    """Every parameter in one vector `[P, *runs]`, in `jax.tree.leaves` order.

    Args:
      policy_params: the parameters of `network` (or their gradients), each leaf its shape
        followed by any trailing run axes.
      network: the `PolicyNetwork`.

    Returns:
      `[P, *runs]`: the parameters of R runs as `[P, R]`.

    Raises:
      ValueError: if the parameters are not shaped as `network`'s.
    """
    shapes, tree = _shape_leaves(network)
    leaves = jax.tree.leaves(policy_params)
    if jax.tree.structure(policy_params) != tree or any(
            leaf.shape[:len(shape)] != shape for leaf, shape in zip(leaves, shapes)):
        raise ValueError(f"policy_params: expected the parameters of hidden={network.hidden}, "
                         f"shaped {parameter_shapes(network)} before any run axes")
    return jnp.concatenate([leaf.reshape(math.prod(shape), *leaf.shape[len(shape):])
                            for leaf, shape in zip(leaves, shapes)])


def unflatten(flat: jax.Array | np.ndarray, network: PolicyNetwork) -> Params:
    """The `policy_params` of a vector `[P, *runs]` from `flatten`, each leaf `[*shape, *runs]`.

    The leaves are arrays of the same kind as `flat` (numpy ones on the host, JAX ones in a traced
    program).
    """
    shapes, tree = _shape_leaves(network)
    bounds = np.cumsum([0, *(math.prod(shape) for shape in shapes)])
    return jax.tree.unflatten(tree, [flat[start:stop].reshape(*shape, *flat.shape[1:])
                                     for shape, start, stop in zip(shapes, bounds, bounds[1:])])


def distribution(module: nn.Module, policy_params: Params, obs: Observation,
                 num_actions: int | None = 2) -> Any:
    """The action distribution of a policy module for observations `[..., K]`.

    Args:
      module: a flax policy module.
      policy_params: its parameters.
      obs: observations `[..., K]`.
      num_actions: the environment's discrete actions (CartPole's 2); None for a continuous one.

    Returns:
      `distributions.from_output` of the module's output: CartPole's logit of P(push left)
      `[...]` (from `[...]`, `[..., 1]` or two logits `[..., 2]`), a `Categorical` or a
      `Gaussian`.

    Raises:
      ValueError: for a module's output of another shape.
    """
    # (flax types `apply` as also returning a state, which it does only when asked to mutate.)
    out: jax.Array = module.apply(policy_params, obs)  # type: ignore[assignment]
    return distributions.from_output(out, obs.shape, num_actions)


@struct.dataclass
class NetworkPolicy:
    """A policy module and its parameters as a policy `(obs [E, K], u [E]) -> action [E]` that
    samples its actions, or takes the likeliest (`network_policy`).

    A pytree of the parameters (the module and `runs` are static): a compiled function that takes
    it as an argument serves every policy of the same module and shapes without compiling again.

    Attributes:
      network: static: the policy module, a `PolicyNetwork` or any other (`distribution`).
      policy_params: its parameters, with any run axes (`network_policy`).
      runs: static: whether another module's parameters carry a trailing run axis.
      num_actions: static: the environment's discrete actions; None for a continuous one.
      greedy: static: take the likeliest action (`distributions.mode`) rather than sample.
    """

    network: nn.Module = struct.field(pytree_node=False)
    policy_params: dict
    runs: bool = struct.field(pytree_node=False, default=False)
    num_actions: int | None = struct.field(pytree_node=False, default=2)
    greedy: bool = struct.field(pytree_node=False, default=False)

    if TYPE_CHECKING:  # flax.struct adds it to the class
        def replace(self, **updates: Any) -> Self:
            """A copy with the fields `updates` names replaced."""
            ...

    def __call__(self, obs: Observation, u: jax.Array) -> Action:
        """Actions `[E]` (`[E, R]`) for observations `[E, K]` (`[E, R, K]`) and uniforms `u`."""
        if isinstance(self.network, PolicyNetwork) and self.network.outputs == 1:
            dist = forward(self.policy_params, obs, self.network.activation)
        else:
            # Any other module's sums in a fixed order (`runwise`), alone as beside other runs,
            # so that a run acts alike in both.
            dist = runs_like_actions(per_run(functools.partial(
                distribution, self.network, num_actions=self.num_actions), self.runs,
                self.policy_params, obs), u, self.runs)
        return distributions.mode(dist) if self.greedy else distributions.sample(dist, u)


def per_run(fn: Callable[[Params, Observation], Any], runs: bool, params: Params,
            obs: Observation) -> Any:
    """`fn(params, obs)` of one run's parameters and observations `[E, K]`, computed by `runwise`;
    with `runs`, for R runs' parameters (a trailing run axis) and observations `[E, R, K]`: the
    outputs with the run axis last."""
    return runwise.runwise(fn, batched=runs)(params, jnp.moveaxis(obs, -2, -1) if runs else obs)


def runs_like_actions(dist: Any, u: jax.Array, runs: bool) -> Any:
    """An action distribution of `per_run` with its run axis (where `runs`) where the actions and
    the uniforms `u` `[E, R]` have it, before the distribution's own axes."""
    if not runs:
        return dist
    return jax.tree.map(lambda leaf: jnp.moveaxis(leaf, -1, u.ndim - 1), dist)


@struct.dataclass
class HiddenRecordingPolicy:
    """A `PolicyNetwork` of `"elu"` hidden layers as a policy in two stages, which a rollout
    records between (`rollout.RecordingPolicy`): the hidden layers' activations, then the sampled
    actions from the last of them. A gradient reads the recorded activations back
    (`forward_layers`' `hidden`) rather than computing them again.

    Attributes:
      network: static: the `PolicyNetwork`, with at least one hidden layer.
      policy_params: its parameters, with any run axes (as `forward` takes them).
    """

    network: PolicyNetwork = struct.field(pytree_node=False)
    policy_params: dict

    def features(self, obs: Observation) -> tuple[jax.Array]:
        """The hidden layers' activations, stacked as one feature `[sum(hidden), E]`
        (`[..., E, R]`), for observations `[E, K]` (`[E, R, K]`)."""
        return (jnp.concatenate(
            forward_layers(self.policy_params, obs, self.network.activation)[1][1:]),)

    def act(self, features: tuple[jax.Array, ...], u: jax.Array) -> Action:
        """Actions `[E]` (`[E, R]`) sampled with uniforms `u` from `features`."""
        layers = self.policy_params["params"]
        out = layers[f"Dense_{len(layers) - 1}"]
        last = hidden_layers(features[0], self.network)[-1]
        return distributions.sample(dense(last, out["kernel"], out["bias"])[0], u)

    def __call__(self, obs: Observation, u: jax.Array) -> Action:
        """Actions `[E]` (`[E, R]`) for observations `[E, K]` (`[E, R, K]`) and uniforms `u`."""
        return self.act(self.features(obs), u)


def hidden_layers(features: jax.Array, network: PolicyNetwork) -> list[jax.Array]:
    """`HiddenRecordingPolicy.features` `[sum(hidden), ...]` as each hidden layer's `[N, ...]`."""
    return jnp.split(features, np.cumsum(network.hidden)[:-1])


def records_hidden(network: nn.Module) -> bool:
    """Whether the fast path's rollout records `network`'s hidden activations
    (`HiddenRecordingPolicy`): a `PolicyNetwork` of one output and `"elu"` hidden layers."""
    return (isinstance(network, PolicyNetwork) and network.outputs == 1
            and network.activation == "elu" and len(network.hidden) > 0)


def network_policy(network: nn.Module, policy_params: Params, runs: bool = False,
                   num_actions: int | None = 2) -> NetworkPolicy:
    """A policy module as a policy `(obs [E, K], u [E]) -> action [E]` that samples its actions.

    Args:
      network: a `PolicyNetwork` or any other policy module (`distribution`).
      policy_params: its parameters. For a `PolicyNetwork` they may hold R runs' parameters on
        trailing axes (kernels `[K, N, R]`), for observations `[E, R, 4]` (computed by `forward`).
      runs: for any other module: whether the parameters carry a trailing run axis `[..., R]`
        (observations `[E, R, K]`, uniforms `[E, R]`).
      num_actions: the environment's discrete actions (CartPole's 2); None for a continuous one.

    Returns:
      A `NetworkPolicy`.
    """
    return NetworkPolicy(network, policy_params, runs, num_actions)
