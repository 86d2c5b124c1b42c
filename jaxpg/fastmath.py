"""Float32 activations by vectorisable arithmetic, where XLA's CPU versions compute much more.

XLA's float32 `expm1` computes both `exp` and `tanh` for every element, and `log_sigmoid` (a
`logaddexp`) an `exp`, a `log1p` and their selects; here `elu` is a range reduction and one
polynomial, `log_sigmoid` an `exp` and one polynomial (measurements in docs/performance.md). Each
keeps JAX's derivative, computed from its value, and any other float dtype takes `jax.nn`'s own.
`policies.forward` and the hand-derived gradient use them, where a run's arrays lie alike alone
and in a block (`policies`).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

_f32 = np.float32
_INV_LN2 = _f32(1 / math.log(2))
_LN2 = (_f32(0.693359375), _f32(-2.12194440e-4))  # sum: ln 2
_EXPM1 = tuple(_f32(1 / math.factorial(k)) for k in range(2, 9))  # Taylor's 1/2! to 1/8!
_ATANH = tuple(_f32(2 / (2 * k + 1)) for k in range(8))  # 2 atanh(s) = s (2 + 2/3 s^2 + ...)


@jax.custom_jvp
def elu(x: jax.Array) -> jax.Array:
    """`x` where positive, else `expm1(x)` (`jax.nn.elu`), within 1 ulp in float32 (XLA's: 5)."""
    negative = jnp.minimum(x, 0)
    expm1 = expm1_nonpositive(negative) if x.dtype == jnp.float32 else jnp.expm1(negative)
    return jnp.where(x > 0, x, expm1)


@elu.defjvp
def _elu_jvp(primals: tuple[jax.Array], tangents: tuple[jax.Array]
             ) -> tuple[jax.Array, jax.Array]:
    """`elu` and its derivative, 1 where `x` is positive, else `elu(x) + 1`, times the tangent.

    `x` is positive exactly where `elu(x)` is: the derivative reads only the value, so that XLA
    need not compute `x` again beside it."""
    (x,), (dx,) = primals, tangents
    y = elu(x)
    return y, _elu_derivative(y) * dx


def _elu_derivative(y: jax.Array) -> jax.Array:
    """`elu`'s derivative at the point where its value is `y`: 1 where `y` is positive, else
    `y + 1`."""
    return jnp.where(y > 0, 1, y + 1)


@jax.custom_jvp
def elu_of_value(x: jax.Array, y: jax.Array) -> jax.Array:
    """`elu(x)`, given as its value `y`, computed before (a rollout's record).

    Its derivative with respect to `x` is `elu`'s, from `y` alone, so that a gradient through it
    computes no `elu`; `x` serves only as what the derivative is taken with respect to.
    """
    del x
    return y


@elu_of_value.defjvp
def _elu_of_value_jvp(primals: tuple[jax.Array, jax.Array], tangents: tuple[jax.Array, jax.Array]
                      ) -> tuple[jax.Array, jax.Array]:
    """`y` and `elu`'s derivative at it times the tangent of `x` (`y` is taken as fixed)."""
    (_, y), (dx, _) = primals, tangents
    return y, _elu_derivative(y) * dx


@jax.custom_jvp
def log_sigmoid(z: jax.Array) -> jax.Array:
    """`log(sigmoid(z))` = `min(z, 0) - log1p(exp(-|z|))`, within 4 ulp in float32 (XLA's: 3)."""
    if z.dtype != jnp.float32:
        return jax.nn.log_sigmoid(z)
    return jnp.minimum(z, 0) - log1p_unit(jnp.exp(-jnp.abs(z)))


@log_sigmoid.defjvp
def _log_sigmoid_jvp(primals: tuple[jax.Array], tangents: tuple[jax.Array]
                     ) -> tuple[jax.Array, jax.Array]:
    """`log_sigmoid` and its derivative `sigmoid(-z)` times the tangent."""
    (z,), (dz,) = primals, tangents
    u = jnp.exp(-jnp.abs(z))  # sigmoid(-z) is u / (1 + u) for z >= 0, else 1 / (1 + u)
    return log_sigmoid(z), jnp.where(z >= 0, u, 1) / (1 + u) * dz


def expm1_nonpositive(x: jax.Array) -> jax.Array:
    """`expm1` of float32 `x` <= 0: 2**n expm1(r) + (2**n - 1), x = n ln 2 + r, |r| <= ln 2 / 2.

    `expm1(r)` is Taylor's polynomial of degree 8 (truncated below 1e-9 of the value). Below -18
    the value rounds to -1, and `x` is taken as -18 there, where 2**n is a normal number.
    """
    x = jnp.maximum(x, _f32(-18))
    n = jnp.round(x * _INV_LN2)
    r = (x - n * _LN2[0]) - n * _LN2[1]
    p: jax.Array | np.float32 = _EXPM1[-1]
    for c in reversed(_EXPM1[:-1]):
        p = c + r * p
    expm1_r = r + r * r * p
    scale = jax.lax.bitcast_convert_type((n.astype(jnp.int32) + 127) << 23, jnp.float32)  # 2**n
    return scale * expm1_r + (scale - 1)


def log1p_unit(u: jax.Array) -> jax.Array:
    """`log1p` of float32 `u` in [0, 1]: 2 atanh(s), s = u / (2 + u) <= 1/3, by its series to s**15.

    The series is truncated below 2e-9 of the value; `u` multiplies last, so that a value stays
    normal as long as `u` is.
    """
    q = 1 / (2 + u)
    s = u * q
    s2 = s * s
    p: jax.Array | np.float32 = _ATANH[-1]
    for c in reversed(_ATANH[:-1]):
        p = c + s2 * p
    return u * (p * q)
