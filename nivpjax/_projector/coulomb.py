"""Coulomb friction on a velocity component, as a proximal map (no multiplier state)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .ball import project_ball
from .base import AbstractProjector, Bound, ProjectionContext, resolve, switch_delay
from .box import clip
from .predict import secant_crossing


def at_zero(v):
    r"""Which components of a velocity vector are zero up to round-off (a stuck velocity,
    or one that a step landed on a reversal with): $|v_i| \le 64\,\epsilon\,(1 +
    \max_j |v_j|)$. A function of the velocity alone, so that the stage that ends at a
    velocity and the stage that starts there classify it alike."""
    tol = 64 * jnp.finfo(v.dtype).eps * (1.0 + jnp.max(jnp.abs(v), initial=0.0))
    return jnp.abs(v) <= tol


class CoulombFriction(AbstractProjector):
    r"""Set-valued Coulomb friction acting directly on velocity components $v$:

    $$ 0 \in R(y) + c(y)\,\operatorname{Sign}(v), $$

    i.e. $m v' \in F - c\,\operatorname{Sign}(v)$ with the friction bound $c = \mu N \ge 0$
    (array, or callable `bound(t, y, args)` for slip-weakening or state-dependent normal
    force). The stage fixed point $v = P(v - \rho R)$ holds with the proximal map of
    $\rho c|v|$ (soft thresholding), written through the Moreau decomposition

    $$ P(z) = z - \rho\,\operatorname{clip}(z/\rho, -c, c), $$

    where the clip is the friction force. This is the physics of the reference package's
    `CoulombProjection`; it is a proximal map, not a projection onto a set (a projector in
    the wide sense of this library: its fixed points encode the inclusion). No extra state is
    needed: in stick the stage residual $R$ is the friction force (per unit mass).

    With `isotropic=True` the whole (sub)vector is one tangential velocity with isotropic
    (2-D, disk) friction: $0 \in R + c\,\partial|v|$, whose friction force lies in the disk
    of radius $c$; the clip becomes [`nivpjax.project_ball`][] (the block's $\rho$ must be
    uniform, as it is on the differential rows of one stage).

    Jacobian: the clip's element (identity on the closed interval), so at the stick/slip
    boundary $|z| = \rho c$ the stick branch ($dP/dz = 0$) is taken; derivatives with respect
    to $c$ (slip-weakening $\mu(s)$) and $\rho$ come from autodiff. Isotropic: the ball's
    element (identity on the closed disk, i.e. stick).
    """

    bound: Bound
    isotropic: bool = eqx.field(static=True, default=False)

    def weighed_rows(self, n: int) -> np.ndarray:
        """Every row: the friction force is bounded and, along a slip or a stick, a smooth
        function of time that a second-order stage must weigh at both ends."""
        return np.ones(n, bool)

    def violation(self, ctx: ProjectionContext):
        r"""Two events inside a step, each measured in velocity units so the step is
        shortened until the event lies within tolerance of a step boundary:

        - a slip reversal (the sliding velocity changes sign between the ends): the smaller
          of the two speeds (Richardson extrapolation cannot see it);
        - a missed breakaway: the step ends stuck ($v_1 = 0$ up to round-off) although the
          applied force there, $F = f(t_1, y_1)$ (`ctx.rate`), exceeds the bound: the
          velocity $h\,(|F| - c)$ the body would gain in one step. Backward Euler checks
          the stick at the end point and never reports it; the trapezoidal rule and Bathe's
          scheme check an average of the force over the step and would let a load that
          grows during a long stick step past the static bound.
        """
        dtype = ctx.y_iter.dtype
        v0, v1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        stuck_tol = 64 * jnp.finfo(dtype).eps * (1.0 + jnp.max(jnp.abs(v0), initial=0.0))
        if self.isotropic:
            reversal = jnp.dot(v0, v1) < 0
            size = jnp.minimum(jnp.linalg.norm(v0), jnp.linalg.norm(v1))
            out = jnp.where(reversal, size, 0.0)
            stuck = jnp.linalg.norm(v1) <= stuck_tol
        else:
            size = jnp.minimum(jnp.abs(v0), jnp.abs(v1))
            out = jnp.max(jnp.where(v0 * v1 < 0, size, 0.0), initial=0.0)
            stuck = jnp.abs(v1) <= stuck_tol
        if ctx.rate is None:
            return out
        force = ctx.restrict(ctx.rate)
        c = jnp.broadcast_to(jnp.maximum(resolve(self.bound, ctx, dtype), 0.0), v1.shape)
        if self.isotropic:
            excess = jnp.linalg.norm(force) - c.reshape(-1)[0]
        else:
            excess = jnp.abs(force) - c
        missed = jnp.max(jnp.where(stuck, ctx.h * jnp.maximum(excess, 0.0), 0.0), initial=0.0)
        return jnp.maximum(out, missed)

    def next_event(self, ctx: ProjectionContext):
        """A sliding velocity reaching zero (stick or reversal), along the secant through
        its values at the two ends of the attempt (interval friction only)."""
        if self.isotropic:
            return jnp.full((), jnp.inf, ctx.y_iter.dtype)
        v0, v1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        return jnp.min(secant_crossing(v0, v1, ctx.h), initial=jnp.inf)

    def switched(self, ctx: ProjectionContext):
        """The velocity went from slip to stick, stick to slip, or reversed."""
        v0, v1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        tol = 64 * jnp.finfo(v1.dtype).eps * (1.0 + jnp.max(jnp.abs(v0), initial=0.0))
        if self.isotropic:
            stuck0, stuck1 = jnp.linalg.norm(v0) <= tol, jnp.linalg.norm(v1) <= tol
            return (stuck0 != stuck1) | (jnp.dot(v0, v1) < 0)
        mode = lambda v: jnp.where(jnp.abs(v) <= tol, 0, jnp.sign(v))
        return jnp.any(mode(v0) != mode(v1))

    @property
    def has_arrests(self) -> bool:
        return not self.isotropic

    def arrest_error(self, ctx: ProjectionContext):
        r"""The velocities that slid at the step's start and stick at its end (as
        `switched` tells them apart) came to rest inside the step. Their value, zero, is
        exact if the slip they left had reached zero by the end: with the slip branch's
        acceleration $a = \dot v - c\,\operatorname{sign} v_0$ at both ends ($\dot v$
        from `ctx.start_rate`, `ctx.end_rate`; $c$ the bound there; unit mass on the
        friction rows, as `violation` assumes), the slip velocity at the end is
        $v_0 + \tfrac h2 (a_0 + a_1)$. Where it still has the sign of $v_0$, the row
        stopped early and that velocity is its error; otherwise the error is zero (the
        arrest's timing is the error of the displacement rows, whose estimates stay).
        Interval friction only (a disk's velocity comes to rest on no scalar switch)."""
        dtype = ctx.y_iter.dtype
        v0, v1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        if self.isotropic or ctx.start_rate is None or ctx.end_rate is None:
            return jnp.zeros(v0.shape, bool), jnp.zeros_like(v0)
        tol = 64 * jnp.finfo(dtype).eps * (1.0 + jnp.max(jnp.abs(v0), initial=0.0))
        arrested = (jnp.abs(v0) > tol) & (jnp.abs(v1) <= tol)
        start = eqx.tree_at(lambda c: c.y_iter, ctx, ctx.y_prev)
        c0 = jnp.broadcast_to(jnp.maximum(resolve(self.bound, start, dtype), 0.0), v0.shape)
        c1 = jnp.broadcast_to(jnp.maximum(resolve(self.bound, ctx, dtype), 0.0), v0.shape)
        direction = jnp.sign(v0)
        a0 = ctx.restrict(ctx.start_rate) - c0 * direction
        a1 = ctx.restrict(ctx.end_rate) - c1 * direction
        slip = v0 + 0.5 * ctx.h * (a0 + a1)
        early = arrested & (slip * direction > 0)
        return arrested, jnp.where(early, slip, 0.0)

    @property
    def has_switch_shift(self) -> bool:
        return not self.isotropic

    def switch_shift(self, ctx: ProjectionContext):
        r"""Slip reversal inside the stage: the friction force per unit mass jumps from
        $-c\,\operatorname{sign}(v^-)$ to $-c\,\operatorname{sign}(v^+)$ at
        $\tau = -v_0/\dot v^-$, $\dot v^- = F - c\,\operatorname{sign}(v_0)$ ($F$ from
        `ctx.rate`, $c$ at the stage start).

        - The velocity changes sign between the stage's start and its solution: the jump
          $c(\operatorname{sign} v^+ - \operatorname{sign} v^-)\,\delta\tau$ shifts the
          stage's base point.
        - The stage ends at zero velocity (`at_zero`) although the applied force exceeds
          the bound ($|F| > c$, opposing $v_0$): the block reverses there, and the next
          stage, which starts at zero, carries no $d\tau$. The end's velocity takes the
          post-reversal derivative $-(F - c\,\operatorname{sign} F)\,\delta\tau$ in
          place of the stage's own, whichever branch the stage took: stuck (no
          sensitivity of its own) or slipping to a velocity within round-off of zero
          (the pre-reversal one; a step that ended 1e-19 short of a reversal lost its
          jump entirely, measured: $d v(T)/d\mu$ 20% off).

        Which side of the reversal a velocity lies on is decided by `at_zero` on the
        velocity alone, so that the stage ending at a velocity and the stage starting
        there agree: the jump is applied once, by the one or by the other. Stick to slip
        at a breakaway and slip to a lasting stick carry no term: the force is continuous
        at a breakaway, and a lasting stick has no sensitivity to its start. Isotropic
        friction: none (a 2-D velocity passes through zero only on a set of measure
        zero)."""
        v0, v1 = ctx.restrict(ctx.y_prev), ctx.restrict(ctx.y_iter)
        dtype = v0.dtype
        zero = jnp.zeros_like(v0)
        if self.isotropic or ctx.rate is None:
            return zero, zero, jnp.zeros((), bool)
        start = eqx.tree_at(lambda c: c.y_iter, ctx, ctx.y_prev)
        c = jnp.broadcast_to(jnp.maximum(resolve(self.bound, start, dtype), 0.0), v0.shape)
        force = ctx.restrict(ctx.rate)
        slipping, stopped = ~at_zero(v0), at_zero(v1)
        reversal = slipping & (v0 * v1 < 0) & ~stopped
        transient = slipping & stopped & (force * v0 < 0) & (jnp.abs(force) > c)
        delta = switch_delay(v0, force - c * jnp.sign(v0), reversal | transient)
        # A transient stick's base shift is the jump to the reversed slip (a multistage
        # scheme reads it for its earlier points; the end replaces the stage's derivative).
        after = jnp.where(reversal, jnp.sign(v1), jnp.sign(force))
        base = jnp.where(reversal | transient, c * (after - jnp.sign(v0)) * delta, 0.0)
        own = v1 - jax.lax.stop_gradient(v1)
        end = jnp.where(transient, -(force - c * jnp.sign(force)) * delta - own, 0.0)
        return base, end, jnp.any(reversal | transient)

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        c = jnp.maximum(resolve(self.bound, ctx, z.dtype), 0.0)
        rho = jnp.broadcast_to(ctx.rho, z.shape)
        if self.isotropic:
            return z - rho * project_ball(z / rho, c)
        return z - rho * clip(z / rho, -c, c)
