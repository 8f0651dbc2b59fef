"""The `checkpoints` argument of the checkpointed adjoint: same gradients, clear errors."""

import jax
import jax.numpy as jnp
import pytest

import nivpjax as nj


jax.config.update("jax_enable_x64", True)


def _loss(checkpoints):
    # A damped oscillator over 40 fixed backward Euler steps: more steps than equinox's
    # default number of checkpoints for max_steps=48 (9), so the default recomputes steps.
    def f(t, y, args):
        return jnp.stack([y[1], -args["k"] * y[0] - 0.1 * y[1]])

    def loss(k):
        sol = nj.solve(
            f,
            0.0,
            2.0,
            jnp.array([1.0, 0.0]),
            {"k": k},
            stepper=nj.BackwardEuler(),
            controller=nj.ConstantStepSize(),
            h0=0.05,
            t_eval=jnp.linspace(0.1, 2.0, 7),
            max_steps=48,
            checkpoints=checkpoints,
        )
        return jnp.sum(sol.y_eval[:, 0] ** 2) + sol.y_final[1]

    return loss


def test_checkpoints_do_not_change_gradients():
    value, grad = jax.value_and_grad(_loss(None))(2.0)
    assert jnp.isfinite(grad) and grad != 0
    for checkpoints in (2, 1000):  # recomputation; every step (clipped to max_steps)
        v, g = jax.value_and_grad(_loss(checkpoints))(2.0)
        assert v == value
        assert jnp.allclose(g, grad, rtol=1e-12, atol=1e-14), (checkpoints, g, grad)


def test_scene_forwards_checkpoints():
    # Validated (before any work) by nivpjax.solve, so it reached it.
    scene, x0, args = nj.scenes.bouncing_ball()
    with pytest.raises(ValueError, match="`checkpoints`"):
        scene.solve(0.0, 1.0, x0, args, checkpoints=0)


@pytest.mark.parametrize(
    "bad, error",
    [(0, ValueError), (-3, ValueError), (2.5, TypeError), (True, TypeError), ("all", TypeError)],
)
def test_bad_checkpoints(bad, error):
    with pytest.raises(error, match="`checkpoints`"):
        _loss(bad)(2.0)


def test_checkpoints_need_checkpointed_adjoint():
    f = lambda t, y, args: -y
    with pytest.raises(ValueError, match="`checkpoints`"):
        nj.solve(f, 0.0, 1.0, jnp.array([1.0]), adjoint="forward", checkpoints=10)
