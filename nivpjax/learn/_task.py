"""What a step-size policy is trained on: a scene with random parameter draws, and the
objective that weighs work against accuracy."""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._controller import AbstractController, PIDController, PolicyController
from .._model import Model
from .._results import RESULTS
from .._scene import Scene
from .._solution import Solution
from .._stepper import AbstractStepper, Bathe, Richardson
from .._validate import check_mass_matrix


class Task(eqx.Module):
    """A family of initial-value problems to learn step sizes on.

    **Arguments:**

    - `scene`: a [`nivpjax.Scene`][].
    - `sample`: `key -> (x0, args)`, one random draw of the scene's initial state and
      parameters (pure JAX, so draws are made inside compiled, vmapped programs).
    - `t1`, `t0`: the interval.
    - `rtol`, `atol`: the error test of the learned controller (and of PID in comparisons).
    - `stepper`: default [`nivpjax.Bathe`][] (wrapped in [`nivpjax.Richardson`][] if
      it has no embedded estimate).
    - `n_eval`: accuracy is measured at `n_eval` equally spaced output times in $(t_0, t_1]$.
    - `max_steps`: attempt budget of a rollout (reaching it is a failure).
    - `reference_rtol`, `reference_atol`, `reference_max_steps`: the tight PID solve that
      accuracy is measured against.
    """

    scene: Scene
    sample: Callable[[Any], tuple[Any, Any]]
    t1: float
    t0: float = 0.0
    rtol: float = 1e-4
    atol: float = 1e-7
    stepper: AbstractStepper = Bathe()
    n_eval: int = eqx.field(static=True, default=20)
    max_steps: int = eqx.field(static=True, default=1000)
    reference_rtol: float = 1e-8
    reference_atol: float = 1e-10
    reference_max_steps: int = eqx.field(static=True, default=20000)

    def __check_init__(self):
        if not isinstance(self.scene, Scene):
            raise TypeError(f"`scene` must be a nivpjax.Scene, got {self.scene!r}.")
        if not callable(self.sample):
            raise TypeError(f"`sample` must be callable key -> (x0, args), got {self.sample!r}.")
        if not float(self.t1) > float(self.t0):
            raise ValueError(f"`t1` must be greater than `t0`, got {self.t0}, {self.t1}.")
        for name in ("rtol", "atol", "reference_rtol", "reference_atol"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"`{name}` must be positive, got {getattr(self, name)}.")

    @property
    def t_eval(self):
        return jnp.linspace(self.t0, self.t1, self.n_eval + 1)[1:]

    @property
    def full_stepper(self) -> AbstractStepper:
        """The stepper with an error estimate (Richardson if it has no embedded one)."""
        return Richardson(self.stepper) if self.stepper.error_order == 0 else self.stepper

    def solve(self, controller: AbstractController, x0, args, *, max_steps=None, **kwargs):
        """Solve one draw with `controller` (no throw, forward adjoint by default); the
        solution carries `y_eval` at the task's output times."""
        kwargs.setdefault("adjoint", "forward")
        return self.scene.solve(
            self.t0,
            self.t1,
            x0,
            args,
            stepper=self.stepper,
            controller=controller,
            t_eval=self.t_eval,
            max_steps=self.max_steps if max_steps is None else max_steps,
            throw=False,
            **kwargs,
        )

    def reference(self, x0, args):
        """`y_eval` of the tight reference solve (stop-gradient), and whether it succeeded."""
        pid = PIDController(rtol=self.reference_rtol, atol=self.reference_atol)
        sol = self.solve(pid, x0, args, max_steps=self.reference_max_steps)
        ok = sol.result == RESULTS.successful
        return jax.lax.stop_gradient(sol.y_eval), ok

    def policy_controller(self, policy, **kwargs) -> PolicyController:
        """A [`nivpjax.PolicyController`][] with this task's tolerances."""
        return PolicyController(policy, rtol=self.rtol, atol=self.atol, **kwargs)

    def model(self) -> tuple[Model, Any]:
        """The assembled [`nivpjax.Model`][] and error mask (what `solve` builds)."""
        scene = self.scene
        A, algebraic = check_mass_matrix(scene.full_mass_matrix, scene.size, np.float64)
        rows = scene.equation_rows
        model = Model.build(
            scene.vector_field,
            scene.projector,
            A,
            algebraic,
            tau=1.0,
            equation_rows=None if rows is None else jnp.asarray(rows),
        )
        return model, jnp.asarray(~algebraic)


class Objective(eqx.Module):
    r"""The cost of one rollout (lower is better):

    $$ w_a\,\text{attempts} + w_i\,\text{iterations} + w_r\,\text{rejections}
       + w_e \max(0, \log(E / E_\star)) + w_f\,[\text{failed}], $$

    where $E$ is the RMS over output times and differential components of
    $(y - y_{\text{ref}})/(\text{atol} + \text{rtol}|y_{\text{ref}}|)$ (the task's
    tolerances), $E_\star$ = `error_target`. Work counts are deterministic (from the
    [`nivpjax.Solution`][]); wall time is reported, never optimised. A failed rollout
    (`max_steps`, `h_min`, nonlinear failure) pays `failure` and no accuracy term.
    """

    attempts: float = 1.0
    iterations: float = 0.1
    rejections: float = 1.0
    error: float = 20.0
    failure: float = 1000.0
    error_target: float = 1.0

    def work(self, attempts, iterations, rejections):
        return (
            self.attempts * attempts + self.iterations * iterations + self.rejections * rejections
        )

    def accuracy(self, error):
        error = jnp.where(jnp.isfinite(error), error, 1.0)
        ratio = jnp.maximum(error, 1e-300) / self.error_target
        return self.error * jnp.maximum(jnp.log(ratio), 0.0)


def scaled_error(task: Task, y_eval, y_ref):
    """RMS scaled error of `y_eval` against the reference (differential components)."""
    n = task.scene.n_states
    diff = (y_eval[:, :n] - y_ref[:, :n]) / (task.atol + task.rtol * jnp.abs(y_ref[:, :n]))
    diff = jnp.where(jnp.isfinite(diff), diff, 0.0)
    return jnp.sqrt(jnp.mean(diff**2))


class Metrics(eqx.Module):
    """Deterministic counts and accuracy of rollouts (arrays, one entry per draw)."""

    attempts: Any
    rejections: Any
    iterations: Any
    error: Any
    failed: Any
    cost: Any


def metrics(task: Task, objective: Objective, sol: Solution, y_ref) -> Metrics:
    """The [`nivpjax.learn.Metrics`][] of one solution against its reference."""
    failed = sol.result != RESULTS.successful
    attempts = sol.n_accepted + sol.n_rejected
    # `Task.solve` interpolates at the task's output times as steppers take their steps
    # (a chord between a ball's long steps was its error, 1e5 of the tolerance).
    error = jnp.where(failed, jnp.inf, scaled_error(task, sol.y_eval, y_ref))
    dtype = sol.ys.dtype
    cost = objective.work(
        attempts.astype(dtype), sol.n_iterations.astype(dtype), sol.n_rejected.astype(dtype)
    )
    cost = cost + jnp.where(failed, objective.failure, objective.accuracy(error))
    return Metrics(attempts, sol.n_rejected, sol.n_iterations, error, failed, cost)
