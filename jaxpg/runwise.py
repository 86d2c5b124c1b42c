"""Any function of one training run, evaluated for many runs at once on a trailing run axis.

`runwise(fn)` traces `fn` for one run and evaluates its jaxpr again, operation by operation, for R
runs whose arrays carry a trailing run axis `[..., R]`, where XLA's CPU backend vectorises over
them (`jax.vmap` moves that axis to the front of matrix products and reshapes instead). On the way,
the operations whose rounding depends on the shape of the whole array are written in a fixed
order: sums (`reduce_sum`, and the contractions of matrix products) add a long axis one entry
after another in a loop, a short one as chains of additions or by halving (`sums.invariant_sum`).
So a run rounds the same alone (no run axis) as beside any number of others, for any policy, loss
or optimizer written in JAX.

One hazard, of comparisons: compiled, XLA may compute an array once for a maximum and again,
rounded otherwise (a multiply-add fused or not), for an `==` against that maximum, so the two can
disagree. `jnp.max`'s derivative counts the entries equal to the maximum and divides by the
count: 0 / 0 there. A maximum that only shifts values (a softmax's) takes no gradient
(`jax.lax.stop_gradient`, as `jax.nn.log_softmax` and `distributions.Categorical` do).

Elementwise work that must round alike for any number of runs, an optimizer's step, can be marked
`runs_first(fn)`: it is then evaluated by `jax.vmap` over a leading run axis (a run alone given one
of size one), where XLA vectorises a run's arithmetic over its own entries as it does alone. With
the runs last, XLA compiled Adam's moments otherwise for a run alone than beside others where the
gradient's last sum was of one episode (docs/performance.md).

Each operation keeps its meaning: an operation without a rule here is evaluated by `jax.vmap`
over the run axis (still exact, not necessarily in a fixed order). `fn` is traced once per shape
of its arguments; differentiate inside it (`jax.grad` in `fn`), so that the backward pass's sums
are rewritten too.
"""

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.extend import core

from jaxpg import sums
from jaxpg.types import Array, ArrayLike

# A value of the jaxpr being evaluated, and whether it carries the trailing run axis.
_Value = tuple[Any, bool]
# A rule for an operation whose parameters name one run's shape or axes: (inputs, the equation's
# parameters, runs) -> the output with its run axis, or None where the rule does not apply.
_Rule = Callable[[list[_Value], dict[str, Any], int], Array | None]

ELEMENTWISE = frozenset("""
    abs acos acosh add add_any and asin asinh atan atan2 atanh cbrt ceil clamp convert_element_type
    copy copy_p cos cosh digamma div eq erf erf_inv erfc exp exp2 expm1 floor ge gt igamma imag
    integer_pow is_finite le lgamma log log1p logistic lt max min mul ne neg nextafter not or pow
    real reduce_precision rem round rsqrt select_n shift_left shift_right_arithmetic
    shift_right_logical sign sin sinh sqrt square sub tan tanh xor
""".split())
# Reductions and scans along axes counted from the front: a trailing run axis leaves them alone.
_ALONG_AXES = frozenset("""
    argmax argmin cummax cummin cumlogsumexp cumprod cumsum reduce_and reduce_max reduce_min
    reduce_or reduce_prod reduce_xor rev squeeze
""".split())
# Calls evaluated through their bodies; custom derivative rules are not needed, since `fn`
# differentiates inside itself (its jaxpr holds the backward pass already).
_CALLS = ("pjit", "jit", "closed_call", "core_call", "custom_jvp_call", "custom_vjp_call")


RUNS_FIRST = "runwise_runs_first"  # the name of a call that `runs_first` marks


def runs_first(fn: Callable[..., Any]) -> Callable[..., Any]:
    """`fn`, marked for `runwise` to evaluate with the runs first; elsewhere `fn` itself.

    `fn` takes and returns pytrees of arrays of one run, and must not sum over its entries in an
    order that matters (its sums stay XLA's).
    """
    def marked(*args: Any) -> Any:
        """`fn` of `args`."""
        return fn(*args)

    marked.__name__ = RUNS_FIRST
    return jax.jit(marked)


def runwise(fn: Callable[..., Any], batched: Any) -> Callable[..., Any]:
    """`fn`, taking and returning pytrees of arrays, evaluated for several runs at once.

    Args:
      fn: a function of one run's arrays.
      batched: a pytree of bools, a prefix of `fn`'s arguments (as a tuple): True where the
        arrays carry a trailing run axis `[..., R]` (the same R for all), False where every run
        shares them. With no True leaf, `fn` is evaluated for one run, in the same fixed order.

    Returns:
      A function of the arguments that returns `fn`'s outputs, each with a trailing run axis
      `[..., R]` where any argument has one.
    """

    def wrapped(*args: Any) -> Any:
        """`fn` of `args`, for every run at once."""
        flags = _broadcast_prefix(batched, args)
        leaves, tree = jax.tree.flatten(args)
        run_sizes = {leaf.shape[-1] for leaf, b in zip(leaves, flags) if b}
        if len(run_sizes) > 1:
            raise ValueError(f"runwise: the run axes differ in size: {sorted(run_sizes)}")
        runs = run_sizes.pop() if run_sizes else None
        one_run = [jax.ShapeDtypeStruct(leaf.shape[:-1] if b else np.shape(leaf), leaf.dtype)
                   for leaf, b in zip(leaves, flags)]
        closed, out_shape = jax.make_jaxpr(
            lambda *flat: fn(*jax.tree.unflatten(tree, flat)), return_shape=True)(*one_run)
        values = _evaluate(closed.jaxpr, closed.consts, list(zip(leaves, flags)), runs)
        outs = [_lift(value, b, runs) if runs else value for value, b in values]
        return jax.tree.unflatten(jax.tree.structure(out_shape), outs)

    return wrapped


def _broadcast_prefix(prefix: Any, tree: Any) -> list[bool]:
    """A bool per leaf of `tree`, from `prefix`, a pytree prefix of it."""
    return jax.tree.leaves(jax.tree.map(
        lambda flag, sub: jax.tree.map(lambda _: bool(flag), sub), prefix, tree))


def _lift(x: ArrayLike, batched: bool, runs: int | None) -> Array:
    """`x` with its trailing run axis: shared values are broadcast to every run."""
    if batched:
        return x  # type: ignore[return-value]  # (a batched value is an array)
    x = jnp.asarray(x)
    return lax.broadcast_in_dim(x, (*x.shape, runs), tuple(range(x.ndim)))


def _to_shape(x: ArrayLike, batched: bool, shape: tuple[int, ...], runs: int) -> Array:
    """An operand of an elementwise operation whose one-run result is `shape`, as `[*shape, R]`."""
    x = jnp.asarray(x)
    if batched and x.ndim == len(shape) + 1:
        return x
    if batched:  # one number per run
        return lax.broadcast_in_dim(x, (*shape, runs), (len(shape),))
    return lax.broadcast_in_dim(x, (*shape, runs), tuple(range(len(shape) - x.ndim, len(shape))))


def _evaluate(jaxpr: core.Jaxpr, consts: Sequence[Any], args: Sequence[_Value],
              runs: int | None) -> list[_Value]:
    """The outputs of `jaxpr` as (value, batched) pairs, from `args`, (value, batched) pairs."""
    env: dict[core.Var, _Value] = {}

    def read(var: core.Var | core.Literal) -> _Value:
        """A variable's (value, batched); a literal's value, shared by every run."""
        if isinstance(var, core.Literal):
            return var.val, False
        return env[var]

    for var, const in zip(jaxpr.constvars, consts):
        env[var] = (const, False)
    for var, arg in zip(jaxpr.invars, args):
        env[var] = arg
    for eqn in jaxpr.eqns:
        ins = [read(var) for var in eqn.invars]
        outs = _apply(eqn, ins, runs)
        for var, out in zip(eqn.outvars, outs):
            env[var] = out
    return [read(var) for var in jaxpr.outvars]


def _apply(eqn: core.JaxprEqn, ins: list[_Value], runs: int | None) -> list[_Value]:
    """One equation's outputs as (value, batched) pairs."""
    name, params = eqn.primitive.name, eqn.params
    values = [value for value, _ in ins]
    any_batched = any(b for _, b in ins)
    if name in _CALLS:
        inner = params["jaxpr"] if "jaxpr" in params else params["call_jaxpr"]
        closed = inner if hasattr(inner, "consts") else core.ClosedJaxpr(inner, ())
        if params.get("name") == RUNS_FIRST:
            return _with_runs_first(closed, ins, runs if any_batched else None)
        return _evaluate(closed.jaxpr, closed.consts, ins, runs)
    if name == "reduce_sum":
        return [(_sum(values[0], params["axes"]), ins[0][1])]
    if name == "scan":  # shared by every run: evaluated as for a run alone
        return _scan(ins, params, runs if any_batched else None)
    if name == "dot_general":
        return [(_dot(ins, params, runs), any_batched)]
    if not any_batched:
        return _bound(eqn, values)
    assert runs is not None  # an argument has a run axis, of `runs` entries
    rule = _RULES.get(name)
    out = None if rule is None else rule(ins, params, runs)
    if out is not None:
        return [(out, True)]
    if name in ELEMENTWISE:
        shape = eqn.outvars[0].aval.shape  # type: ignore[attr-defined]  # (a ShapedArray's)
        return _bound(eqn, [_to_shape(v, b, shape, runs) for v, b in ins], batched=True)
    if name in _ALONG_AXES:
        return _bound(eqn, values, batched=True)
    vmapped = jax.vmap(functools.partial(_bind, eqn), in_axes=[-1 if b else None for _, b in ins],
                       out_axes=-1)
    return [(out, True) for out in vmapped(*values)]


def _with_runs_first(closed: core.ClosedJaxpr, ins: list[_Value],
                     runs: int | None) -> list[_Value]:
    """A `runs_first` call: its jaxpr by `vmap_runs_first`, a run alone (`runs` None) given a run
    axis of one entry."""
    fn = vmap_runs_first(core.jaxpr_as_fun(closed))
    if runs is None:
        return [(out[..., 0], False) for out in fn(*(jnp.expand_dims(v, -1) for v, _ in ins))]
    return [(out, True) for out in fn(*(_lift(v, b, runs) for v, b in ins))]


def vmap_runs_first(fn: Callable[..., Any]) -> Callable[..., Any]:
    """`fn` of one run's pytrees, for runs on the last axis of every leaf, computed by `jax.vmap`
    over the runs moved first; its outputs with the runs last again.

    With the runs first, XLA vectorises a run's elementwise arithmetic over the run's own
    entries, as for a run alone; on the last axis its vectorised and scalar loops round a run's
    optimizer step differently for different numbers of runs.
    """
    def wrapped(*args: Any) -> Any:
        """`fn` of every run."""
        out = jax.vmap(fn)(*jax.tree.map(lambda leaf: jnp.moveaxis(leaf, -1, 0), args))
        return jax.tree.map(lambda leaf: jnp.moveaxis(leaf, 0, -1), out)

    return wrapped


def _scan(ins: list[_Value], params: dict[str, Any], runs: int | None) -> list[_Value]:
    """`lax.scan` whose body is evaluated by `runwise` too: for several runs, every carry and
    output with the run axis (the scanned axis stays first, the run axis last); for a run alone
    (`runs` None), without."""
    body, consts = params["jaxpr"], ins[:params["num_consts"]]
    num_carry, batched = params["num_carry"], runs is not None

    def lifted(values: Sequence[_Value]) -> list[Any]:
        """The values, with the run axis for several runs."""
        return [_lift(v, b, runs) if batched else v for v, b in values]

    carry = lifted(ins[len(consts):len(consts) + num_carry])
    xs = ins[len(consts) + num_carry:]

    def step(carry: list[Array], x: list[Any]) -> tuple[list[Array], list[Array]]:
        """One step of the body, its outputs with the run axis for several runs."""
        args = [*consts, *((c, batched) for c in carry), *zip(x, (b for _, b in xs))]
        outs = lifted(_evaluate(body.jaxpr, body.consts, args, runs))
        return outs[:num_carry], outs[num_carry:]

    carry, ys = lax.scan(step, carry, [v for v, _ in xs], length=params["length"],
                         reverse=params["reverse"], unroll=params["unroll"])
    return [(out, batched) for out in (*carry, *ys)]


def _bind(eqn: core.JaxprEqn, *values: Any) -> list[Any]:
    """The equation's operation applied to `values`: a list of its outputs."""
    outs = eqn.primitive.bind(*values, **eqn.params)
    return outs if eqn.primitive.multiple_results else [outs]


def _bound(eqn: core.JaxprEqn, values: Sequence[Any], batched: bool = False) -> list[_Value]:
    """`_bind`'s outputs as (value, batched) pairs."""
    return [(out, batched) for out in _bind(eqn, *values)]


def _sum(x: Array, axes: Sequence[int]) -> Array:
    """`x` summed over `axes` (of one run's axes) in a fixed order.

    Over the first of them one entry after another where it is long (`_in_order`), then over the
    others by halving.
    """
    axes = tuple(axes)
    if not axes:
        return x
    x = jnp.asarray(x)
    if x.shape[axes[0]] > LOOPED:
        rest = tuple(a - (a > axes[0]) for a in axes[1:])
        total = _in_order(x.shape[axes[0]],
                          lambda start, size: lax.dynamic_slice_in_dim(x, start, size, axes[0]),
                          lambda group, i: lax.index_in_dim(group, i, axes[0], keepdims=False))
        return _sum(total, rest)
    return sums.invariant_sum(x, axes)


LOOPED = 64  # an axis summed (or contracted) longer than this: in a loop, `GROUP` entries a step
GROUP = 8  # the additions chained in one kernel (a longer chain is slower)
TILE = 2  # entries of a long first axis of a product's first operand computed at once (`_dot`)


def _in_order(entries: int, fetch: Callable[[Any, int], Any],
              term: Callable[[Any, int], Array], chain: int = GROUP) -> Array:
    """The sum of `entries` terms, added one after another: `chain` of them chained per kernel.

    The first `entries % chain` (or `chain`) terms are added at once, the others `chain` per step
    of a loop, each step's chain of additions (and the multiplications of a product's terms) fused
    by XLA into one kernel. The order of additions is that of a loop over one entry at a time.

    Args:
      entries: how many terms.
      fetch: `(start, size)` -> the operands of `size` consecutive terms from `start` (a traced
        integer in the loop).
      term: `(operands, i)` -> term `i` of the fetched ones, `i` static.
      chain: the terms chained per kernel (`entries`: one chain, no loop).
    """
    first = entries % chain or chain
    group = fetch(0, first)
    total = term(group, 0)
    for i in range(1, first):
        total = total + term(group, i)

    def add_group(g: Array, total: Array) -> Array:
        """`total` plus the terms of group `g` after the first, in order."""
        group = fetch(first + g * chain, chain)
        for i in range(chain):
            total = total + term(group, i)
        return total

    if entries > first:
        total = lax.fori_loop(0, (entries - first) // chain, add_group, total)
    return total


def _dot(ins: list[_Value], params: dict[str, Any], runs: int | None) -> Array:
    """`lax.dot_general` as products summed in a fixed order over the contracting axes.

    Over the first contracting axis the products are added one entry after another
    (`_in_order`: chains of `GROUP` multiply-adds that XLA fuses into one kernel each, the chains
    after the first in a loop); where other contracting axes follow a short first one, one chain
    of all its entries (in chains of `GROUP` there, a run alone rounded otherwise than among
    others). Then they are summed over the other contracting axes by halving. A long first axis
    of the first operand, the steps of a gradient's `[T, E, n] x [n, m]`, is computed `TILE`
    entries at a time, so that each tile's totals stay in cache through its chains; every total
    adds its terms in the same order. Each entry's products are sliced out of the operands before
    they are laid out as [other contracting, batch, free] (plus the run axis) and expanded against
    the other operand's free axes, so that no whole operand is transposed.
    """
    (x, x_batched), (y, y_batched) = ins
    x, y, ((x_contract, y_contract), (x_batch, y_batch)) = _merged(
        (x, x_batched), (y, y_batched), params["dimension_numbers"])
    x_ndim, y_ndim = np.ndim(x) - x_batched, np.ndim(y) - y_batched
    x_free = [a for a in range(x_ndim) if a not in x_contract and a not in x_batch]
    y_free = [a for a in range(y_ndim) if a not in y_contract and a not in y_batch]
    x, (x_contract, x_batch, x_free) = _small_in_order(x, x_batched, (x_contract, x_batch, x_free))
    y, (y_contract, y_batch, y_free) = _small_in_order(y, y_batched, (y_contract, y_batch, y_free))
    contract = len(x_contract)
    x_layout = (x_batched, [*x_contract, *x_batch, *x_free], x_ndim, len(y_free))
    y_layout = (y_batched, [*y_contract, *y_batch, *y_free], contract + len(y_batch), len(x_free))

    def products(operands: tuple[Array, Array], i: int | None) -> Array:
        """The products of entry `i` of the operands' first contracting axis (of all, for
        None)."""
        terms = []
        for v, axes, layout in zip(operands, (x_contract, y_contract), (x_layout, y_layout)):
            arranged = _arranged(v if i is None else lax.slice_in_dim(v, i, i + 1, axis=axes[0]),
                                 *layout)
            terms.append(_lift(arranged, layout[0], runs) if x_batched != y_batched
                         else arranged)
        return terms[0] * terms[1] if i is None else terms[0][0] * terms[1][0]

    if not contract:
        return _typed(products((x, y), None), params)
    entries = np.shape(x)[x_contract[0]]

    def contracted(x: Array) -> Array:
        """The products of `x` and `y` summed over the contracting axes."""
        def fetch(start: Any, size: int) -> tuple[Array, Array]:
            """The operands' entries `start` to `start + size` of their first contracting axis."""
            return (lax.dynamic_slice_in_dim(x, start, size, axis=x_contract[0]),
                    lax.dynamic_slice_in_dim(y, start, size, axis=y_contract[0]))

        # Beside other contracting axes, a short first one is one chain of all its entries.
        result = _in_order(entries, fetch, products,
                           entries if contract > 1 and entries <= LOOPED else GROUP)
        return _sum(result, tuple(range(contract - 1)))

    # A long first axis of `x`, the steps of a gradient's `[T, E, n] x [n, m]`, in tiles: each
    # tile's total over its chains stays in cache rather than every chain passing over the whole.
    x_len = np.shape(x)[0]
    if (entries > GROUP and not x_batch and x_free[:1] == [0] and x_len > LOOPED
            and x_len % TILE == 0):
        tiles = lax.map(contracted, lax.reshape(x, (x_len // TILE, TILE, *np.shape(x)[1:])))
        return _typed(lax.reshape(tiles, (x_len, *tiles.shape[2:])), params)
    return _typed(contracted(x), params)


def _merged(x_in: _Value, y_in: _Value, dimension_numbers: Any) -> tuple[Array, Array, Any]:
    """The operands of a product with consecutive contracting axes, the first long, merged into one.

    Where the product is large (more than `LOOPED` entries a run), as a gradient's weights
    summed over steps and episodes `[T, E]`: they are then added one step and episode after
    another, chained `GROUP` per kernel, rather than as `[E, ...]` totals over the steps summed
    over the episodes at the end, which are E times as large in memory. A small product keeps
    its `[E, ...]` totals: a tenth of the loop's steps.

    Returns:
      (x, y, the dimension numbers of the merged operands).
    """
    (x, x_batched), (y, y_batched) = x_in, y_in
    (x_contract, y_contract), (x_batch, y_batch) = dimension_numbers
    if len(x_contract) < 2 or np.shape(x)[x_contract[0]] <= LOOPED or not all(
            list(axes) == list(range(axes[0], axes[0] + len(axes)))
            for axes in (x_contract, y_contract)):
        return x, y, dimension_numbers
    x_shape, y_shape = np.shape(x)[:np.ndim(x) - x_batched], np.shape(y)[:np.ndim(y) - y_batched]
    outputs = math.prod(size for a, size in enumerate(x_shape) if a not in x_contract) * math.prod(
        size for a, size in enumerate(y_shape) if a not in (*y_contract, *y_batch))
    if outputs <= LOOPED:
        return x, y, dimension_numbers

    def merged(v: Array, axes: Sequence[int]) -> Array:
        """`v` with `axes` merged into one."""
        shape = np.shape(v)
        return lax.reshape(v, (*shape[:axes[0]], math.prod(shape[a] for a in axes),
                               *shape[axes[-1] + 1:]))

    def shifted(dims: Sequence[int], axes: Sequence[int]) -> list[int]:
        """`dims` after `axes` are merged into one."""
        return [d - len(axes) + 1 if d > axes[-1] else d for d in dims]

    return merged(x, x_contract), merged(y, y_contract), (
        ([x_contract[0]], [y_contract[0]]), (shifted(x_batch, x_contract),
                                             shifted(y_batch, y_contract)))


def _small_in_order(v: Array, batched: bool, groups: tuple[Sequence[int], ...]
                    ) -> tuple[Array, list[list[int]]]:
    """`v` with one run's axes in the order of `groups` (contracting, batch, free) if it is small.

    Small: no axis longer than `LOOPED`, as a weight matrix. Each entry of its first contracting
    axis is then one contiguous slice, rather than a strided one read again by every product.

    Returns:
      (v, the groups' axes in it).
    """
    order = [a for group in groups for a in group]
    if order == sorted(order) or max(np.shape(v)[:len(order)], default=0) > LOOPED:
        return v, [list(group) for group in groups]
    v = lax.transpose(v, (*order, *([len(order)] if batched else [])))
    starts = np.cumsum([0, *map(len, groups)])
    return v, [list(range(start, start + len(group))) for start, group in zip(starts, groups)]


def _typed(result: Array, params: dict[str, Any]) -> Array:
    """A product's `result` in the dtype its equation asks for, if any."""
    dtype = params.get("preferred_element_type")
    return result if dtype is None else result.astype(dtype)


def _arranged(x: ArrayLike, batched: bool, order: Sequence[int], expand_at: int,
              count: int) -> Array:
    """One run's axes of `x` put in `order`, with `count` axes of size one inserted at `expand_at`.

    A trailing run axis stays last.
    """
    x = jnp.asarray(x)
    x = lax.transpose(x, (*order, *([x.ndim - 1] if batched else [])))
    shape = (*x.shape[:expand_at], *(1,) * count, *x.shape[expand_at:])
    dims = tuple(i if i < expand_at else i + count for i in range(x.ndim))
    return lax.broadcast_in_dim(x, shape, dims)


# --- Operations whose parameters name one run's shape or axes: the run axis appended. A rule
# returns None where it does not apply, and `jax.vmap` evaluates the operation. ----------------


def _broadcast_in_dim(ins: list[_Value], params: dict[str, Any], runs: int) -> Array:
    """`lax.broadcast_in_dim` to the shape with the run axis appended."""
    (x, _), *dynamic = ins
    shape = (*params["shape"], runs)
    dims = (*params["broadcast_dimensions"], len(params["shape"]))
    return lax.broadcast_in_dim(x, shape, dims)


def _reshape(ins: list[_Value], params: dict[str, Any], runs: int) -> Array:
    """`lax.reshape` to the new sizes with the run axis appended."""
    return lax.reshape(ins[0][0], (*params["new_sizes"], runs))


def _transpose(ins: list[_Value], params: dict[str, Any], runs: int) -> Array:
    """`lax.transpose` with the run axis kept last."""
    perm = params["permutation"]
    return lax.transpose(ins[0][0], (*perm, len(perm)))


def _slice(ins: list[_Value], params: dict[str, Any], runs: int) -> Array:
    """`lax.slice` with the whole run axis kept."""
    strides = params["strides"]
    return lax.slice(ins[0][0], (*params["start_indices"], 0), (*params["limit_indices"], runs),
                     None if strides is None else (*strides, 1))


def _pad(ins: list[_Value], params: dict[str, Any], runs: int) -> Array | None:
    """`lax.pad` with the run axis unpadded; None for a padding value per run."""
    (x, _), (value, value_batched) = ins
    if value_batched:  # a padding value per run: left to `jax.vmap`
        return None
    return lax.pad(x, value, (*params["padding_config"], (0, 0, 0)))


def _concatenate(ins: list[_Value], params: dict[str, Any], runs: int) -> Array:
    """`lax.concatenate` of the operands, each with its run axis (shared ones broadcast)."""
    return lax.concatenate([_lift(v, b, runs) for v, b in ins], params["dimension"])


_RULES: dict[str, _Rule] = {
    "broadcast_in_dim": _broadcast_in_dim,
    "reshape": _reshape,
    "transpose": _transpose,
    "slice": _slice,
    "concatenate": _concatenate,
    "pad": _pad,
}
