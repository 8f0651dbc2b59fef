import jax.numpy as jnp
import numpy as np

from .base import AbstractProjector, ProjectionContext, face
from .box import sign_resolvent_interval


def _indices(index):
    out = []
    for i in np.atleast_1d(index).tolist():
        if isinstance(i, bool) or not isinstance(i, int):
            raise TypeError(f"`s_index`/`w_index` indices must be integers, got {i!r}.")
        out.append(i)
    return tuple(out)


class SignResolvent(AbstractProjector):
    r"""The relay/sign relation $w \in \operatorname{sign}(s)$ on a pair of state components,
    through its resolvent

    $$ w \leftarrow \operatorname{clip}(w + \tau s, -1, 1), $$

    whose fixed points are exactly the pairs with $w \in \operatorname{sign}(s)$ (for any
    $\tau > 0$): if $s > 0$ then $w = 1$, if $s < 0$ then $w = -1$, and $s = 0$ leaves any
    $w \in [-1, 1]$. Components other than `w_index` pass through unchanged; the row of $w$ in
    the implicit residual is ignored (it is typically an algebraic row).

    This mirrors the reference package's `SignProjection`. It is a resolvent, not a projection:
    it is not idempotent unless $s = 0$. In a model you write yourself, the equivalent and
    better-scaled form is a [`nivpjax.Box`][] $[-1, 1]$ on an algebraic multiplier whose row
    is $f_w = s$.

    `tau=None` (default) uses the stage's own scaling $\tau = \rho_w$ (as the reference
    does); on an algebraic row that is $\tau_{\text{model}}/h$, which makes one fixed-point
    sweep exact for a multiplier entering its state with weight $h$.

    Kinks: the Jacobian of the clip (identity on the closed interval, see
    [`nivpjax.clip`][]).
    """

    s_index: tuple[int, ...]
    w_index: tuple[int, ...]
    tau: float | None = None

    def __init__(self, s_index, w_index, tau: float | None = None):
        s, w = _indices(s_index), _indices(w_index)
        if len(s) != len(w):
            raise ValueError(
                f"`s_index` and `w_index` must have the same length, got {len(s)} and {len(w)}."
            )
        if tau is not None and not tau > 0:
            raise ValueError(f"`tau` must be positive, got {tau}.")
        self.s_index = s
        self.w_index = w
        self.tau = tau

    def validate(self, n: int) -> None:
        bad = [i for i in self.s_index + self.w_index if not -n <= i < n]
        if bad:
            raise ValueError(
                f"SignResolvent indices {bad} are out of range for a state of size {n}."
            )

    def __call__(self, z, ctx: ProjectionContext):
        z = jnp.asarray(z)
        s = np.asarray(self.s_index)
        w = np.asarray(self.w_index)
        tau = jnp.broadcast_to(ctx.rho, z.shape)[w] if self.tau is None else self.tau
        return z.at[w].set(sign_resolvent_interval(z[w], tau * z[s]))

    def switched(self, ctx: ProjectionContext):
        """A selection $w$ moved onto, off or between $\\pm 1$."""
        w = np.asarray(self.w_index)
        w0, w1 = ctx.restrict(ctx.y_prev)[w], ctx.restrict(ctx.y_iter)[w]
        return jnp.any(face(w0, -1.0, 1.0) != face(w1, -1.0, 1.0))
