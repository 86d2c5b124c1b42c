"""The REINFORCE trainer a researcher writes in plain JAX, with jaxpg's `cartpole.step`.

`jit(vmap over seeds(scan over iterations(rollout scan, jax.grad, optax)))`: every seed plays
`episodes` episodes of `max_steps` steps per iteration with a flax policy of two logits (a
categorical over push left / push right), discounts the rewards, normalises them over the
iteration's alive steps and takes one Adam step on -mean(A_t log pi(a_t | s_t)), the book's loss.
Nothing here is jaxpg's but the environment: it is the peer that `one_engine.py` measures jaxpg's
trainer against.
"""

from collections.abc import Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from jaxpg import cartpole


class MLP(nn.Module):
    """Dense(size) -> activation (tanh unless named) for each hidden size, then Dense(2): the
    logits of left and right."""

    hidden: Sequence[int] = (32, 32)
    activation: str = "tanh"

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        for size in self.hidden:
            obs = getattr(nn, self.activation)(nn.Dense(size)(obs))
        return nn.Dense(2)(obs)


def make_train(network: nn.Module, iterations: int = 150, episodes: int = 10,
               max_steps: int = 200, discount: float = 0.95,
               learning_rate: float = 0.01,
               optimizer: optax.GradientTransformation | None = None,
               ) -> Callable[[jax.Array], tuple]:
    """`train(seeds [S]) -> (params, mean returns [S, iterations])`, one jitted program.

    The optimizer is Adam at `learning_rate` unless `optimizer` is given.
    """
    env_params = cartpole.CartPoleParams()
    optimizer = optax.adam(learning_rate) if optimizer is None else optimizer

    def rollout(params, key):
        key_reset, key_steps = jax.random.split(key)
        _, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
            jax.random.split(key_reset, episodes), env_params)

        def step(carry, key):
            state, done = carry
            obs = cartpole.observe(state)
            action = jax.random.categorical(key, network.apply(params, obs))
            _, state, reward, terminated, truncated = jax.vmap(
                cartpole.step, in_axes=(0, 0, None))(state, action, env_params)
            alive = ~done
            return (state, done | terminated | truncated), (obs, action, reward * alive, alive)

        _, batch = jax.lax.scan(step, (state, jnp.zeros(episodes, bool)),
                                jax.random.split(key_steps, max_steps))
        return batch

    def loss(params, batch):
        obs, action, reward, alive = batch

        def accumulate(future, reward):
            future = reward + discount * future
            return future, future

        _, returns = jax.lax.scan(accumulate, jnp.zeros(episodes), reward, reverse=True)
        count = alive.sum()
        mean = jnp.where(alive, returns, 0).sum() / count
        std = jnp.sqrt(jnp.where(alive, (returns - mean) ** 2, 0).sum() / count)
        advantages = (returns - mean) / std
        log_probs = jax.nn.log_softmax(network.apply(params, obs))
        taken = jnp.take_along_axis(log_probs, action[..., None], axis=-1)[..., 0]
        return -jnp.where(alive, advantages * taken, 0).sum() / count

    def iteration(carry, _):
        params, opt_state, key = carry
        key, key_rollout = jax.random.split(key)
        batch = rollout(params, key_rollout)
        grads = jax.grad(loss)(params, batch)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state, key), batch[2].sum(0).mean()

    def train_one(seed):
        key, key_init = jax.random.split(jax.random.PRNGKey(seed))
        params = network.init(key_init, jnp.zeros((1, 4)))
        (params, _, _), returns = jax.lax.scan(
            iteration, (params, optimizer.init(params), key), length=iterations)
        return params, returns

    return jax.jit(jax.vmap(train_one))
