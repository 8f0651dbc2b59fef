"""The VI fixed-point (projection) method: projection steps with an extragradient
safeguard and a self-adaptive step."""

import equinox as eqx
import jax.numpy as jnp
from jax import lax

from .._custom_types import plain_int
from .._linear import AbstractLinearSolver, AutoLinear
from .base import AbstractNonlinearSolver, init_history, scaled_error


class FixedPointVI(AbstractNonlinearSolver):
    r"""The projection method for $y = P(y - \rho R(y))$ with an adaptive step $\alpha$.

    Each iteration starts from $y$ and its predictor $\bar y = P(y - \alpha\rho R(y))$ and
    takes one of three moves:

    1. **projection step** $y \leftarrow \bar y$ when it contracts the natural residual,
       $|P(\bar y - \alpha\rho R(\bar y)) - \bar y| \le \kappa\,|\bar y - y|$ (the plain
       Uzawa/Picard iteration: fast on strongly monotone stages, e.g. stiff decay);
    2. otherwise, if the local Lipschitz ratio
       $L = \alpha|R(\bar y) - R(y)|_{\rho} / |\bar y - y|_{\rho^{-1}} \le \nu$, the
       **extragradient** step $y \leftarrow P(y - \alpha\rho R(\bar y))$ (Korpelevich), which
       converges for every monotone Lipschitz stage, including the saddle-point coupling of
       a state with its multiplier on which plain projection cycles;
    3. otherwise **reject** and shrink $\alpha$ by $0.9\max(\text{shrink}, \nu/L)$.

    After an accepted move with $L < \nu/2$, $\alpha$ grows by `grow` up to `alpha_max`.
    Norms are weighted by $\rho$ and $\rho^{-1}$: the iteration is a projection method in
    the metric $\operatorname{diag}(\rho)^{-1}$, where the stage residual is monotone.

    Stopping test: the natural residual $|\bar y - y| / \min(1, \alpha) \ge |G(y)|$ at $y$;
    the returned value is then the full projection step $\bar y$ if $\alpha = 1$ and it
    contracts (as in move 1), else $y$, and the reported residual is $|G|$ recomputed
    there. The full step solves rows that are explicit given the others exactly (positions
    $q = q_0 + h v$); it is not taken on saddle stages ($\alpha < 1$), where it cycles.

    **Arguments:**

    - `rtol`, `atol`, `max_steps`: as for [`nivpjax.SemismoothNewton`][] (default 500).
    - `alpha0`: initial $\alpha$; `alpha_max`: its cap; `nu`: acceptance threshold on $L$;
      `kappa`: contraction required of a projection step; `grow`, `shrink`: adaptation
      factors.
    - `linear_solver`: solves the implicit-function system of derivatives (the
      iteration itself needs none); default [`nivpjax.AutoLinear`][].
    """

    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = eqx.field(static=True, default=500, converter=plain_int)
    alpha0: float = 1.0
    alpha_max: float = 1.0
    nu: float = 0.9
    kappa: float = 0.7
    grow: float = 1.5
    shrink: float = 0.3
    linear_solver: AbstractLinearSolver = eqx.field(default_factory=AutoLinear)

    def _iterate(self, residual, project, rho, y0, rtol, atol):
        tiny = jnp.finfo(y0.dtype).tiny
        rho = jnp.broadcast_to(jnp.asarray(rho, y0.dtype), y0.shape)

        def wnorm(v, w):
            return jnp.sqrt(jnp.sum(w * v**2))

        def predictor(y, R, alpha):
            y_bar = project(y - alpha * rho * R, y, alpha * rho)
            return y_bar, residual(y_bar)

        def cond(carry):
            y, R, y_bar, R_bar, alpha, k, history, done = carry
            return (k < self.max_steps) & ~done & jnp.isfinite(alpha) & (alpha > 1e-14)

        def body(carry):
            y, R, y_bar, R_bar, alpha, k, history, _ = carry
            step = y_bar - y
            natural = step / jnp.minimum(1.0, alpha)
            finite = jnp.all(jnp.isfinite(y_bar)) & jnp.all(jnp.isfinite(R_bar))
            # Never stop at the initial guess (see SemismoothNewton): move at least once.
            argument = (y - alpha * rho * R) / jnp.minimum(1.0, alpha)  # natural's scale
            done = finite & (k > 0) & (scaled_error(natural, y, rtol, atol, argument) <= 1)
            den = wnorm(step, 1 / rho)
            L = alpha * wnorm(R_bar - R, rho) / jnp.where(den > tiny, den, 1.0)
            L = jnp.where(den > tiny, L, 0.0)
            # 1. the projection step from y_bar, if it contracts
            z = project(y_bar - alpha * rho * R_bar, y_bar, alpha * rho)
            plain = (
                finite & jnp.all(jnp.isfinite(z)) & (wnorm(z - y_bar, 1 / rho) <= self.kappa * den)
            )
            # 2. the extragradient step, if the step size is safe
            extra = ~plain & finite & (L <= self.nu)
            y_extra = project(y - alpha * rho * R_bar, y_bar, alpha * rho)
            accept = plain | extra
            # On convergence, end with the projection step if it contracts: it is free (the
            # predictor is computed) and solves rows that are explicit given the others
            # exactly (positions q = q0 + h v), which would otherwise keep an error of the
            # tolerance's size (e.g. 1e-10 of position per step: enough to sustain
            # micro-bounces of a ball at rest).
            moved = jnp.where(plain, y_bar, jnp.where(extra, y_extra, y))
            y_new = jnp.where(done, jnp.where(plain & (alpha >= 1.0), y_bar, y), moved)
            shrink = 0.9 * jnp.maximum(self.shrink, self.nu / jnp.where(L > 0, L, 1.0))
            shrink = jnp.where(finite, shrink, self.shrink)
            grown = jnp.minimum(alpha * self.grow, self.alpha_max)
            alpha_new = jnp.where(
                accept, jnp.where(L < 0.5 * self.nu, grown, alpha), alpha * shrink
            )
            alpha_new = jnp.where(done, alpha, alpha_new)
            R_new = residual(y_new)
            y_bar_new, R_bar_new = predictor(y_new, R_new, alpha_new)
            k = k + 1
            history = history.at[k].set(jnp.max(jnp.abs(natural), initial=0.0))
            return y_new, R_new, y_bar_new, R_bar_new, alpha_new, k, history, done

        alpha = jnp.asarray(self.alpha0, y0.dtype)
        R0 = residual(y0)
        y_bar0, R_bar0 = predictor(y0, R0, alpha)
        history = init_history(self.max_steps, y0.dtype, jnp.nan)
        carry = (y0, R0, y_bar0, R_bar0, alpha, jnp.array(0), history, jnp.array(False))
        y, *_, k, history, _ = lax.while_loop(cond, body, carry)
        return y, (k.astype(y.dtype), history, jnp.zeros((), y.dtype))
