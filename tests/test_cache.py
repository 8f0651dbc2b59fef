"""The compile cache at the solve boundary: run-time tolerances, closures of the same code
with new constants, changed structures, and the fallback for closures that need concrete
constants. Compilations are counted with JAX's own backend-compile event."""

import contextlib
import gc
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj
from nivpjax._solve import _solve_jit


_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
_compiles = [0]


def _listener(event, duration, **kwargs):
    if event == _COMPILE_EVENT:
        _compiles[0] += 1


jax.monitoring.register_event_duration_secs_listener(_listener)


@contextlib.contextmanager
def count_compiles():
    """Counts XLA compilations and traces of the solve program inside the block."""
    out = {}
    c0, t0 = _compiles[0], _solve_jit.cache_info().traces
    yield out
    out["xla"] = _compiles[0] - c0
    out["traces"] = _solve_jit.cache_info().traces - t0


def decay(k):
    def f(t, y, args):
        return -k * y

    return f


def growth(k):  # the same maths, other code: another structure
    def f(t, y, args):
        return k * y

    return f


Y0 = jnp.array([1.0, 0.5])


def _solve(f, max_steps=256, **kw):
    return nj.solve(f, 0.0, 1.0, Y0, stepper=nj.BackwardEuler(), max_steps=max_steps, **kw)


def test_new_closure_same_structure_compiles_nothing():
    sol1 = _solve(decay(1.0))  # may compile: first use of this structure
    # May compile too: the eager conversion of an array constant, once per process (JAX's
    # own cache of it is emptied where conftest clears the caches before this module:
    # measured 1 XLA compile, no trace, in a long CI worker).
    _solve(decay(jnp.asarray(0.5)))
    with count_compiles() as n:
        sol2 = _solve(decay(2.0))
        sol3 = _solve(decay(jnp.asarray(3.0)))  # a weakly typed array like the float
    assert n == {"xla": 0, "traces": 0}
    # Backward Euler under per-step error control at the default rtol 1e-3 has a global
    # error of order sqrt(rtol) * k: measured 2.0% (k = 1) and 6.2% (k = 3). The three
    # answers differ by factors of e, so 10% still tells a stale constant from the right one.
    for sol, k in ((sol1, 1.0), (sol2, 2.0), (sol3, 3.0)):
        np.testing.assert_allclose(sol.y_final, np.exp(-k) * np.asarray(Y0), rtol=0.1)


RATE = 1.0


def test_changed_global_is_not_served_a_stale_program():
    """A function that reads a module-level constant: after the constant changes, a new
    function object of the same code must not reuse the program traced with the old value
    (`jax.jit` would retrace a new function object too)."""
    global RATE
    try:
        RATE = 1.0
        sol1 = _solve(lambda t, y, args: -RATE * y)
        RATE = 3.0
        sol3 = _solve(lambda t, y, args: -RATE * y)
    finally:
        RATE = 1.0
    np.testing.assert_allclose(sol1.y_final, np.exp(-1.0) * np.asarray(Y0), rtol=0.1)
    np.testing.assert_allclose(sol3.y_final, np.exp(-3.0) * np.asarray(Y0), rtol=0.1)


def test_changed_structure_compiles_once():
    _solve(growth(0.5))
    t_eval = np.linspace(0.0, 1.0, 3)
    with count_compiles() as n:
        _solve(decay(1.0), t_eval=t_eval)  # new: t_eval
        _solve(decay(2.0), t_eval=t_eval)
    assert n["traces"] == 1
    assert n["xla"] == 1


def test_tolerance_sweep_compiles_once():
    f = decay(1.0)
    controller = nj.PIDController(rtol=1e-2, atol=1e-4, h_max=0.5)
    sols = [_solve(f, max_steps=1024, controller=controller)]
    with count_compiles() as n:
        for rtol, h_max in ((1e-3, 0.25), (1e-4, 0.1)):
            controller = nj.PIDController(rtol=rtol, atol=1e-8, h_max=h_max)
            sols.append(_solve(f, max_steps=1024, controller=controller))
    assert n == {"xla": 0, "traces": 0}
    steps = [int(s.n_accepted) for s in sols]
    assert steps[0] < steps[1] < steps[2]  # tighter tolerances take more steps
    errors = [float(jnp.max(jnp.abs(s.y_final - jnp.exp(-1.0) * Y0))) for s in sols]
    assert errors[2] < errors[1] < errors[0]
    assert max(float(jnp.max(s.hs)) for s in sols[2:]) <= 0.1 * (1 + 1e-12)


def test_tolerances_are_arrays_and_still_checked():
    c = nj.PIDController(rtol=1e-4, h_min=1e-9)
    assert isinstance(c.rtol, jax.Array) and c.rtol.weak_type
    assert c.h_max is None
    with pytest.raises(ValueError, match="rtol"):
        nj.PIDController(rtol=-1.0)
    with pytest.raises(ValueError, match="h_min"):
        nj.PIDController(h_min=1.0, h_max=0.5)


def test_vmapped_tolerances():
    f = decay(1.0)

    def final(rtol):
        controller = nj.PIDController(rtol=rtol, atol=1e-8)
        return _solve(f, controller=controller, throw=False).n_accepted

    steps = jax.vmap(final)(jnp.array([1e-2, 1e-5]))
    assert steps[0] < steps[1]


def test_closure_needing_concrete_constant_falls_back():
    def clipped(k):
        if k > 1.0:  # Python control flow: k must stay concrete
            k = 1.0

        def f(t, y, args):
            if k > 0.75:
                return -k * y
            return -2.0 * k * y

        return f

    info0 = _solve_jit.cache_info()
    sol_a = _solve(clipped(0.5))
    sol_b = _solve(clipped(2.0))
    assert _solve_jit.cache_info().fallbacks == info0.fallbacks + 1
    np.testing.assert_allclose(sol_a.y_final, np.exp(-1.0) * np.asarray(Y0), rtol=5e-2)
    np.testing.assert_allclose(sol_b.y_final, np.exp(-1.0) * np.asarray(Y0), rtol=5e-2)
    sol_c = _solve(clipped(0.8))  # same code, another constant: a new static program
    np.testing.assert_allclose(sol_c.y_final, np.exp(-0.8) * np.asarray(Y0), rtol=5e-2)


def test_scene_rebuilt_in_a_function_compiles_once():
    def scene(c):
        def dynamics(t, x, args, multipliers):
            return jnp.array([x[1], -x[0] - c * x[1]])

        return nj.Scene(dynamics, n_states=2)

    x0 = jnp.array([1.0, 0.0])
    kw = dict(stepper=nj.BackwardEuler(), controller=nj.ConstantStepSize(), h0=0.1)
    scene(0.1).solve(0.0, 1.0, x0, **kw)
    with count_compiles() as n:
        a = scene(0.2).solve(0.0, 1.0, x0, **kw)
        b = scene(0.0).solve(0.0, 1.0, x0, **kw)
    assert n == {"xla": 0, "traces": 0}
    assert not np.allclose(a.y_final, b.y_final)


def test_compat_rebuilt_callbacks_compile_once():
    from nivpjax.compat import solve_ivp_ns

    def run(k):
        def fun(t, y):
            return jnp.array([y[1], -k * y[0]])

        return solve_ivp_ns(
            fun, (0.0, 0.5), [1.0, 0.0], method="backward_euler", h0=0.05, adaptive=False
        )

    run(1.0)
    with count_compiles() as n:
        t, y, *_ = run(4.0)
    assert n == {"xla": 0, "traces": 0}
    # backward Euler on x'' = -4 x: the first step solved by hand
    h = 0.05
    A = np.array([[1.0, -h], [4.0 * h, 1.0]])
    np.testing.assert_allclose(y[1], np.linalg.solve(A, [1.0, 0.0]), rtol=1e-8)


def test_compiler_options_are_known_to_xla_and_dropped_when_not(monkeypatch):
    from nivpjax import _compiler

    assert nj.compiler_options("gpu") == {}
    # The option nivpjax relies on is one this XLA accepts (a renamed or removed option
    # would silently bring back the slow compile: this test is what notices).
    assert nj.compiler_options("cpu") == {"xla_cpu_use_fusion_emitters": False}
    monkeypatch.setattr(_compiler, "_CPU", {**_compiler._CPU, "xla_cpu_no_such_option": True})
    assert nj.compiler_options("cpu") == {"xla_cpu_use_fusion_emitters": False}


def test_solves_under_an_outer_jit_give_the_top_level_answer():
    # Top level: nivpjax's compiler options. Under an outer jit (traced arguments, a
    # traced closure, or constants only) JAX refuses nested compiler options: the same
    # program without them, and the failure check in the outer graph.
    f = decay(1.5)
    top = _solve(f)
    traced = jax.jit(
        lambda y0: nj.solve(f, 0.0, 1.0, y0, stepper=nj.BackwardEuler(), max_steps=256)
    )(Y0)
    closure = jax.jit(lambda k: _solve(decay(k)))(1.5)  # raised before the fix
    constant = jax.jit(lambda: _solve(f))()
    for sol in (traced, closure, constant):
        assert int(sol.n_accepted) == int(top.n_accepted)
        assert int(sol.n_rejected) == int(top.n_rejected)
        np.testing.assert_allclose(sol.ys, top.ys, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(top.y_final, np.exp(-1.5) * np.asarray(Y0), rtol=0.1)


def test_a_failure_under_an_outer_jit_seen_only_in_a_closure_raises():
    with pytest.raises(RuntimeError, match="maximum number of time steps"):
        jax.block_until_ready(jax.jit(lambda k: _solve(decay(k), max_steps=2).y_final)(1.5))


def test_filter_jit_with_options_works_at_top_level_and_nested():
    # nivpjax.learn and nivpjax.rl compile their programs through this wrapper: with the
    # compiler options at top level, without them under an outer jit (traced arguments,
    # or constants only, where JAX refuses them at trace time).
    from nivpjax._compiler import filter_jit

    @filter_jit
    def solve_final(k, y0):
        return nj.solve(decay(k), 0.0, 1.0, y0, stepper=nj.BackwardEuler(), max_steps=256).y_final

    top = solve_final(1.5, Y0)
    traced = jax.jit(solve_final)(1.5, Y0)
    constant = jax.jit(lambda: solve_final(1.5, Y0))()
    for y in (traced, constant):
        np.testing.assert_allclose(y, top, rtol=1e-13)
    np.testing.assert_allclose(top, np.exp(-1.5) * np.asarray(Y0), rtol=0.1)


def test_two_outer_jits_each_called_twice_with_defaults_built_under_the_first(monkeypatch):
    # The first solve of a process built the default controller inside the user's jit: its
    # run-time tolerances were tracers of that trace, cached for every later solve. A
    # second outer jit then captured the dead tracers as constants and failed on its second
    # call ("Execution supplied 1 arguments but compiled program expected 6"), on JAX's
    # C++ fast path. An empty cache of defaults makes this test's first solve that one.
    from nivpjax import _validate

    monkeypatch.setattr(_validate, "_DEFAULTS", {})

    def field(t, y, args):
        return -args * y

    def outer(rate):  # `rate` concrete: a constant captured by the outer program
        return jax.jit(
            lambda y0: (
                nj.solve(field, 0.0, 1.0, y0, rate, stepper=nj.BackwardEuler(), max_steps=256).ys
            )
        )

    for k in (1.0, 2.0):
        rate = jnp.array([k, 2.0 * k])
        f = outer(rate)
        runs = [f(Y0) for _ in range(2)]
        direct = _solve(field, args=rate).ys
        for ys in runs:
            np.testing.assert_allclose(ys, direct, rtol=1e-13, atol=1e-15)
    assert not isinstance(_validate._DEFAULTS["controller"].rtol, jax.core.Tracer)


def test_runtime_floats_of_a_module_built_under_jit_are_concrete():
    # A module built inside a trace and kept (by the user, or nivpjax's defaults) must
    # not carry that trace's tracers into later programs.
    built = []

    def make(x):
        built.append(nj.PIDController(rtol=1e-4, h_max=0.5))
        return x

    jax.jit(make)(1.0)
    (controller,) = built
    for value, expected in ((controller.rtol, 1e-4), (controller.h_max, 0.5)):
        assert not isinstance(value, jax.core.Tracer)
        assert value.weak_type
        assert float(value) == expected


def test_learning_task_scenes_built_under_jit_hold_no_tracer():
    # The tasks' scenes are cached for the process; a sampler may build one first inside
    # a jit. Its parameters must be concrete there, or the next trace takes the dead
    # tracers as constants (the second-jit failure of `runtime_float`'s test above).
    from nivpjax.learn import tasks

    tasks._scene.cache_clear()
    key = jax.random.PRNGKey(0)
    first = jax.jit(tasks._slider_sample)(key)
    args = tasks._scene("slider")[2]
    assert not any(isinstance(v, jax.core.Tracer) for v in jax.tree.leaves(args))
    second = jax.jit(lambda k: tasks._slider_sample(k))(key)
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(second)):
        np.testing.assert_array_equal(a, b)


def _mappings():
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


@pytest.mark.skipif(not os.path.exists("/proc/self/maps"), reason="Linux's /proc only")
def test_clear_caches_frees_the_compiled_programs():
    """`nj.clear_caches` drops the solve cache's programs and releases their executables'
    memory mappings (what a long process runs out of); the next solve compiles again and
    gives the same answer."""
    nj.clear_caches()  # a clean start: earlier tests' programs freed now, not during this one
    gc.collect()
    sol = _solve(decay(1.0), max_steps=96)  # a structure of its own
    held = _mappings()
    for k in range(1, 9):  # eight more programs, each with executables of its own
        _solve(decay(1.0), max_steps=96 + k)
    grown = _mappings()
    assert _solve_jit.cache_info().size > 0
    nj.clear_caches()
    gc.collect()
    assert _solve_jit.cache_info().size == 0
    # Measured: about twenty mappings per XLA executable; the eight programs' are released.
    assert grown - held > 8 * 10
    assert _mappings() < held
    with count_compiles() as n:
        again = _solve(decay(1.0), max_steps=96)
    assert n["traces"] == 1
    np.testing.assert_array_equal(again.y_final, sol.y_final)


def test_jitted_solve_without_throw_holds_no_host_callback():
    # JAX's persistent cache never stores a program with a host callback. A solve traced
    # in the user's jit checked its inputs through equinox.error_if (a callback) whatever
    # `throw` said, so no jitted solve was ever stored; with throw=False it holds none now
    # (throw=True raises through one, by design).
    decay = lambda t, y, a: -y  # noqa: E731
    y0 = jnp.ones(2)

    def text(throw):
        fn = jax.jit(lambda y: nj.solve(decay, 0.0, 1.0, y, throw=throw).y_final)
        return fn.lower(y0).as_text()

    assert "callback" not in text(False)
    assert "callback" in text(True)
