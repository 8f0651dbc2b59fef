"""Loop iterations per device of a sharded sweep: one loop per device's share
(`nj.solve_batched`, `jax.shard_map`) against one loop for the whole batch with its
inputs and outputs sharded (`with_sharding_constraint` under one `jit`, what
`solve_batched` did before).

Three variants: the two programs built here alike (the same vmapped solve, inputs placed
on the devices beforehand), and `Scene.sweep` (`solve_batched`) end to end, with its
host-side work (ordering, placing the inputs, the structural cache lookup).

The batch: bouncing balls over [0, T1] with restitutions from 0.05 to 0.95, whose step
counts differ several-fold (a low restitution comes to rest in a few bounces, a high one
bounces to the end). Members in increasing restitution (as `cost=` sorts them), so each
device holds a contiguous range, and shuffled.

Under `jax.vmap` a while loop runs until its last member is done, so a loop's iteration
count is the largest attempt count (`n_accepted + n_rejected`) among the members it
carries: with one loop for the batch, every device runs the batch's largest; with one loop
per share, each device its share's largest. Wall times are the fastest of repeated runs on
forced host devices (`XLA_FLAGS=--xla_force_host_platform_device_count=4`) of this shared
CPU machine: the devices share its cores, so the time tracks the total work.

Run:  python -m benchmarks.sweep_devices [--devices 4] [--n 64] [--repeats 3]

Each variant runs in its own process (the device count is fixed when JAX starts, and a
second program around the same solve in one process can fail in jax 0.10.2).
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np


T1 = 3.0
MAX_STEPS = 2048


def _members(n, order):
    es = np.linspace(0.05, 0.95, n)
    if order == "shuffled":
        es = np.random.default_rng(0).permutation(es)
    return es


def _variant(name, n, order, repeats):
    import jax
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    import nivpjax as nj
    from nivpjax import _solve

    from ._common import block, median_time  # float64

    scene, x0, args = nj.scenes.bouncing_ball()
    es = _members(n, order)
    axes = {**{k: None for k in args}, "e": 0}
    kw = dict(max_steps=MAX_STEPS)
    mesh = Mesh(np.asarray(jax.devices()), ("batch",))
    batch = NamedSharding(mesh, PartitionSpec("batch"))

    def one(e):
        return scene.solve(0.0, T1, x0, {**args, "e": e}, saveat=nj.SaveAt(), throw=False, **kw)

    def members(e):
        token = _solve._IN_GRAPH_CHECKS.set(False)  # as solve_batched does
        try:
            return jax.vmap(one)(e)
        finally:
            _solve._IN_GRAPH_CHECKS.reset(token)

    if name == "solve_batched":  # the entry point, with its host-side work

        def run():
            return scene.sweep(0.0, T1, x0, {**args, "e": es}, args_axes=axes, **kw)

    else:
        if name == "shard_map":  # one loop per device's share, as solve_batched runs it
            spec = PartitionSpec("batch")
            whole = jax.shard_map(
                members, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False
            )
        else:  # one loop for the whole batch, sharded through its inputs and outputs

            def whole(e):
                sol = members(e)
                return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, batch), sol)

        f = jax.jit(whole)
        e_sharded = jax.device_put(es, batch)

        def run():
            return f(e_sharded)

    start = time.perf_counter()
    block(run())
    first = time.perf_counter() - start
    # The fastest of the repeats: on a shared machine the other jobs only add time.
    dt = min(median_time(run, repeats=1)[0] for _ in range(repeats))
    sol = run()
    attempts = np.asarray(sol.n_accepted) + np.asarray(sol.n_rejected)
    return dict(
        run=dt,
        compile=first - dt,
        attempts=attempts.tolist(),
        y_final=np.asarray(sol.y_final).tolist(),
        ok=bool(np.all(np.asarray(sol.result._value) == 0)),
        devices=len(jax.devices()),
    )


def _spawn(name, devices, n, order, repeats):
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["JAX_PLATFORMS"] = "cpu"
    cmd = [sys.executable, "-m", "benchmarks.sweep_devices", "--variant", name]
    cmd += ["--n", str(n), "--order", order, "--repeats", str(repeats)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--devices", type=int, default=4)
    p.add_argument("--n", type=int, default=64)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--variant", default=None)
    p.add_argument("--order", default="sorted")
    a = p.parse_args()
    if a.variant is not None:
        print(json.dumps(_variant(a.variant, a.n, a.order, a.repeats)))
        return
    print(f"bouncing ball, t1 = {T1}, N = {a.n}, {a.devices} forced host devices")
    print("| order | variant | loop iterations per device | sum | run s | run / before |")
    print("|---|---|---|---|---|---|")
    for order in ("sorted", "shuffled"):
        variants = ("constraint", "shard_map", "solve_batched")
        res = {v: _spawn(v, a.devices, a.n, order, a.repeats) for v in variants}
        same = np.array_equal(res["constraint"]["y_final"], res["shard_map"]["y_final"])
        for v, r in res.items():
            att = np.asarray(r["attempts"])
            shares = np.array_split(att, a.devices)
            if v == "constraint":
                per = [int(att.max())] * a.devices
            else:
                per = [int(s.max()) for s in shares]
            ratio = r["run"] / res["constraint"]["run"]
            label = {
                "constraint": "one loop, sharded (before)",
                "shard_map": "shard_map, loop per device",
                "solve_batched": "solve_batched (shard_map, with its host-side work)",
            }[v]
            print(f"| {order} | {label} | {per} | {sum(per)} | {r['run']:.3f} | {ratio:.2f} |")
        att = np.asarray(res["shard_map"]["attempts"])
        print(
            f"| {order} | attempts per member: min {att.min()}, max {att.max()}; "
            f"same final states: {same}; all succeeded: "
            f"{res['constraint']['ok'] and res['shard_map']['ok']} | | | | |"
        )


if __name__ == "__main__":
    main()
