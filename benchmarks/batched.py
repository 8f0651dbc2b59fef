"""Batched parameter sweeps on CPU: `jax.vmap` of a whole adaptive nivpjax solve.

For each batch size N the sweep compiles `jax.jit(jax.vmap(solve_one))` over N parameter
values (drawn uniformly at random, fixed seed, nested: the first N of one draw) and
reports the batch run time (median of repeats after compilation), trajectories/s,
accepted step-trajectories/s (accepted steps summed over members per second), compile
time, memory and the final position error of the worst member against the exact solution
(the position, not the whole state: the velocity jumps at impacts and friction switches,
and a member with an event within the tolerance of `t1` would report the jump).

Memory: "XLA buffers" = argument + output + temporary bytes of the compiled executable
(`Compiled.memory_analysis()`, what XLA allocates for one call); "RSS high-water growth"
= growth of the process's `ru_maxrss` during compile + runs of that size (0 when the
process had already been that large).

Waste: under `vmap` the loop runs until the slowest member is done, every member doing an
(masked) attempt per iteration. waste = sum over members of (max attempts - own attempts)
/ (N x max attempts), attempts = accepted + rejected steps. Mitigation measured: the largest
batch split into chunks of 100 (one compiled executable), in random order vs sorted by the
parameter (members with similar parameters need similar step counts).

The reference package runs the same model in a Python loop over a few parameter values;
its per-trajectory time is multiplied by N (extrapolated, labelled as such).
"""

import resource
import time

import jax
import jax.numpy as jnp
import numpy as np

import nivpjax as nj

from . import reference_models
from ._common import TimeLimit, block, median_time, time_limit
from .cases import CASES


CHUNK = 100
REF_LIMIT = 120.0  # seconds per reference run in the loop

SWEEPS = {
    "ball": dict(
        case="ball",
        param="restitution e",
        lo=0.8,
        hi=0.95,
        rtol=1e-3,
        max_steps=1024,
        set_args=lambda args, p: dict(args, e=p),
        set_ref=lambda p0, p: dict(p0, e=p),
    ),
    "slider": dict(
        case="slider",
        param="friction mu",
        lo=0.1,
        hi=0.3,
        rtol=1e-3,
        max_steps=1024,
        set_args=lambda args, p: dict(args, mu_s=p, mu_k=p),
        set_ref=lambda p0, p: dict(p0, mu_s=p, mu_k=p),
    ),
}


def settings(quick, sizes=None, scenes=None):
    if quick:
        cfg = dict(scenes=("ball",), sizes=(1, 10, 100, 1000), ref_subset=2, chunk_repeats=2)
    else:
        cfg = dict(
            scenes=("ball", "slider"),
            sizes=(1, 10, 100, 1000, 10000),
            ref_subset=5,
            chunk_repeats=3,
        )
    if sizes:
        if any(n < 1 for n in sizes):
            raise ValueError(f"batch sizes must be positive, got {sizes}")
        cfg["sizes"] = tuple(sorted(set(sizes)))
    if scenes:
        cfg["scenes"] = tuple(scenes)
    return cfg


def _maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _batched_solver(sweep, case):
    scene, x0, args = case.make()

    def one(p):
        controller = nj.PIDController(rtol=sweep["rtol"], atol=sweep["rtol"] * 1e-3)
        sol = scene.solve(
            0.0,
            case.t1,
            x0,
            sweep["set_args"](args, p),
            stepper=nj.Bathe(),
            controller=controller,
            max_steps=sweep["max_steps"],
            saveat=nj.SaveAt(),  # the final state only: no step buffers per member
            throw=False,
        )
        x, _ = scene.split(sol.y_final)
        return x, sol.n_accepted, sol.n_rejected, sol.result._value

    return jax.vmap(one)


def _exact_final(case, sweep, params):
    base = case.build()[2]
    out = []
    for p in params:
        # The exact solution of the case with the parameter changed.
        ref_case = _with_params(case, sweep["set_ref"](base, float(p)))
        out.append(ref_case.exact(np.array([case.t1]))[0])
    return np.array(out)


def _with_params(case, params):
    from dataclasses import replace

    scene, x0, _ = case.make()
    return replace(case, make=lambda: (scene, x0, {k: jnp.asarray(v) for k, v in params.items()}))


def _waste(attempts):
    attempts = np.asarray(attempts)
    top = attempts.max()
    return float(np.sum(top - attempts) / (attempts.size * top)) if top > 0 else 0.0


def run_sweep(name, cfg, log):
    sweep = SWEEPS[name]
    case = CASES[sweep["case"]]
    batched = _batched_solver(sweep, case)
    rng = np.random.default_rng(0)
    all_params = rng.uniform(sweep["lo"], sweep["hi"], max(cfg["sizes"]))
    log(f"[batched {name}] vmap over {sweep['param']} in [{sweep['lo']}, {sweep['hi']}]")
    rows = []
    compiled_by_size = {}
    for n in cfg["sizes"]:
        params = jnp.asarray(all_params[:n])
        rss0 = _maxrss_mb()
        t0 = time.perf_counter()
        compiled = jax.jit(batched, compiler_options=nj.compiler_options()).lower(params).compile()
        compile_s = time.perf_counter() - t0
        mem = compiled.memory_analysis()
        xla_mb = (
            mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes
        ) / 1e6
        t0 = time.perf_counter()
        out = block(compiled(params))
        once = time.perf_counter() - t0
        repeats = 3 if once < 2.0 else 1
        t_run, out = (once, out) if repeats == 1 else median_time(compiled, params, repeats=3)
        rss_growth = _maxrss_mb() - rss0
        compiled_by_size[n] = compiled
        x, acc, rej, result = (np.asarray(o) for o in out)
        exact = _exact_final(case, sweep, all_params[:n])
        errs = np.abs(x[:, 0] - exact[:, 0])  # position (see the module docstring)
        err = float(np.max(errs))
        failed = int(np.sum(result != nj.RESULTS.successful._value))
        rows.append(
            dict(
                scene=name,
                n=n,
                compile=compile_s,
                time=t_run,
                per_traj=t_run / n,
                traj_per_s=n / t_run,
                steps_per_s=float(np.sum(acc)) / t_run,
                accepted_mean=float(np.mean(acc)),
                attempts_max=int(np.max(acc + rej)),
                waste=_waste(acc + rej),
                xla_mb=xla_mb,
                rss_growth_mb=rss_growth,
                max_error=err,
                median_error=float(np.median(errs)),
                failed=failed,
            )
        )
        log(
            f"  N={n}: compile {compile_s:.1f} s, run {t_run:.3f} s, "
            f"{n / t_run:.0f} traj/s, waste {rows[-1]['waste']:.0%}, "
            f"final error median {np.median(errs):.1e} / max {err:.1e}"
        )

    # Mitigation on the largest batch: chunks of CHUNK, random order vs sorted by parameter.
    n_big = max(cfg["sizes"])
    mitigation = []
    if CHUNK in compiled_by_size and n_big > CHUNK:
        exe = compiled_by_size[CHUNK]
        big = next(r for r in rows if r["n"] == n_big)
        mitigation.append(
            dict(
                scene=name,
                strategy=f"one batch of {n_big}",
                time=big["time"],
                waste=big["waste"],
            )
        )
        for label, order in (
            (f"{n_big // CHUNK} chunks of {CHUNK}, random order", np.arange(n_big)),
            (f"{n_big // CHUNK} chunks of {CHUNK}, sorted by parameter", np.argsort(all_params)),
        ):
            chunks = [jnp.asarray(all_params[order[i : i + CHUNK]]) for i in range(0, n_big, CHUNK)]
            run_all = lambda chunks=chunks: [block(exe(c)) for c in chunks]
            t_run, outs = median_time(run_all, repeats=cfg["chunk_repeats"])
            idle = sum(
                np.sum(np.max(np.asarray(o[1] + o[2])) - np.asarray(o[1] + o[2])) for o in outs
            )
            total = sum(np.asarray(o[1]).size * np.max(np.asarray(o[1] + o[2])) for o in outs)
            mitigation.append(
                dict(scene=name, strategy=label, time=t_run, waste=float(idle / total))
            )
            log(f"  {label}: {t_run:.3f} s, waste {mitigation[-1]['waste']:.0%}")

    # The reference in a Python loop over a few parameter values.
    base = case.build()[2]
    _, x0, _ = case.build()
    subset = all_params[: cfg["ref_subset"]]
    times, errs, timeouts = [], [], 0
    exact = _exact_final(case, sweep, subset)
    for p, ex in zip(subset, exact):
        kw, to_x, label = reference_models.BUILDERS[case.name](
            sweep["set_ref"](base, float(p)), x0, case.t1, sweep["rtol"], sweep["rtol"] * 1e-3
        )
        t0 = time.perf_counter()
        try:
            with time_limit(REF_LIMIT):
                t, y, *_ = reference_models.run(kw)
        except TimeLimit:
            # Counted at the limit: a lower bound on its time.
            times.append(REF_LIMIT)
            errs.append(np.inf)
            timeouts += 1
            continue
        times.append(time.perf_counter() - t0)
        done = t[-1] >= case.t1 - 1e-9
        errs.append(float(abs(to_x(y)[-1][0] - ex[0])) if done else np.inf)
    ref = dict(
        scene=name,
        label=label,
        n=len(subset),
        per_traj=float(np.mean(times)),
        max_error=float(np.max(errs)),
        rtol=sweep["rtol"],
        timeouts=timeouts,
    )
    log(f"  reference loop over {len(subset)} values: {ref['per_traj']:.2f} s per trajectory")
    return dict(sweep=sweep, rows=rows, mitigation=mitigation, reference=ref)
