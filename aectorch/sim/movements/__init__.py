"""The eye movements of `ActiveDepthEnv`, one module each over the head state the environment keeps.

`base.Movement` says what a movement is; `pursuit.Pursuit` (the ``parallax`` cue),
`vergence.Vergence` (``stereo``), `accommodation.Accommodation` and ``AccommodationRight``
(``accommodation``, ``accommodation_right``) and `slip.Slip` (``slip``) are this environment's.
A movement is registered by naming its class in a cue of `ActiveDepthEnv.CUES`.
"""

from aectorch.sim.movements.accommodation import Accommodation, AccommodationRight
from aectorch.sim.movements.base import Movement
from aectorch.sim.movements.pursuit import Pursuit
from aectorch.sim.movements.slip import Slip
from aectorch.sim.movements.vergence import Vergence

__all__ = ["Accommodation", "AccommodationRight", "Movement", "Pursuit", "Slip", "Vergence"]
