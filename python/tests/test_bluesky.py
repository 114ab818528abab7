"""The Bluesky devices and the alignment plan under a real RunEngine, against simulated
controllers on loopback: moves that reach the true shafts, refusals that fail the plan
with the controller's message, a camera scan that follows the beam, an alignment run
that is the run of `optalign.run`, and an abort that leaves the axis stopped."""

import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("bluesky", reason="the bluesky extra is not installed")
pytest.importorskip("ophyd_async", reason="the bluesky extra is not installed")

import bluesky.plan_stubs as bps  # noqa: E402
import bluesky.plans as bp  # noqa: E402
from bluesky import RunEngine  # noqa: E402
from bluesky.utils import FailedStatus, RunEngineInterrupted  # noqa: E402
from ophyd_async.plan_stubs import ensure_connected  # noqa: E402

import optalign  # noqa: E402
from optalign.bluesky import MotorController, align, simulated_rig  # noqa: E402

KEY = "s3cret-for-bluesky"


@pytest.fixture(scope="module")
def RE():
    engine = RunEngine({}, call_returns_result=True)
    yield engine


@pytest.fixture
def documents(RE):
    seen = []
    token = RE.subscribe(lambda name, doc: seen.append((name, doc)))
    yield seen
    RE.unsubscribe(token)


def _controller(RE, peer, axes=4):
    controller = MotorController(peer.url, axes, key=KEY, name="mc")
    RE(ensure_connected(controller))
    return controller


def test_mv_moves_the_true_shafts_exactly_and_the_readings_follow(RE):
    with optalign.SimulatedPeer(axes=4, key=KEY, time_scale=50.0) as peer:
        controller = _controller(RE, peer)
        RE(bps.mv(controller.axes[0], 400, controller.axes[2], -250))
        assert peer.shaft_positions() == [400, 0, -250, 0]
        RE(bps.mvr(controller.axes[0], -100))
        assert peer.shaft_positions() == [300, 0, -250, 0]
        reading = RE(bps.rd(controller.axes[0])).plan_result
        assert reading == 300
        config = RE(bps.read(controller.axes[1].backlash)).plan_result
        assert list(config.values())[0]["value"] == 0


def test_a_refused_move_fails_the_plan_with_the_controllers_message(RE):
    with optalign.SimulatedPeer(axes=2, key=KEY, time_scale=50.0) as peer:
        controller = _controller(RE, peer, axes=2)
        controller.client.config(0, min=-100, max=100)
        with pytest.raises(FailedStatus) as refused:
            RE(bps.mv(controller.axes[0], 500))
        assert "target 500 outside soft limits -100..=100" in repr(refused.value.__cause__ or refused.value)
        assert peer.shaft_positions() == [0, 0]
        controller.client.emergency_stop()
        with pytest.raises(FailedStatus) as latched:
            RE(bps.mv(controller.axes[1], 50))
        assert "emergency stop" in repr(latched.value.__cause__ or latched.value)
        RE(ensure_connected(controller, force_reconnect=True))
        assert RE(bps.rd(controller.emergency_stopped)).plan_result is True


def test_a_scan_across_the_camera_follows_the_beam(RE, documents):
    rig = simulated_rig("michelson", seed=0, obs_size=(320, 180))
    with rig:
        truths = []
        RE.subscribe(lambda name, doc: truths.append(rig.truth()["score"]["beam_centres_px"]), "event")
        RE(bp.scan([rig.camera], rig.controller.axes[0], -3000, 3000, 3))
    events = [doc for name, doc in documents if name == "event"]
    assert len(events) == len(truths) == 3
    # The binned camera is a sixth of the full one: true centres are in full-frame px.
    # Every beam well inside the frame is found where it truly is.
    followed = []
    for event, truth in zip(events, truths):
        xs, ys = event["data"]["rig-camera-centres_x"], event["data"]["rig-camera-centres_y"]
        for true_x, true_y in truth:
            x, y = true_x / 6, true_y / 6
            if 15 < x < 305 and 15 < y < 165:
                nearest = min((cx - x) ** 2 + (cy - y) ** 2 for cx, cy in zip(xs, ys))
                assert nearest < 2.0**2, (truth, list(zip(xs, ys)))
                followed.append((x, y))
    assert len(followed) >= len(events), "a beam in view at every point"
    assert max(x for x, _ in followed) - min(x for x, _ in followed) > 25, "the beam crossed the camera"


def test_align_emits_one_event_per_evaluation_and_is_the_run_of_optalign_run(RE, documents, tmp_path):
    # The random policy decides without looking, so small frames keep the run the same
    # (the suite builds the module unoptimised: full frames cost seconds each there).
    scenario = tmp_path / "short.toml"
    scenario.write_text("[tasks.cavity]\nbudget = 3\n")
    with simulated_rig("cavity", seed=0, scenario=scenario, obs_size=(160, 128)) as rig:
        summary = RE(align("cavity", rig, policy="random")).plan_result
    expected = optalign.run("cavity", policy="random", seed=0, scenario=scenario)
    for field in ("success", "terminal_error", "evaluations_used", "declared_done", "error_trace"):
        assert summary[field] == expected[field], field
    start = next(doc for name, doc in documents if name == "start")
    assert (start["task"], start["policy"], start["budget"], start["seed"]) == ("cavity", "random", 3, 0)
    streams = {doc["uid"]: doc["name"] for name, doc in documents if name == "descriptor"}
    counts = {}
    for name, doc in documents:
        if name == "event":
            counts[streams[doc["descriptor"]]] = counts.get(streams[doc["descriptor"]], 0) + 1
    assert counts["primary"] == counts["truth"] == expected["evaluations_used"]
    assert counts["initial"] == counts["outcome"] == 1
    primary = next(uid for uid, name in streams.items() if name == "primary")
    descriptor = next(doc for name, doc in documents if name == "descriptor" and doc["uid"] == primary)
    assert not any(key.startswith("truth") for key in descriptor["data_keys"]), "truth stays apart"
    truth_errors = [doc["data"]["truth-error"] for name, doc in documents
                    if name == "event" and streams[doc["descriptor"]] == "truth"]
    assert truth_errors == expected["error_trace"][1:]
    stop = next(doc for name, doc in documents if name == "stop")
    assert stop["exit_status"] == "success"
    assert stop["reason"].startswith("aligned" if expected["success"] else "not aligned")
    assert f"after {expected['evaluations_used']} of 3 evaluations" in stop["reason"]


def test_an_abort_mid_move_leaves_the_axis_stopped(RE):
    with optalign.SimulatedPeer(axes=1, key=KEY, time_scale=1.0) as peer:
        controller = _controller(RE, peer, axes=1)
        timer = threading.Timer(0.4, RE.abort)
        timer.start()
        with pytest.raises(RunEngineInterrupted):
            RE(bps.mv(controller.axes[0], 90_000))
        timer.join()
        assert controller.client.status()["axes"][0]["moving"] is False, "at rest once aborted"
        first = peer.shaft_positions()[0]
        time.sleep(0.2)
        assert peer.shaft_positions()[0] == first
        assert 0 < first < 90_000


EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "bluesky_align.py"
DOCS = Path(__file__).resolve().parents[2] / "docs" / "python.md"


def test_the_documented_example_runs_and_is_the_one_in_the_docs():
    code = EXAMPLE.read_text()
    body = code.split('"""', 2)[2].strip()
    assert body in DOCS.read_text(), "docs/python.md shows python/examples/bluesky_align.py as it is"
    done = subprocess.run([sys.executable, str(EXAMPLE)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "rig-camera-x" in done.stdout, "the live table's header"
    assert done.stdout.count("|") >= 5 * 7, "a row per scan point"
    assert "50 evaluations, best true error" in done.stdout
    assert "after 50 of 50 evaluations" in done.stdout, "the stop document's outcome"


def test_an_abort_mid_alignment_ends_the_run_with_the_motion_stopped(RE, documents):
    with simulated_rig("cavity", seed=0, obs_size=(320, 256), time_scale=1.0) as rig:

        def abort_in_the_second_move(name, doc):
            if name == "event" and doc["seq_num"] == 1 and "action-text" in doc["data"]:
                threading.Timer(0.1, RE.abort).start()

        token = RE.subscribe(abort_in_the_second_move)
        try:
            with pytest.raises(RunEngineInterrupted):
                RE(align("cavity", rig, policy="random"))
        finally:
            RE.unsubscribe(token)
        status = rig.controller.client.status()
        assert not any(axis["moving"] for axis in status["axes"]), "at rest once aborted"
        shafts = rig.peer.shaft_positions()
        time.sleep(0.2)
        assert rig.peer.shaft_positions() == shafts
    stop = next(doc for name, doc in documents if name == "stop")
    assert stop["exit_status"] == "abort"
