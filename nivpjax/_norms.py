"""The one masked, weighted error norm used by every controller."""

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


def scaled_rms_norm(
    y_error: Float[Array, " n"],
    y0: Float[Array, " n"],
    y1: Float[Array, " n"],
    rtol,
    atol,
    mask: Bool[Array, " n"] | None = None,
) -> Float[Array, ""]:
    r"""RMS of $e_i / (\text{atol} + \text{rtol}\max(|y_{0,i}|, |y_{1,i}|))$ over the unmasked
    components (those with `mask[i] == True`). Components left out of the mask (algebraic rows,
    multipliers) do not enter the norm; with an empty mask the norm is zero."""
    scale = atol + rtol * jnp.maximum(jnp.abs(y0), jnp.abs(y1))
    ratio = y_error / scale
    if mask is None:
        return jnp.sqrt(jnp.mean(ratio**2))
    count = jnp.maximum(jnp.sum(mask), 1)
    return jnp.sqrt(jnp.sum(jnp.where(mask, ratio**2, 0.0)) / count)


def violation_scale(rtol, atol, y0: Float[Array, " n"], mask=None) -> Float[Array, ""]:
    r"""The size a step's constraint violation (`StepInfo.violation`, state units) is
    charged against: $\text{atol} + \text{rtol}\,\|y_0\|_\infty$, the start state's scale,
    over the rows the error norm judges (`mask`, the controller's `error_mask`: by
    default the differential rows). A relay's selection $|w| = 1$ counted would set the
    scale of a state of size $10^{-3}$ to rtol: its switches were crossed unseen, and a
    forced relay scaled by $10^{-3}$ ended 0.14 off (scaled back), `successful`, with
    backward Euler's pair. A projector whose violation has a natural scale of its own (a
    contact's penetration, judged like an error in its gap) converts it to this one
    (`ProjectionContext.violation_scale`)."""
    y0 = jnp.abs(y0) if mask is None else jnp.where(mask, jnp.abs(y0), 0.0)
    return atol + rtol * jnp.max(y0, initial=0.0)
