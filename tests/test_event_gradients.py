"""Gradients through impacts: the derivative of the state after an impact includes how the
impact time moves with the parameters (the saltation term, `UnilateralContact.event_time`),
checked against the closed form of a ball dropped onto the floor."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj


jax.config.update("jax_enable_x64", True)

H, T = 1.0, 1.0  # drop height; final time, after the first impact and before the second


def _exact(e, g):
    # Impact at t_i = sqrt(2H/g) with speed g t_i, then flight with e g t_i upwards.
    t_i = jnp.sqrt(2 * H / g)
    s = T - t_i
    return jnp.stack([e * g * t_i * s - 0.5 * g * s**2, e * g * t_i - g * s])


@eqx.filter_jit
def _final_state(params, stepper):
    scene, x0, _ = nj.scenes.bouncing_ball(height=H)
    sol = scene.solve(
        0.0,
        T,
        x0,
        {"e": params[0], "g": params[1]},
        stepper=stepper,
        controller=nj.PIDController(rtol=1e-8, atol=1e-10),
        max_steps=2048,
        checkpoints=2048,
        throw=False,
    )
    return sol.y_final, sol.result


@pytest.mark.parametrize("stepper", [nj.Bathe(), nj.Trapezoidal()], ids=["bathe", "tr"])
def test_gradient_through_an_impact_matches_closed_form(stepper):
    params = jnp.array([0.8, 9.81])
    (y, result) = _final_state(params, stepper)
    assert result == nj.RESULTS.successful
    np.testing.assert_allclose(y, _exact(*params), rtol=0, atol=1e-6)
    jac = jax.jacrev(lambda p: _final_state(p, stepper)[0])(params)
    exact = jax.jacfwd(lambda p: _exact(*p))(params)
    # Without the event-time term d q(T)/d g was -0.054 against the exact -0.094.
    np.testing.assert_allclose(jac, exact, rtol=1e-4, atol=1e-5)
