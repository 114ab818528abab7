"""optalign from Python: Gymnasium environments of the three alignment tasks, a client
for motor controllers, and runs and benches of the policies.

Importing the package registers ``optalign/Michelson-v0``, ``optalign/Cavity-v0`` and
``optalign/Relay-v0`` with Gymnasium. Everything runs on the optalign Rust crates: the
scenes, the tasks, the simulated firmware and the protocol client are the ones the
``optalign`` command uses.
"""

from ._native import (
    ControllerError,
    ControllerRefused,
    ControllerTimeout,
    __version__,
)
from .controller import Controller
from .envs import CavityEnv, MichelsonEnv, RelayEnv, register_envs
from .peer import SimulatedPeer
from .runs import bench, run

register_envs()

__all__ = [
    "CavityEnv",
    "Controller",
    "ControllerError",
    "ControllerRefused",
    "ControllerTimeout",
    "MichelsonEnv",
    "RelayEnv",
    "SimulatedPeer",
    "__version__",
    "bench",
    "run",
]
