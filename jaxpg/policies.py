"""Policies: the book's hand-coded angle policy and the flax policy network.

A policy, as `rollout` uses it, maps a batch of observations `[E, 4]` and a key to actions `[E]`:
0 pushes left, 1 pushes right.
"""

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxpg import sums

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
            x = ACTIVATIONS[self.activation](Dense(size)(x))
        return Dense(1)(x)[..., 0]


class Dense(nn.Module):
    """A dense layer with Keras's initialisation, computed by `dense`."""

    features: int

    @nn.compact
    def __call__(self, x):
        kernel = self.param(
            "kernel", nn.initializers.glorot_uniform(), (x.shape[-1], self.features)
        )
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        return dense(x, kernel, bias)


@jax.custom_vjp
def dense(x, kernel, bias):
    """`x [..., K] @ kernel [K, N] + bias [N]`, elementwise, with batch-invariant gradients.

    The policy's matrices are tiny: written as K multiply-adds they fuse with the activations and
    the physics around them instead of becoming one small matrix-multiply call per layer and step.
    The gradient sums over the batch pairwise (`sums.pairwise_sum`), so it rounds the same for a
    run alone as for a run in a sweep.
    """
    return _matmul(x, kernel) + bias


def _matmul(x, kernel):
    out = x[..., 0, None] * kernel[0]
    for k in range(1, kernel.shape[0]):
        out = out + x[..., k, None] * kernel[k]
    return out


def _dense_fwd(x, kernel, bias):
    return dense(x, kernel, bias), (x, kernel)


def _dense_bwd(residuals, grad):
    x, kernel = residuals
    batch = tuple(range(grad.ndim - 1))
    return (
        _matmul(grad, kernel.T),
        sums.pairwise_sum(x[..., :, None] * grad[..., None, :], batch),
        sums.pairwise_sum(grad, batch),
    )


dense.defvjp(_dense_fwd, _dense_bwd)


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
