"""A simulated motor controller on a loopback port, to try :class:`optalign.Controller`
without hardware."""

from __future__ import annotations

from typing import List, Optional

from . import _native


class SimulatedPeer:
    """The firmware core on simulated mounts, served on ``127.0.0.1`` like
    ``optalign peer``: ``axes`` axes, the access ``key`` (None: no key provisioned, so
    network clients get status but no motion), a true ``backlash`` of the mounts in steps,
    and ``time_scale`` times real time. ``port=0`` picks a free port; :attr:`url` says
    which. Use it as a context manager or call :meth:`close`."""

    def __init__(
        self,
        axes: int = 4,
        key: Optional[str] = None,
        backlash: int = 0,
        time_scale: float = 1.0,
        port: int = 0,
    ):
        self._native = _native.SimulatedPeer(axes, key, backlash, time_scale, port)

    @classmethod
    def for_rig(
        cls,
        task: str,
        seed: int,
        scenario: Optional[str] = None,
        key: Optional[str] = None,
        time_scale: Optional[float] = None,
    ) -> "SimulatedPeer":
        """The simulated controller of ``task``'s rig for ``seed``, as ``optalign run
        --sim`` moves it: the scenario's mounts (backlash, pitch error, hysteresis, lost
        steps drawn for the seed) and axis settings. ``time_scale=None`` runs it on
        instant time: a move ends as soon as it is sent."""
        peer = cls.__new__(cls)
        peer._native = _native.SimulatedPeer.for_rig(task, int(seed), scenario, key, time_scale)
        return peer

    @property
    def url(self) -> str:
        """``tcp://127.0.0.1:PORT``."""
        return self._native.url

    def shaft_positions(self) -> List[int]:
        """The true shaft positions of the simulated mounts, steps."""
        return self._native.shaft_positions()

    def close(self) -> None:
        self._native.close()

    def __enter__(self) -> "SimulatedPeer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"SimulatedPeer({self.url!r})"
