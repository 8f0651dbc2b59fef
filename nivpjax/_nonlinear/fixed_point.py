"""The VI fixed-point (projection) method: extragradient with a self-adaptive step."""

import equinox as eqx
import jax.numpy as jnp
from jax import lax

from .base import AbstractNonlinearSolver, init_history, scaled_error


class FixedPointVI(AbstractNonlinearSolver):
    r"""The projection method for $y = P(y - \rho R(y))$ in extragradient form, with an
    adaptive step $\alpha$ (Korpelevich's extragradient with Khobotov's step rule):

    $$ \bar y = P(y - \alpha\rho R(y)), \qquad y^+ = P(y - \alpha\rho R(\bar y)). $$

    A trial is accepted when the local Lipschitz ratio
    $L = \alpha\,|R(\bar y) - R(y)|_{\rho} / |\bar y - y|_{\rho^{-1}} \le \nu$ (norms weighted
    by $\rho$ and $\rho^{-1}$: the iteration is a projection method in the metric
    $\operatorname{diag}(\rho)^{-1}$, where the stage residual is monotone); otherwise
    $\alpha$ shrinks by $0.9\max(\text{shrink}, \nu/L)$ and the trial is repeated. After an
    accepted trial with $L < \nu/2$, $\alpha$ grows by `grow` up to `alpha_max`. Unlike the
    plain iteration $y \leftarrow P(y - \alpha\rho R(y))$, which cycles on the saddle-point
    coupling between a state and its multiplier, the extragradient method converges for every
    monotone Lipschitz residual (linearly when it is strongly monotone).

    Stopping test: the natural residual $|\bar y - y| / \min(1, \alpha) \ge |G(y)|$, so the
    iteration never stops early; the reported residual is $|G|$ recomputed at the result.

    **Arguments:**

    - `rtol`, `atol`, `max_steps`: as for [`nivpjax.SemismoothNewton`][] (default 500).
    - `alpha0`: initial $\alpha$; `alpha_max`: its cap; `nu`: acceptance threshold on $L$;
      `grow`, `shrink`: adaptation factors.
    """

    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps: int = eqx.field(static=True, default=500)
    alpha0: float = 1.0
    alpha_max: float = 1.0
    nu: float = 0.9
    grow: float = 1.5
    shrink: float = 0.3

    def _iterate(self, residual, project, rho, y0, rtol, atol):
        R0 = residual(y0)
        tiny = jnp.finfo(y0.dtype).tiny
        rho = jnp.broadcast_to(jnp.asarray(rho, y0.dtype), y0.shape)

        def cond(carry):
            y, R, alpha, k, history, done = carry
            return (k < self.max_steps) & ~done & jnp.isfinite(alpha) & (alpha > 1e-14)

        def body(carry):
            y, R, alpha, k, history, _ = carry
            y_bar = project(y - alpha * rho * R, y, alpha * rho)
            R_bar = residual(y_bar)
            step = y_bar - y
            num = alpha * jnp.sqrt(jnp.sum(rho * (R_bar - R) ** 2))
            den = jnp.sqrt(jnp.sum(step**2 / rho))
            L = jnp.where(den > tiny, num / jnp.where(den > tiny, den, 1.0), 0.0)
            finite = jnp.all(jnp.isfinite(y_bar)) & jnp.all(jnp.isfinite(R_bar))
            accept = finite & (L <= self.nu)
            natural = step / jnp.minimum(1.0, alpha)
            done = accept & (scaled_error(natural, y, rtol, atol) <= 1)
            # At convergence keep y itself: its natural residual is the certified one.
            y_plus = project(y - alpha * rho * R_bar, y_bar, alpha * rho)
            R_plus = residual(y_plus)
            move = accept & ~done
            y_new = jnp.where(move, y_plus, y)
            R_new = jnp.where(move, R_plus, R)
            shrink = 0.9 * jnp.maximum(self.shrink, self.nu / jnp.where(L > 0, L, 1.0))
            shrink = jnp.where(finite, shrink, self.shrink)
            grown = jnp.minimum(alpha * self.grow, self.alpha_max)
            alpha_new = jnp.where(
                accept, jnp.where(L < 0.5 * self.nu, grown, alpha), alpha * shrink
            )
            k = k + 1
            history = history.at[k].set(jnp.max(jnp.abs(natural), initial=0.0))
            return y_new, R_new, alpha_new, k, history, done

        history = init_history(self.max_steps, y0.dtype, jnp.nan)
        alpha = jnp.asarray(self.alpha0, y0.dtype)
        carry = (y0, R0, alpha, jnp.array(0), history, jnp.array(False))
        y, _, _, k, history, _ = lax.while_loop(cond, body, carry)
        return y, (k.astype(y.dtype), history)
