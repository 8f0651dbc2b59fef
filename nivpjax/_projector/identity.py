import jax.numpy as jnp
import numpy as np

from .base import AbstractProjector, ProjectionContext


class Identity(AbstractProjector):
    """$P(z) = z$: no constraint. With this projector every implicit stage is an ordinary
    implicit step, and the Newton matrix is exactly the step's Jacobian."""

    def __call__(self, z, ctx: ProjectionContext):
        return jnp.asarray(z)

    def acts_on(self, n: int) -> np.ndarray:
        return np.zeros(n, bool)
