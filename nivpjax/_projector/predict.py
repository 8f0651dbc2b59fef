"""Event prediction kernels: the first future zero of a switching function's local model."""

import jax.numpy as jnp


def first_root(s, ds, dds):
    r"""The smallest $\tau > 0$ with $s + \dot s\,\tau + \tfrac12 \ddot s\,\tau^2 = 0$,
    componentwise; `inf` where there is none. Written with the cancellation-free form
    $\tau = 2s / (-\dot s \pm \sqrt{\dot s^2 - 2 \ddot s s})$, so a quadratic term at
    round-off level gives the linear root."""
    disc = ds**2 - 2 * dds * s
    ok = disc >= 0
    root = jnp.sqrt(jnp.where(ok, disc, 0.0))
    inf = jnp.full_like(s, jnp.inf)

    def candidate(den):
        safe = jnp.where(den != 0, den, 1.0)
        tau = jnp.where(den != 0, 2 * s / safe, inf)
        return jnp.where(ok & (tau > 0), tau, inf)

    return jnp.minimum(candidate(-ds + root), candidate(-ds - root))


def secant_crossing(s0, s1, h):
    r"""The time from the start of a step of size $h$ at which the switching functions
    $s_0 \to s_1$ (values at its two ends) reach zero along their secant: inside the step
    if they changed sign, beyond it if they approach zero, `inf` if they move away from
    it or sit on it (up to round-off)."""
    tiny = 64 * jnp.finfo(s1.dtype).eps * (1.0 + jnp.maximum(jnp.abs(s0), jnp.abs(s1)))
    ds = s1 - s0
    approaching = (s0 * ds < 0) & (jnp.abs(s0) > tiny) & (jnp.abs(ds) > tiny)
    tau = h * s0 / jnp.where(approaching, -ds, 1.0)
    return jnp.where(approaching & (tau > 0), tau, jnp.inf)


def hermite_excursion(s0, s1, m0, m1):
    r"""How far the cubic Hermite interpolant of a switching function reaches across zero
    inside a step whose two ends lie on the same side: $p(0) = s_0$, $p(1) = s_1$,
    $p'(0) = m_0$, $p'(1) = m_1$ (the rates times the step size), componentwise. The
    largest $|p(\theta)|$ at an extremum $\theta \in (0, 1)$ where $p$ has the sign opposite
    to $s_0$; 0 where there is none (no pair of crossings inside the step that the end
    values and rates show)."""
    c2 = -3 * s0 - 2 * m0 + 3 * s1 - m1
    c3 = 2 * s0 + m0 - 2 * s1 + m1
    # p'(theta) = m0 + 2 c2 theta + 3 c3 theta^2: its roots, cancellation-free
    # (theta = -m0 / (c2 +- sqrt(c2^2 - 3 c3 m0)), the linear root where c3 vanishes).
    disc = c2**2 - 3 * c3 * m0
    root = jnp.sqrt(jnp.where(disc >= 0, disc, 0.0))

    def reach(den):
        safe = jnp.where(den != 0, den, 1.0)
        theta = -m0 / safe
        p = s0 + theta * (m0 + theta * (c2 + theta * c3))
        inside = (disc >= 0) & (den != 0) & (theta > 0) & (theta < 1)
        across = inside & (p * s0 < 0) & (s0 * s1 > 0)
        return jnp.where(across, jnp.abs(p), 0.0)

    return jnp.maximum(reach(c2 + root), reach(c2 - root))
