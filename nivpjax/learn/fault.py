r"""The reference's fault study as a learning task: [`nivpjax.scenes.fault`][] with random
draws of $(D_c, \Delta\mu, \text{over-stress})$, and the study's own step-size environment
(its action, observation, reward and episode) as pure functions, in the graph.

The study's code (`solve_nivp`'s `rl/env.py` and the `2d_Fault*.ipynb` notebooks of its
companion study) is the reference for every definition here; where this module departs
from it, the docstring says so and why."""

import math
import os
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np

from .. import scenes
from .._elastic import spectral_apply
from .._nonlinear import FixedPointVI
from .._results import RESULTS
from .._stepper import AbstractStepper, Bathe
from ._task import Task


class FaultSampler(eqx.Module):
    r"""Random draws of the fault's parameters, `key -> (x0, args)`: $D_c$ and $\Delta\mu$
    uniform in their ranges, the initial over-stress $\epsilon$ log-uniform; the initial
    state is the study's, $v = s = 0$, $u = (1 + \epsilon)\,u_c$ with
    $u_c = -K^{-1}(\mu_r + \Delta\mu)\sigma$ (linear in $\mu_r + \Delta\mu$, so it is the
    fixed `u_unit` scaled). Also carries what the study's observation needs: the grid and
    the units."""

    args: dict
    u_unit: Any  # -K^{-1} sigma: u_c per unit peak friction coefficient
    Dc: tuple[float, float]
    delta_mu: tuple[float, float]
    overstress: tuple[float, float]
    nx: int = eqx.field(static=True)
    nz: int = eqx.field(static=True)
    time_unit_ms: float
    velocity_unit: float  # mm/ms (= m/s) per nondimensional velocity unit

    def __call__(self, key):
        k1, k2, k3 = jr.split(key, 3)
        dtype = self.u_unit.dtype
        Dc = jr.uniform(k1, (), dtype, *self.Dc)
        delta_mu = jr.uniform(k2, (), dtype, *self.delta_mu)
        lo, hi = (math.log(x) for x in self.overstress)
        eps = jnp.exp(jr.uniform(k3, (), dtype, lo, hi))
        args = dict(self.args, Dc=Dc, delta_mu=delta_mu)
        u0 = (1 + eps) * self.instability(args)
        zeros = jnp.zeros_like(u0)
        return jnp.concatenate([zeros, u0, zeros]), args

    def instability(self, args):
        """$u_c$ of a draw: where every cell is at its static limit."""
        return (args["mu_res"] + args["delta_mu"]) * self.u_unit

    def stiffness(self, args, u):
        """$K u$ with the draw's kernel (dense or spectral)."""
        if "K" in args:
            return args["K"] @ u
        return spectral_apply(args["symbol"].astype(u.dtype), u, self.nx, self.nz)


def fault_task(
    kernel="spectral",
    nx=None,
    nz=None,
    *,
    length=3.0,
    depth=3.0,
    t1=None,
    Dc=(500.0, 2000.0),
    delta_mu=(0.05, 0.15),
    overstress=(1e-6, 1e-4),
    stepper: AbstractStepper | None = None,
    rtol=1e-3,
    atol=1e-6,
    max_steps=2000,
    reference_rtol=1e-7,
    reference_atol=1e-9,
    reference_max_steps=50_000,
    n_eval=10,
    **scene_kwargs,
) -> Task:
    r"""A [`nivpjax.learn.Task`][] on the study's fault ([`nivpjax.scenes.fault`][]).

    - `kernel`, `nx`, `nz`, `length`, `depth` and `scene_kwargs`: as for the scene; a
      `kernel` that is a path (`.npy`) is read with [`nivpjax.scenes.load_fault_kernel`][].
    - `t1`: default the study's 30 s in the scene's time unit (34.641 for a 3 km patch).
    - `Dc`, `delta_mu`: uniform ranges (the study: 1000 and 0.1); `overstress`: the
      log-uniform range of $\epsilon$ in $u = (1 + \epsilon) u_c$ (the study: 1e-5).
    - `stepper`: default the study's scheme, [`nivpjax.Bathe`][] with
      [`nivpjax.FixedPointVI`][] (its `"composite"` method with the `"VI"` solver).
    - the remaining arguments: as for [`nivpjax.learn.Task`][] (the reference is tight,
      `reference_rtol` 1e-7).

    The task serves both environments: nivpjax's own ([`nivpjax.learn.StepSizeEnv`][],
    [`nivpjax.StepFeatures`][] and [`nivpjax.learn.Objective`][], and
    [`nivpjax.learn.train`][]) and the study's ([`nivpjax.learn.FaultEnv`][]).
    """
    if isinstance(kernel, os.PathLike) or (isinstance(kernel, str) and kernel != "spectral"):
        kernel = scenes.load_fault_kernel(kernel)
    for name, (lo, hi) in (("Dc", Dc), ("delta_mu", delta_mu), ("overstress", overstress)):
        if not 0 < lo <= hi:
            raise ValueError(f"`{name}` must be a range (lo, hi) with 0 < lo <= hi, got {lo, hi}.")
    with jax.ensure_compile_time_eval():
        scene, x0, args = scenes.fault(
            kernel, nx, nz, length=length, depth=depth, overshoot=0.0, **scene_kwargs
        )
    n = scene.n_states // 3
    mu0 = float(args["mu_res"]) + float(args["delta_mu"])
    grid_nx, grid_nz = scenes._fault_grid(kernel, nx, nz)
    units = scenes.fault_units(
        length,
        scene_kwargs.get("shear_modulus", 3e4),
        slip_unit=scene_kwargs.get("slip_unit", 0.1),
    )
    sampler = FaultSampler(
        args=args,
        u_unit=jnp.asarray(np.asarray(x0)[n : 2 * n] / mu0),
        Dc=(float(Dc[0]), float(Dc[1])),
        delta_mu=(float(delta_mu[0]), float(delta_mu[1])),
        overstress=(float(overstress[0]), float(overstress[1])),
        nx=grid_nx,
        nz=grid_nz,
        time_unit_ms=float(units["time_ms"]),
        velocity_unit=float(units["velocity_mm_per_ms"]),
    )
    t1 = 30_000.0 / units["time_ms"] if t1 is None else t1
    return Task(
        scene,
        sampler,
        t1=float(t1),
        rtol=rtol,
        atol=atol,
        stepper=Bathe(solver=FixedPointVI()) if stepper is None else stepper,
        n_eval=n_eval,
        max_steps=max_steps,
        reference_rtol=reference_rtol,
        reference_atol=reference_atol,
        reference_max_steps=reference_max_steps,
    )


def mean_final_slip(task: Task, y):
    """The study's accuracy measure: the mean cumulated slip $\\bar s$ of a state."""
    n = task.scene.n_states // 3
    return jnp.mean(y[..., 2 * n : 3 * n], axis=-1)


def study_error(y_lo, y_hi, rtol=1e-3, atol=1e-6, order=1):
    r"""The study's step-doubling error (`AdaptiveStepperEnv._get_E`):
    $E = \operatorname{RMS}_i\,\frac{(y_{\text{lo},i} - y_{\text{hi},i})/(2^p - 1)}
    {\text{atol} + \text{rtol}\max(|y_{\text{lo},i}|, |y_{\text{hi},i}|)}$ over all
    components, with $y_\text{lo}$ the full step and $y_\text{hi}$ the two half steps."""
    scale = atol + rtol * jnp.maximum(jnp.abs(y_lo), jnp.abs(y_hi))
    e = (y_lo - y_hi) / (2.0**order - 1.0) / scale
    return jnp.sqrt(jnp.mean(e**2))


class FaultEnvParams(eqx.Module):
    r"""Runtime parameters of [`nivpjax.learn.FaultEnv`][]: `alpha`, the weight
    $\alpha$ of the error in the reward $e^{-\alpha E}$ (the study sweeps it; its trainer
    uses 8)."""

    alpha: float = 8.0


class FaultEnvState(eqx.Module):
    """One episode of [`nivpjax.learn.FaultEnv`][]: time, state and the drawn parameters
    (`draw`: the entries of `args` that differ between draws; `FaultEnv.args(state)` is
    the full `args`); the running extremes of the per-step cost (for $S_2$); counters; and
    the last observation."""

    t: Any
    y: Any
    draw: Any
    energy_c: Any  # elastic energy at the instability, the observation's unit
    cost_min: Any
    cost_max: Any
    steps: Any
    n_accepted: Any
    n_rejected: Any
    n_iterations: Any
    done: Any
    obs: Any


_DRAWN = ("Dc", "delta_mu")  # the entries of `args` that FaultSampler draws
_NOT_RUN = 2.0  # the study's placeholder residual of a solve it did not run


class FaultEnv(eqx.Module):
    r"""The study's step-size environment on a [`nivpjax.learn.fault_task`][], as pure
    functions (gymnax's convention: `reset(key, params)`, `step(key, state, action,
    params)`); `jit` and `vmap` over keys, states and actions.

    **Action** $a \in [0, 1]$ (clipped): $\Delta t = \Delta t_{\min} + a(\Delta t_{\max} -
    \Delta t_{\min})$, $\Delta t_{\min}$ = 1e-6 (nondimensional), $\Delta t_{\max}$ = 6 s
    in the task's time unit.

    **Step** (step doubling): one step of $\Delta t$ ($y_\text{lo}$) and two of
    $\Delta t/2$ ($y_\text{hi}$, propagated) with the task's stepper. The step is accepted
    whenever the three nonlinear solves converge (no error-based rejection); a rejected
    step leaves the state as it was. $E$ = [`nivpjax.learn.fault.study_error`][] with
    $p = 1$, atol 1e-6, rtol 1e-3.

    **Reward**: rejected, $-(\Delta t - \Delta t_{\min})/(\Delta t_{\max} - \Delta t_{\min})$;
    accepted, $S_1 S_2 e^{-\alpha E}$ with $S_1$ the taken step normalised the same way
    (clipped to $[0, 1]$) and $S_2 = 1 - (c - c_{\min})/\max(10^{-8}, c_{\max} - c_{\min})$,
    $c$ the step's cost and $c_{\min}, c_{\max}$ the extremes over the accepted steps so far
    (this one included).

    **Observation** (6 features, as the study's `obs_fn`): (0) the elastic energy
    $\tfrac12 u^T K u$ over its value at the instability $\tfrac12 u_c^T K u_c$; (1) the
    mean slip rate over its expected peak, 0.07 m/s; (2) the sum of the three solves' final
    residual norms over 4 (a solve not run counts 2, the study's placeholder); (3) converged
    (1 or 0); (4) $1/(1 + E)$ if converged, else 0; (5) the normalised requested step, signed
    $+$ if accepted and $-$ if not. After `reset`: the energy and slip-rate features of the
    initial state and the study's placeholders $(0.5, 0, 0, -0.5)$.

    **Episode**: done at $t_1$, or after `max_steps` actions (truncated; default the task's
    `max_steps`). After `done`, steps change nothing and return reward 0.

    **Departures from the study, deliberate:**

    - $S_2$'s cost $c$ is a deterministic proxy, the step's nonlinear iterations (of the
      solves run), instead of its measured wall time (`cost="wall"` is not offered: wall
      time does not exist inside a compiled program and would make the rewards
      irreproducible). The running extremes restart with each episode (the study's
      persist across episodes, on the environment object).
    - The last step is shortened to land on $t_1$ (the study's may overshoot it); the
      reward's $S_1$ uses the step taken, as the study's does.
    - Residual norms are nivpjax's (the largest final residual over a step's stages),
      not the study's VI residual; feature 2 has the same role, not the same scale.
    - Non-finite candidates count as not converged.

    **Arguments:** `task` (its `sample` a [`nivpjax.learn.fault.FaultSampler`][], as
    [`nivpjax.learn.fault_task`][] makes), `dt_min`, `dt_max` (default 6 s in the task's
    unit), `rtol`, `atol`, `order` ($p$), `v_peak` (m/s), `max_steps`.
    """

    task: Task
    dt_min: float = 1e-6
    dt_max: float | None = None
    rtol: float = 1e-3
    atol: float = 1e-6
    order: int = eqx.field(static=True, default=1)
    v_peak: float = 0.07
    max_steps: int | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if not isinstance(self.task.sample, FaultSampler):
            raise TypeError("`task` must come from nivpjax.learn.fault_task (a FaultSampler).")
        if not 0 < self.dt_min < self.dt_range[1]:
            raise ValueError(f"`dt_min` must lie in (0, dt_max), got {self.dt_min}.")

    @property
    def sampler(self) -> FaultSampler:
        return self.task.sample

    @property
    def dt_range(self):
        hi = 6_000.0 / self.sampler.time_unit_ms if self.dt_max is None else self.dt_max
        return self.dt_min, hi

    @property
    def episode_steps(self) -> int:
        return self.task.max_steps if self.max_steps is None else self.max_steps

    @property
    def obs_size(self) -> int:
        return 6

    @property
    def action_bounds(self):
        return 0.0, 1.0

    def default_params(self) -> FaultEnvParams:
        return FaultEnvParams()

    def args(self, state: FaultEnvState):
        """The scene's `args` of the episode's draw (the fixed kernel is not in the state:
        it would be copied by every batched and selected state)."""
        return dict(self.sampler.args, **state.draw)

    def _physics(self, y, args, energy_c):
        n = self.task.scene.n_states // 3
        v, u = y[:n], y[n : 2 * n]
        energy = 0.5 * jnp.dot(u, self.sampler.stiffness(args, u))
        v_peak = self.v_peak / self.sampler.velocity_unit
        return energy / energy_c, jnp.mean(v) / v_peak

    def reset(self, key, params: FaultEnvParams | None = None):
        x0, args = self.task.sample(key)
        y0 = self.task.scene.initial_state(jnp.asarray(x0))
        dtype = y0.dtype
        u_c = self.sampler.instability(args).astype(dtype)
        energy_c = 0.5 * jnp.dot(u_c, self.sampler.stiffness(args, u_c))
        energy, rate = self._physics(y0, args, energy_c)
        obs = jnp.stack([energy, rate, *jnp.asarray([0.5, 0.0, 0.0, -0.5], dtype)]).astype(dtype)
        zero = jnp.zeros((), jnp.int32)
        state = FaultEnvState(
            t=jnp.asarray(self.task.t0, dtype),
            y=y0,
            draw={k: args[k] for k in _DRAWN},
            energy_c=energy_c,
            cost_min=jnp.asarray(jnp.inf, dtype),
            cost_max=jnp.asarray(-jnp.inf, dtype),
            steps=zero,
            n_accepted=zero,
            n_rejected=zero,
            n_iterations=zero,
            done=jnp.zeros((), bool),
            obs=obs,
        )
        return obs, state

    def doubling(self, t, h, y, args):
        """The three solves of a step of `h` from `(t, y)`: `(full, half1, half2)`
        [`nivpjax.StepOutput`][]s (the full step and the first half step batched, as
        [`nivpjax.Richardson`][] does)."""
        model, _ = self.task.model()
        stepper = self.task.stepper
        both = jax.vmap(lambda hh: stepper.step(model, t, hh, y, args))(jnp.stack([h, 0.5 * h]))
        full = jax.tree.map(lambda x: x[0], both)
        half1 = jax.tree.map(lambda x: x[1], both)
        half2 = stepper.step(model, t + 0.5 * h, 0.5 * h, half1.y1, args)
        return full, half1, half2

    def step(self, key, state: FaultEnvState, action, params: FaultEnvParams | None = None):
        del key  # deterministic given the draw
        params = self.default_params() if params is None else params
        dtype = state.y.dtype
        lo, hi = self.dt_range
        a = jnp.clip(jnp.asarray(action, dtype).reshape(-1)[0], 0.0, 1.0)
        dt = lo + a * (hi - lo)
        t1 = jnp.asarray(self.task.t1, dtype)
        h = jnp.minimum(dt, t1 - state.t)
        h = jax.lax.stop_gradient(jnp.where(h > 0, h, dt))  # finished members keep h > 0
        args = self.args(state)
        full, half1, half2 = self.doubling(state.t, h, state.y, args)
        ok = [s.stats.nonlinear_result == RESULTS.successful for s in (full, half1, half2)]
        ran = [jnp.ones((), bool), ok[0], ok[0] & ok[1]]  # the study stops at a failure
        converged = ok[0] & ok[1] & ok[2] & jnp.all(jnp.isfinite(half2.y1))
        converged = converged & jnp.all(jnp.isfinite(full.y1))
        E = study_error(full.y1, half2.y1, self.rtol, self.atol, self.order)
        converged = converged & jnp.isfinite(E)
        E = jnp.where(converged, E, 0.0)
        outs = (full, half1, half2)
        residual = sum(
            jnp.where(r, jnp.nan_to_num(o.stats.residual_norm, nan=1e10, posinf=1e10), _NOT_RUN)
            for r, o in zip(ran, outs)
        )
        iterations = sum(jnp.where(r, o.stats.iterations, 0) for r, o in zip(ran, outs))
        cost = iterations.astype(dtype)
        cost_min = jnp.where(converged, jnp.minimum(state.cost_min, cost), state.cost_min)
        cost_max = jnp.where(converged, jnp.maximum(state.cost_max, cost), state.cost_max)
        span = hi - lo
        s1 = jnp.clip((h - lo) / span, 0.0, 1.0)
        width = jnp.maximum(1e-8, cost_max - cost_min)
        s2 = 1.0 - (cost - cost_min) / jnp.where(converged, width, 1.0)
        reward = jnp.where(converged, s1 * s2 * jnp.exp(-params.alpha * E), -(dt - lo) / span)
        t_new = jnp.where(converged, jnp.where(h >= t1 - state.t, t1, state.t + h), state.t)
        y_new = jnp.where(converged, half2.y1, state.y)
        energy, rate = self._physics(y_new, args, state.energy_c)
        sign = jnp.where(converged, 1.0, -1.0)
        flag = converged.astype(dtype)
        obs = jnp.stack(
            [energy, rate, residual / 4.0, flag, flag / (1.0 + E), sign * (dt - lo) / span]
        ).astype(dtype)
        steps = state.steps + 1
        at_end = t_new >= t1
        truncated = ~at_end & (steps >= self.episode_steps)
        candidate = FaultEnvState(
            t=t_new,
            y=y_new,
            draw=state.draw,
            energy_c=state.energy_c,
            cost_min=cost_min,
            cost_max=cost_max,
            steps=steps,
            n_accepted=state.n_accepted + converged.astype(jnp.int32),
            n_rejected=state.n_rejected + (~converged).astype(jnp.int32),
            n_iterations=state.n_iterations + iterations.astype(jnp.int32),
            done=at_end | truncated,
            obs=obs,
        )
        keep = state.done
        out = jax.tree.map(lambda old, x: jnp.where(keep, old, x), state, candidate)
        info = {
            "t": out.t,
            "h": h,
            "dt": dt,
            "E": E,
            "converged": converged & ~keep,
            "iterations": jnp.where(keep, 0, iterations),
            "residual": residual,
            "terminated": at_end & ~keep,
            "truncated": truncated & ~keep,
        }
        return out.obs, out, jnp.where(keep, 0.0, reward).astype(dtype), out.done, info
