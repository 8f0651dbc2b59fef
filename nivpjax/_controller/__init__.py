from .base import AbstractController as AbstractController, StepInfo as StepInfo
from .constant import ConstantStepSize as ConstantStepSize
from .pid import PIDController as PIDController
