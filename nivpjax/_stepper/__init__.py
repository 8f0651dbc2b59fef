from .base import AbstractStepper as AbstractStepper, StepOutput as StepOutput
from .bathe import Bathe as Bathe
from .embedded_betr import EmbeddedBETR as EmbeddedBETR
from .event_driven import EventDriven as EventDriven
from .one_leg import BackwardEuler as BackwardEuler, Theta as Theta, Trapezoidal as Trapezoidal
from .richardson import Richardson as Richardson
