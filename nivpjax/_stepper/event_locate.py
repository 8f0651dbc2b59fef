r"""Locating the first event of a step on its dense output: sampled, then bracketed."""

import jax
import jax.numpy as jnp


# Interior sample points of a step's dense output at which the switching functions are
# read: a pair of crossings closer than 1/SAMPLES of the step, both between two samples, is
# missed (Julia's callbacks sample 10 points per step the same way).
SAMPLES = 8
# Bracketing iterations (Illinois, a regula falsi with halved weights): superlinear, so the
# bracket is at round-off well before this many.
ITERATIONS = 40


def first_bracket(phi_samples):
    r"""`(found, k)`: whether a sample of $\varphi$ (the smallest switching function, at
    $\theta_k = k/S$, $k = 1..S$) is negative, and the first such $k$ (the event lies in
    $[\theta_{k-1}, \theta_k]$). The start, $\theta_0 = 0$, is on the face by its
    decision."""
    negative = phi_samples < 0
    k = jnp.argmax(negative) + 1
    return jnp.any(negative), k


def illinois(phi, lo, hi, phi_lo, phi_hi, tol):
    r"""The root of the scalar function `phi` in $[lo, hi]$ with $\varphi(lo) \ge 0 >
    \varphi(hi)$, by the Illinois method, to a bracket of width `tol` (or `ITERATIONS`).
    Returns the bracket's end where $\varphi < 0$ (just past the event: the step ends
    on the far side, so the next one starts on the new face) and the one before it."""

    def cond(carry):
        i, lo, hi, *_ = carry
        return (i < ITERATIONS) & (hi - lo > tol)

    def body(carry):
        i, lo, hi, f_lo, f_hi, side = carry
        # Secant point, kept strictly inside the bracket.
        x = (lo * f_hi - hi * f_lo) / jnp.where(f_hi != f_lo, f_hi - f_lo, 1.0)
        mid = 0.5 * (lo + hi)
        x = jnp.where(jnp.isfinite(x) & (x > lo) & (x < hi), x, mid)
        fx = phi(x)
        right = fx < 0  # the root is left of x: x becomes hi
        # Illinois: halve the retained end's value when the same end is kept twice.
        new_side = jnp.where(right, 1, -1)
        same = new_side == side
        f_lo_new = jnp.where(right, jnp.where(same, 0.5 * f_lo, f_lo), fx)
        f_hi_new = jnp.where(right, fx, jnp.where(same, 0.5 * f_hi, f_hi))
        lo_new = jnp.where(right, lo, x)
        hi_new = jnp.where(right, x, hi)
        return i + 1, lo_new, hi_new, f_lo_new, f_hi_new, new_side

    init = (jnp.array(0), lo, hi, phi_lo, phi_hi, jnp.array(0))
    _, lo, hi, *_ = jax.lax.while_loop(cond, body, init)
    return hi, lo
