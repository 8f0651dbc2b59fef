from .base import AbstractEffect as AbstractEffect, Scene as Scene, scene_state as scene_state
from .contact import Contact as Contact
from .friction import Friction as Friction
from .switching import (
    Diode as Diode,
    Relay as Relay,
    Saturation as Saturation,
    SetValued as SetValued,
    StateEffect as StateEffect,
)
