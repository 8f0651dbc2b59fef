"""Learned step-size control: train [`nivpjax.PolicyController`][] policies over batches of
scene-parameter draws, every rollout inside one compiled, vmapped program, with optax.

The core (`nivpjax._*`) never imports this package."""

from ._env import EnvParams as EnvParams, EnvState as EnvState, StepSizeEnv as StepSizeEnv
from ._estimators import (
    collect_episodes as collect_episodes,
    es_gradient as es_gradient,
    reinforce_gradient as reinforce_gradient,
)
from ._policy import (
    ResidualPolicy as ResidualPolicy,
    load_policy as load_policy,
    make_policy as make_policy,
    save_policy as save_policy,
)
from ._task import Metrics as Metrics, Objective as Objective, Task as Task, metrics as metrics
from ._train import (
    TrainResult as TrainResult,
    draw as draw,
    evaluate as evaluate,
    plot_learning_curve as plot_learning_curve,
    train as train,
)
from .fault import (
    FaultEnv as FaultEnv,
    FaultEnvParams as FaultEnvParams,
    FaultEnvState as FaultEnvState,
    fault_task as fault_task,
)
