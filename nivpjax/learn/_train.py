"""Training loops: every rollout of an iteration in one compiled, vmapped program."""

import dataclasses
import sys
import time
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import optax

from .._compiler import filter_jit
from ._env import EnvParams, StepSizeEnv
from ._estimators import collect_episodes, es_gradient, reinforce_gradient
from ._policy import save_policy
from ._task import Metrics, Objective, Task, metrics


@dataclasses.dataclass
class TrainResult:
    """What [`nivpjax.learn.train`][] returns.

    - `policy`: the trained policy (same structure as the one passed in).
    - `history`: one dict per iteration: `iteration`, `objective` (mean cost of the current
      policy on the training draws; for REINFORCE the mean cost of the noisy episodes),
      `seconds` (wall time of the iteration, compile included for the first).
    - `initial`, `final`: [`nivpjax.learn.Metrics`][] of the deterministic policy on the
      training draws before and after (ES only; `None` for REINFORCE).
    - `seconds`: total wall time.
    """

    policy: Any
    history: list
    initial: Metrics | None
    final: Metrics | None
    seconds: float


@filter_jit
def _draw(task, keys):
    x0, args = jax.vmap(task.sample)(keys)
    y_ref, ok = jax.vmap(task.reference)(x0, args)
    return x0, args, y_ref, ok


def draw(task: Task, key, n: int):
    """`n` draws `(x0, args)` and their references `(y_ref, ok)`, in one compiled program."""
    return _draw(task, jr.split(key, n))


@filter_jit
def _evaluate(task, objective, controller, x0, args, y_ref):
    def one(x0, args, y_ref):
        return metrics(task, objective, task.solve(controller, x0, args), y_ref)

    return jax.vmap(one)(x0, args, y_ref)


def evaluate(task: Task, controller, x0, args, y_ref, objective: Objective = Objective()):
    """[`nivpjax.learn.Metrics`][] of `controller` on a batch of draws (one vmapped solve)."""
    return _evaluate(task, objective, controller, x0, args, y_ref)


def _bar(i, n, text):
    filled = int(30 * i / max(n, 1))
    sys.stderr.write(f"\rtraining [{'#' * filled:<30}] {i}/{n} {text}")
    if i == n:
        sys.stderr.write("\n")
    sys.stderr.flush()


def train(
    task: Task,
    policy,
    *,
    method: Literal["es", "reinforce"] = "es",
    objective: Objective = Objective(),
    optimiser: optax.GradientTransformation | None = None,
    iterations: int = 20,
    batch: int = 8,
    pairs: int = 8,
    sigma: float = 0.05,
    noise: float = 0.1,
    env: StepSizeEnv | None = None,
    horizon: int | None = None,
    seed: int = 0,
    draws=None,
    keep_best: bool = True,
    progress: bool = True,
    curve_png: str | None = None,
    save_path: str | None = None,
) -> TrainResult:
    """Trains `policy` (an equinox module `features -> log factor`) on `task`.

    - `method="es"`: antithetic evolution strategies ([`nivpjax.learn.es_gradient`][]) on
      `batch` fixed training draws: each iteration solves the draws with $2P$ perturbed
      policies (`pairs` $P$, `sigma`) and the current one, all in one compiled, vmapped
      program, through [`nivpjax.solve`][] with a [`nivpjax.PolicyController`][].
    - `method="reinforce"`: REINFORCE with a mean baseline on `batch` episodes of the
      functional environment (`env`, default `StepSizeEnv(task)`) per iteration, actions
      Gaussian around the policy's output with std `noise` (in the env's normalised units;
      build the policy with `output_scale=env.action_scale`), `horizon` steps (default
      `task.max_steps`) of a `lax.scan`.

    `draws`: optional training draws `(x0, args, y_ref)` for ES (default: `batch` draws
    from `seed`). `keep_best` (ES): return the iterate with the lowest objective on the
    training draws (the estimates are noisy; the last iterate may be worse). Reproducible
    from `seed`; `progress` draws a bar on stderr; `curve_png` writes the
    learning curve; `save_path` saves the policy ([`nivpjax.learn.save_policy`][]).
    The default optimiser is `optax.adam(1e-2)`.
    """
    if method not in ("es", "reinforce"):
        raise ValueError(f"`method` must be 'es' or 'reinforce', got {method!r}.")
    if not (isinstance(iterations, int) and iterations >= 1):
        raise ValueError(f"`iterations` must be a positive int, got {iterations!r}.")
    if not (isinstance(batch, int) and batch >= 1):
        raise ValueError(f"`batch` must be a positive int, got {batch!r}.")
    optimiser = optax.adam(1e-2) if optimiser is None else optimiser
    params, static = eqx.partition(policy, eqx.is_inexact_array)
    opt_state = optimiser.init(params)
    key_draws, key_train = jr.split(jr.PRNGKey(seed))
    start = time.perf_counter()
    history = []
    best = (float("inf"), params)
    if method == "es":
        if draws is None:
            x0, args, y_ref, _ = draw(task, key_draws, batch)
        else:
            x0, args, y_ref = draws
        step = _es_step(task, objective, optimiser, static, pairs, sigma)
        controller = lambda p: task.policy_controller(eqx.combine(p, static))
        initial = evaluate(task, controller(params), x0, args, y_ref, objective)
    else:
        env = StepSizeEnv(task) if env is None else env
        reset_keys = jr.split(key_draws, batch)
        step = _reinforce_step(env, optimiser, static, noise, horizon or task.max_steps)
        initial = None
    for i in range(iterations):
        t = time.perf_counter()
        key_i = jr.fold_in(key_train, i)
        if method == "es":
            previous = params
            params, opt_state, value = step(params, opt_state, key_i, x0, args, y_ref)
            if float(value) < best[0]:
                best = (float(value), previous)
        else:
            params, opt_state, value = step(params, opt_state, key_i, reset_keys)
        value = float(value)
        history.append(dict(iteration=i, objective=value, seconds=time.perf_counter() - t))
        if progress:
            _bar(i + 1, iterations, f"objective {value:.4g}")
    if method == "es" and keep_best:
        params = best[1]
    policy = eqx.combine(params, static)
    final = None
    if method == "es":
        final = evaluate(task, controller(params), x0, args, y_ref, objective)
    result = TrainResult(policy, history, initial, final, time.perf_counter() - start)
    if curve_png is not None:
        plot_learning_curve(history, curve_png)
    if save_path is not None:
        save_policy(save_path, policy)
    return result


def _es_step(task, objective, optimiser, static, pairs, sigma):
    def batch_cost(p, x0, args, y_ref):
        controller = task.policy_controller(eqx.combine(p, static))

        def one(x0, args, y_ref):
            return metrics(task, objective, task.solve(controller, x0, args), y_ref).cost

        return jnp.mean(jax.vmap(one)(x0, args, y_ref))

    @filter_jit
    def step(params, opt_state, key, x0, args, y_ref):
        loss = lambda p: batch_cost(p, x0, args, y_ref)
        grads, losses = es_gradient(loss, params, key, pairs=pairs, sigma=sigma, centre=True)
        value = losses[-1]
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, value

    return step


def _reinforce_step(env, optimiser, static, noise, horizon):
    @filter_jit
    def step(params, opt_state, key, reset_keys):
        policy = eqx.combine(params, static)
        noise_keys = jr.split(key, reset_keys.shape[0])
        obs, actions, alive, returns = collect_episodes(
            env, policy, reset_keys, noise_keys, horizon=horizon, noise=noise, params=EnvParams()
        )
        grads = reinforce_gradient(policy, obs, actions, alive, returns, noise=noise)
        grads, _ = eqx.partition(grads, eqx.is_inexact_array)
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, -jnp.mean(returns)

    return step


def plot_learning_curve(history, path, title="learning curve"):
    """Writes objective against iteration to a PNG (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.plot([h["iteration"] for h in history], [h["objective"] for h in history], "o-")
    ax.set_xlabel("iteration")
    ax.set_ylabel("objective (lower is better)")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
