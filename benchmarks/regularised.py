"""The smooth regularised models users write today, solved with diffrax and scipy.

Each model is one function `rhs(t, x, p, reg, xp)` on the scene's states `x` (no
multipliers), `p` the scene's parameters as floats, `reg` the regularisation strength and
`xp` either `numpy` (scipy) or `jax.numpy` (diffrax):

- ball: a penalty spring-damper, F = -k q - c v while q < 0 (Kelvin-Voigt), with the
  damping ratio zeta that gives the restitution e = exp(-zeta pi / sqrt(1 - zeta^2)) of a
  linear contact; reg = k.
- slider: friction mu N tanh(v / eps); reg = eps.
- relay, super-twisting: sign(s) -> tanh(s / eps); reg = eps (super-twisting also needs
  sqrt|s|, written (s^2 + 1e-20)^(1/4) so that its derivative is finite at s = 0).
- rectifier: the diode current eps softplus((src - v)/eps) / R_s (a smooth max); reg = eps
  in volts.
- chua: sat(x) = clip(x, -1, 1) smoothed as ((x+1)^2 + eps^2)^(1/2)/2 - ((x-1)^2 +
  eps^2)^(1/2)/2; reg = eps, with reg = 0 meaning the plain `clip` (the kink left to the
  ODE solver, which is what most users write for Chua).

Errors are measured against the exact nonsmooth reference, so they include the modelling
error of the regularisation, which no tolerance removes.
"""

import time

import diffrax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

from ._common import auto_number, median_time


def _ball(t, x, p, k, xp):
    e = p["e"]
    zeta = -np.log(e) / np.sqrt(np.pi**2 + np.log(e) ** 2)
    c = 2 * zeta * xp.sqrt(k)
    q, v = x[0], x[1]
    force = xp.where(q < 0, -k * q - c * v, 0.0)
    return xp.stack([v, -p["g"] + force])


def _slider(t, x, p, eps, xp):
    s, v = x[0], x[1]
    force = p["k"] * (p["V"] * t - s) - p["c"] * v - p["mu_k"] * p["N"] * xp.tanh(v / eps)
    return xp.stack([v, force / p["m"]])


def _relay(t, x, p, eps, xp):
    d = p["amplitude"] * xp.sin(2 * np.pi * p["frequency"] * t)
    return xp.stack([-xp.tanh(x[0] / eps) + d])


def _super_twisting(t, x, p, eps, xp):
    s = x[1] + p["c"] * x[0]
    w = xp.tanh(s / eps)
    u = -p["k1"] * (s * s + 1e-20) ** 0.25 * w + x[2]
    return xp.stack([x[1], u + 0.3 * xp.sin(5.0 * t), -p["k2"] * w])


def _softplus(z, xp):
    return xp.logaddexp(0.0, z)


def _rectifier(t, x, p, eps, xp):
    v = x[0]
    gap = p["V"] * xp.sin(p["omega"] * t) - v
    i = eps * _softplus(gap / eps, xp) / p["R_s"]
    return xp.stack([(i - v / p["R_L"]) / p["C"]])


def _chua(t, u, p, eps, xp):
    x = u[0]
    smooth = 0.5 * (
        xp.sqrt((x + 1) ** 2 + eps**2 + 1e-300) - xp.sqrt((x - 1) ** 2 + eps**2 + 1e-300)
    )
    sat = xp.where(eps > 0, smooth, xp.clip(x, -1.0, 1.0))
    g = p["m0"] * x + (p["m1"] - p["m0"]) * sat
    return xp.stack([p["alpha"] * (u[1] - x - g), x - u[1] + u[2], -p["beta"] * u[1]])


MODELS = dict(
    ball=_ball,
    slider=_slider,
    relay=_relay,
    super_twisting=_super_twisting,
    rectifier=_rectifier,
    chua=_chua,
)

# Regularisation strengths (full mode; quick mode takes the first and the last).
STRENGTHS = dict(
    ball=(1e4, 1e5, 1e6),
    slider=(1e-2, 1e-3, 1e-4),
    relay=(1e-2, 1e-3, 1e-4),
    super_twisting=(1e-2, 1e-3, 1e-4),
    rectifier=(1e-2, 1e-3, 1e-4),
    chua=(1e-2, 1e-3, 0.0),
)


def reg_label(name, reg):
    if name == "ball":
        return f"k={reg:.0e}"
    if name == "chua" and reg == 0:
        return "clip"
    return f"eps={reg:.0e}"


# --- diffrax ---------------------------------------------------------------------------------
DIFFRAX_SOLVERS = {"Kvaerno5": diffrax.Kvaerno5, "Tsit5": diffrax.Tsit5}
DIFFRAX_TIERS = (1024, 16384, 100_000)  # output-buffer sizes (max_steps), see BufferTiers


def make_diffrax(case, solver_name, max_steps):
    """`run(rtol, atol, reg, x0)` for one scene and solver, to be compiled once per buffer
    size (the tolerances and the regularisation strength are inputs, so one compilation
    serves the whole sweep). Returns (ts, xs, accepted, rejected, success, overflowed)
    with ts padded by inf."""
    _, _, p = case.build()
    model = MODELS[case.name]
    term = diffrax.ODETerm(lambda t, x, reg: model(t, x, p, reg, jnp))
    solver = DIFFRAX_SOLVERS[solver_name]()

    def run(rtol, atol, reg, x0):
        controller = diffrax.PIDController(rtol=rtol, atol=atol, dtmax=case.h_max)
        sol = diffrax.diffeqsolve(
            term,
            solver,
            0.0,
            case.t1,
            None,
            x0,
            args=reg,
            stepsize_controller=controller,
            saveat=diffrax.SaveAt(t0=True, steps=True),
            max_steps=max_steps,
            throw=False,
        )
        return (
            sol.ts,
            sol.ys,
            sol.stats["num_accepted_steps"],
            sol.stats["num_rejected_steps"],
            sol.result == diffrax.RESULTS.successful,
            sol.result == diffrax.RESULTS.max_steps_reached,
        )

    return run


def diffrax_overflowed(out):
    return bool(out[-1])


def run_diffrax(tiers, x0, rtol, atol, reg, repeats):
    """Time one diffrax configuration with the `BufferTiers` of `make_diffrax`."""
    args = (jnp.asarray(rtol), jnp.asarray(atol), jnp.asarray(reg), jnp.asarray(x0))
    fn, _, _ = tiers(*args)
    t_run, out = median_time(fn, *args, repeats=repeats, number=auto_number(fn, *args))
    ts, xs, acc, rej, ok, _ = (np.asarray(o) for o in out)
    keep = np.isfinite(ts)
    return dict(
        ts=ts[keep],
        xs=xs[keep],
        time=t_run,
        accepted=int(acc),
        rejected=int(rej),
        iterations=None,
        status="ok" if bool(ok) else "failed (max_steps or step size)",
    )


# --- scipy -----------------------------------------------------------------------------------
def run_scipy(case, x0, method, rtol, atol, reg, repeats):
    """One scipy `solve_ivp` configuration (finite-difference Jacobians, as users call it).
    Returns a dict of results (median time of `repeats`, 1 if a run takes over 1 s)."""
    _, _, p = case.build()
    model = MODELS[case.name]
    fun = lambda t, x: model(t, x, p, reg, np)
    kw = dict(method=method, rtol=rtol, atol=atol)
    if case.h_max is not None:
        kw["max_step"] = case.h_max
    call = lambda: solve_ivp(fun, (0.0, case.t1), np.asarray(x0, float), **kw)
    t0 = time.perf_counter()
    sol = call()
    first = time.perf_counter() - t0
    if first < 1.0 and repeats > 1:
        first, sol = median_time(call, repeats=repeats)
    return dict(
        ts=np.asarray(sol.t),
        xs=np.asarray(sol.y).T,
        time=first,
        accepted=int(sol.t.size - 1),
        rejected=None,
        iterations=None,
        rhs_evals=int(sol.nfev),
        status="ok" if sol.status == 0 else f"failed ({sol.message})",
    )
