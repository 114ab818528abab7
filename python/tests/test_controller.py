"""The controller client against a simulated controller on loopback: moves, the access
key, the emergency stop, configuration and clear errors."""

import threading
import time

import pytest

import optalign
from optalign import (
    Controller,
    ControllerError,
    ControllerRefused,
    ControllerTimeout,
    SimulatedPeer,
)

KEY = "s3cret-for-tests"


@pytest.fixture
def peer():
    with SimulatedPeer(axes=4, key=KEY, time_scale=50.0) as peer:
        yield peer


@pytest.fixture(autouse=True)
def no_key_in_the_environment(monkeypatch):
    monkeypatch.delenv("OPTALIGN_KEY", raising=False)


def test_moves_with_the_key_end_where_they_were_sent(peer):
    controller = Controller(peer.url, key=KEY)
    assert controller.axes == 4 and peer.url.startswith("tcp://127.0.0.1:")
    report = controller.move_to({0: 400, 2: -250})
    assert report["outcome"] == "Completed"
    assert report["positions"] == [400, 0, -250, 0]
    report = controller.move_by([(0, -100), (1, 50)])
    assert report["positions"] == [300, 50, -250, 0]
    assert controller.positions() == {0: 300, 1: 50, 2: -250, 3: 0}
    assert peer.shaft_positions() == [300, 50, -250, 0]
    status = controller.status()
    assert status["session"]["authenticated"] is True


def test_the_key_may_come_from_the_environment_as_on_the_command_line(peer, monkeypatch):
    monkeypatch.setenv("OPTALIGN_KEY", KEY)
    assert Controller(peer.url).move_to({1: 120})["positions"][1] == 120


def test_without_the_key_status_is_given_but_motion_is_refused(peer):
    controller = Controller(peer.url)
    assert controller.status()["session"]["authenticated"] is False
    with pytest.raises(ControllerRefused, match="OPTALIGN_KEY") as refused:
        controller.move_to({0: 100})
    assert isinstance(refused.value.code, int)
    with pytest.raises(ControllerRefused):
        controller.config(0, max_speed=500)
    assert peer.shaft_positions() == [0, 0, 0, 0]
    with pytest.raises(ControllerError):
        Controller(peer.url, key="not-the-key").move_to({0: 100})


def test_an_emergency_stop_from_anyone_latches_until_cleared(peer):
    keyed = Controller(peer.url, key=KEY)
    Controller(peer.url).emergency_stop()
    assert keyed.status()["emergency_stopped"] is True
    with pytest.raises(ControllerRefused, match="clear-emergency"):
        keyed.move_to({0: 100})
    keyed.clear_emergency()
    assert keyed.move_to({0: 100})["positions"][0] == 100


def test_configuration_is_read_and_changed_as_config_set_does(peer):
    controller = Controller(peer.url, key=KEY)
    assert len(controller.config()) == 4
    changed = controller.config(1, max_speed=600, backlash_mode="take-up")
    assert changed["max_speed"] == 600
    assert controller.config(1) == changed
    with pytest.raises(ControllerError, match="unknown configuration key"):
        controller.config(1, speed=3)


def test_bad_addresses_and_axes_are_refused_clearly(peer):
    with pytest.raises(ValueError):
        Controller("http://127.0.0.1:1")
    with pytest.raises(ValueError, match="unknown axis 9"):
        Controller(peer.url, key=KEY).move_to({9: 10})
    closed = SimulatedPeer()
    url = closed.url
    closed.close()
    with pytest.raises(ControllerError, match=f"connecting to {url}"):
        Controller(url, timeout=0.3)


def test_the_exceptions_form_one_family():
    assert issubclass(optalign.ControllerRefused, optalign.ControllerError)
    assert issubclass(optalign.ControllerTimeout, optalign.ControllerError)


def test_stop_from_another_thread_ends_a_blocking_move_early(peer):
    controller = Controller(peer.url, key=KEY)
    outcome = {}

    def long_move():
        try:
            controller.move_to({0: 90_000})
        except ControllerError as error:
            outcome["error"] = str(error)

    mover = threading.Thread(target=long_move)
    mover.start()
    time.sleep(0.3)
    controller.stop()
    mover.join(timeout=10)
    assert not mover.is_alive()
    assert "move ended early (Stopped)" in outcome["error"]
    stopped_at = controller.positions()[0]
    assert 0 < stopped_at < 90_000


def test_a_move_that_outlasts_its_timeout_raises_and_says_what_to_do(peer):
    controller = Controller(peer.url, key=KEY)
    with pytest.raises(ControllerTimeout, match=r"stop\(\) or emergency_stop\(\)"):
        controller.move_to({0: 90_000}, timeout=0.2)
    controller.stop()
    with pytest.raises(ValueError, match="timeout must be a positive number"):
        controller.move_to({0: 0}, timeout=-1)
