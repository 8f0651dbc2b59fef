"""What a `jax.vmap` sweep pays for what it keeps: `jax.jit(jax.vmap(lambda e:
scene.solve(...)))` over N restitution values of the bouncing ball, returning

- `full Solution`: the default `SaveAt(steps=True)`, every member with buffers of
  `max_steps + 1` rows (what a sweep paid before `SaveAt`);
- `y_final + counts`: the same solve, only the final state and step counts returned (XLA
  drops the unused outputs, but the loop still carries the buffers);
- `SaveAt()`: the whole `Solution` of a final-state-only solve (no step buffers in the
  loop);
- `SaveAt(ts=...)`: the whole `Solution` with the states at 16 output times, filled in the
  loop.

Run:  python -m benchmarks.sweep_saveat [--n 10000] [--repeats 3]

Each row runs in its own process (started one after another by this one): a second
`jax.jit` of another function around the same solve in one process failed on its second
call in jax 0.10.2 ("Execution supplied 1 arguments but compiled program expected 7").
Each row: compile time (first call minus a run) and the median run time; ratios are
against the first row of the same run (machine load affects all rows alike).
"""

import argparse
import json
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import nivpjax as nj

from ._common import block, median_time


def _cases(scene, x0, args, t1, kw, t_eval):
    def solve(e, **more):
        return scene.solve(0.0, t1, x0, {**args, "e": e}, throw=False, **kw, **more)

    return {
        "full Solution": lambda e: solve(e),
        "y_final + counts": lambda e: (lambda s: (s.y_final, s.n_accepted, s.result))(solve(e)),
        "SaveAt()": lambda e: solve(e, saveat=nj.SaveAt()),
        "SaveAt(ts=16 times)": lambda e: solve(e, saveat=nj.SaveAt(ts=t_eval)),
    }


T1, MAX_STEPS = 1.5, 4096


def one_case(name, n, repeats):
    """Compile and time one row; its numbers as a dict (the final states as a list)."""
    scene, x0, args = nj.scenes.bouncing_ball()
    t_eval = jnp.linspace(0.0, T1, 16)
    fn = _cases(scene, x0, args, T1, dict(max_steps=MAX_STEPS), t_eval)[name]
    es = jnp.asarray(np.linspace(0.5, 0.95, n))
    f = jax.jit(jax.vmap(fn))
    start = time.perf_counter()
    out = block(f(es))
    first = time.perf_counter() - start
    dt, out = median_time(f, es, repeats=repeats)
    y_final = out[0] if isinstance(out, tuple) else out.y_final
    out_bytes = sum(x.nbytes for x in jax.tree.leaves(out))
    return dict(compile=first - dt, run=dt, bytes=out_bytes, y_final=np.asarray(y_final).tolist())


def run(n=10_000, repeats=3):
    names = list(_cases(None, None, None, T1, {}, None))
    rows, finals = [], {}
    for name in names:
        cmd = [sys.executable, "-m", "benchmarks.sweep_saveat", "--case", name]
        cmd += ["--n", str(n), "--repeats", str(repeats)]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        finals[name] = np.asarray(r["y_final"])
        rows.append((name, r["compile"], r["run"], r["bytes"]))
    base = rows[0][2]
    t1, max_steps = T1, MAX_STEPS
    print(f"bouncing ball, t1 = {t1}, max_steps = {max_steps}, N = {n} restitutions")
    print("| returned | compile s | run s | run / full | output MB |")
    print("|---|---|---|---|---|")
    for name, comp, dt, nbytes in rows:
        print(f"| {name} | {comp:.2f} | {dt:.3f} | {dt / base:.2f} | {nbytes / 1e6:.1f} |")
    ref = finals["full Solution"]
    same = all(np.array_equal(ref, y) for y in finals.values())
    print(f"y_final identical in every row: {same}")
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--case", default=None, help="run one row (used by the parent run)")
    a = parser.parse_args()
    if a.case is None:
        run(a.n, a.repeats)
    else:
        print(json.dumps(one_case(a.case, a.n, a.repeats)))


if __name__ == "__main__":
    main()
