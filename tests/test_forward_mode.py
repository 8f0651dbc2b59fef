"""Forward mode: `jax.jacfwd` through a solve with `adjoint="forward"` equals reverse mode
(`jax.jacrev` with the default checkpointed adjoint), across impacts and slip reversals
(their event-time terms included). The default adjoint has no forward-mode rule (pinned)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj


jax.config.update("jax_enable_x64", True)


def _ball(p, adjoint):
    # Two parameters, the whole state at three times: an impact at 0.45.
    scene, x0, _ = nj.scenes.bouncing_ball()
    sol = scene.solve(
        0.0,
        0.8,
        x0,
        {"e": p[0], "g": p[1]},
        stepper=nj.BackwardEuler(),
        controller=nj.PIDController(rtol=1e-5, atol=1e-8),
        t_eval=jnp.array([0.3, 0.6, 0.8]),
        max_steps=1024,
        adjoint=adjoint,
        throw=False,
    )
    return sol.y_eval[:, :2]


def _slider(p, adjoint):
    # Friction and initial velocity; a slip reversal at ~3.1.
    scene, x0, args = nj.scenes.spring_slider()
    sol = scene.solve(
        0.0,
        4.0,
        jnp.stack([jnp.zeros_like(p[1]), p[1]]),
        dict(args, mu_s=p[0], mu_k=p[0]),
        stepper=nj.BackwardEuler(),
        controller=nj.PIDController(rtol=1e-5, atol=1e-8),
        max_steps=1024,
        adjoint=adjoint,
        throw=False,
    )
    return sol.y_final[:2]


CASES = {"ball": (_ball, jnp.array([0.8, 9.81])), "slider": (_slider, jnp.array([0.2, 0.9]))}


@pytest.mark.parametrize("name", sorted(CASES))
def test_jacfwd_matches_jacrev(name):
    fn, p = CASES[name]
    reverse = jax.jit(jax.jacrev(lambda q: fn(q, "checkpointed")))(p)
    forward = jax.jit(jax.jacfwd(lambda q: fn(q, "forward")))(p)
    assert np.all(np.isfinite(reverse)) and np.any(np.abs(reverse) > 1e-3)
    np.testing.assert_allclose(forward, reverse, rtol=1e-8, atol=1e-10)


@pytest.mark.xfail(raises=TypeError, strict=True, reason="checkpointed loop is a custom_vjp")
def test_jacfwd_through_the_default_adjoint():
    # Known limitation: forward mode needs adjoint="forward" (the checkpointed loop only
    # has a reverse rule: "can't apply forward-mode autodiff (jvp) to a custom_vjp").
    fn, p = CASES["ball"]
    jax.jacfwd(lambda q: fn(q, "checkpointed"))(p)
