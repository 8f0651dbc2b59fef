"""`interpolate` computes each distinct step's parts once (`_loop._parts_at`: a scan over
chunks of distinct steps on models with selection rows): the outputs must be those of
the parts computed per output time, whatever the order of the times."""

import jax
import jax.numpy as jnp
import numpy as np

import nivpjax as nj
from nivpjax import _loop
from nivpjax._model import Model
from nivpjax._validate import check_mass_matrix


def _relay():
    scene, x0, args = nj.scenes.relay(amplitude=1.3)
    y0 = scene.initial_state(jnp.asarray(x0), None)
    mass, algebraic = check_mass_matrix(scene.full_mass_matrix, y0.shape[0], jnp.float64)
    model = Model.build(scene.vector_field, scene.projector, mass, algebraic)
    sol = scene.solve(0.0, 2.0, x0, args, controller=nj.PIDController(rtol=1e-4, atol=1e-6))
    return model, sol, args


def test_distinct_step_parts_equal_per_output_parts():
    model, sol, args = _relay()
    assert model.has_selections
    k = int(sol.n_accepted)
    assert k > 2 * _loop.PARTS_CHUNK  # several chunks, some skipped
    # Times in a shuffled order (allowed when traced), several per step, the ends too.
    rng = np.random.default_rng(0)
    t_eval = jnp.asarray(rng.permutation(np.linspace(0.0, 2.0, 301)))
    got = jax.jit(lambda s, t: _loop.interpolate(s, t, model, args))(sol, t_eval)

    def reference(sol, t_eval):
        # The parts of each output's step computed for that output alone.
        idx = jnp.searchsorted(sol.ts, t_eval, side="right") - 1
        idx = jnp.clip(idx, 0, k - 1)
        ta, tb = sol.ts[idx], sol.ts[idx + 1]
        w = jnp.clip((t_eval - ta) / (tb - ta), 0.0, 1.0)
        parts = jax.vmap(lambda a, ya, b, yb: _loop._step_parts(model, a, ya, b, yb, args))(
            ta, sol.ys[idx], tb, sol.ys[idx + 1]
        )
        return _loop._values(model, parts, t_eval, w, args, None, 0)

    want = jax.jit(reference)(sol, t_eval)
    assert np.all(np.isfinite(np.asarray(got)))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
