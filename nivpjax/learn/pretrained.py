"""Small trained policies shipped with the package, one per evidence scene, and the recipe
that trains them (used by `examples/learn_*.py`)."""

import json
from pathlib import Path

import jax.random as jr
import numpy as np

from ._policy import ResidualPolicy, load_policy, make_policy
from ._task import Objective, Task
from ._train import TrainResult, draw, evaluate, train
from .tasks import TASKS


POLICY_DIR = Path(__file__).parent / "policies"
WIDTH, DEPTH = 16, 2


def skeleton(task: Task) -> ResidualPolicy:
    """The untrained policy (exactly PID) with the shipped policies' structure."""
    return make_policy(task.full_stepper.error_order, key=jr.PRNGKey(0), width=WIDTH, depth=DEPTH)


def load(name: str) -> tuple[Task, ResidualPolicy]:
    """`(task, policy)` of a shipped policy: `"ball_zeno"`, `"stick_slip"`,
    `"relay_sliding"` or `"rectifier"`."""
    if name not in TASKS:
        raise ValueError(f"`name` must be one of {sorted(TASKS)}, got {name!r}.")
    task = TASKS[name]()
    path = POLICY_DIR / f"{name}.eqx"
    if not path.exists():
        raise FileNotFoundError(f"no shipped policy {path}; train it with examples/learn_*.py.")
    return task, load_policy(path, skeleton(task))


def calibrated_objective(task: Task, x0, args, y_ref) -> Objective:
    """An objective in Newton iterations at PID's accuracy: the work is the nonlinear
    iterations; error above PID's (geometric mean over the draws, at the task's
    tolerances) costs PID's mean work per e-fold, a failure ten times that."""
    from .._controller import PIDController

    pid = evaluate(task, PIDController(rtol=task.rtol, atol=task.atol), x0, args, y_ref)
    ok = ~np.asarray(pid.failed)
    work = float(np.mean(np.asarray(pid.iterations)[ok]))
    err = np.asarray(pid.error)[ok]
    target = float(np.exp(np.mean(np.log(np.maximum(err, 1e-12)))))
    return Objective(
        attempts=0.0,
        iterations=1.0,
        rejections=0.0,
        error=work,
        failure=10 * work,
        error_target=max(target, 1e-12),
    )


def train_scene(
    name: str,
    *,
    iterations: int = 10,
    batch: int = 8,
    pairs: int = 8,
    sigma: float = 0.05,
    learning_rate: float = 1e-2,
    seed: int = 0,
    save: bool = True,
    curve_png: str | None = None,
) -> TrainResult:
    """Trains the policy of one scene with ES on `batch` draws and (by default) writes it
    to the package's `policies/` folder."""
    import optax

    task = TASKS[name]()
    x0, args, y_ref, _ = draw(task, jr.fold_in(jr.PRNGKey(seed), 1), batch)
    objective = calibrated_objective(task, x0, args, y_ref)
    POLICY_DIR.mkdir(exist_ok=True)
    result = train(
        task,
        skeleton(task),
        objective=objective,
        optimiser=optax.adam(learning_rate),
        iterations=iterations,
        batch=batch,
        pairs=pairs,
        sigma=sigma,
        seed=seed,
        draws=(x0, args, y_ref),
        curve_png=curve_png,
        save_path=str(POLICY_DIR / f"{name}.eqx") if save else None,
    )
    if save:
        log = dict(history=result.history, seconds=result.seconds, batch=batch, pairs=pairs)
        (POLICY_DIR / f"{name}.json").write_text(json.dumps(log, indent=1))
    return result
