"""nivpjax: JAX-native, differentiable time integration of nonsmooth ODE/DAE systems."""

from ._nonlinear import (
    AbstractNonlinearSolver as AbstractNonlinearSolver,
    FixedPointVI as FixedPointVI,
    NonlinearSolution as NonlinearSolution,
    SemismoothNewton as SemismoothNewton,
)
from ._projector import (
    AbstractProjector as AbstractProjector,
    Ball as Ball,
    BlockProjector as BlockProjector,
    Box as Box,
    clip as clip,
    CoulombFriction as CoulombFriction,
    CustomProjector as CustomProjector,
    default_context as default_context,
    Identity as Identity,
    lcp_solve as lcp_solve,
    NonNegative as NonNegative,
    project_ball as project_ball,
    project_soc as project_soc,
    ProjectionContext as ProjectionContext,
    SecondOrderCone as SecondOrderCone,
    SignResolvent as SignResolvent,
    UnilateralContact as UnilateralContact,
)
from ._controller import (
    AbstractController as AbstractController,
    ConstantStepSize as ConstantStepSize,
    PIDController as PIDController,
    StepInfo as StepInfo,
)
from ._model import Model as Model
from ._results import RESULTS as RESULTS
from ._solution import AttemptLog as AttemptLog, Solution as Solution, StepStats as StepStats
from ._solve import solve as solve, SolveError as SolveError
from ._stepper import (
    AbstractStepper as AbstractStepper,
    BackwardEuler as BackwardEuler,
    Bathe as Bathe,
    EmbeddedBETR as EmbeddedBETR,
    Richardson as Richardson,
    StepOutput as StepOutput,
    Theta as Theta,
    Trapezoidal as Trapezoidal,
)


__version__ = "0.1.0"
