"""Linear algebra of large stages: a driven spring-block (Burridge-Knopoff) chain with
slip-weakening friction on every block, solved through the Scene API with the default
stepper (Bathe) and controller (PID, rtol 1e-3), dense against matrix-free semismooth Newton.

Reports, per chain length N (2N states): attempts, wall time per attempt, Newton
iterations per attempt and Krylov iterations per Newton iteration, and the exponent of the
cost per attempt in N (a least-squares slope of log cost against log N).

Run:  python -m benchmarks.large_linalg [--sizes 40 100 200 400 1000] [--steps 300]

The trajectory is capped at `--steps` attempts (throw=False), so large chains finish in
minutes; the cost per attempt is wall time over attempts, compile excluded (the solve is
timed a second time, after a first call that compiled it).
"""

import argparse
import os
import time


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import nivpjax as nj  # noqa: E402

from . import _common  # noqa: E402, F401  (float64)


def chain(n, seed=0):
    r"""A driven chain of `n` blocks, positions $u$ and velocities $v$ (state $(u, v)$):

    $$ u_i'' = k_c (u_{i+1} - 2u_i + u_{i-1}) + k_p (V t + u^0_i - u_i)
       - \mu(u_i - u^0_i) N \operatorname{Sign}(u_i'), $$

    free ends, $\mu(s) = \mu_k + (\mu_s - \mu_k) e^{-|s|/D_c}$ from 0.6 to 0.5. The
    initial prestress $u^0$ is random (seeded), so blocks start slipping at different
    times and events run along the chain.
    """

    def dynamics(t, x, a, m):
        u, v = x[:n], x[n:]
        left = jnp.concatenate([u[:1], u[:-1]])
        right = jnp.concatenate([u[1:], u[-1:]])
        force = a["kc"] * (left - 2 * u + right) + a["kp"] * (a["V"] * t + a["u0"] - u)
        return jnp.concatenate([v, force])

    def bound(t, x, a):
        slip = jnp.abs(x[:n] - a["u0"])
        return (a["mu_k"] + (a["mu_s"] - a["mu_k"]) * jnp.exp(-slip / a["Dc"])) * a["N"]

    scene = nj.Scene(dynamics, 2 * n, (nj.Friction(velocities=np.arange(n, 2 * n), bound=bound),))
    rng = np.random.default_rng(seed)
    u0 = jnp.asarray(0.4 * rng.random(n))
    args = dict(
        kc=jnp.asarray(4.0),
        kp=jnp.asarray(1.0),
        V=jnp.asarray(0.1),
        u0=u0,
        mu_s=jnp.asarray(0.6),
        mu_k=jnp.asarray(0.5),
        Dc=jnp.asarray(0.05),
        N=jnp.asarray(1.0),
    )
    return scene, jnp.zeros(2 * n), args


def run(n, solver, steps, t1=20.0):
    """`(seconds per attempt, attempts, iterations per attempt, solution)` of the chain of
    `n` blocks with Bathe's scheme, the default controller and the nonlinear `solver`,
    capped at `steps` attempts."""
    scene, x0, args = chain(n)
    stepper = nj.Bathe(solver=solver)

    def go():
        # nj.solve compiles and caches its own program (no outer jit).
        return scene.solve(0.0, t1, x0, args, stepper=stepper, max_steps=steps, throw=False)

    jax.block_until_ready(go())
    walls = []
    for _ in range(2):
        t = time.perf_counter()
        sol = jax.block_until_ready(go())
        walls.append(time.perf_counter() - t)
    attempts = int(sol.n_accepted + sol.n_rejected)
    return min(walls) / attempts, attempts, float(sol.n_iterations) / attempts, sol


def stage_iterations(n, solver, sol, samples=16):
    """Mean Newton iterations and Krylov iterations per Newton iteration of backward
    Euler stages of the chain taken from `samples` accepted steps of `sol` (the same
    states and step sizes; the stages of Bathe's scheme are of this kind)."""
    _, _, args = chain(n)
    scene = chain(n)[0]
    k = int(sol.n_accepted)
    picks = np.linspace(1, k - 1, samples).astype(int)

    @jax.jit
    def one(t0, y0, h):
        def residual(y):
            return (y - y0) / h - scene.vector_field(t0 + h, y, args)

        def project(z, y, rho):
            ctx = nj.ProjectionContext(t=t0 + h, h=h, y_prev=y0, y_iter=y, rho=rho, args=args)
            return scene.projector(z, ctx)

        out = solver.solve(residual, project, h, y0)
        return out.iterations, out.linear_iterations

    newton = krylov = 0
    for i in picks:
        its, lin = one(sol.ts[i - 1], sol.ys[i - 1], sol.hs[i])
        newton, krylov = newton + int(its), krylov + int(lin)
    return newton / samples, krylov / max(newton, 1)


def _block_jacobi(n):
    # Cells (u_i, v_i), coupled to their neighbours only: colours i mod 3.
    cells = np.stack([np.arange(n), np.arange(n, 2 * n)], axis=1)
    return nj.Krylov(preconditioner=nj.BlockJacobi(cells, np.arange(n) % 3))


SOLVERS = {
    "dense": lambda n: nj.SemismoothNewton(linear_solver=nj.DenseLU()),
    "gmres": lambda n: nj.SemismoothNewton(linear_solver=nj.Krylov()),
    "gmres-warm": lambda n: nj.SemismoothNewton(linear_solver=nj.Krylov(warm_start=True)),
    "gmres-5": lambda n: nj.SemismoothNewton(linear_solver=nj.Krylov(restart=5, max_steps=40)),
    "gmres-bj": lambda n: nj.SemismoothNewton(linear_solver=_block_jacobi(n)),
    "bicgstab": lambda n: nj.SemismoothNewton(
        linear_solver=nj.Krylov(method="bicgstab", max_steps=100)
    ),
    # the VI method: no linear solves (its derivatives would use the default linear solver)
    "vi": lambda n: nj.FixedPointVI(),
}


def full(n, names, t1=20.0, max_steps=100_000):
    """Whole trajectories of the chain of `n` blocks to `t1` with each solver: wall time
    (compile excluded), attempts, and the largest difference of the final state from the
    first solver's."""
    scene, x0, args = chain(n)
    first = None
    for name in names:
        stepper = nj.Bathe(solver=SOLVERS[name](n))
        # The final state only: buffers of every step would be max_steps x 2n.
        go = lambda: scene.solve(
            0.0, t1, x0, args, stepper=stepper, max_steps=max_steps, throw=False, saveat=nj.SaveAt()
        )
        t = time.perf_counter()
        jax.block_until_ready(go())
        compile_and_run = time.perf_counter() - t
        t = time.perf_counter()
        sol = jax.block_until_ready(go())
        wall = time.perf_counter() - t
        first = sol.y_final if first is None else first
        attempts = int(sol.n_accepted + sol.n_rejected)
        print(
            f"full N={n} {name:>9}: {wall:.2f} s ({compile_and_run:.2f} s with compile), "
            f"{attempts} attempts, {1e3 * wall / attempts:.3f} ms each, result {sol.result}, "
            f"|y - y_first| = {float(jnp.max(jnp.abs(sol.y_final - first))):.2e}",
            flush=True,
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[40, 100, 200, 400, 1000])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--dense-max", type=int, default=400, help="largest N solved densely")
    parser.add_argument("--solvers", nargs="+", default=["dense", "gmres"], choices=SOLVERS)
    parser.add_argument("--full", type=int, nargs="*", default=[], help="whole trajectories")
    ns = parser.parse_args()
    for n in ns.full:
        full(n, ns.solvers)
    if ns.full:
        return
    print(
        f"{'N':>6} {'states':>6} {'solver':>9} {'attempts':>8} {'ms/attempt':>10} "
        f"{'iters/att':>10} {'iters/stage':>12} {'krylov/newton':>13} {'t reached':>9}"
    )
    costs = {name: [] for name in ns.solvers}
    for n in ns.sizes:
        for name in ns.solvers:
            if name == "dense" and n > ns.dense_max:
                continue
            solver = SOLVERS[name](n)
            per, attempts, newton, sol = run(n, solver, ns.steps)
            stage_newton, krylov = stage_iterations(n, solver, sol)
            costs[name].append((n, per))
            print(
                f"{n:6d} {2 * n:6d} {name:>9} {attempts:8d} {1e3 * per:10.3f} {newton:10.2f} "
                f"{stage_newton:12.2f} {krylov:13.1f} {float(sol.t_final):9.4f}",
                flush=True,
            )
    for name, c in costs.items():
        if len(c) > 1:
            x, y = np.log([n for n, _ in c]), np.log([p for _, p in c])
            print(f"{name}: cost per attempt ~ N^{np.polyfit(x, y, 1)[0]:.2f}")


if __name__ == "__main__":
    main()
