"""The VI fixed-point (projection) method: projection steps with an extragradient
safeguard and a self-adaptive step."""

import equinox as eqx
import jax.numpy as jnp
from jax import lax

from .. import _linalg
from .._custom_types import plain_int
from .._linear import AbstractLinearSolver, AutoLinear
from .base import AbstractNonlinearSolver, init_history, residual_scale, scaled_error


# The iteration stops at the round-off floor of its residual (`residual_scale`) once its
# natural residual has not fallen below STALL_FACTOR of its best for STALL_ITERATIONS: the
# floor is a bound, and an iteration still converging goes on to the tolerance (a stiff
# spring's contact force: 6e-11 of itself there, 7e-9 when stopped at the floor).
STALL_FACTOR = 0.9
STALL_ITERATIONS = 8


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

    **Anderson acceleration** (`anderson` = $m > 0$): before those moves, the iterates'
    last $m$ pairs $(y_j, \bar y_j)$ at the current $\alpha$ give the extrapolation
    $y_A = \sum_j c_j \bar y_j$, $\sum_j c_j = 1$, whose residuals' combination
    $\sum_j c_j (\bar y_j - y_j)$ is smallest (Walker and Ni's type II). It replaces the
    move when its own natural residual is smaller than $y$'s. On a stage whose map is
    affine on the current faces it is GMRES on the fixed-point equation, and converges in
    a few iterations where the moves above contract at $1 - \mu/L$ per iteration: a
    Filippov spiral's step into its Zeno point, $w$ inside the box of a rotation with
    coupling 0.02 ($\mu / L = 0.02$), took more than 1 000 iterations without it and
    failed; super-twisting's sliding mode likewise (every run of the reliability
    campaign stalled). It costs one residual and one projection per iteration more.
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
    - `anderson`: Anderson acceleration's memory $m$ (default 5; 0: none).
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
    anderson: int = eqx.field(static=True, default=5, converter=plain_int)
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
            (y, R, y_bar, R_bar, alpha, k, history, done, _), _ = carry
            return (k < self.max_steps) & ~done & jnp.isfinite(alpha) & (alpha > 1e-14)

        def body(carry):
            (y, R, y_bar, R_bar, alpha, k, history, _, (best, stalled)), memory = carry
            step = y_bar - y
            natural = step / jnp.minimum(1.0, alpha)
            finite = jnp.all(jnp.isfinite(y_bar)) & jnp.all(jnp.isfinite(R_bar))
            # Never stop at the initial guess (see SemismoothNewton): move at least once.
            argument = (y - alpha * rho * R) / jnp.minimum(1.0, alpha)  # natural's scale
            done = finite & (k > 0) & (scaled_error(natural, y, rtol, atol, argument) <= 1)
            # Or stalled at the round-off of rho R's terms (`residual_scale`).
            size = jnp.max(jnp.abs(natural), initial=0.0)
            stalled = jnp.where(size < STALL_FACTOR * best, 0, stalled + 1)
            best = jnp.minimum(best, size)
            floor = jnp.abs(argument) + alpha * rho * noise / jnp.minimum(1.0, alpha)
            at_floor = scaled_error(natural, y, rtol, atol, floor) <= 1
            done = done | (finite & at_floor & (stalled >= STALL_ITERATIONS))
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

            def moving(_):
                R_new = residual(y_new)
                return (y_new, R_new, *predictor(y_new, R_new, alpha_new), alpha_new)

            memory = _remember(memory, y, y_bar, alpha, finite)
            y_a, R_a, y_bar_a, use = _accelerated(memory, alpha, den, finite & ~done)

            def accelerating(_):
                return y_a, R_a, y_bar_a, residual(y_bar_a), alpha

            y_new, R_new, y_bar_new, R_bar_new, alpha_new = lax.cond(
                use, accelerating, moving, None
            )
            k = k + 1
            history = history.at[k].set(size)
            state = (y_new, R_new, y_bar_new, R_bar_new, alpha_new, k, history, done)
            state = state + ((best, stalled),)
            return state, memory

        def _remember(memory, y, y_bar, alpha, finite):
            # The pair (y, y_bar = T_alpha(y)) joins the last ones at the same alpha (a
            # new alpha is a new map: the memory restarts).
            # A ring: the rows' order does not matter to the extrapolation.
            Ys, Gs, count, slot, alpha_memory = memory
            if self.anderson == 0:
                return memory
            same = alpha == alpha_memory
            count, slot = jnp.where(same, count, 0), jnp.where(same, slot, 0)
            Ys = Ys.at[slot].set(jnp.where(finite, y, Ys[slot]))
            Gs = Gs.at[slot].set(jnp.where(finite, y_bar, Gs[slot]))
            count = jnp.where(finite, jnp.minimum(count + 1, self.anderson), count)
            slot = jnp.where(finite, (slot + 1) % self.anderson, slot)
            return Ys, Gs, count, slot, alpha

        def _accelerated(memory, alpha, den, allowed):
            # Anderson's extrapolation from the memory and its predictor; `use` where
            # its natural residual is below y's (`den`).
            Ys, Gs, count, _, _ = memory
            if self.anderson == 0:
                return y0, y0, y0, jnp.zeros((), bool)
            y_a = _anderson(Ys, Gs, count, 1 / rho)
            R_a = residual(y_a)
            y_bar_a = project(y_a - alpha * rho * R_a, y_a, alpha * rho)
            better = wnorm(y_bar_a - y_a, 1 / rho) < den
            ok = jnp.all(jnp.isfinite(y_bar_a)) & jnp.all(jnp.isfinite(R_a))
            return y_a, R_a, y_bar_a, allowed & (count >= 2) & ok & better

        alpha = jnp.asarray(self.alpha0, y0.dtype)
        R0 = residual(y0)
        noise = residual_scale(residual, y0)
        y_bar0, R_bar0 = predictor(y0, R0, alpha)
        history = init_history(self.max_steps, y0.dtype, jnp.nan)
        state = (y0, R0, y_bar0, R_bar0, alpha, jnp.array(0), history, jnp.array(False))
        state = state + ((jnp.asarray(jnp.inf, y0.dtype), jnp.array(0)),)
        empty = jnp.zeros((self.anderson,) + y0.shape, y0.dtype)
        memory = (empty, empty, jnp.array(0), jnp.array(0), alpha)
        (y, *_, k, history, _, _), _ = lax.while_loop(cond, body, (state, memory))
        return y, (k.astype(y.dtype), history, jnp.zeros((), y.dtype))


def _anderson(Ys, Gs, count, weight):
    r"""Anderson's type-II extrapolation $\sum_j c_j G_j$ over the first `count` rows,
    $c$ minimising $|\sum_j c_j (G_j - Y_j)|$ in the `weight`ed 2-norm subject to
    $\sum_j c_j = 1$ (its KKT system, Tikhonov-regularised at $10^{-10}$ of the
    residuals' mean square, unused rows held at $c_j = 0$)."""
    m = Ys.shape[0]
    F = (Gs - Ys) * jnp.sqrt(weight)
    valid = jnp.arange(m) < count
    gram = jnp.where(valid[:, None] & valid[None, :], F @ F.T, 0.0)
    scale = jnp.trace(gram) / jnp.maximum(count, 1) + jnp.finfo(Ys.dtype).tiny
    gram = gram + jnp.diag(jnp.where(valid, 1e-10 * scale, scale))
    ones = valid.astype(Ys.dtype)
    kkt = jnp.block([[gram, ones[:, None]], [ones[None, :], jnp.zeros((1, 1), Ys.dtype)]])
    rhs = jnp.zeros(m + 1, Ys.dtype).at[m].set(1.0)
    c = _linalg.solve_or_nan(kkt, rhs)[:m]
    return jnp.where(valid, c, 0.0) @ Gs
