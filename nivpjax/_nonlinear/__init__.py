from .base import (
    AbstractNonlinearSolver as AbstractNonlinearSolver,
    NonlinearSolution as NonlinearSolution,
)
from .fixed_point import FixedPointVI as FixedPointVI
from .semismooth_newton import SemismoothNewton as SemismoothNewton
