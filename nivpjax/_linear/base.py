"""Interface of the linear solve inside semismooth Newton: how the Newton direction and the
implicit-function-theorem solve are computed from the natural map $G$."""

import abc
from collections.abc import Callable
from typing import Any

import equinox as eqx
from jaxtyping import Array, Bool, Float, Int


Map = Callable[[Array], Array]


class AbstractLinearSolver(eqx.Module):
    r"""How a Newton iteration solves $G'(y)\,d = -G(y)$, $G'$ an element of the
    generalised Jacobian of the natural map (the projectors' custom JVPs select it), and
    how the implicit function theorem solves $g(x) = b$ with $g$ the linearisation of $G$
    at the solution.

    A strategy is static configuration plus a small state carried between the Newton
    iterations of one solve (a forcing term, a warm start); it never writes to itself.
    """

    @abc.abstractmethod
    def init(self, y: Float[Array, " n"]) -> Any:
        """The state before the first Newton iteration of a solve from `y`."""

    @abc.abstractmethod
    def direction(
        self,
        G: Map,
        y: Float[Array, " n"],
        g: Float[Array, " n"],
        scale,
        state,
        linearize: Callable[[], Map] | None = None,
    ) -> tuple[Float[Array, " n"], Bool[Array, ""], Int[Array, ""], Any]:
        r"""`(d, ok, linear_iterations, state)`: the Newton direction $d$ with
        $G'(y)\,d \approx -g$ ($g = G(y)$), whether it is usable (finite; for an inexact
        solve, not necessarily to its tolerance: the nonlinear test decides), the Krylov
        iterations it took (0 for direct solves), and the next state. `scale`: the
        per-component tolerance $\text{atol} + \text{rtol}|y|$ of the nonlinear test.
        `linearize`: where given, returns $v \mapsto G'(y)\,v$ more cheaply than
        `jax.linearize(G, y)` (semismooth Newton knows the projection's argument at $y$)."""

    @abc.abstractmethod
    def tangent_solve(self, g: Map, b: Float[Array, " n"]) -> Float[Array, " n"]:
        r"""$x$ with $g(x) = b$, for `jax.lax.custom_root`: linear in `b` and
        transposable (reverse mode solves with $g^\top$). A solve that fails returns NaN,
        never a wrong finite derivative."""

    def resolve(self, n: int) -> "AbstractLinearSolver":
        """The strategy actually used for `n` unknowns (itself unless it chooses)."""
        return self
