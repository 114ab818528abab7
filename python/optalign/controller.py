"""A blocking client of a motor controller (a Pico W board or ``optalign peer``), for lab
scripts and notebooks."""

from __future__ import annotations

import json
from typing import Dict, Iterable, Mapping, Optional, Tuple, Union

from . import _native

Targets = Union[Mapping[int, int], Iterable[Tuple[int, int]]]


def _pairs(values: Targets) -> list:
    items = values.items() if isinstance(values, Mapping) else values
    return [(int(axis), int(steps)) for axis, steps in items]


class Controller:
    """An open link to one controller at ``tcp://HOST:PORT`` or ``serial://PATH``.

    ``key`` is the access key (default: the ``OPTALIGN_KEY`` environment variable). Over
    the network a controller answers ``status()`` and ``config()`` to anyone and obeys
    ``emergency_stop()`` from anyone, but moves and configuration changes need the key:
    without it they raise :class:`optalign.ControllerRefused`. ``timeout`` is how long to
    wait for each reply, in seconds, before the request is sent again.

    Every call blocks until the controller has answered (moves: until the motion has
    ended, at most ``timeout`` seconds of the move call) and raises
    :class:`optalign.ControllerError` (or a subclass) with the protocol's message.
    """

    def __init__(self, url: str, key: Optional[str] = None, timeout: float = 1.5):
        self._native = _native.Controller(url, key, timeout)

    @property
    def url(self) -> str:
        return self._native.url()

    @property
    def axes(self) -> int:
        """Number of axes the controller drives."""
        return self._native.axes()

    def status(self) -> dict:
        """The controller's identity and the state of every axis (position, target,
        moving, faults, limits, ...), plus the session: whether this link is
        authenticated and whether the emergency stop is latched. The same report as
        ``optalign status --json`` (schema ``optalign.status/1``, docs/protocol.md):
        faults and the boot record in words, e.g. ``"faults": ["position-lost"]``."""
        return json.loads(self._native.status_json())

    def positions(self) -> Dict[int, int]:
        """The logical position of every axis, in steps."""
        axes = self.status()["axes"]
        return {index: axis["position"] for index, axis in enumerate(axes)}

    def move_to(self, targets: Targets, timeout: float = 60.0) -> dict:
        """Moves axes to absolute positions, ``{axis: steps}``, and returns when the
        motion has ended: ``{"outcome", "positions", "duration_ms"}``. A move the
        controller ends early (stop, emergency stop, fault) raises ControllerError."""
        return self._report(self._native.move_to(_pairs(targets), timeout))

    def move_by(self, deltas: Targets, timeout: float = 60.0) -> dict:
        """Moves axes by relative amounts, ``{axis: steps}``; as :meth:`move_to`."""
        return self._report(self._native.move_by(_pairs(deltas), timeout))

    def stop(self) -> None:
        """Decelerates every axis to rest."""
        self._native.stop()

    def emergency_stop(self) -> None:
        """Stops every axis at once, cuts the coils and latches motion off until
        :meth:`clear_emergency`. Allowed without the key."""
        self._native.emergency_stop()

    def clear_emergency(self) -> None:
        """Releases the emergency latch so that moves are accepted again."""
        self._native.clear_emergency()

    def config(self, axis: Optional[int] = None, save: bool = False, **fields) -> Union[dict, list]:
        """Reads one axis's configuration (or all axes' as a list when ``axis`` is None).
        With keyword fields (``max_speed=600``, ``backlash=40``, ``backlash_mode="take-up"``,
        ``min=-20000``, ... as ``optalign config set`` spells them) it changes them on
        ``axis`` first, saving to flash when ``save``, and returns the new configuration."""
        if fields or save:
            if axis is None:
                raise ValueError("say which axis to change: config(axis, field=value, ...)")
            changes = [f"{name}={_spell(value)}" for name, value in fields.items()]
            return json.loads(self._native.set_config_json(int(axis), changes, save))
        if axis is None:
            return [json.loads(self._native.config_json(a)) for a in range(self.axes)]
        return json.loads(self._native.config_json(int(axis)))

    def __repr__(self) -> str:
        return f"Controller({self.url!r})"

    @staticmethod
    def _report(report) -> dict:
        outcome, positions, duration_ms = report
        return {"outcome": outcome, "positions": positions, "duration_ms": duration_ms}


def _spell(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)
