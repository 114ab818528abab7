"""The camera of a simulated rig as an ophyd-async device: each trigger grabs a frame and
runs optalign's beam detector on it.

It is a plain triggerable :class:`~ophyd_async.core.StandardReadable`, not a
``StandardDetector``: that machinery arms an area detector and a file writer for frames
streamed to disk (HDF5 through a path provider), while this camera makes one frame per
trigger, in memory, small enough to go into the event as an array.
"""

from __future__ import annotations

import asyncio
import json
import math

import numpy as np
from ophyd_async.core import (
    Array1D,
    AsyncStatus,
    StandardReadable,
    soft_signal_r_and_setter,
)
from ophyd_async.core import StandardReadableFormat as Format

from .. import _native


def _column(beams, pick, dtype):
    return np.array([pick(beam) for beam in beams], dtype=dtype)


class CameraStation(StandardReadable):
    """Where the relay's camera stands (0 = C1 .. 7 = C8); ``set(station)`` moves it."""

    def __init__(self, native: "_native.SimCamera", name: str = ""):
        self._native = native
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.index, self._set_index = soft_signal_r_and_setter(int, native.station())
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def set(self, station: int):
        await asyncio.to_thread(self._native.place, int(station))
        self._set_index(int(station))


class BeamCamera(StandardReadable):
    """A rig's camera and the beam detector the agents use.

    ``trigger()`` grabs the next frame; the readings are then ``x``, ``y`` and
    ``uncertainty`` of the strongest beam (px, NaN when no beam is found; hinted), the
    number of ``beams``, per-beam arrays (strongest first) of each beam's centre
    (``centres_x``, ``centres_y``), centre uncertainty, second-moment radii, peak and
    flags (``saturated``, ``clipped`` by the border, ``localised``: a compact spot rather
    than speckle), the frame's ``background`` and ``read_noise``, and the ``image`` itself
    (8-bit, height x width)."""

    def __init__(self, native: "_native.SimCamera", name: str = ""):
        self._native = native
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.x, self._set_x = soft_signal_r_and_setter(float, math.nan, units="px")
            self.y, self._set_y = soft_signal_r_and_setter(float, math.nan, units="px")
            self.uncertainty, self._set_uncertainty = soft_signal_r_and_setter(
                float, math.nan, units="px"
            )
        with self.add_children_as_readables():
            self.beams, self._set_beams = soft_signal_r_and_setter(int)
            self.centres_x, self._set_centres_x = soft_signal_r_and_setter(
                Array1D[np.float64], units="px"
            )
            self.centres_y, self._set_centres_y = soft_signal_r_and_setter(
                Array1D[np.float64], units="px"
            )
            self.uncertainties, self._set_uncertainties = soft_signal_r_and_setter(
                Array1D[np.float64], units="px"
            )
            self.radii_major, self._set_radii_major = soft_signal_r_and_setter(
                Array1D[np.float64], units="px"
            )
            self.radii_minor, self._set_radii_minor = soft_signal_r_and_setter(
                Array1D[np.float64], units="px"
            )
            self.peaks, self._set_peaks = soft_signal_r_and_setter(Array1D[np.float64])
            self.saturated, self._set_saturated = soft_signal_r_and_setter(Array1D[np.bool_])
            self.clipped, self._set_clipped = soft_signal_r_and_setter(Array1D[np.bool_])
            self.localised, self._set_localised = soft_signal_r_and_setter(Array1D[np.bool_])
            self.background, self._set_background = soft_signal_r_and_setter(float)
            self.read_noise, self._set_read_noise = soft_signal_r_and_setter(float)
            self.image, self._set_image = soft_signal_r_and_setter(np.ndarray)
        self.station = CameraStation(native)
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def trigger(self):
        pixels, shape, report = await asyncio.to_thread(self._native.grab)
        self._show(np.frombuffer(pixels, dtype=np.uint8).reshape(shape), json.loads(report))

    def _show(self, image: np.ndarray, report: dict) -> None:
        beams = report["beams"]
        strongest = beams[0] if beams else None
        self._set_x(strongest["centre"][0] if strongest else math.nan)
        self._set_y(strongest["centre"][1] if strongest else math.nan)
        self._set_uncertainty(strongest["uncertainty"] if strongest else math.nan)
        self._set_beams(len(beams))
        self._set_centres_x(_column(beams, lambda b: b["centre"][0], np.float64))
        self._set_centres_y(_column(beams, lambda b: b["centre"][1], np.float64))
        self._set_uncertainties(_column(beams, lambda b: b["uncertainty"], np.float64))
        self._set_radii_major(_column(beams, lambda b: b["radii"][0], np.float64))
        self._set_radii_minor(_column(beams, lambda b: b["radii"][1], np.float64))
        self._set_peaks(_column(beams, lambda b: b["peak"], np.float64))
        self._set_saturated(_column(beams, lambda b: b["saturated"], np.bool_))
        self._set_clipped(_column(beams, lambda b: b["clipped"], np.bool_))
        self._set_localised(_column(beams, lambda b: b["localised"], np.bool_))
        self._set_background(float(report["background"]))
        self._set_read_noise(float(report["read_noise"]))
        self._set_image(image)
