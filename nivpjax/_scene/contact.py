import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._projector import Bound, FrictionalContact, HeldGaps, UnilateralContact
from .base import AbstractEffect, OnScene, scene_state
from .curvature import gap_is_affine, gap_reads_time


class Contact(AbstractEffect):
    r"""Unilateral contacts with Newton restitution on a mechanical state $x = (\dots q \dots,
    \dots v \dots)$ with $q' = v$: gaps $g(q) \ge 0$, impact law
    $0 \le u^+ + e u^- \perp p \ge 0$ with $u = \nabla g^T v$.

    - `gap(t, x, args) -> (m,)`: signed distances, of the positions and parameters only
      (a gap that reads `t`, a moving surface, is refused: the laws take its rate as
      $\nabla g^T v$).
    - `positions`, `velocities`: indices of $q$ and $v$ in $x$ (same length).
    - `restitution`: $e$, scalar, per contact, or callable `(t, y, args)`.
    - `inverse_mass`: $M^{-1}$ (constant, `(n_dof, n_dof)`), default identity: impulses
      change velocities by $M^{-1} \nabla g\, p$.

    - `curved`: whether the gap is not affine in the positions (a wall that bends: a
      bowl, a circular track, a cam; static). A closed contact on such a gap drifts off
      it by $O(h^2)$ per step at velocity level, and its reaction turns with the normal:
      with `curved=True` persistent contacts are held on their gap at position level
      ([`nivpjax.HeldGaps`][]) and their reaction is weighed at both ends of the
      trapezoidal stages, which keeps Bathe's scheme and the trapezoidal rule at second
      order (backward Euler at first). A flat gap needs neither. The default `None`
      decides when the scene is solved, from the gap's traced Hessian in the positions
      (zero whatever the state and the parameters: flat; see `resolved`); a projector
      built from an unresolved contact treats it as flat.

    - `friction`: Coulomb's $\mu$ (scalar array or callable `(t, x, args)`), default
      `None` (frictionless): the contact's impulse $p_n$ then comes with a friction impulse
      in the tangent plane, $|p_t| \le \mu\,p_n$, opposing the tangential velocity
      ([`nivpjax.FrictionalContact`][]): a ball sliding or sticking on a wall. One
      contact (`gap` of length 1), and an isotropic mass only (`inverse_mass` `None` or
      a positive multiple of the identity: the normal and tangential impulses then
      decouple; a general mass couples them through $W^T M^{-1} W$).

    The contact normals $W^T = \partial g / \partial q$ come from autodiff of `gap`. See
    [`nivpjax.UnilateralContact`][] for the active set, the LCP and event location.
    """

    gap: object
    positions: tuple[int, ...] = eqx.field(static=True)
    velocities: tuple[int, ...] = eqx.field(static=True)
    restitution: Bound = 0.0
    inverse_mass: object = None
    lookahead: float = 0.5
    name: str = eqx.field(static=True, default="contact")
    curved: bool | None = eqx.field(static=True, default=None)
    friction: Bound | None = None

    def __init__(
        self,
        gap,
        positions,
        velocities,
        restitution=0.0,
        inverse_mass=None,
        lookahead=0.5,
        name="contact",
        curved=None,
        friction=None,
    ):
        self.gap = gap
        self.positions = tuple(int(i) for i in np.atleast_1d(positions))
        self.velocities = tuple(int(i) for i in np.atleast_1d(velocities))
        if len(self.positions) != len(self.velocities):
            raise ValueError("`positions` and `velocities` must have the same length.")
        self.restitution = restitution
        self.inverse_mass = None if inverse_mass is None else jnp.asarray(inverse_mass)
        self.lookahead = lookahead
        self.name = name
        self.curved = None if curved is None else bool(curved)
        if friction is not None and inverse_mass is not None:
            _check_isotropic(inverse_mass)
        if friction is not None and not callable(friction):
            mu = np.asarray(friction)
            if mu.size != 1 or not np.isfinite(mu).all() or mu.reshape(()) < 0:
                raise ValueError(
                    "`friction` must be one finite coefficient >= 0 or a callable, got "
                    f"{friction!r}."
                )
        self.friction = friction

    def _check_gap(self, t, x, args):
        # Friction is for one contact: the gap's length is read off its shape.
        m = jax.eval_shape(lambda: jnp.atleast_1d(self.gap(t, x, args))).shape[0]
        if self.friction is not None and m != 1:
            raise ValueError(f"`friction` needs one contact (`gap` of length 1), got {m}.")
        if gap_reads_time(self.gap, t, x, args):
            # The contact laws read the gap's rate as W^T v: a surface that moves would pass
            # through the body unseen (a floor rising under a ball at rest: `successful`,
            # the ball left 1 m below it after 1 s).
            raise ValueError(
                "`gap` depends on the time `t`: moving surfaces are not supported (the "
                "contact's normal velocity is dg/dq . v, without dg/dt). Write the gap "
                "in the positions and parameters only."
            )

    def resolved(self, t, x, args) -> "Contact":
        """With `curved=None`, this contact with `curved` set: `False` when the Hessian
        of `gap` in the positions is zero whatever the state and the parameters (read
        off its traced program, at trace time), `True` otherwise."""
        self._check_gap(t, x, args)
        if self.curved is not None:
            return self
        affine = gap_is_affine(self.gap, self.positions, t, x, args)
        return dataclasses.replace(self, curved=not affine)

    def blocks(self, n_states, offset):
        normals = _Normals(self.gap, n_states, self.positions)
        impulse_map = None if self.inverse_mass is None else _Impulses(normals, self.inverse_mass)
        projector = UnilateralContact(
            gap=_Gaps(self.gap, n_states),
            velocity_map=normals,
            impulse_map=impulse_map,
            restitution=self.restitution,
            lookahead=self.lookahead,
            weighed=bool(self.curved),
        )
        on_velocities = projector
        if self.friction is not None:
            mu = OnScene(self.friction, n_states) if callable(self.friction) else self.friction
            on_velocities = FrictionalContact(projector, mu)
        if not self.curved:
            return [(self.velocities, on_velocities)]
        return [
            (self.velocities, on_velocities),
            (self.positions, HeldGaps(projector, self.velocities)),
        ]


def _check_isotropic(inverse_mass):
    # Friction's impulses decouple from the normal one for M^-1 = c I (c > 0) only.
    try:
        m = np.asarray(inverse_mass, float)
    except Exception:  # a traced inverse mass: its value cannot be checked
        m = None
    ok = m is not None and m.ndim == 2 and m.shape[0] == m.shape[1] and m.size > 0
    ok = ok and m[0, 0] > 0 and np.allclose(m, m[0, 0] * np.eye(m.shape[0]), rtol=0, atol=0)
    if not ok:
        raise ValueError(
            "`friction` needs an isotropic mass (`inverse_mass` None or a concrete positive "
            f"multiple of the identity), got inverse_mass={inverse_mass!r}."
        )


class _Gaps(eqx.Module):
    gap: object
    n_states: int = eqx.field(static=True)

    def __call__(self, t, y, args):
        return jnp.atleast_1d(self.gap(t, scene_state(y, self.n_states), args))


class _Normals(eqx.Module):
    # W^T = dg/dq by autodiff of the gap function.
    gap: object
    n_states: int = eqx.field(static=True)
    positions: tuple[int, ...] = eqx.field(static=True)

    def __call__(self, t, y, args):
        # Forward mode along the positions' unit vectors of the whole state: the same
        # derivatives as differentiating in q after scattering it into x, without the
        # scatter and gather (about 45 traced operations a call; the solve calls it dozens
        # of times).
        x = scene_state(y, self.n_states)
        basis = np.eye(self.n_states, dtype=x.dtype)[list(self.positions)]
        gap = lambda x: jnp.atleast_1d(self.gap(t, x, args))  # noqa: E731
        return jax.vmap(lambda e: jax.jvp(gap, (x,), (e,))[1], out_axes=1)(basis)


class _Impulses(eqx.Module):
    normals: _Normals
    inverse_mass: object

    def __call__(self, t, y, args):
        return self.inverse_mass @ self.normals(t, y, args).T
