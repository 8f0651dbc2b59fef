"""A scene pays only for the effects it calls for: cost per step of one oscillator with no
effect, with Coulomb friction, and with friction and a unilateral contact.

The model is a planar mass on a spring above a floor, x = (q_x, q_y, v_x, v_y):
q'' = -k (q - q_rest) - g e_y. The three scenes share the dynamics and differ only in their
effects tuple: none; Coulomb friction on the tangential velocity v_x; friction plus a
unilateral floor contact on q_y (restitution 0.5). Each is integrated
with the same fixed step (nj.ConstantStepSize), the same stepper (Bathe, semismooth Newton)
and the same number of steps, so the time per step compares the per-step work of the
compiled programs directly. Also printed: Newton iterations per step and the size of the
compiled program (number of HLO instructions), which measures what each effect adds to it.

Run:  python -m benchmarks.bench_effects
"""

from ._common import median_time, time_once  # noqa: I001  (sets float64, BLAS threads)

import equinox as eqx
import jax
import jax.numpy as jnp

import nivpjax as nj


STEPS = 2000
H = 1e-3


def dynamics(t, x, a, m):
    q, v = x[:2], x[2:]
    acc = -a["k"] * (q - a["q_rest"]) - jnp.stack([0.0, a["g"]])
    return jnp.concatenate([v, acc])


def scenes():
    friction = nj.Friction([2], lambda t, x, a: a["mu"] * a["g"])
    contact = nj.Contact(lambda t, x, a: x[1:2], positions=[1], velocities=[3], restitution=0.5)
    return {
        "no effect": nj.Scene(dynamics, 4, ()),
        "friction": nj.Scene(dynamics, 4, (friction,)),
        "friction + contact": nj.Scene(dynamics, 4, (friction, contact)),
    }


ARGS = {
    "k": jnp.asarray(40.0),
    "q_rest": jnp.asarray([0.0, 0.2]),
    "g": jnp.asarray(9.81),
    "mu": jnp.asarray(0.3),
}
X0 = jnp.array([0.5, 1.0, 0.0, 0.0])


def hlo_size(fn, *args):
    text = jax.jit(fn).lower(*args).compile().as_text()
    return sum(1 for line in text.splitlines() if " = " in line)


def main():
    rows = []
    for name, scene in scenes().items():

        def run(x0, args, scene=scene):
            sol = scene.solve(
                0.0,
                STEPS * H,
                x0,
                args,
                stepper=nj.Bathe(),
                controller=nj.ConstantStepSize(),
                h0=H,
                max_steps=STEPS + 1,
            )
            return sol.y_final, sol.n_accepted, sol.n_iterations

        run = eqx.filter_jit(run)
        t_first, _ = time_once(run, X0, ARGS)
        t_run, (y, n, iters) = median_time(run, X0, ARGS, repeats=5)
        rows.append((name, t_first - t_run, t_run, int(n), int(iters), hlo_size(run, X0, ARGS)))
    base = rows[0][2] / rows[0][3]
    print(f"fixed step h = {H}, {STEPS} steps, Bathe + semismooth Newton, float64\n")
    print("| scene | compile s | run ms | us / step | vs no effect | Newton it / step | HLO ops |")
    print("|---|---|---|---|---|---|---|")
    for name, tc, tr, n, it, ops in rows:
        per = tr / n
        print(
            f"| {name} | {tc:.2f} | {1e3 * tr:.2f} | {1e6 * per:.2f} | {per / base:.2f}x | "
            f"{it / n:.2f} | {ops} |"
        )


if __name__ == "__main__":
    main()
