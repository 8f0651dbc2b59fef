from .auto import AutoLinear as AutoLinear
from .base import AbstractLinearSolver as AbstractLinearSolver
from .dense import DenseLU as DenseLU
from .krylov import Krylov as Krylov
from .preconditioner import (
    AbstractPreconditioner as AbstractPreconditioner,
    BlockJacobi as BlockJacobi,
)
