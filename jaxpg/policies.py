"""Policies: the book's hand-coded angle policy and the flax policy network.

A policy, as `rollout` uses it, maps a batch of observations `[E, 4]` and a key to actions `[E]`:
0 pushes left, 1 pushes right.
"""

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

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


def basic_policy(obs, key=None):
    """0 (push left) if the pole angle is negative, else 1; any batch shape `[..., 4]`."""
    del key  # deterministic
    return jnp.where(obs[..., 2] < 0, 0, 1).astype(jnp.int32)


def check_network(hidden, activation):
    """Raises a ValueError naming `hidden` or `activation` when they are not allowed."""
    if activation not in ACTIVATIONS:
        raise ValueError(
            f"activation: unknown {activation!r}; allowed: {', '.join(ACTIVATIONS)}"
        )
    if len(hidden) == 0 or any(int(h) != h or h < 1 for h in hidden):
        raise ValueError(f"hidden: must be one or more positive layer sizes, got {tuple(hidden)}")


class PolicyNetwork(nn.Module):
    """Dense(hidden) -> activation -> ... -> Dense(1): the logit of P(push left).

    Weights start Glorot-uniform and biases at zero, as Keras's Dense does.
    """

    hidden: Sequence[int] = (5,)
    activation: str = "elu"

    @nn.compact
    def __call__(self, obs):
        x = obs
        for size in self.hidden:
            x = ACTIVATIONS[self.activation](_dense(size)(x))
        return _dense(1)(x)[..., 0]


def _dense(features):
    return nn.Dense(
        features,
        kernel_init=nn.initializers.glorot_uniform(),
        bias_init=nn.initializers.zeros,
        dot_general=_small_dot_general,
    )


def _small_dot_general(lhs, rhs, dimension_numbers, precision=None, preferred_element_type=None):
    """`lhs [..., K] @ rhs [K, N]` as a broadcast multiply and sum.

    The policy's matrices are tiny (K, N <= a few dozen); written elementwise they fuse with the
    activations around them instead of becoming one small matrix-multiply call per layer, which
    under `vmap` over seeds is what dominates the run time on CPU.
    """
    del precision, preferred_element_type
    (lhs_contract, rhs_contract), (lhs_batch, rhs_batch) = dimension_numbers
    assert tuple(lhs_contract) == (lhs.ndim - 1,) and tuple(rhs_contract) == (0,)
    assert not lhs_batch and not rhs_batch
    return jnp.sum(lhs[..., :, None] * rhs, axis=-2)


def init_network(key, network):
    """Initial `policy_params` of a `PolicyNetwork`."""
    return network.init(key, jnp.zeros((4,)))


def log_prob(logit, action):
    """log pi(action | obs) from the logit of P(left): `log sigmoid(logit)` for action 0."""
    return jax.nn.log_sigmoid(jnp.where(action == 0, logit, -logit))


def sample_action(logit, key):
    """Pushes left with probability sigmoid(logit): action 1 (right) when u > P(left), as the book."""
    u = jax.random.uniform(key, jnp.shape(logit))
    return (u > jax.nn.sigmoid(logit)).astype(jnp.int32)


def network_policy(network, policy_params):
    """The trained network as a policy `(obs [E, 4], key) -> action [E]` that samples its actions."""

    def policy(obs, key):
        return sample_action(network.apply(policy_params, obs), key)

    return policy
