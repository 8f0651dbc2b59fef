"""`solve_batched`: per-member results equal single solves, in the original order, with
result codes per member; sharded across host devices equals unsharded (in a subprocess,
since the device count is fixed when JAX starts)."""

import os
import socket
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj


def decay(t, y, args):
    return -args["k"] * y


KS = np.array([3.0, 0.5, 8.0, 1.0, 2.0])
Y0 = np.array([1.0, 0.5])
KW = dict(stepper=nj.BackwardEuler(), max_steps=40)


def test_members_match_single_solves_in_original_order():
    sol = nj.solve_batched(decay, 0.0, 1.0, Y0, {"k": KS}, cost=KS, chunk_size=2, **KW)
    assert sol.y_final.shape == (5, 2)
    codes = np.asarray(sol.result._value)
    for i, k in enumerate(KS):
        single = nj.solve(decay, 0.0, 1.0, jnp.asarray(Y0), {"k": k}, throw=False, **KW)
        assert codes[i] == int(single.result._value)
        assert int(sol.n_accepted[i]) == int(single.n_accepted)
        np.testing.assert_allclose(sol.y_final[i], single.y_final, rtol=1e-12, atol=1e-14)
    # per-member codes: the stiffest members run out of steps, the others finish
    ok = codes == int(nj.RESULTS.successful._value)
    assert ok[1] and ok[3] and not ok[2]
    np.testing.assert_allclose(sol.y_final[1], np.exp(-0.5) * Y0, rtol=5e-2)
    waste_sorted = nj.lockstep_waste(sol, chunk_size=2, cost=KS)
    waste_plain = nj.lockstep_waste(sol)
    assert 0.0 <= waste_sorted < waste_plain


def test_throw_names_failed_members():
    with pytest.raises(nj.SolveError, match="members failed"):
        nj.solve_batched(decay, 0.0, 1.0, Y0, {"k": KS}, throw=True, **KW)


def test_bad_batch_sizes_raise():
    with pytest.raises(ValueError, match="batch size"):
        nj.solve_batched(decay, 0.0, 1.0, np.ones((3, 2)), {"k": KS}, **KW)


_SCRIPT = textwrap.dedent(
    """
    import re, sys
    import jax, numpy as np
    mode, path = sys.argv[1], sys.argv[2]
    if mode == "distributed":  # two processes of two devices each, on this host
        port, pid = sys.argv[3], int(sys.argv[4])
        jax.distributed.initialize(
            f"127.0.0.1:{port}", num_processes=2, process_id=pid, initialization_timeout=60
        )
    jax.config.update("jax_enable_x64", True)
    import nivpjax as nj
    from nivpjax import _batched
    calls = []  # the compiled batch programs' calls, to read their HLO
    _run = _batched._batched_jit._run
    _batched._batched_jit._run = lambda call: calls.append(call) or _run(call)
    def decay(t, y, args):
        return -args["k"] * y
    ks = np.linspace(0.5, 4.0, 10)
    kw = dict(stepper=nj.BackwardEuler(), max_steps=128, cost=-ks, chunk_size=8)
    kw["t_eval"] = np.linspace(0.0, 1.0, 5)
    if mode != "distributed":  # every step too (the distributed run: the default SaveAt())
        kw["saveat"] = nj.SaveAt(steps=True)
    y0 = np.array([1.0, 0.5])
    sol = nj.solve_batched(decay, 0.0, 1.0, y0, {"k": ks}, **kw)
    assert np.all(np.asarray(sol.result._value) == 0)
    if mode == "sharded":  # against single solves of a few members
        for i in (0, 4, 9):
            one = nj.solve(decay, 0.0, 1.0, y0, {"k": ks[i]}, stepper=nj.BackwardEuler(),
                           max_steps=128)
            assert int(sol.n_accepted[i]) == int(one.n_accepted), i
            np.testing.assert_allclose(sol.y_final[i], one.y_final, rtol=1e-13)
        # Each device runs its own loop: no collective in the program (one loop for the
        # whole batch needs an all-reduce per iteration for its stopping test).
        program = _batched._batched_jit._program(calls[0].key, False)
        hlo = program.lower(calls[0].dynamic).compile().as_text()
        assert not re.search("all-reduce|all-gather|collective-permute|all-to-all", hlo)
    leaves = jax.tree_util.tree_flatten_with_path(sol)[0]
    out = {jax.tree_util.keystr(k): np.asarray(x) for k, x in leaves}
    out["devices"] = np.array([len(jax.devices()), jax.process_count()])
    if jax.process_index() == 0:
        np.savez(path, **out)
    """
)


def _env(n_devices):
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n_devices}"
    env["JAX_PLATFORMS"] = "cpu"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _run(n_devices, mode, path):
    cmd = [sys.executable, "-c", _SCRIPT, mode, str(path)]
    out = subprocess.run(cmd, env=_env(n_devices), capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return np.load(path)


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    return _run(1, "single", tmp_path_factory.mktemp("batched") / "single.npz")


# Times, states, steps, counts and codes are bitwise identical. The stage residuals at the
# solution (multipliers and residual norms, here pure round-off ~1e-15) and the states at
# t_eval may differ in the last bits: XLA vectorises 2 members per device differently from
# 8, and fills t_eval in the loop without saved steps.
_ROUNDOFF = {".multipliers", ".residual_norms", ".y_eval"}


def _compare(run, single, names):
    differ = [n for n in names if not np.array_equal(run[n], single[n])]
    assert set(differ) <= _ROUNDOFF, differ
    for name in _ROUNDOFF & set(names):
        np.testing.assert_allclose(run[name], single[name], rtol=0, atol=1e-13)


def test_sharded_equals_unsharded(single, tmp_path):
    # Another process: the device count is fixed when JAX starts. Each of the 4 devices
    # runs the loop of its own share (shard_map); the process also checks a few members
    # against single solves.
    sharded = _run(4, "sharded", tmp_path / "sharded.npz")
    assert sharded["devices"].tolist() == [4, 1]
    names = [n for n in single.files if n != "devices"]
    assert set(sharded.files) == set(single.files) and len(names) > 10
    _compare(sharded, single, names)


def test_two_processes_equal_one(single, tmp_path):
    # `jax.distributed` on localhost: two processes of two devices each, every process
    # building its own devices' shards and receiving the whole result. Final-state-only
    # saving (the default): the states at t_eval filled in the loop.
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    path = tmp_path / "distributed.npz"
    cmd = [sys.executable, "-c", _SCRIPT, "distributed", str(path), str(port)]
    procs = [
        subprocess.Popen(
            cmd + [str(pid)],
            env=_env(2),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        for pid in (0, 1)
    ]
    try:
        errors = [p.communicate(timeout=300)[1] for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert all(p.returncode == 0 for p in procs), [e[-2000:] for e in errors]
    run = np.load(path)
    assert run["devices"].tolist() == [4, 2]
    names = [n for n in run.files if n != "devices"]
    assert {".y_final", ".y_eval", ".n_accepted", ".result._value"} <= set(names)
    assert ".ys" not in names  # no steps saved
    _compare(run, single, names)
