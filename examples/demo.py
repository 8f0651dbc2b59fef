"""nivpjax demo: simulate classic nonsmooth scenes and show what accuracy costs in time.

For each scene the demo solves the model at two tolerances, compares it with an exact
reference (closed form or exact piecewise solution), and prints a table of error, steps,
compile time and run time after compilation. It finishes with a batched (`vmap`) parameter
sweep and a reverse-mode gradient through a whole trajectory with impacts.

Run:  python examples/demo.py
"""

import os
import time


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import nivpjax as nj  # noqa: E402


jax.config.update("jax_enable_x64", True)
S = nj.scenes


# --- exact references ------------------------------------------------------------------------
def ball_exact(t_end, e=0.8, g=9.81, q=1.0, v=0.0):
    t = 0.0
    while True:
        t_hit = (v + np.sqrt(v**2 + 2 * g * q)) / g
        if t + t_hit > t_end:
            dt = t_end - t
            return np.array([q + v * dt - 0.5 * g * dt**2, v - g * dt])
        t, v, q = t + t_hit, -e * (v - g * t_hit), 0.0
        if e < 1 and t + 2 * v / (g * (1 - e)) <= t_end:
            # The remaining bounces take 2 v / (g (1 - e)) in all (Zeno): at rest by t_end.
            return np.zeros(2)


def relay_trajectory(t, a=0.5, x0=0.5):
    # x' = -1 + a sin(2 pi t) until x = 0 (reached before t = 2 here), then x = 0 (sliding).
    x = lambda t: x0 - t + a / (2 * np.pi) * (1 - np.cos(2 * np.pi * t))
    lo, hi = 0.0, 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if x(mid) > 0 else (lo, mid)
    t = np.asarray(t)
    return np.where(t < hi, x(t), 0.0)[:, None]


def block_exact(mu=0.3, g=9.81, v=(2.0, 1.0)):
    v = np.asarray(v)
    d = np.dot(v, v) / (2 * mu * g)
    return np.concatenate([d * v / np.linalg.norm(v), [0.0, 0.0]])


def slider_exact(m=1.0, k=1.0, fric=0.6, v0=0.1):
    # m s'' = -k s - fric (sliding forward), s(0) = 0, s'(0) = v0: s = A sin(wt) + B(cos wt - 1)
    w = np.sqrt(k / m)
    b = fric / k
    t_stop = np.arctan2(v0 / w, b) / w
    s = (v0 / w) * np.sin(w * t_stop) + b * (np.cos(w * t_stop) - 1)
    return np.array([s, 0.0])


# (name, scene, end time, exact reference, the two tolerances of its rows)
SCENES = [
    # The ball's error follows the tolerance down to round-off (with event_margin=None the
    # margin by which steps land before an impact shrinks with rtol below 1e-6): its second
    # row is at rtol 1e-8.
    ("bouncing ball (e=0.8, t=1.5)", S.bouncing_ball(), 1.5, lambda: ball_exact(1.5), (1e-3, 1e-8)),
    ("spring-slider, Coulomb stick", S.spring_slider(), 2.0, slider_exact, (1e-3, 1e-6)),
    # The relay's final state sits on the sliding surface (error exactly 0): measure its
    # error over the trajectory, at 201 output times, against the exact solution.
    ("relay, Filippov sliding", S.relay(), 2.0, relay_trajectory, (1e-3, 1e-6)),
    ("block on plane, disk friction", S.block_on_plane(), 1.0, block_exact, (1e-3, 1e-6)),
    (
        "block on plane, 3-D cone",
        S.block_on_plane(cone=True),
        1.0,
        lambda: np.insert(np.insert(block_exact(), 2, 0.0), 5, 0.0),
        (1e-3, 1e-6),
    ),
]


def timed(fn, *args):
    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t


def main():
    print(f"nivpjax {nj.__version__} on {jax.devices()[0].platform}, float64\n")
    cols = ("scene", "rtol", "error", "steps", "rejected", "compile s", "run ms")
    widths = (32, 6, 9, 5, 8, 9, 8)
    header = (
        "| "
        + " | ".join(
            c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cols, widths))
        )
        + " |"
    )
    print(header)
    print("|" + "|".join("-" * (len(c)) for c in header.split("|")[1:-1]) + "|")
    for name, (scene, x0, args), t1, exact, rtols in SCENES:
        trajectory = exact is relay_trajectory
        t_eval = np.linspace(0.0, t1, 201) if trajectory else None
        ref = exact(t_eval) if trajectory else exact()
        for rtol in rtols:
            # Tolerances are run-time values: both rows share one compiled solve per scene
            # (the first row's "compile s" includes it, the second's is ~0).
            # event_margin=None: steps land before an impact by a margin that follows rtol.
            ctrl = nj.PIDController(rtol=rtol, atol=rtol * 1e-2, event_margin=None)
            run = lambda x0, args, s=scene, c=ctrl, t1=t1: s.solve(
                0.0, t1, x0, args, controller=c, max_steps=4096, t_eval=t_eval
            )
            sol, t_first = timed(run, x0, args)
            sol, t_run = timed(run, x0, args)
            x, _ = scene.split(sol.y_eval if trajectory else sol.y_final)
            err = float(np.max(np.abs(np.asarray(x) - ref)))
            print(
                f"| {name:32s} | {rtol:6.0e} | {err:9.2e} | {int(sol.n_accepted):5d} | "
                f"{int(sol.n_rejected):8d} | {max(t_first - t_run, 0.0):9.2f} | "
                f"{1e3 * t_run:8.2f} |"
            )
    print(
        "\ncompile s: the first call's time minus the second's (tracing and XLA compilation)."
        "\nTolerances are run-time values, so a scene's second row reuses the program its"
        "\nfirst row compiled: 0.00 there is the point, not a missing measurement."
    )

    # Batched parameter sweep: 1000 restitution coefficients in one compiled call.
    scene, x0, args = S.bouncing_ball()
    ctrl = nj.PIDController(rtol=1e-4, atol=1e-6)

    def height(e):
        sol = scene.solve(
            0.0,
            1.5,
            x0,
            {**args, "e": e},
            controller=ctrl,
            max_steps=1024,
            throw=False,
            adjoint="forward",
        )
        return sol.y_final[0], sol.result == nj.RESULTS.successful

    es = jnp.linspace(0.5, 0.95, 1000)
    # A jit of our own: pass nivpjax's compiler options (half the XLA compile time on CPU).
    sweep = jax.jit(jax.vmap(height), compiler_options=nj.compiler_options())
    (_, _), t_first = timed(sweep, es)
    (h, ok), t_run = timed(sweep, es)
    exact = np.array([ball_exact(1.5, e=float(e))[0] for e in es])
    print(
        f"\nvmap sweep: 1000 bouncing balls (restitution 0.5..0.95) in {1e3 * t_run:.1f} ms "
        f"({1e6 * t_run / 1000:.0f} us per trajectory, compile {t_first - t_run:.1f} s); "
        f"all succeeded: {bool(jnp.all(ok))}; max height error {np.max(np.abs(h - exact)):.1e}"
    )

    # Reverse-mode gradient of a calibration loss through impacts.
    def loss(e):
        sol = scene.solve(0.0, 1.5, x0, {**args, "e": e}, controller=ctrl, max_steps=1024)
        return (sol.y_final[0] - 0.3) ** 2

    grad = jax.jit(jax.grad(loss), compiler_options=nj.compiler_options())
    g, t_grad_first = timed(grad, 0.8)
    g, t_grad = timed(grad, 0.8)
    q = ball_exact(1.5)[0]
    eps = 1e-4
    fd = (
        (ball_exact(1.5, e=0.8 + eps)[0] - 0.3) ** 2 - (ball_exact(1.5, e=0.8 - eps)[0] - 0.3) ** 2
    ) / (2 * eps)
    print(
        f"gradient of (height(1.5) - 0.3)^2 w.r.t. restitution: {float(g):.5f} "
        f"(exact {fd:.5f}, height {q:.4f}), reverse mode through the adaptive loop: "
        f"{1e3 * t_grad:.1f} ms per gradient after a first call of {t_grad_first:.1f} s "
        "(compiling the reverse-mode program)"
    )


if __name__ == "__main__":
    main()
