import equinox as eqx
import numpy as np

from .._projector import CoulombFriction
from .base import AbstractEffect, OnScene


class Friction(AbstractEffect):
    r"""Coulomb friction on velocity components, without extra states:
    $0 \in R(y) + c\,\partial\phi(v)$ with $\phi(v) = \sum_i |v_i|$ (interval friction, one
    independent bound per component) or $\phi(v) = |v|$ (`isotropic=True`: 2-D disk
    friction on a tangential velocity).

    - `velocities`: indices of the sliding velocities in $x$.
    - `bound(t, x, args)`: the friction bound $c = \mu N / m$ per unit mass (a constant
      array is accepted too). State-dependent and slip-weakening laws are callables; their
      derivatives enter Newton's Jacobian by autodiff.

    See [`nivpjax.CoulombFriction`][] for the proximal map and its Jacobian.
    """

    velocities: tuple[int, ...] = eqx.field(static=True)
    bound: object
    isotropic: bool = eqx.field(static=True, default=False)
    name: str = eqx.field(static=True, default="friction")

    def __init__(self, velocities, bound, isotropic=False, name="friction"):
        self.velocities = tuple(int(i) for i in np.atleast_1d(velocities))
        self.bound = bound
        self.isotropic = isotropic
        self.name = name

    def blocks(self, n_states, offset):
        bound = OnScene(self.bound, n_states) if callable(self.bound) else self.bound
        return [(self.velocities, CoulombFriction(bound, isotropic=self.isotropic))]
