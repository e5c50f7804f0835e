"""Arithmetic with the same bits on every CPU: IEEE operations only, in place of libm.

glibc's ``exp``, ``log``, ``pow``, ``sin``, ``atan2`` ... (and so numpy's and
Python's) choose FMA or plain code by the CPU and differ in the last bit
between machines (see :mod:`fracture_cli.system.numeric_env`). Where such a value
reaches an output or a decision, the library uses these instead: each is built
from ``+ - * /``, ``sqrt``, ``rint``, ``frexp`` and ``ldexp``, which IEEE 754
rounds the same way everywhere, and each is within a few units in the last
place of the true value (tests/test_numerics.py).
"""

from __future__ import annotations

import math

import numpy as np


def square(x):
    """``x * x`` (not ``x ** 2``: on Python and numpy scalars that calls libm's ``pow``)."""
    return x * x


def cube(x):
    """``x * x * x`` (not ``x ** 3``: libm's ``pow`` rounds by the CPU)."""
    return x * x * x


def pseudo_angle(y, x):
    """A number in [0, 4) that increases with ``atan2(y, x)`` taken in [0, 2 pi).

    Sorting by it orders directions as their angles do, with only additions and
    one division (the same bits on every CPU, unlike ``atan2``); equal directions
    get equal values; ``(0, 0)`` gives 0.

    Parameters
    ----------
    y, x : float or (n,) float array
        Components of the directions.

    Returns
    -------
    float or (n,) float array
    """
    y = np.asarray(y, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    total = np.abs(x) + np.abs(y)
    ratio = np.divide(y, total, out=np.zeros_like(total), where=total > 0.0)
    # The "diamond angle": the position along the unit L1 diamond, quadrant by quadrant.
    value = np.where(x >= 0.0, np.where(y >= 0.0, ratio, 4.0 + ratio), 2.0 - ratio)
    value = np.where(value >= 4.0, 0.0, value)
    return value if value.ndim else float(value)


# ---------------------------------------------------------------------------
# Elementary functions from IEEE operations only (+, -, *, /, sqrt, rint, frexp, ldexp), in place of
# libm's: the same bits on every machine, within a few units in the last place of the true value.

_LN2_HI = 6.93147180369123816490e-01  # ln 2 to 32 bits: k * _LN2_HI is exact for |k| < 2**20
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e00
_SQRT_HALF = 0.70710678118654752440
_PI = 3.141592653589793
_PIO2_HI = 1.57079632673412561417e00  # pi / 2 to 33 bits
_PIO2_LO = 6.07710050650619224932e-11
_TAN_PI_12 = 0.26794919243112270  # 2 - sqrt(3)
_SQRT3 = 1.7320508075688772
_EXP_TERMS = 14  # |r| <= ln(2) / 2: r**14 / 14! < 1e-17
_LOG_TERMS = 11  # |s| <= 0.1716: s**22 / 23 < 1e-17
_ATAN_TERMS = 15  # |u| <= 0.268: u**30 / 31 < 1e-18
_SIN_TERMS = 10  # |r| <= pi / 4: r**21 / 21! < 1e-20


def _horner(coefficients: tuple[float, ...], x: np.ndarray) -> np.ndarray:
    """``sum(c[i] * x**i)`` by Horner's rule (separate products and sums: no fused multiply-add)."""
    result = np.full_like(x, coefficients[-1])
    for c in coefficients[-2::-1]:
        result = result * x + c
    return result


# Series coefficients from exact integers (math.factorial), each rounded once.
_EXP_COEF = tuple(1.0 / math.factorial(n) for n in range(_EXP_TERMS))
_LOG_COEF = tuple(1.0 / (2 * i + 1) for i in range(_LOG_TERMS))
_ATAN_COEF = tuple((-1) ** i / (2 * i + 1) for i in range(_ATAN_TERMS))
_SIN_COEF = tuple((-1) ** i / math.factorial(2 * i + 1) for i in range(_SIN_TERMS))
_COS_COEF = tuple((-1) ** i / math.factorial(2 * i) for i in range(_SIN_TERMS))


def _out(value: np.ndarray, like) -> np.ndarray | float:
    return value if np.ndim(like) else float(value)


def exp(x):
    """``e ** x`` (float or array), the same bits on every CPU (range reduction by ln 2, Taylor series)."""
    x = np.asarray(x, dtype=np.float64)
    k = np.rint(x * _INV_LN2)
    r = (x - k * _LN2_HI) - k * _LN2_LO
    with np.errstate(over="ignore"):
        value = np.ldexp(_horner(_EXP_COEF, r), np.clip(k, -2000, 2000).astype(np.int64))
    return _out(value, x)


def log(x):
    """Natural logarithm of positive ``x`` (float or array), the same bits on every CPU."""
    x = np.asarray(x, dtype=np.float64)
    m, e = np.frexp(x)
    low = m < _SQRT_HALF
    m = np.where(low, 2.0 * m, m)
    k = (e - low).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (m - 1.0) / (m + 1.0)  # m - 1 is exact (Sterbenz)
        value = k * _LN2_HI + (2.0 * s * _horner(_LOG_COEF, s * s) + k * _LN2_LO)
    value = np.where(x > 0.0, value, np.where(x == 0.0, -np.inf, np.nan))
    return _out(value, x)


def power(base, exponent):
    """``base ** exponent`` for positive ``base``, as ``exp(exponent * log(base))`` (the same bits everywhere)."""
    return exp(np.asarray(exponent, dtype=np.float64) * np.asarray(log(base)))


def cbrt(x):
    """Cube root of ``x >= 0`` (float or array), the same bits on every CPU: one Newton step on exp/log."""
    x = np.asarray(x, dtype=np.float64)
    guess = np.asarray(exp(np.asarray(log(np.where(x > 0.0, x, 1.0))) / 3.0))
    value = guess - (guess * guess * guess - x) / (3.0 * guess * guess)
    return _out(np.where(x > 0.0, value, 0.0), x)


def _atan_unit(t: np.ndarray) -> np.ndarray:
    """atan of ``t`` in [0, 1]: above tan(pi/12), atan(t) = pi/6 + atan((t sqrt3 - 1) / (t + sqrt3))."""
    high = t > _TAN_PI_12
    u = np.where(high, (t * _SQRT3 - 1.0) / (t + _SQRT3), t)
    return np.where(high, _PI / 6.0, 0.0) + u * _horner(_ATAN_COEF, u * u)


def atan2(y, x):
    """The angle of ``(x, y)`` in [-pi, pi] (float or arrays), the same bits on every CPU."""
    y = np.asarray(y, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    a, b = np.abs(y), np.abs(x)
    big, small = np.maximum(a, b), np.minimum(a, b)
    t = np.divide(small, big, out=np.zeros_like(big), where=big > 0.0)
    angle = _atan_unit(t)
    angle = np.where(a > b, _PI / 2.0 - angle, angle)
    angle = np.where(x < 0.0, _PI - angle, angle)
    angle = np.where(np.signbit(y), -angle, angle)
    return _out(angle, y if np.ndim(y) else x)


def acos(c):
    """arccos of ``c`` clipped to [-1, 1] (float or array), in [0, pi], the same bits on every CPU."""
    c = np.clip(np.asarray(c, dtype=np.float64), -1.0, 1.0)
    return _out(np.asarray(atan2(np.sqrt((1.0 - c) * (1.0 + c)), c)), c)


def sin_cos(angle):
    """``(sin(angle), cos(angle))`` (floats or arrays) for ``|angle| < 1e6``, the same bits on every CPU."""
    angle = np.asarray(angle, dtype=np.float64)
    k = np.rint(angle / (_PI / 2.0))
    r = (angle - k * _PIO2_HI) - k * _PIO2_LO
    r2 = r * r
    s = r * _horner(_SIN_COEF, r2)
    c = _horner(_COS_COEF, r2)
    quadrant = np.mod(k, 4.0)
    sine = np.where(quadrant == 0, s, np.where(quadrant == 1, c, np.where(quadrant == 2, -s, -c)))
    cosine = np.where(quadrant == 0, c, np.where(quadrant == 1, -s, np.where(quadrant == 2, -c, s)))
    return _out(sine, angle), _out(cosine, angle)


def uniform_directions(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` unit vectors uniform on the sphere (rejection from the cube: no libm, unlike ``rng.normal``).

    Returns
    -------
    (count, 3) float array
    """
    found: list[np.ndarray] = []
    have = 0
    while have < count:
        v = rng.uniform(-1.0, 1.0, (2 * (count - have) + 8, 3))
        r2 = np.einsum("ij,ij->i", v, v)
        v = v[(r2 <= 1.0) & (r2 > 1e-6)]
        found.append(v)
        have += len(v)
    v = np.concatenate(found)[:count]
    return v / np.sqrt(np.einsum("ij,ij->i", v, v))[:, None]


def exact_log_ceil(value: float, ratio: float) -> int:
    """The smallest integer ``k >= 0`` with ``ratio ** k >= value``, by repeated products (no ``log``).

    Parameters
    ----------
    value : float
        Must be finite.
    ratio : float
        Greater than 1.
    """
    if not math.isfinite(value):
        raise ValueError(f"exact_log_ceil needs a finite value, got {value}")
    k, power = 0, 1.0
    while power < value:
        power *= ratio
        k += 1
    return k
