"""Position-level companion of a velocity-level contact: closed contacts held on their gap."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import _linalg
from .base import AbstractProjector, ProjectionContext
from .contact import UnilateralContact


class HeldGaps(AbstractProjector):
    r"""Keeps persistent contacts on their gap $g(q) = 0$ at position level, beside the
    velocity-level [`nivpjax.UnilateralContact`][] that it accompanies (a stabilisation in
    the manner of Gear, Gupta and Leimkuhler: a second multiplier $\mu$ enters the position
    rows only).

    A velocity-level contact keeps $u = W^T(q)\,v \ge 0$ but not the gap itself: on a curved
    gap (a ball in a bowl, a bead against a circular wall) a closed contact drifts off its
    surface by $O(h^2)$ per step, and the next step reads the drift as a flight and an
    impact. This projector acts on the position rows of the contact's bodies (the block
    pairs them with the contact's velocity rows, as [`nivpjax.Contact`][] does) and, on the
    contacts *held* in the stage, projects the candidate positions $z$ onto the gap's
    tangent plane at $z$, in the metric of the impulse map $B = M^{-1} W$:

    $$ P(z) = z + B(z)\,\mu, \qquad g(z) + W^T(z) B(z)\,\mu = 0 \ \text{on held contacts}, $$

    one Gauss–Newton step of the projection onto $\{g = 0\}$: at a stage's solution the
    correction is the step's drift (third order in $h$ for second-order schemes), and
    $g(P(z)) = O(|\mu|^2)$.

    A contact is held when, at the stage start, it is closed and resting (the contact's
    own rules) and the free flow presses into it: the normal acceleration of the vector
    field, curvature included, $\dot u = W^T \dot v + (\dot W^T) v < 0$. A contact whose
    free flow pulls it away is not held; the velocity-level contact's lift-off prediction
    lands a step where the normal acceleration turns.

    Jacobian: the derivative of the formula above on the held set (a linear map of $z$
    plus the derivative of the normals); the identity where nothing is held.
    """

    contact: UnilateralContact
    velocities: tuple[int, ...] = eqx.field(static=True)

    def held(self, ctx: ProjectionContext):
        """The contacts this stage holds on their gap (see the class docstring)."""
        # The contact reads its normal velocities on its own rows, the velocities.
        velocity_ctx = dataclasses.replace(ctx, block=self.velocities)
        return self.contact.pressed(velocity_ctx, ctx.y_prev.dtype)

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        held = self.held(ctx)
        y = ctx.y_iter.at[np.asarray(ctx.block)].set(z)
        gap = jnp.atleast_1d(jnp.asarray(self.contact.gap(ctx.t, y, ctx.args), z.dtype))
        Wt, B = self.contact._maps(ctx.t, y, ctx.args, z.dtype)
        m = gap.shape[0]
        D = jnp.where(held[:, None] & held[None, :], Wt @ B, jnp.eye(m, dtype=z.dtype))
        mu = _linalg.solve_or_nan(D, -jnp.where(held, gap, 0.0))
        return z + B @ jnp.where(held, mu, 0.0)

    def acts_on(self, n: int) -> np.ndarray:
        """None: the correction is the step's drift off the gap (third order in $h$ for
        second-order schemes), so the positions' rate is the vector field's, the
        velocities (outputs between steps take them as such)."""
        return np.zeros(n, bool)
