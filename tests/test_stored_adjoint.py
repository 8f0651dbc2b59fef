"""Reverse mode through the stored loop (`nivpjax._stored_loop`, the default adjoint when the
loop states fit its budget) and the custom VJP at the solve boundary
(`CachedJit.call_with_vjp`): the same gradients as equinox's checkpointed loop (which a
`checkpoints` below `max_steps` selects) and as central finite differences, from the stored
residuals and from the stored states alike, under `jit` and `vmap`; a second gradient
compiles nothing."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj
from nivpjax import _loop, _stored_loop
from nivpjax._solve import _solve_jit


jax.config.update("jax_enable_x64", True)

SCENE, X0, ARGS = nj.scenes.bouncing_ball()
TIMES = jnp.linspace(0.1, 1.1, 6)


def _solve(e, **kw):
    # Across two impacts; Backward Euler keeps the compilation small.
    return SCENE.solve(
        0.0,
        1.2,
        X0,
        {**ARGS, "e": e},
        stepper=nj.BackwardEuler(),
        controller=nj.PIDController(rtol=1e-4, atol=1e-7),
        t_eval=TIMES,
        max_steps=512,
        **kw,
    )


def _final(e, **kw):
    sol = _solve(e, **kw)
    return sol.y_final[0] + 0.5 * sol.y_final[1]


def _loss(e, **kw):
    # Final state, saved steps (a buffer's cotangent) and states at output times.
    sol = _solve(e, **kw)
    saved = jnp.where(jnp.isfinite(sol.ts), sol.ys[:, 1], 0.0)
    return sol.y_final[0] + 0.5 * sol.y_final[1] + 0.01 * jnp.sum(saved) + jnp.sum(sol.y_eval)


E = jnp.asarray(0.8)


@pytest.fixture(scope="module")
def stored():
    _solve_jit.cache_clear()
    traces = _solve_jit.cache_info().traces
    value, grad = jax.value_and_grad(_loss)(E)
    first = _solve_jit.cache_info().traces - traces
    again = jax.value_and_grad(_loss)(E)
    second = _solve_jit.cache_info().traces - traces - first
    return value, grad, again, first, second


def test_same_gradient_as_equinox_checkpointed_loop(stored):
    value, grad, *_ = stored
    v, g = jax.value_and_grad(lambda e: _loss(e, checkpoints=7))(E)  # recomputes steps
    assert value == v
    np.testing.assert_allclose(grad, g, rtol=1e-12, atol=0)


def test_matches_finite_differences(stored):
    # The final state is smooth in e between impact-count changes (the saved steps and
    # the states at fixed times near an impact are not): central differences with a step
    # well above the solver's tolerance (its step-size choices move y by ~atol).
    grad = jax.grad(_final)(E)  # the same compiled programs as `stored`
    d = 1e-3
    fd = (_final(E + d) - _final(E - d)) / (2 * d)
    np.testing.assert_allclose(grad, fd, rtol=1e-2)


def test_second_gradient_compiles_nothing(stored):
    value, grad, (value2, grad2), first, second = stored
    assert first == 1  # the forward program of reverse mode (values and residuals) only
    assert second == 0
    assert value2 == value and grad2 == grad


def test_states_stored_when_residuals_exceed_budget(stored, monkeypatch):
    # Residuals over the budget: the forward pass stores each attempt's state and the
    # backward pass linearises the step again there. Same gradient.
    _, grad, *_ = stored
    monkeypatch.setattr(_stored_loop, "STORE_BUDGET_BYTES", 1)
    _solve_jit.cache_clear()
    np.testing.assert_allclose(jax.grad(_loss)(E), grad, rtol=1e-12, atol=0)
    _solve_jit.cache_clear()


def test_states_over_budget_use_equinox_loop(monkeypatch):
    # By default a loop whose states exceed the budget is equinox's checkpointed loop; an
    # explicit `checkpoints=max_steps` stores every state regardless.
    state = _loop._LoopState(
        t=jnp.zeros(()),
        h=jnp.zeros(()),
        h_last=jnp.zeros(()),
        h_min=jnp.zeros(()),
        y=jnp.zeros(1000),
        controller_state=None,
        n_accepted=jnp.zeros((), jnp.int32),
        n_rejected=jnp.zeros((), jnp.int32),
        n_attempts=jnp.zeros((), jnp.int32),
        n_iterations=jnp.zeros((), jnp.int32),
        result=nj.RESULTS.successful,
        attempts=None,
        **_loop._NO_STEPS,
    )
    assert _loop.stores_every_step(state, 4096, None)
    monkeypatch.setattr(_loop, "STORE_BUDGET_BYTES", 4096 * 8000)
    assert not _loop.stores_every_step(state, 4096, None)
    assert _loop.stores_every_step(state, 4096, 4096)
    assert not _loop.stores_every_step(state, 4096, 4095)


def test_under_jit_and_vmap(stored):
    _, grad, *_ = stored
    np.testing.assert_allclose(jax.jit(jax.grad(_loss))(E), grad, rtol=1e-12, atol=0)
    es = jnp.array([0.85, 0.8])
    batched = jax.vmap(jax.grad(_loss))(es)
    np.testing.assert_allclose(batched[1], grad, rtol=1e-12, atol=0)
    np.testing.assert_allclose(batched[0], jax.grad(_loss)(es[0]), rtol=1e-12, atol=0)


class _Stop(Exception):
    pass


def test_vmap_keeps_equinox_checkpoints(monkeypatch):
    # Under vmap the stored rows would be allocated per member: the default is equinox's
    # own schedule there (31 checkpoints for max_steps=512), top level stores every step.
    # Read off the solve's call to its program cache (argument 14), which is stopped there:
    # nothing is compiled.
    seen = []

    def spy(*args):
        seen.append(args[14])
        raise _Stop

    monkeypatch.setattr(_solve_jit, "prepare", spy)
    for fn in (jax.vmap(jax.grad(_final)), jax.jit(jax.vmap(jax.grad(_final)))):
        with pytest.raises(_Stop):
            fn(jnp.array([0.85, 0.8]))
    with pytest.raises(_Stop):
        jax.grad(_final)(E)
    assert seen == [31, 31, None]
