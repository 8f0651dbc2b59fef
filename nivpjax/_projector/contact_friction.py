"""Coulomb friction on a unilateral contact whose normal turns (a curved wall)."""

import jax.numpy as jnp
import numpy as np

from .ball import _safe_norm, project_ball
from .base import AbstractProjector, Bound, ProjectionContext, resolve
from .contact import UnilateralContact
from .predict import secant_crossing


class FrictionalContact(AbstractProjector):
    r"""One unilateral contact with Coulomb friction in its tangent plane, on the contact's
    velocity rows (unit or isotropic masses, $B = c\,W$): the velocity-level contact
    [`nivpjax.UnilateralContact`][] (its normal impulse $p_n\,n$, $n = W/|W|$ the unit
    normal at the iterate), then friction on the tangential part

    $$ P(z) = z^+ - \Pi_{\mu |B p|}\big((I - n n^T) z^+\big), \qquad z^+ = z + B p, $$

    $\Pi_r$ the projection onto the ball of radius $r$ in the tangent plane
    ([`nivpjax.project_ball`][]): the friction impulse opposes the tangential velocity
    and is at most $\mu$ times the normal impulse (stick where the tangential velocity
    it meets is inside that bound). With isotropic masses and one contact the normal and
    tangential problems decouple, so this is the exact solution of the impulse-level
    Coulomb law $|p_t| \le \mu p_n$ with $p_t$ opposing the tangential velocity after
    the step (Moreau–Jean, De Saxcé's bipotential).

    Everything the contact decides (active set, impacts, events, the persistent contacts
    of its law) is the contact's. Its reaction rows are weighed, on a flat gap as on a
    curved one: the friction force of a persistent contact, $-\mu N\,v_t/|v_t|$ in slip
    and the holding force in stick, enters the trapezoidal stages at both ends like the
    vector field (see `Model.law_reaction`). Applied whole at the stage's end instead, a
    friction force that turns with the sliding velocity (a block thrown across a slope)
    is integrated at first order.

    Events: a tangential velocity that passes through zero between the two ends of a
    step (a stick or a reversal; its smaller speed, in velocity units, is reported as a
    violation, so the step is cut until the kink lies within tolerance of a step end),
    and its secant crossing predicted by `next_event`.

    Jacobian: the contact's, then the ball's element (identity on the closed ball:
    stick); derivatives of the normals and of $\mu$ by autodiff.
    """

    contact: UnilateralContact
    mu: Bound

    def _friction(self, z, out, ctx: ProjectionContext, y):
        # The tangential friction impulse taken off `out`, the contact's projection of z
        # with normals at y; |out - z| is the normal impulse's velocity change (one contact,
        # isotropic masses: the friction impulse's is bounded by mu times it).
        n = self._normal(ctx, y, z.dtype)
        mu = jnp.maximum(resolve(self.mu, ctx, z.dtype), 0.0).reshape(())
        tangential = out - n * jnp.dot(n, out)
        return out - project_ball(tangential, mu * _safe_norm(out - z))

    def _normal(self, ctx: ProjectionContext, y, dtype):
        Wt, _ = self.contact._maps(ctx.t, y, ctx.args, dtype)
        return Wt[0] / _safe_norm(Wt[0])

    def _tangential(self, ctx: ProjectionContext, y):
        v = ctx.restrict(y)
        n = self._normal(ctx, y, v.dtype)
        return v - n * jnp.dot(n, v)

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        return self._friction(z, self.contact(z, ctx), ctx, ctx.y_iter)

    def impact(self, ctx: ProjectionContext):
        """Newton's impact law (the contact's), with the friction impulse it bounds."""
        z = ctx.restrict(ctx.y_prev)
        return self._friction(z, self.contact.impact(ctx), ctx, ctx.y_iter)

    def _slip(self, ctx: ProjectionContext):
        # The tangential speed at the start and the signed one at the end (negative when
        # the tangential velocity reversed), on a contact closed at both ends.
        dtype = ctx.y_iter.dtype
        vt0, vt1 = self._tangential(ctx, ctx.y_prev), self._tangential(ctx, ctx.y_iter)
        s0, s1 = _safe_norm(vt0), _safe_norm(vt1)
        s1 = jnp.where(jnp.dot(vt0, vt1) < 0, -s1, s1)
        _, _, gap0, u0, _ = self.contact._start(ctx, dtype)
        gap1, u1 = self.contact._end(ctx, dtype)
        closed0 = self.contact._closed(gap0, u0, ctx.y_prev, ctx.h)
        closed1 = self.contact._closed(gap1, u1, ctx.y_iter, ctx.h)
        return s0, s1, jnp.all(closed0 & closed1)

    def violation(self, ctx: ProjectionContext):
        """The contact's, and a tangential velocity through zero inside the step (see the
        class docstring)."""
        s0, s1, closed = self._slip(ctx)
        through = closed & (s1 < 0)
        slip = jnp.where(through, jnp.minimum(s0, -s1), 0.0)
        return jnp.maximum(self.contact.violation(ctx), slip)

    def next_event(self, ctx: ProjectionContext):
        """The contact's, and the tangential speed's zero along its secant."""
        s0, s1, closed = self._slip(ctx)
        stop = jnp.where(closed, secant_crossing(s0, s1, ctx.h), jnp.inf)
        return jnp.minimum(self.contact.next_event(ctx), stop)

    def initial_violation(self, ctx: ProjectionContext):
        return self.contact.initial_violation(ctx)

    @property
    def has_event_time(self) -> bool:
        return self.contact.has_event_time

    def event_time(self, ctx: ProjectionContext):
        return self.contact.event_time(ctx)

    def switched(self, ctx: ProjectionContext):
        """The contact's, or the tangential velocity stopped, started or reversed."""
        s0, s1, closed = self._slip(ctx)
        tol = 64 * jnp.finfo(s0.dtype).eps * (1.0 + jnp.abs(s0))
        stuck0, stuck1 = s0 <= tol, jnp.abs(s1) <= tol
        moved = closed & ((stuck0 != stuck1) | (s1 < -tol))
        return self.contact.switched(ctx) | moved

    def impulsive(self, ctx: ProjectionContext):
        return self.contact.impulsive(ctx)

    def acts_on(self, n: int):
        return self.contact.acts_on(n)

    def weighed_rows(self, n: int):
        """Every row, whether the contact's are weighed (a curved gap) or not (a flat one:
        its friction force still turns with the sliding velocity)."""
        return np.ones(n, bool)
