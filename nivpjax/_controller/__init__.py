from .base import AbstractController as AbstractController, StepInfo as StepInfo
from .constant import ConstantStepSize as ConstantStepSize
from .features import (
    AbstractFeatures as AbstractFeatures,
    FeatureMemory as FeatureMemory,
    StepFeatures as StepFeatures,
)
from .pid import PIDController as PIDController
from .policy import (
    IntegralPolicy as IntegralPolicy,
    PolicyController as PolicyController,
    PolicyState as PolicyState,
)
from .step_doubling import StepDoublingController as StepDoublingController
