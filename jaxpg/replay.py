"""A policy module's forward pass, recorded by the rollout and replayed by the gradient.

The rollout computes a module's output at every step; the gradient of a loss needs the same pass
over every step again, for the values its backward pass reads (`jax.vjp`'s residuals: for a tanh
MLP, each hidden layer's activations). `plan` finds, in the jaxpr of the module's `jax.vjp`, the
values the rollout is to record: the module's output and each residual that depends on the
observations and is not an elementwise function of the parameters, the observations and other
recorded values (`1 - tanh(x)` is computed again from `tanh(x)`). `record` computes them at each
step, each `[E, n]` (`ReplayPolicy`, a `rollout.RecordingPolicy`); `replayed` is the module's
`apply` whose value is the recorded output and whose derivative reads the recorded residuals, so
that the gradient computes no forward pass of its own (XLA removes the pass's unused
operations). It serves where the parameters that played are the ones differentiated (one update
on every episode), for a module that computes each observation's output from that observation
alone (`rowwise`): the rollout passes E observations at a time, the gradient all T x E.
"""

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct
from jax.extend import core

from jaxpg import distributions, policies, runwise
from jaxpg.runwise import ELEMENTWISE
from jaxpg.types import Action, Array, Observation, Params

# Operations that move entries about, or pass them on unchanged.
_MOVES = frozenset({"broadcast_in_dim", "reshape", "squeeze", "transpose", "slice", "concatenate",
                    "stack", "stop_gradient"})
# Operations cheap enough to compute again in the gradient rather than record.
_CHEAP = ELEMENTWISE | _MOVES


class Plan(NamedTuple):
    """What a module's pass records, for observations of one batch shape.

    Attributes:
      jaxpr: `(params leaves, obs) -> (*the vjp's residuals, *the output's leaves)`, the vjp
        with respect to the parameters.
      residuals: the tree of `jax.vjp`'s function, whose leaves are the first outputs.
      output: the tree of the module's output.
      recorded: the jaxpr's variables recorded, in order (the output's first).
      rows: each recorded variable's shape per observation (after the batch axes).
    """

    jaxpr: core.ClosedJaxpr
    residuals: Any
    output: Any
    recorded: tuple[core.Var, ...]
    rows: tuple[tuple[int, ...], ...]


def plan(apply: Any, params: Params, obs: Any) -> Plan | None:
    """The `Plan` of `apply(params, obs)`, for `obs` `[*batch, K]` (arrays or shapes).

    Returns:
      The plan; None where the output is not computed from the observations, the module mixes
      observations (`rowwise`), or a recorded value does not lead with the batch axes or is
      neither a float nor a bool (a bool, as a ReLU's mask, is recorded as 0 or 1).
    """
    batch = tuple(obs.shape[:-1])
    # Traced with `jax.jit`'s functions inline (`jax.nn.swish`, `elu`): their operations are then
    # the plan's own, and what is cheap among them is computed again rather than recorded.
    with jax.disable_jit():
        closed, (pullback, out) = jax.make_jaxpr(
            lambda params, obs: jax.vjp(lambda p: apply(p, obs), params)[::-1],
            return_shape=True)(params, obs)
    jaxpr = closed.jaxpr
    num_residuals = len(jax.tree.leaves(pullback))
    residual_vars = {v for v in jaxpr.outvars[:num_residuals] if isinstance(v, core.Var)}
    output_vars = jaxpr.outvars[num_residuals:]
    if not all(isinstance(v, core.Var) for v in output_vars):
        return None  # a constant output
    output_vars = list(dict.fromkeys(output_vars))
    # The output is recorded (the rollout acts on it), then each residual that the gradient
    # cannot compute cheaply from the parameters, the observations and the values recorded.
    available = {*jaxpr.invars, *jaxpr.constvars, *output_vars}
    varying = {jaxpr.invars[-1]}  # the variables that depend on the observations
    recorded = [*output_vars]
    for eqn in jaxpr.eqns:
        inputs = [v for v in eqn.invars if isinstance(v, core.Var)]
        depends = any(v in varying for v in inputs)
        if depends:
            varying.update(eqn.outvars)
        if all(v in available for v in inputs) and (not depends
                                                     or eqn.primitive.name in _CHEAP):
            available.update(eqn.outvars)
        else:
            new = [v for v in eqn.outvars if v in residual_vars and v not in available]
            recorded += new
            available.update(new)
    if not all(v in varying for v in output_vars) or not rowwise(jaxpr, len(batch)):
        return None  # an output not computed from the observations, or observations mixed
    rows = []
    for var in recorded:
        shape, dtype = var.aval.shape, var.aval.dtype
        if shape[:len(batch)] != batch or not (jnp.issubdtype(dtype, jnp.floating)
                                               or dtype == jnp.bool_):
            return None
        rows.append(shape[len(batch):])
    return Plan(closed, jax.tree.structure(pullback), jax.tree.structure(out),
                tuple(recorded), tuple(rows))


def rowwise(jaxpr: core.Jaxpr, batch_axes: int, varying: Any = None) -> bool:
    """Whether `jaxpr` computes each observation's values from that observation alone, as the
    rollout (E observations at a time) and the gradient (all T x E) each assume of the other.

    Its last input is the observations (or the inputs in `varying`), their first `batch_axes`
    axes the batch. Every value computed from them must keep those axes first and untouched:
    arithmetic, products that contract other axes against values not computed from the
    observations, reductions, slices and reshapes of the other axes, calls whose bodies do so.
    Anything else (a mean over the batch, an operation this does not know) counts as mixing
    observations.
    """
    # The values computed from the observations, batch axes first.
    intact = {jaxpr.invars[-1]} if varying is None else set(varying)
    lead = tuple(range(batch_axes))

    def after(axes: Any) -> bool:
        """Whether every axis of `axes` comes after the batch axes."""
        return all(axis >= batch_axes for axis in axes)

    def keeps(eqn: core.JaxprEqn) -> bool:
        """Whether the equation keeps the batch axes first and untouched."""
        name, params = eqn.primitive.name, eqn.params
        moving = [i for i, v in enumerate(eqn.invars) if isinstance(v, core.Var) and v in intact]
        if name in ELEMENTWISE or name in ("concatenate", "stack", "stop_gradient"):
            return after([params.get("dimension", params.get("axis", batch_axes))])
        if name == "dot_general":
            (contract, _), (batched, _) = params["dimension_numbers"]
            return moving == [0] and not batched and after(contract)
        if name in ("jit", "pjit", "closed_call", "core_call", "custom_jvp_call",
                    "custom_vjp_call"):
            inner = params["jaxpr"] if "jaxpr" in params else params["call_jaxpr"]
            inner = getattr(inner, "jaxpr", inner)
            return rowwise(inner, batch_axes, [inner.invars[i] for i in moving])
        if len(moving) != 1:
            return False
        shape = eqn.invars[moving[0]].aval.shape  # type: ignore[attr-defined]
        if name in ("reduce_sum", "reduce_max", "reduce_min", "reduce_prod", "argmax", "argmin",
                    "reduce_and", "reduce_or"):
            return after(params["axes"])
        if name in ("cumsum", "cumprod", "cummax", "cummin", "cumlogsumexp"):
            return after([params["axis"]])
        if name == "broadcast_in_dim":
            return tuple(params["broadcast_dimensions"][:batch_axes]) == lead
        if name == "reshape":
            return tuple(params["new_sizes"][:batch_axes]) == shape[:batch_axes]
        if name == "squeeze":
            return after(params["dimensions"])
        if name == "transpose":
            return tuple(params["permutation"][:batch_axes]) == lead
        if name == "slice":
            return (tuple(params["start_indices"][:batch_axes]) == (0,) * batch_axes
                    and tuple(params["limit_indices"][:batch_axes]) == shape[:batch_axes]
                    and (params["strides"] is None
                         or set(params["strides"][:batch_axes]) <= {1}))
        return False

    for eqn in jaxpr.eqns:
        if any(v in intact for v in eqn.invars if isinstance(v, core.Var)):
            if not keeps(eqn):
                return False
            intact.update(eqn.outvars)
    return True


def same_layout(a: Plan, b: Plan) -> bool:
    """Whether two plans (of two batch shapes) record the same values in the same rows."""
    def positions(p: Plan) -> list[tuple[int, int]]:
        """Where each recorded variable is computed: (equation, output)."""
        where = {v: (i, j) for i, eqn in enumerate(p.jaxpr.jaxpr.eqns)
                 for j, v in enumerate(eqn.outvars)}
        return [where[v] for v in p.recorded]

    return (len(a.jaxpr.jaxpr.eqns) == len(b.jaxpr.jaxpr.eqns) and a.rows == b.rows
            and positions(a) == positions(b))


def record(p: Plan, params: Params, obs: Observation) -> tuple[Array, ...]:
    """The recorded values of the pass over `obs` `[*batch, K]`, each `[*batch, n]` in the
    observations' dtype (a bool as 0 or 1)."""
    batch = obs.shape[:-1]
    env = _evaluate(p, params, obs, {}, p.recorded)
    return tuple(env[v].reshape(*batch, -1).astype(obs.dtype) for v in p.recorded)


def output(p: Plan, recorded: tuple[Array, ...]) -> Any:
    """The module's output from its `recorded` values."""
    values = _values(p, recorded)
    outs = [values[v] for v in p.jaxpr.jaxpr.outvars[-p.output.num_leaves:]]
    return jax.tree.unflatten(p.output, outs)


def replayed(p: Plan) -> Any:
    """`apply(params, obs, recorded)`: the module's output as `record` recorded it over `obs`,
    and the derivative of `apply(params, obs)` with respect to `params` from the recorded
    residuals. `obs` and `recorded` take no gradient."""

    @jax.custom_vjp
    def replay(params: Params, obs: Observation, recorded: tuple[Array, ...]) -> Any:
        """The recorded output."""
        del params, obs
        return output(p, recorded)

    def forward(params: Params, obs: Observation, recorded: tuple[Array, ...]
                ) -> tuple[Any, list[Array]]:
        """The recorded output, and the vjp's residuals from the recorded values."""
        wanted = p.jaxpr.jaxpr.outvars[:p.residuals.num_leaves]
        env = _evaluate(p, params, obs, _values(p, recorded), wanted)
        residuals = [_read(env, v) for v in wanted]
        return output(p, recorded), residuals

    def backward(residuals: list[Array], cotangent: Any) -> tuple[Params, None, None]:
        """The parameters' cotangent, by the vjp's function on the recorded residuals."""
        pullback = jax.tree.unflatten(p.residuals, residuals)
        return pullback(cotangent)[0], None, None

    replay.defvjp(forward, backward)
    return replay


def _values(p: Plan, recorded: tuple[Array, ...]) -> dict[core.Var, Array]:
    """Each recorded variable's value, from its record `[*batch, n]`."""
    return {v: value.reshape(*value.shape[:-1], *row).astype(
                v.aval.dtype)  # type: ignore[attr-defined]  # (a ShapedArray's)
            for v, row, value in zip(p.recorded, p.rows, recorded, strict=True)}


def _read(env: dict[Any, Array], var: Any) -> Any:
    """A variable's value, or a literal's."""
    return var.val if isinstance(var, core.Literal) else env[var]


def _evaluate(p: Plan, params: Params, obs: Observation, known: dict[core.Var, Array],
              wanted: Any) -> dict[Any, Array]:
    """The values of the `wanted` variables of the plan's jaxpr (and others), from `params`,
    `obs` and the `known` variables' values, computing only what they need beyond those."""
    jaxpr = p.jaxpr.jaxpr
    needed = {v for v in wanted if isinstance(v, core.Var)} - set(known)
    eqns = []
    for eqn in reversed(jaxpr.eqns):
        if any(v in needed for v in eqn.outvars) and not all(v in known for v in eqn.outvars):
            eqns.append(eqn)
            needed.update(v for v in eqn.invars if isinstance(v, core.Var) and v not in known)
    env: dict[Any, Array] = dict(zip(jaxpr.constvars, p.jaxpr.consts))
    env.update(zip(jaxpr.invars, [*jax.tree.leaves(params), obs]))
    env.update(known)
    for eqn in reversed(eqns):
        bind_params = eqn.primitive.get_bind_params(eqn.params)
        # Older JAX (0.8) gives a call's functions too: (functions, parameters).
        functions, bind_params = (bind_params if isinstance(bind_params, tuple)
                                  else ((), bind_params))
        outs = eqn.primitive.bind(*functions, *(_read(env, v) for v in eqn.invars),
                                  **bind_params)
        env.update(zip(eqn.outvars, outs if eqn.primitive.multiple_results else [outs]))
    return env


@struct.dataclass
class ReplayPolicy:
    """A policy module as a policy in two stages, which a rollout records between
    (`rollout.RecordingPolicy`): the values of its pass that `plan` names, then actions sampled
    from the output among them. The gradient reads them back (`replayed`).

    Attributes:
      plan: static: the `Plan` of the module's pass for one step's observations `[E, K]`.
      policy_params: the module's parameters, with a trailing run axis where `runs`.
      runs: static: whether the parameters carry a trailing run axis `[..., R]` (observations
        `[E, R, K]`, uniforms `[E, R]`).
      num_actions: static: the environment's discrete actions; None for a continuous one.
    """

    plan: Plan = struct.field(pytree_node=False)
    policy_params: dict
    runs: bool = struct.field(pytree_node=False, default=False)
    num_actions: int | None = struct.field(pytree_node=False, default=2)

    def features(self, obs: Observation) -> tuple[Array, ...]:
        """The recorded values, each `[1, E, n]` (`[1, E, n, R]`), of observations `[E, K]`
        (`[E, R, K]`): each a field of the rollout's records, which then hold it `[1, T, E, n]`,
        laid out as the gradient reads it."""
        values = policies.per_run(lambda params, obs: record(self.plan, params, obs), self.runs,
                                  self.policy_params, obs)
        return tuple(value[None] for value in values)

    def act(self, features: tuple[Array, ...], u: Array) -> Action:
        """Actions `[E]` (`[E, R]`) sampled with uniforms `u` from `features`."""
        def dist(*recorded: Array) -> Any:
            """The action distribution of one run's recorded output."""
            return distributions.from_output(output(self.plan, recorded),
                                             (*recorded[0].shape[:-1], 0), self.num_actions)

        played = runwise.runwise(dist, batched=self.runs)(*(f[0] for f in features))
        return distributions.sample(policies.runs_like_actions(played, u, self.runs), u)

    def __call__(self, obs: Observation, u: Array) -> Action:
        """Actions `[E]` (`[E, R]`) for observations `[E, K]` (`[E, R, K]`) and uniforms `u`."""
        return self.act(self.features(obs), u)
