"""Gradients: `jax.value_and_grad` of a calibration loss over a whole trajectory against the
forward solve alone.

Loss: mean squared difference between the computed position on a fixed output grid
(`t_eval`, piecewise-linear interpolation between accepted steps) and synthetic
observations (the exact solution at the true parameter), as a function of one parameter
evaluated away from the truth:

- ball (impacts): q(t) on 60 points in [0.05, 3], restitution e, truth 0.8, evaluated at
  e = 0.75;
- slider (friction): s(t) on 100 points in [0.1, 10], friction mu, truth 0.2, evaluated
  at mu = 0.25.

Both with Bathe + semismooth Newton, PID rtol 1e-5 (atol 1e-8), `max_steps=4096` and the
checkpointed adjoint with `checkpoints=max_steps`: every attempted step's loop state (a few
scalars and the state vector) is stored, so reverse mode recomputes nothing. Measured
value_and_grad / forward (ratio of the minimum times over 15-20 interleaved repeats): ball
(429 attempted steps) 4.6x with equinox's default (90 checkpoints for max_steps=4096),
4.4x with 128, 3.9x with 512, 2.7x with 4096; slider (129 attempts) 5.6x default,
5.9x/5.6x/5.2x/12.4x with 32/64/128/512, 2.9x with 4096 (counts below max_steps go through
equinox's general online checkpoint schedule; only `checkpoints == max_steps` takes its
store-every-step fast path).

Timings: compile of `jax.jit(loss)` and of `jax.jit(jax.value_and_grad(loss))`, run =
median of repeats after compilation. The gradient is also checked against the derivative of
the same loss evaluated on the exact solution (central difference of the closed form, step
1e-6). Two things matter for the ball. (1) Impact times move with the parameter: each
stage with an impact carries the saltation term through `UnilateralContact.event_time`
(without it the gradient was -0.38 against the exact -0.2345 even on a fine grid). (2) Bathe
integrates ballistic flight exactly, so without a step cap the steps between impacts are
long and the piecewise-linear `t_eval` interpolation is off by up to 0.16 (the computed loss
by ~40%); the ball's loss therefore caps the step at `h_max = 0.01` (the `h_max` column).
On the slider the computed loss is accurate (its finite differences match the exact
derivative) but the derivative was biased by ~13% while slip reversals carried no
event-time term; `CoulombFriction.switch_shift` now adds it (derivative accuracy per rtol:
`python -m benchmarks.calibration`, `benchmarks/results/calibration.md`; this loss not
re-measured since).
"""

import jax
import jax.numpy as jnp
import numpy as np

import nivpjax as nj

from ._common import auto_number, compile_timed, median_time
from .cases import CASES


RTOL = 1e-5
MAX_STEPS = 4096

PROBLEMS = {
    "ball": dict(
        case="ball",
        param="e",
        truth=0.8,
        at=0.75,
        grid=np.linspace(0.05, 3.0, 60),
        set_args=lambda args, p: dict(args, e=p),
        component=0,
        h_max=0.01,
    ),
    "slider": dict(
        case="slider",
        param="mu",
        truth=0.2,
        at=0.25,
        grid=np.linspace(0.1, 10.0, 100),
        set_args=lambda args, p: dict(args, mu_s=p, mu_k=p),
        component=0,
    ),
}


def _exact_positions(case, prob, p):
    from dataclasses import replace

    scene, x0, args = case.make()
    params = {k: float(v) for k, v in prob["set_args"](args, p).items()}
    c = replace(case, make=lambda: (scene, x0, params))
    return c.exact(prob["grid"])[:, prob["component"]]


def run_problem(name, quick, log):
    prob = PROBLEMS[name]
    case = CASES[prob["case"]]
    scene, x0, args = case.make()
    grid = jnp.asarray(prob["grid"])
    obs = jnp.asarray(_exact_positions(case, prob, prob["truth"]))

    def loss(p):
        controller = nj.PIDController(rtol=RTOL, atol=RTOL * 1e-3, h_max=prob.get("h_max"))
        sol = scene.solve(
            0.0,
            case.t1,
            x0,
            prob["set_args"](args, p),
            stepper=nj.Bathe(),
            controller=controller,
            t_eval=grid,
            max_steps=MAX_STEPS,
            checkpoints=MAX_STEPS,
            throw=False,
        )
        return jnp.mean((sol.y_eval[:, prob["component"]] - obs) ** 2)

    p = jnp.asarray(prob["at"])
    repeats = 3 if quick else 7
    options = nj.compiler_options()
    fwd, fwd_compile = compile_timed(loss, p, options=options)
    vg, vg_compile = compile_timed(jax.value_and_grad(loss), p, options=options)
    t_fwd, value = median_time(fwd, p, repeats=repeats, number=auto_number(fwd, p))
    t_vg, (value2, grad) = median_time(vg, p, repeats=repeats, number=auto_number(vg, p))

    def exact_loss(q):
        return float(np.mean((_exact_positions(case, prob, q) - np.asarray(obs)) ** 2))

    h = 1e-6
    exact_grad = (exact_loss(prob["at"] + h) - exact_loss(prob["at"] - h)) / (2 * h)
    row = dict(
        scene=name,
        param=prob["param"],
        h_max=prob.get("h_max"),
        fwd_compile=fwd_compile,
        vg_compile=vg_compile,
        fwd=t_fwd,
        vg=t_vg,
        ratio=t_vg / t_fwd,
        loss=float(value),
        exact_loss=exact_loss(prob["at"]),
        grad=float(grad),
        exact_grad=exact_grad,
        grad_rel_err=abs(float(grad) - exact_grad) / abs(exact_grad),
    )
    log(
        f"[gradient {name}] forward {t_fwd * 1e3:.2f} ms, value_and_grad {t_vg * 1e3:.2f} ms "
        f"(ratio {row['ratio']:.2f}); grad {row['grad']:.4g} vs exact {exact_grad:.4g}; "
        f"compile {fwd_compile:.1f} s / {vg_compile:.1f} s"
    )
    return row
