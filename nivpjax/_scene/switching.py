"""Multiplier effects: relays (Filippov sliding), saturation, ideal diodes, user sets."""

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._projector import AbstractProjector, Box, EventLocated, NonNegative
from .base import AbstractEffect, OnScene, scene_state
from .bounds import check_bounds


class _SaturationSurface(eqx.Module):
    signal: Callable
    n_states: int = eqx.field(static=True)
    lower: object
    upper: object

    def __call__(self, t, y, args):
        u = jnp.atleast_1d(self.signal(t, scene_state(y, self.n_states), args))
        return jnp.concatenate([u - self.lower, u - self.upper])


class _DiodeSurface(eqx.Module):
    # The voltage each diode would see without current: it changes sign at a switch.
    voltage: Callable
    n_states: int = eqx.field(static=True)
    n: int = eqx.field(static=True)

    def __call__(self, t, y, args):
        x = scene_state(y, self.n_states)
        return jnp.atleast_1d(self.voltage(t, x, jnp.zeros(self.n, y.dtype), args))


class Relay(AbstractEffect):
    r"""A relay / sign nonlinearity as `n` multipliers $w$ with bounds $\ell < u$:
    $w = u$ where $s(t, x) > 0$, $w = \ell$ where $s < 0$, $w \in [\ell, u]$ at $s = 0$
    (Filippov's convexification: in sliding mode $w$ takes the equivalent-control value).
    The default bounds $[-1, 1]$ make it $w \in \operatorname{sign}(s)$; others are the
    affine image $w = \ell + (u - \ell)(v + 1)/2$ of such a $v$ (Siconos' `RelayNSL`).
    The dynamics read it as `multipliers[name]`. Crossings of $s = 0$ inside a step are
    located by the step-size controller ([`nivpjax.EventLocated`][]).

    **Arguments:**

    - `name`: the key of its multipliers.
    - `switch`: `switch(t, x, args) -> (n,)`, the switching function $s$.
    - `n`: the number of relays (default 1).
    - `lower`, `upper`: the bounds $\ell < u$ (default $-1$, $1$), scalars or arrays of
      shape `(n,)`; JAX arrays are run-time values (sweep or differentiate them).
    """

    name: str = eqx.field(static=True)
    switch: Callable
    n: int = eqx.field(static=True, default=1)
    lower: object = -1.0
    upper: object = 1.0

    def __check_init__(self):
        check_bounds(self.lower, self.upper, self.n)

    @property
    def size(self):
        return self.n

    def blocks(self, n_states, offset):
        box = Box(self.lower, self.upper)
        projector = EventLocated(box, OnScene(self.switch, n_states), saltation=True)
        return [(np.arange(offset, offset + self.n), projector)]

    def constraint(self, t, x, lam, args):
        return self.switch(t, x, args)


class Saturation(AbstractEffect):
    r"""A saturated signal $\sigma = \operatorname{clip}(u(t, x), \ell, h)$ as multipliers,
    through the VI $\sigma \in [\ell, h]$, $\langle \sigma - u, \eta - \sigma\rangle \ge 0$.
    Its rows are algebraic equations ($O(1)$ sensitivity): scaled $\rho = \tau$."""

    name: str = eqx.field(static=True)
    signal: Callable
    lower: object = -1.0
    upper: object = 1.0
    n: int = eqx.field(static=True, default=1)

    @property
    def size(self):
        return self.n

    @property
    def equation(self):
        return True

    def blocks(self, n_states, offset):
        surface = _SaturationSurface(self.signal, n_states, self.lower, self.upper)
        projector = EventLocated(Box(self.lower, self.upper), surface)
        return [(np.arange(offset, offset + self.n), projector)]

    def constraint(self, t, x, lam, args):
        return jnp.asarray(self.signal(t, x, args)) - lam


class Diode(AbstractEffect):
    r"""Ideal diodes: currents $i \ge 0$, $v_D(t, x, i) \le 0$, $i\,v_D = 0$
    (complementarity), with `voltage(t, x, i, args)` the voltage across each diode (anode
    minus cathode) as the circuit determines it (it may depend on the diode currents through
    series resistors). Rows scaled as algebraic equations, $\rho = \tau$."""

    name: str = eqx.field(static=True)
    voltage: Callable
    n: int = eqx.field(static=True, default=1)

    @property
    def size(self):
        return self.n

    @property
    def equation(self):
        return True

    def blocks(self, n_states, offset):
        projector = EventLocated(NonNegative(), _DiodeSurface(self.voltage, n_states, self.n))
        return [(np.arange(offset, offset + self.n), projector)]

    def constraint(self, t, x, lam, args):
        return self.voltage(t, x, lam, args)


class SetValued(AbstractEffect):
    r"""A user-defined multiplier effect: `n` multipliers $\lambda \in K$ for any
    projector $K$, with algebraic rows `constraint_fn(t, x, lam, args)` (the stage solves
    $\lambda = P_K(\lambda + \rho\,\text{constraint})$). `is_equation=True` scales the rows
    as algebraic equations.

    **Arguments:**

    - `name`: the key of its multipliers.
    - `projector`: the set $K$, a [`nivpjax.AbstractProjector`][] on the `n` multipliers.
    - `constraint_fn`: `constraint_fn(t, x, lam, args) -> (n,)`, the algebraic rows.
    - `n`: the number of multipliers (default 1).
    - `is_equation`: scale the rows as algebraic equations with $O(1)$ sensitivity to
      $\lambda$ ($\rho = \tau$) rather than multipliers entering the state with weight $h$
      ($\rho = \tau / h$; default).
    """

    name: str = eqx.field(static=True)
    projector: AbstractProjector
    constraint_fn: Callable
    n: int = eqx.field(static=True, default=1)
    is_equation: bool = eqx.field(static=True, default=False)

    @property
    def size(self):
        return self.n

    @property
    def equation(self):
        return self.is_equation

    def blocks(self, n_states, offset):
        return [(np.arange(offset, offset + self.n), self.projector)]

    def constraint(self, t, x, lam, args):
        return self.constraint_fn(t, x, lam, args)


class StateEffect(AbstractEffect):
    """A user-defined effect acting directly on state components `indices` of $x$ with any
    projector (no multipliers)."""

    name: str = eqx.field(static=True)
    indices: tuple[int, ...] = eqx.field(static=True)
    projector: AbstractProjector

    def blocks(self, n_states, offset):
        return [(self.indices, self.projector)]
