"""optalign in Bluesky: ophyd-async devices of a motor controller (:class:`MotorController`,
one :class:`ControllerAxis` per axis) and of a simulated rig's camera with the beam
detector (:class:`BeamCamera`), a simulated rig in one call (:func:`simulated_rig`) and
the alignment plan :func:`align`.

Needs the ``bluesky`` extra: ``pip install './python[bluesky]'`` (bluesky and
ophyd-async). The rest of the package never imports this module.
"""

try:
    import bluesky as _bluesky  # noqa: F401
    import ophyd_async as _ophyd_async  # noqa: F401
except ImportError as missing:  # pragma: no cover - depends on the install
    raise ImportError(
        f"optalign.bluesky needs the bluesky extra ({missing.name} is missing): "
        "pip install './python[bluesky]'"
    ) from missing

from .camera import BeamCamera, CameraStation
from .devices import ControllerAxis, MotorController
from .plans import align
from .rig import SimulatedRig, simulated_rig

__all__ = [
    "BeamCamera",
    "CameraStation",
    "ControllerAxis",
    "MotorController",
    "SimulatedRig",
    "align",
    "simulated_rig",
]
