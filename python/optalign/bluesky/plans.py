"""``align``: one optalign alignment as a Bluesky plan and run.

The run is the one ``optalign run`` makes (the same policy, task rules, budget and summary:
the run loop runs natively beside the plan); every action it decides is carried out by the
plan on the devices: ``bps.mv`` of the controller's axes (``bps.mvr`` for the relay's
tilts), the relay camera's station, then a camera trigger.

Documents: the start document holds ``task``, ``policy``, ``budget`` and ``seed``; the
stream ``initial`` the first frame's reading; the ``primary`` stream one event per
evaluation (the ``action``, the camera's readings: the detector's results and the frame,
the axes); the stream ``truth`` the hidden error, success and shaft positions after each
evaluation, apart from what a policy sees; the stream ``outcome`` the run's summary, and
the stop document's ``reason`` says it in words. ``RE.abort()`` or ``RE.stop()`` end the
run with the controller's motion stopped.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any, Dict, Optional

import bluesky.plan_stubs as bps
from bluesky.utils import FailedStatus
import numpy as np
from ophyd_async.core import Array1D, StandardReadable, soft_signal_r_and_setter
from ophyd_async.plan_stubs import ensure_connected

from .. import _native
from .._native import ControllerError
from .rig import SimulatedRig


class _Action(StandardReadable):
    """What the policy did at one evaluation."""

    def __init__(self, name: str = ""):
        with self.add_children_as_readables():
            self.evaluation, self._set_evaluation = soft_signal_r_and_setter(int)
            self.text, self._set_text = soft_signal_r_and_setter(str)
            self.done, self._set_done = soft_signal_r_and_setter(bool)
        super().__init__(name=name)


class _Truth(StandardReadable):
    """The hidden state after an evaluation."""

    def __init__(self, name: str = ""):
        with self.add_children_as_readables():
            self.error, self._set_error = soft_signal_r_and_setter(float)
            self.success, self._set_success = soft_signal_r_and_setter(bool)
            self.shafts, self._set_shafts = soft_signal_r_and_setter(Array1D[np.int64], units="steps")
        super().__init__(name=name)

    def show(self, truth: dict) -> None:
        error = truth["error"]
        self._set_error(float("nan") if error is None else float(error))
        self._set_success(bool(truth["success"]))
        self._set_shafts(np.array(truth["shafts"], dtype=np.int64))


class _Outcome(StandardReadable):
    """The run's summary."""

    def __init__(self, name: str = ""):
        with self.add_children_as_readables():
            self.success, self._set_success = soft_signal_r_and_setter(bool)
            self.declared_done, self._set_declared_done = soft_signal_r_and_setter(bool)
            self.terminal_error, self._set_terminal_error = soft_signal_r_and_setter(float)
            self.best_error, self._set_best_error = soft_signal_r_and_setter(float)
            self.evaluations_used, self._set_evaluations = soft_signal_r_and_setter(int)
            self.failure, self._set_failure = soft_signal_r_and_setter(str)
        super().__init__(name=name)

    def show(self, summary: dict) -> None:
        nan = float("nan")
        self._set_success(bool(summary["success"]))
        self._set_declared_done(bool(summary["declared_done"]))
        terminal, best = summary["terminal_error"], summary["best_error"]
        self._set_terminal_error(nan if terminal is None else float(terminal))
        self._set_best_error(nan if best is None else float(best))
        self._set_evaluations(int(summary["evaluations_used"]))
        self._set_failure(summary.get("failure") or "")


def _outcome_text(summary: dict) -> str:
    state = "aligned" if summary["success"] else "not aligned"
    error = summary["terminal_error"]
    error = "dark" if error is None else f"{error:.1f}"
    text = (
        f"{state}: error {error} after {summary['evaluations_used']} of "
        f"{summary['budget']} evaluations"
    )
    if summary["declared_done"]:
        text += ", declared done"
    if summary.get("failure"):
        text += f"; {summary['failure']}"
    return text


def _awaited(start):
    """Waits in the RunEngine's event loop for the awaitable ``start()`` makes."""
    (task,) = yield from bps.wait_for([start])
    return task.result()


def _read(stream: str, *devices):
    yield from bps.create(stream)
    for device in devices:
        yield from bps.read(device)
    yield from bps.save()


def _carry_out(rig: SimulatedRig, orders: Dict[str, Any]):
    """Moves the axes and the camera as ``orders`` say."""
    moves = []
    for axis, value in orders["moves"]:
        moves += [rig.controller.axes[axis], value]
    if moves:
        yield from (bps.mvr if orders["relative"] else bps.mv)(*moves)
    if "station" in orders:
        yield from bps.mv(rig.camera.station, orders["station"])


def align(task: str, rig: SimulatedRig, policy: str = "vision", md: Optional[dict] = None):
    """Runs one alignment of ``task`` with ``policy`` ("vision", "bo", "random") on the
    simulated ``rig`` (:func:`~optalign.bluesky.simulated_rig` of the same task) and
    returns the run summary (as ``optalign.run`` does). On a fresh rig of seed ``s`` it
    makes the very run ``optalign.run(task, policy, seed=s)`` makes."""
    if not isinstance(rig, SimulatedRig):
        raise TypeError(f"align runs on a simulated rig (optalign.bluesky.simulated_rig), got {rig!r}")
    if rig.task != task:
        raise ValueError(f"the rig is a {rig.task} rig, not a {task} one")
    action, truth, outcome = _Action(name="action"), _Truth(name="truth"), _Outcome(name="outcome")
    yield from ensure_connected(rig.controller, rig.camera, action, truth, outcome)
    yield from bps.trigger(rig.camera, wait=True)
    session = _native.Alignment(policy, rig.seed, rig.camera._native, rig.scenario)
    start = {
        "plan_name": "align",
        "task": task,
        "policy": policy,
        "budget": session.budget,
        "seed": rig.seed,
        **(md or {}),
    }
    yield from bps.open_run(md=start)
    commanded = [0] * len(rig.controller.axes)
    finished = False
    failure: Optional[BaseException] = None
    try:
        yield from _read("initial", rig.camera, rig.controller)
        evaluation = 0
        while True:
            kind, payload = yield from _awaited(lambda: asyncio.to_thread(session.next))
            if kind == "finished":
                finished = True
                summary = json.loads(payload)
                break
            if kind == "emergency_stop":
                yield from _awaited(rig.controller.emergency_stop)
                session.done()
                continue
            orders = json.loads(payload)
            try:
                yield from _carry_out(rig, orders)
                yield from bps.trigger(rig.camera, wait=True)
            except (FailedStatus, ControllerError) as error:  # the controller's refusal or report
                failure = error
                session.failed(f"executing {orders['action']}: {error}")
                continue
            evaluation += 1
            commanded = orders.get("command", commanded)
            action._set_evaluation(evaluation)
            action._set_text(orders["action"])
            action._set_done(bool(orders["done"]))
            truth.show(rig.truth(commanded))
            yield from _read("primary", action, rig.camera, rig.controller)
            yield from _read("truth", truth)
            session.done()
    finally:
        if not finished:
            session.close()
    outcome.show(summary)
    yield from _read("outcome", outcome)
    if failure is not None:
        raise failure
    yield from bps.close_run(exit_status="success", reason=_outcome_text(summary))
    return summary
