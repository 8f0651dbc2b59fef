"""Shared test utilities: pytree comparison, central finite differences, the projector
catalogue, a scene's model."""

import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np

import nivpjax as nv


def tree_allclose(x, y, *, rtol=1e-5, atol=1e-8):
    """Whether two pytrees have the same structure and allclose leaves."""
    x_leaves, x_def = jtu.tree_flatten(x)
    y_leaves, y_def = jtu.tree_flatten(y)
    if x_def != y_def:
        return False
    return all(
        np.shape(a) == np.shape(b) and np.allclose(a, b, rtol=rtol, atol=atol)
        for a, b in zip(x_leaves, y_leaves)
    )


def fd_jacobian(f, args, argnum=0, eps=1e-6):
    """Central finite-difference Jacobian of the array-valued `f(*args)` with respect to the
    array `args[argnum]`, laid out like `jax.jacfwd`: `out.shape + arg.shape`.

    Error: truncation $O(\\varepsilon^2 |f'''|)$ plus roundoff $O(\\text{ulp}(f)/\\varepsilon)$,
    about 1e-10 for $\\varepsilon = 10^{-6}$ and O(1) values in float64. Only meaningful where
    `f` is smooth on the stencil: keep the point more than `eps` away from kinks.
    """
    args = [jnp.asarray(a) for a in args]
    x = np.asarray(args[argnum], dtype=np.float64)
    out_shape = np.shape(f(*args))
    jac = np.zeros(out_shape + x.shape)
    for i in np.ndindex(x.shape):
        plus, minus = x.copy(), x.copy()
        plus[i] += eps
        minus[i] -= eps
        f_plus = np.asarray(f(*args[:argnum], jnp.asarray(plus), *args[argnum + 1 :]))
        f_minus = np.asarray(f(*args[:argnum], jnp.asarray(minus), *args[argnum + 1 :]))
        jac[(Ellipsis,) + i] = (f_plus - f_minus) / (2 * eps)
    return jac


# Projectors onto fixed (state-independent) closed convex sets, usable with
# `nv.default_context`: (name, projector, dimension of z).
ALL_PROJECTORS = (
    ("identity", nv.Identity(), 3),
    ("nonnegative", nv.NonNegative(), 3),
    ("box", nv.Box(lower=jnp.array([-1.0, 0.0, 2.0]), upper=jnp.array([1.0, 0.5, 2.0])), 3),
    ("ball", nv.Ball(radius=jnp.array(1.5)), 2),
    ("soc", nv.SecondOrderCone(mu=jnp.array(0.7)), 3),
    (
        "block",
        nv.BlockProjector(
            [
                ((0,), nv.NonNegative()),
                ((1, 2), nv.Ball(radius=jnp.array(1.0))),
                ((3, 4, 5), nv.SecondOrderCone(mu=jnp.array(0.7))),
            ]
        ),
        7,
    ),
)


def scene_model(scene):
    """The `Model` a scene's solve builds (rows with a zero mass are algebraic), for
    tests that take a stepper's or the model's single steps."""
    from nivpjax._model import Model

    mass = scene.full_mass_matrix
    algebraic = np.zeros(scene.size, bool) if mass is None else np.asarray(mass.diagonal() == 0)
    return Model.build(
        scene.vector_field, scene.projector, mass, algebraic, equation_rows=scene.equation_rows
    )
