"""The reference package's classic step-doubling controller, as a baseline."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import plain_int
from .._norms import scaled_rms_norm
from .._results import RESULTS
from .base import AbstractController, StepInfo


class StepDoublingController(AbstractController):
    r"""Step doubling with the classic PI rule of `solve_nivp`'s adaptive stepping
    ("classic" mode), the baseline of its companion study on learned step sizes.

    Every attempt takes one step of size $h$ and two of size $h/2$ (the stepper is wrapped
    in [`nivpjax.Richardson`][] whatever its embedded estimate) and propagates the two
    half steps. With $y_\text{lo}$ the full step and $y_\text{hi}$ the half steps,

    $$ E = \operatorname{RMS}_i \frac{(y_{\text{lo},i} - y_{\text{hi},i})/(2^p - 1)}
       {\text{atol} + \text{rtol}\max(|y_{\text{lo},i}|, |y_{\text{hi},i}|)}. $$

    The attempt is accepted when $E \le 1$ (and its nonlinear solves converged). After an
    acceptance $h \leftarrow h\,\operatorname{clip}(s\,E^{-\alpha}E_\text{prev}^{-\beta},
    f_\text{down}, f_\text{up})$ with $\alpha = 0.7/(p + 1)$, $\beta = 0.4/(p + 1)$ and
    $E_\text{prev}$ the last accepted step's error; the first acceptance (no
    $E_\text{prev}$) uses $s\,E^{-1/(p+1)}$, and $E = 0$ gives $f_\text{up}$. After a
    rejection $h \leftarrow f_\text{down}\,h$.

    The sign of $\beta$ is the reference's: a Gustafsson PI filter would raise
    $E_\text{prev}$ to $+\beta$. Kept, since this is a baseline to reproduce. The
    reference scales by $\max(|y_\text{lo}|, |y_\text{hi}|)$ per component, as here.

    **Arguments:**

    - `rtol`, `atol`: tolerances (the reference's defaults, 1e-3 and 1e-6).
    - `order`: $p$ in the estimate and the exponents; `None` (default) uses the stepper's
      order. The study sets its method order to 1 for the composite (Bathe) scheme; as its code
      runs, the controller infers 2 from the scheme (exponents 0.2333 and 0.1333).
    - `safety`, `factormin`, `factormax`: $s$, $f_\text{down}$, $f_\text{up}$ (the
      study's 0.9, 0.6, 1.8).
    - `use_pi`: `False` for the proportional rule $s\,E^{-1/(p+1)}$ at every step.
    - `h_min`, `h_max`: step bounds (the study's 1e-7 and 1e3 in its units; if `None`,
      the loop's default floor and no ceiling).
    """

    rtol: float = 1e-3
    atol: float = 1e-6
    order: int | None = eqx.field(static=True, default=None)
    safety: float = 0.9
    factormin: float = 0.6
    factormax: float = 1.8
    use_pi: bool = eqx.field(static=True, default=True)
    h_min: float | None = None
    h_max: float | None = None

    def __check_init__(self):
        for name in ("rtol", "atol", "safety", "factormin", "factormax"):
            value = getattr(self, name)
            if not isinstance(value, jax.core.Tracer) and not float(value) > 0:
                raise ValueError(f"`{name}` must be positive, got {value!r}.")
        if not isinstance(self.factormin, jax.core.Tracer) and not (
            float(self.factormin) <= 1 <= float(self.factormax)
        ):
            raise ValueError(
                "`factormin` <= 1 <= `factormax` is required, got "
                f"{self.factormin!r} and {self.factormax!r}."
            )
        if self.order is not None and plain_int(self.order) < 1:
            raise ValueError(f"`order` must be an int >= 1, got {self.order!r}.")

    def tolerances(self):
        return self.rtol, self.atol

    @property
    def needs_error_estimate(self) -> bool:
        return True

    @property
    def step_doubling(self) -> bool:
        """Always estimate by step doubling (see `nivpjax.solve`'s `error_estimate`)."""
        return True

    @property
    def bounds(self):
        return self.h_min, self.h_max

    def init(self, t0, t1, y0, h0, f0, error_order, error_mask):
        one = jnp.ones((), y0.dtype)
        h = jnp.asarray(1e-2 if h0 is None else h0, y0.dtype)  # the reference's h0
        if self.h_max is not None:
            h = jnp.minimum(h, self.h_max)
        return h, (one, jnp.zeros((), bool))

    def adapt(self, info: StepInfo, state):
        prev, has_prev = state
        # Richardson divides by 2^q - 1 with q the stepper's order; rescaled to this
        # controller's p.
        q = info.error_order - 1
        p = q if self.order is None else self.order
        # Richardson's estimate is (y_hi - y_lo)/(2^q - 1): the full step y_lo is recovered
        # from it, for the reference's scale max(|y_lo|, |y_hi|).
        y_lo = info.y1 - info.y_error * (2.0**q - 1.0)
        y_error = info.y_error * ((2.0**q - 1.0) / (2.0**p - 1.0))
        err = scaled_rms_norm(y_error, y_lo, info.y1, self.rtol, self.atol, info.error_mask)
        ok = (info.stats.nonlinear_result == RESULTS.successful) & jnp.all(jnp.isfinite(info.y1))
        ok = ok & jnp.isfinite(err)
        accept = ok & (err <= 1)
        err_safe = jnp.where(ok & (err > 0), err, 1.0)
        alpha, beta = 0.7 / (p + 1.0), 0.4 / (p + 1.0)
        proportional = self.safety * err_safe ** (-1.0 / (p + 1.0))
        # The previous error enters only when it is positive (the reference's test).
        use_prev = has_prev & (prev > 1e-16)
        pi = self.safety * err_safe**-alpha * jnp.where(use_prev, prev, 1.0) ** -beta
        grow = jnp.where(use_prev & self.use_pi, pi, proportional)
        grow = jnp.where(err > 0, jnp.clip(grow, self.factormin, self.factormax), self.factormax)
        factor = jax.lax.stop_gradient(jnp.where(accept, grow, self.factormin))
        h_next = info.h * factor
        if self.h_max is not None:
            h_next = jnp.minimum(h_next, self.h_max)
        new_state = (jnp.where(accept, err, prev), has_prev | accept)
        return accept, h_next, jax.lax.stop_gradient(new_state)
