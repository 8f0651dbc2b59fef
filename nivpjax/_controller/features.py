"""The observation of a learned step-size controller: finite, scale-free features of an
attempted step."""

import abc
import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._norms import scaled_rms_norm, violation_scale
from .._results import RESULTS
from .base import StepInfo


_LOG_CLIP = 25.0  # |log| beyond this carries no more information (e^25 ~ 7e10)
# The floor below which every log is clipped anyway; 1 / floor stands for inf. Both fit
# float32 (a floor of 1e-300 made 1e300, which overflowed the cast to float32).
_FLOOR = math.exp(-_LOG_CLIP)


def safe_log(x, floor=_FLOOR):
    """$\\log\\max(x, \\text{floor})$, clipped to $[-25, 25]$: finite for $x \\le 0$, NaN or
    inf, and with a zero derivative there (guards the loop body of finished members)."""
    x = jnp.where(jnp.isfinite(x), x, jnp.where(jnp.isnan(x), floor, 1.0 / floor))
    return jnp.clip(jnp.log(jnp.maximum(x, floor)), -_LOG_CLIP, _LOG_CLIP)


class FeatureMemory(eqx.Module):
    """What the features remember between attempts (part of the controller state).

    - `log_errors`: log scaled error norms of the previous attempts, newest first.
    - `accepted`: 1.0 if the previous attempt was accepted (initially 1.0).
    - `span`: the length of the integration interval.
    """

    log_errors: Float[Array, " m"]
    accepted: Float[Array, ""]
    span: Float[Array, ""]


class AbstractFeatures(eqx.Module):
    """Maps an attempted step to the vector a policy sees.

    - `size`: the length of the feature vector.
    - `init(t0, t1, dtype) -> FeatureMemory`.
    - `__call__(info, error, memory) -> features`: `error` is the scaled error norm of the
      attempt (the one the error test uses, possibly inf), `memory` the state before it.
    - `update(memory, error, accepted) -> memory`.

    Replace it to change what a policy observes; every output must be finite whatever the
    step (finished members of a `vmap` batch run the loop body with `h` possibly 0).
    """

    @property
    @abc.abstractmethod
    def size(self) -> int: ...

    @abc.abstractmethod
    def init(self, t0, t1, dtype) -> FeatureMemory: ...

    @abc.abstractmethod
    def __call__(self, info: StepInfo, error, memory: FeatureMemory) -> Float[Array, " f"]: ...

    @abc.abstractmethod
    def update(self, memory: FeatureMemory, error, accepted) -> FeatureMemory: ...


class StepFeatures(AbstractFeatures):
    r"""The default features, in this order (all finite and scale-free):

    0. $\log e_n$, the log scaled error norm of this attempt (with the violation counted as
       error, as in [`nivpjax.PIDController`][]);
    1. `history` entries: $\log e$ of the previous attempts, newest first ($0$ before the first);
    2. $\log(h / (t_1 - t_{\text{start}}))$;
    3. whether the previous attempt was accepted (1 or 0);
    4. $\log(1 + \text{iterations})$ of the nonlinear solve, and 5. whether it succeeded;
    6. $\log(1 + v/s)$: the constraint violation $v$ at the end of the step, in units of
       the error scale $s = \text{atol} + \text{rtol}\,\|y_0\|_\infty$;
    7. $\log(\tau / h)$ clipped to $[-c, c]$ with $\tau$ the predicted time to the next event
       (`StepInfo.next_event`; $c$ when none is predicted), `c = event_clip`;
    8. $\log(1 + \|y_1 - y_0\|/s)$ (scaled RMS over the error mask): how much the state moved;
    9. the fraction of the interval left after this attempt,
       $(t_1 - t_0 - h)/(t_1 - t_{\text{start}})$.

    (Indices 1..8 shift by `history - 1`: entries 1 to `history` hold the previous errors.)

    **Arguments:** `rtol`, `atol` (the error scale; the controller fills them in),
    `history` (how many previous error norms; default 2), `event_clip` (default 10).
    """

    rtol: float = 1e-3
    atol: float = 1e-6
    history: int = eqx.field(static=True, default=2)
    event_clip: float = 10.0

    @property
    def size(self) -> int:
        return self.history + 9

    def init(self, t0, t1, dtype):
        return FeatureMemory(
            log_errors=jnp.zeros((self.history,), dtype),
            accepted=jnp.ones((), dtype),
            span=jnp.asarray(t1 - t0, dtype),
        )

    def __call__(self, info: StepInfo, error, memory: FeatureMemory):
        dtype = info.y1.dtype
        span = jnp.where(memory.span > 0, memory.span, 1.0)
        h = info.h
        h_safe = jnp.where(h > 0, h, span)
        scale = violation_scale(self.rtol, self.atol, info.y0, info.error_mask)
        ok = info.stats.nonlinear_result == RESULTS.successful
        y1 = jnp.where(jnp.isfinite(info.y1), info.y1, info.y0)
        moved = scaled_rms_norm(y1 - info.y0, info.y0, y1, self.rtol, self.atol, info.error_mask)
        event = jnp.where(jnp.isfinite(info.next_event), info.next_event, jnp.inf)
        log_event = jnp.where(
            event < jnp.inf,
            jnp.clip(safe_log(event) - safe_log(h_safe), -self.event_clip, self.event_clip),
            self.event_clip,
        )
        left = jnp.clip((info.t1 - info.t0 - h) / span, 0.0, 1.0)
        scalars = jnp.stack(
            [
                safe_log(h_safe / span),
                memory.accepted,
                jnp.log1p(jnp.asarray(info.stats.iterations, dtype)),
                ok.astype(dtype),
                jnp.log1p(jnp.clip(info.violation / scale, 0.0, 1e10)),
                log_event,
                jnp.log1p(jnp.clip(moved, 0.0, 1e10)),
                left,
            ]
        ).astype(dtype)
        return jnp.concatenate([safe_log(error, 1e-10)[None], memory.log_errors, scalars])

    def update(self, memory: FeatureMemory, error, accepted):
        log_errors = jnp.concatenate([safe_log(error, 1e-10)[None], memory.log_errors[:-1]])
        return FeatureMemory(
            log_errors=log_errors[: self.history],
            accepted=jnp.asarray(accepted, memory.accepted.dtype),
            span=memory.span,
        )
