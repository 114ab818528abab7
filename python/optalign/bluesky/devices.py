"""ophyd-async devices of an optalign motor controller: one :class:`ControllerAxis` per
axis and the :class:`MotorController` that groups them, with the emergency stop and the
fault state.

The controller runs one motion at a time (a new move replaces the running one), so the
axes of one controller do not move on their own: the sets made together (one ``bps.mv``
of several axes) go out as one multi-axis move, and a set made while a move runs starts
when it has ended. Positions are read back from the controller while a move runs.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Dict, Optional, Tuple

from ophyd_async.core import (
    DeviceConnector,
    DeviceVector,
    MovableLogic,
    Reference,
    StandardMovable,
    StandardReadable,
    TimeoutCalculator,
    soft_signal_r_and_setter,
)
from ophyd_async.core import StandardReadableFormat as Format

from ..controller import Controller

#: Seconds between position read-backs while a move runs.
POLL_S = 0.05


@dataclass
class _AxisMotion(MovableLogic[int]):
    """How an axis moves: through its controller, which groups the sets made together."""

    axis: "ControllerAxis"

    async def move(self, new_position: int, timeout: TimeoutCalculator) -> None:
        await self.axis.controller._move(self.axis.index, int(new_position), timeout())

    async def stop(self) -> None:
        await self.axis.controller.stop()


class ControllerAxis(StandardReadable, StandardMovable[int]):
    """One axis of a controller, in motor steps.

    ``set(position)`` returns a status that completes when the controller reports the move
    finished and fails with the controller's error (a target beyond the soft limits, a lost
    position, an emergency stop, a move the controller ended early). ``stop()`` stops the
    controller's motion (the protocol stops all axes of a controller at once). Readings:
    ``position`` (hinted) and ``target``; configuration: the soft limits, speed,
    acceleration and backlash compensation, as the controller holds them."""

    def __init__(self, controller: "MotorController", index: int, name: str = ""):
        self._controller = Reference(controller)
        self.index = index
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.position, self._set_position = soft_signal_r_and_setter(int, units="steps")
        with self.add_children_as_readables():
            self.target, self._set_target = soft_signal_r_and_setter(int, units="steps")
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            self.limit_min, self._set_limit_min = soft_signal_r_and_setter(int, units="steps")
            self.limit_max, self._set_limit_max = soft_signal_r_and_setter(int, units="steps")
            self.max_speed, self._set_max_speed = soft_signal_r_and_setter(int, units="steps/s")
            self.acceleration, self._set_acceleration = soft_signal_r_and_setter(
                int, units="steps/s^2"
            )
            self.backlash, self._set_backlash = soft_signal_r_and_setter(int, units="steps")
            self.backlash_mode, self._set_backlash_mode = soft_signal_r_and_setter(str)
        self.faults, self._set_faults = soft_signal_r_and_setter(Sequence[str])
        super().__init__(name=name)

    @property
    def controller(self) -> "MotorController":
        """The controller this axis belongs to."""
        return self._controller()

    @cached_property
    def movable_logic(self) -> _AxisMotion:
        return _AxisMotion(setpoint=self.target, readback=self.position, axis=self)

    def _show_status(self, axis: dict) -> None:
        self._set_position(int(axis["position"]))
        self._set_target(int(axis["target"]))
        self._set_faults(list(axis["faults"]))

    def _show_config(self, config: dict) -> None:
        self._set_limit_min(int(config["limits"]["min"]))
        self._set_limit_max(int(config["limits"]["max"]))
        self._set_max_speed(int(config["max_speed"]))
        self._set_acceleration(int(config["acceleration"]))
        self._set_backlash(int(config["backlash"]))
        self._set_backlash_mode(str(config["backlash_mode"]))


class _Link(DeviceConnector):
    """Connects a controller device: its signals, then the link to the controller."""

    async def connect_real(self, device: "MotorController", timeout: float, force_reconnect: bool):
        await super().connect_real(device, timeout, force_reconnect)
        if device._client is None or force_reconnect:
            device._client = await asyncio.to_thread(
                Controller, device.url, device._key, device._timeout
            )
            if device._client.axes < len(device.axes):
                raise ValueError(
                    f"{device.url} drives {device._client.axes} axes, "
                    f"not the {len(device.axes)} this device was made with"
                )
        await device.refresh(configuration=True)


class MotorController(StandardReadable):
    """An optalign motor controller (a Pico W board or a simulated peer) at ``url`` with
    ``axes`` axes, as a device: ``axes[i]`` are the :class:`ControllerAxis` devices,
    ``emergency_stopped`` and ``faults`` (one ``"axis N: fault"`` line each) its state.

    ``key`` is the access key (default: ``OPTALIGN_KEY``), ``timeout`` the wait for each
    reply (s). Connect it as any ophyd-async device (``init_devices`` or ``await
    controller.connect()``)."""

    def __init__(
        self,
        url: str,
        axes: int,
        key: Optional[str] = None,
        timeout: float = 1.5,
        name: str = "",
    ):
        self.url = url
        self._key = key
        self._timeout = timeout
        self._client: Optional[Controller] = None
        self._pending: Dict[int, Tuple[int, asyncio.Future]] = {}
        self._mover: Optional[asyncio.Task] = None
        with self.add_children_as_readables():
            self.axes = DeviceVector({i: ControllerAxis(self, i) for i in range(int(axes))})
        self.emergency_stopped, self._set_emergency = soft_signal_r_and_setter(bool)
        self.faults, self._set_faults = soft_signal_r_and_setter(Sequence[str])
        super().__init__(name=name, connector=_Link())

    @property
    def client(self) -> Controller:
        """The blocking client underneath (for calls the devices do not cover)."""
        if self._client is None:
            raise RuntimeError(f"{self.name or self.url} is not connected: connect it first")
        return self._client

    async def refresh(self, configuration: bool = False) -> None:
        """Reads the controller's state (and with ``configuration`` every axis's
        configuration) into the signals."""
        status = await asyncio.to_thread(self.client.status)
        self._show_status(status)
        if configuration:
            configs = await asyncio.to_thread(self.client.config)
            for index, axis in self.axes.items():
                axis._show_config(configs[index])

    async def stop(self, rest_timeout: float = 30.0) -> None:
        """Decelerates every axis to rest; returns once no axis moves (at most
        ``rest_timeout`` s)."""
        await asyncio.to_thread(self.client.stop)
        waited = 0.0
        while True:
            status = await asyncio.to_thread(self.client.status)
            self._show_status(status)
            if not any(axis["moving"] for axis in status["axes"]):
                return
            if waited >= rest_timeout:
                raise TimeoutError(f"{self.url}: the axes still move {rest_timeout} s after stop")
            await asyncio.sleep(POLL_S)
            waited += POLL_S

    async def emergency_stop(self) -> None:
        """Stops every axis at once, cuts the coils and latches motion off until
        :meth:`clear_emergency` (allowed without the key)."""
        await asyncio.to_thread(self.client.emergency_stop)
        await self.refresh()

    async def clear_emergency(self) -> None:
        """Releases the emergency latch."""
        await asyncio.to_thread(self.client.clear_emergency)
        await self.refresh()

    def _show_status(self, status: dict) -> None:
        self._set_emergency(bool(status["emergency_stopped"]))
        faults = []
        for index, axis in self.axes.items():
            reported = status["axes"][index]
            axis._show_status(reported)
            faults += [f"axis {index}: {fault}" for fault in reported["faults"]]
        self._set_faults(faults)

    async def _move(self, index: int, target: int, timeout: Optional[float]) -> None:
        """Moves axis ``index`` to ``target`` with the other sets made with it; returns
        when the controller reports the move finished."""
        done = asyncio.get_running_loop().create_future()
        self._pending[index] = (target, done)
        if self._mover is None or self._mover.done():
            self._mover = asyncio.create_task(self._run_moves(timeout))
        await done

    async def _run_moves(self, timeout: Optional[float]) -> None:
        while self._pending:
            # Let the other sets of the same `mv` join this move.
            for _ in range(3):
                await asyncio.sleep(0)
            batch, self._pending = self._pending, {}
            targets = {index: target for index, (target, _) in batch.items()}
            for index, target in targets.items():
                self.axes[index]._set_target(target)
            try:
                await self._moving(targets, timeout)
            except Exception as error:  # the controller's refusal or report, to each set
                outcome: Optional[Exception] = error
            else:
                outcome = None
            for _, done in batch.values():
                if not done.done():
                    if outcome is None:
                        done.set_result(None)
                    else:
                        done.set_exception(outcome)

    async def _moving(self, targets: Dict[int, int], timeout: Optional[float]) -> None:
        client = self.client
        move = asyncio.ensure_future(
            asyncio.to_thread(client.move_to, targets, timeout or 3600.0)
        )
        # Its failure comes out of move.result() below, or goes with a read-back that failed.
        move.add_done_callback(_settled)
        while not move.done():
            await asyncio.wait({move}, timeout=POLL_S)
            if not move.done():
                await self.refresh()
        try:
            move.result()
        finally:
            await self.refresh()


def _settled(future: asyncio.Future) -> None:
    """Marks a finished future's exception as seen."""
    if not future.cancelled():
        future.exception()
