from .ball import Ball as Ball, project_ball as project_ball
from .base import (
    AbstractProjector as AbstractProjector,
    Bound as Bound,
    ProjectionContext as ProjectionContext,
    default_context as default_context,
)
from .block import BlockProjector as BlockProjector
from .box import Box as Box, NonNegative as NonNegative, clip as clip
from .contact import UnilateralContact as UnilateralContact
from .contact_friction import FrictionalContact as FrictionalContact
from .coulomb import CoulombFriction as CoulombFriction
from .custom import CustomProjector as CustomProjector
from .held_gap import HeldGaps as HeldGaps
from .identity import Identity as Identity
from .lcp import lcp_solve as lcp_solve
from .located import EventLocated as EventLocated
from .sign import SignResolvent as SignResolvent
from .soc import SecondOrderCone as SecondOrderCone, project_soc as project_soc
