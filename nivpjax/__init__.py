"""nivpjax: JAX-native, differentiable time integration of nonsmooth ODE/DAE systems."""

from . import scenes as scenes
from ._batched import lockstep_waste as lockstep_waste, solve_batched as solve_batched
from ._cache import (
    clear_caches as clear_caches,
    enable_persistent_cache as enable_persistent_cache,
)
from ._compiler import compiler_options as compiler_options
from ._controller import (
    AbstractController as AbstractController,
    AbstractFeatures as AbstractFeatures,
    ConstantStepSize as ConstantStepSize,
    FeatureMemory as FeatureMemory,
    IntegralPolicy as IntegralPolicy,
    PIDController as PIDController,
    PolicyController as PolicyController,
    PolicyState as PolicyState,
    StepDoublingController as StepDoublingController,
    StepFeatures as StepFeatures,
    StepInfo as StepInfo,
)
from ._fit import FitResult as FitResult, fit as fit
from ._linear import (
    AbstractLinearSolver as AbstractLinearSolver,
    AbstractPreconditioner as AbstractPreconditioner,
    AutoLinear as AutoLinear,
    BlockJacobi as BlockJacobi,
    DenseLU as DenseLU,
    Krylov as Krylov,
)
from ._model import Model as Model
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
    CoulombFriction as CoulombFriction,
    CustomProjector as CustomProjector,
    EventLocated as EventLocated,
    FrictionalContact as FrictionalContact,
    HeldGaps as HeldGaps,
    Identity as Identity,
    NonNegative as NonNegative,
    ProjectionContext as ProjectionContext,
    SecondOrderCone as SecondOrderCone,
    SignResolvent as SignResolvent,
    UnilateralContact as UnilateralContact,
    clip as clip,
    default_context as default_context,
    lcp_solve as lcp_solve,
    project_ball as project_ball,
    project_soc as project_soc,
)
from ._results import RESULTS as RESULTS
from ._saveat import SaveAt as SaveAt
from ._scene import (
    AbstractEffect as AbstractEffect,
    Contact as Contact,
    Diode as Diode,
    Friction as Friction,
    Relay as Relay,
    Saturation as Saturation,
    Scene as Scene,
    SetValued as SetValued,
    StateEffect as StateEffect,
    scene_state as scene_state,
)
from ._solution import AttemptLog as AttemptLog, Solution as Solution, StepStats as StepStats
from ._solve import SolveError as SolveError, solve as solve
from ._stepper import (
    AbstractStepper as AbstractStepper,
    BackwardEuler as BackwardEuler,
    Bathe as Bathe,
    EmbeddedBETR as EmbeddedBETR,
    EventDriven as EventDriven,
    Richardson as Richardson,
    StepOutput as StepOutput,
    Theta as Theta,
    Trapezoidal as Trapezoidal,
)


__version__ = "0.1.0"
