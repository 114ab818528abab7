"""A simulated rig in one call: the simulated controller of a task's rig (the mounts and
axis settings ``optalign run --sim`` uses for the seed) on a loopback port, its
:class:`~optalign.bluesky.MotorController` device and the :class:`~optalign.bluesky.BeamCamera`
watching the mirrors where the controller truly put them."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import List, Optional, Tuple

from bluesky.run_engine import call_in_bluesky_event_loop
from ophyd_async.core import wait_for_connection

from .. import _native
from ..peer import SimulatedPeer
from .camera import BeamCamera
from .devices import MotorController

#: The access key the simulated rig's controller is given.
SIM_KEY = "optalign-bluesky-sim"


@dataclass
class SimulatedRig:
    """The parts of a simulated rig: ``controller`` and ``camera`` are the devices,
    ``peer`` the simulated controller behind them."""

    task: str
    seed: int
    scenario: Optional[str]
    peer: SimulatedPeer
    controller: MotorController
    camera: BeamCamera

    def truth(self, commanded: Optional[List[int]] = None) -> dict:
        """The hidden state now: ``score`` (the task's error), ``success`` and the true
        ``shafts``; the Michelson's commanded score needs the absolute settings last
        commanded. Hidden truth: for records and tests, never for a policy."""
        commanded = list(commanded) if commanded is not None else [0] * len(self.controller.axes)
        return json.loads(self.camera._native.truth_json(commanded))

    def close(self) -> None:
        self.peer.close()

    def __enter__(self) -> "SimulatedRig":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def simulated_rig(
    task: str,
    seed: int = 0,
    *,
    scenario: Optional[str] = None,
    obs_size: Optional[Tuple[int, int]] = None,
    time_scale: Optional[float] = None,
    name: str = "rig",
    connect: bool = True,
) -> SimulatedRig:
    """The simulated rig of ``task`` ("michelson", "cavity", "relay") for ``seed``.

    ``time_scale=None`` runs the controller on instant time (a move ends as soon as it is
    sent); a number runs it that many times faster than real time. ``obs_size=(width,
    height)`` shrinks the frames. The devices are named ``{name}-controller`` and
    ``{name}-camera`` and, with ``connect``, connected in the RunEngine's event loop (make
    the RunEngine first; otherwise connect them with
    ``ophyd_async.plan_stubs.ensure_connected``)."""
    scenario = None if scenario is None else os.fspath(scenario)
    size = None if obs_size is None else tuple(int(side) for side in obs_size)
    peer = SimulatedPeer.for_rig(task, seed, scenario, SIM_KEY, time_scale)
    try:
        camera = BeamCamera(
            _native.SimCamera(task, int(seed), peer._native, scenario, size), name=f"{name}-camera"
        )
        axes = len(peer.shaft_positions())
        controller = MotorController(peer.url, axes, key=SIM_KEY, name=f"{name}-controller")
        if connect:
            call_in_bluesky_event_loop(
                wait_for_connection(controller=controller.connect(), camera=camera.connect())
            )
    except BaseException:
        peer.close()
        raise
    return SimulatedRig(task, int(seed), scenario, peer, controller, camera)
