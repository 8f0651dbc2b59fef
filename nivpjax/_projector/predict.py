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
