"""The Gymnasium environments: the checker, seeds that match the bench, bounds, info,
termination and truncation, both motor paths, vectorised use."""

import os

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import optalign

ENV_IDS = ["optalign/Michelson-v0", "optalign/Cavity-v0", "optalign/Relay-v0"]
SMALL = {
    "optalign/Michelson-v0": (160, 90),
    "optalign/Cavity-v0": (64, 51),
    "optalign/Relay-v0": (64, 48),
}


def make(env_id, **kwargs):
    kwargs.setdefault("obs_size", SMALL[env_id])
    return gymnasium.make(env_id, **kwargs).unwrapped


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_gymnasium_checker_passes_at_full_frame(env_id):
    env = gymnasium.make(env_id)
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_observation_is_the_camera_image_at_the_asked_size(env_id):
    env = make(env_id)
    obs, _ = env.reset(seed=0)
    image = obs["image"] if env_id.endswith("Relay-v0") else obs
    width, height = SMALL[env_id]
    assert image.shape == (height, width) and image.dtype == np.uint8
    assert image.max() > image.min(), "a lit frame, not a blank one"
    full, _ = make(env_id, obs_size=None).reset(seed=0)
    full_image = full["image"] if env_id.endswith("Relay-v0") else full
    assert full_image.shape[0] > height and full_image.shape[1] > width


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_a_seed_gives_the_same_episode_every_time(env_id):
    first, second = make(env_id), make(env_id)
    obs_a, _ = first.reset(seed=11)
    obs_b, _ = second.reset(seed=11)
    other, _ = second.reset(seed=12)
    image = (lambda o: o["image"]) if env_id.endswith("Relay-v0") else (lambda o: o)
    np.testing.assert_array_equal(image(obs_a), image(obs_b))
    assert not np.array_equal(image(obs_a), image(other))
    second.reset(seed=11)
    first.action_space.seed(3)
    for _ in range(4):
        action = first.action_space.sample()
        if env_id.endswith("Relay-v0"):
            action["kind"] = 0
        step_a = first.step(action)
        step_b = second.step(action)
        np.testing.assert_array_equal(image(step_a[0]), image(step_b[0]))
        assert step_a[1:4] == step_b[1:4]


@pytest.mark.parametrize("task", ["michelson", "cavity", "relay"])
def test_reset_seed_n_is_the_hidden_misalignment_of_bench_seed_n(task):
    env_id = f"optalign/{task.capitalize()}-v0"
    env = make(env_id, privileged_info=True)
    for seed in (0, 7):
        _, info = env.reset(seed=seed)
        summary = optalign.run(task, policy="random", seed=seed)
        assert summary["error_trace"][0] == info["true_error"]


def test_privileged_information_is_off_by_default():
    env = make("optalign/Cavity-v0")
    _, info = env.reset(seed=0)
    assert set(info) == {"evaluations", "remaining", "seed"}
    _, reward, _, _, info = env.step(np.array([100, -100]))
    assert set(info) == {"evaluations", "remaining"}
    assert info == {"evaluations": 1, "remaining": 49}
    assert reward < 0


def test_privileged_information_holds_the_true_error_and_state_and_the_reward_is_minus_it():
    env = make("optalign/Michelson-v0", privileged_info=True)
    _, info = env.reset(seed=2)
    assert info["true_error"] > 0 and info["success"] is False
    assert info["state"]["shafts"] == [0, 0, 0, 0]
    _, reward, _, _, info = env.step(np.array([500, -500, 300, 0]))
    assert reward == -info["true_error"]
    assert info["state"]["score"]["task"] == "michelson"
    assert info["state"]["shafts"] != [0, 0, 0, 0]


def test_commands_outside_the_task_bounds_are_refused_with_the_reason():
    env = make("optalign/Michelson-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"mirror_1_axis_1=9000 is outside \[-8192, 8192\]"):
        env.step(np.array([9000, 0, 0, 0]))
    with pytest.raises(ValueError, match="takes 4 values"):
        env.step(np.array([0, 0]))
    cavity = make("optalign/Cavity-v0")
    cavity.reset(seed=0)
    with pytest.raises(ValueError, match=r"y=-5001 is outside \[-5000, 5000\]"):
        cavity.step(np.array([0, -5001]))
    _, _, _, _, info = cavity.step(np.array([0, 0]))
    assert info["evaluations"] == 1, "a refused command spends no evaluation"


def test_relay_bounds_per_action_raise_and_cumulative_ones_are_rejected_without_cost():
    env = make("optalign/Relay-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="per-action bound"):
        env.step({"kind": 0, "mirror": 1, "tilt": [15001, 0], "station": 7})
    with pytest.raises(ValueError, match="mirror must be 0..=3"):
        env.step({"kind": 0, "mirror": 4, "tilt": [0, 0], "station": 7})
    for _ in range(2):
        env.step({"kind": 0, "mirror": 1, "tilt": [15000, 0], "station": 7})
    obs, _, terminated, truncated, info = env.step(
        {"kind": 0, "mirror": 1, "tilt": [1, 0], "station": 7}
    )
    assert "allowed now: [-15000, 0]" in info["rejected"]
    assert info["evaluations"] == 2 and not terminated and not truncated
    obs, _, _, _, info = env.step({"kind": 1, "mirror": 0, "tilt": [0, 0], "station": 2})
    assert obs["station"] == 2 and "rejected" not in info
    _, _, terminated, _, info = env.step({"kind": 2, "mirror": 0, "tilt": [0, 0], "station": 0})
    assert "only while the camera is at C8" in info["rejected"] and not terminated


def test_ten_rejections_in_a_row_truncate_like_a_run(tmp_path):
    env = make("optalign/Relay-v0")
    env.reset(seed=0)
    env.step({"kind": 1, "mirror": 0, "tilt": [0, 0], "station": 0})
    outcomes = [
        env.step({"kind": 2, "mirror": 0, "tilt": [0, 0], "station": 0})[3] for _ in range(10)
    ]
    assert outcomes == [False] * 9 + [True]


def test_a_scenario_file_sets_the_budget_and_the_episode_truncates_there(tmp_path):
    scenario = tmp_path / "short.toml"
    scenario.write_text("[tasks.cavity]\nbudget = 3\n")
    env = make("optalign/Cavity-v0", scenario=scenario)
    _, info = env.reset(seed=0)
    assert info["remaining"] == 3
    truncated = [env.step(np.array([10 * i, 0]))[3] for i in range(1, 4)]
    assert truncated == [False, False, True]
    bad = tmp_path / "bad.toml"
    bad.write_text("[mount]\nbacklash = 3\n")
    with pytest.raises(ValueError, match="backlash"):
        make("optalign/Cavity-v0", scenario=bad)


def test_declaring_done_or_reaching_success_terminates():
    env = make("optalign/Cavity-v0", privileged_info=True, done_action=True)
    assert env.action_space.shape == (3,)
    env.reset(seed=4)
    _, _, terminated, _, _ = env.step(np.array([0, 0, 0]))
    assert not terminated
    _, _, terminated, _, _ = env.step(np.array([0, 0, 1]))
    assert terminated
    env.reset(seed=4)
    aligned = _aligned_setting(env)
    _, reward, terminated, _, info = env.step(np.array(aligned + [0]))
    assert terminated and info["success"] and reward > -500


def _aligned_setting(env):
    """The cavity's aligned setting from the privileged error at three probes: the error
    is the distance from it in steps, so two differences of squares locate it."""
    probes = {}
    for command in ([0, 0], [1000, 0], [0, 1000]):
        _, _, _, _, info = env.step(np.array(command + [0]))
        probes[tuple(command)] = info["true_error"] ** 2
    e0, ex, ey = probes[(0, 0)], probes[(1000, 0)], probes[(0, 1000)]
    x = (e0 - ex + 1000**2) / 2000
    y = (e0 - ey + 1000**2) / 2000
    return [round(x), round(y)]


def test_bad_options_are_refused_clearly():
    too_wide = r"obs_size: a frame size of \(4000, 90\) does not fit the michelson camera of 1920x"
    with pytest.raises(ValueError, match=too_wide):
        make("optalign/Michelson-v0", obs_size=(4000, 90))
    with pytest.raises(ValueError, match="obs_size must be"):
        make("optalign/Michelson-v0", obs_size=(160,))
    with pytest.raises(ValueError, match='unknown motors "usb"'):
        make("optalign/Cavity-v0", motors="usb")
    with pytest.raises(RuntimeError, match="has not been reset"):
        make("optalign/Cavity-v0").step(np.array([0, 0]))


def test_motors_through_the_simulated_peer_give_the_in_process_episode():
    in_process = make("optalign/Cavity-v0", privileged_info=True)
    peer = make("optalign/Cavity-v0", privileged_info=True, motors="peer")
    for env in (in_process, peer):
        env.reset(seed=3)
    for command in ([1500, -700], [-300, 2200]):
        a = in_process.step(np.array(command))
        b = peer.step(np.array(command))
        np.testing.assert_array_equal(a[0], b[0])
        assert a[4]["state"] == b[4]["state"]


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="counts open files in /proc")
def test_resetting_a_peer_environment_does_not_leave_its_old_peers_listening():
    env = make("optalign/Cavity-v0", motors="peer")
    env.reset(seed=0)
    env.step(np.array([10, 10]))
    before = len(os.listdir("/proc/self/fd"))
    for seed in range(1, 21):
        env.reset(seed=seed)
        env.step(np.array([10, 10]))
    assert len(os.listdir("/proc/self/fd")) - before < 5


def test_environments_run_in_an_async_vector():
    envs = gymnasium.vector.AsyncVectorEnv(
        [lambda: gymnasium.make("optalign/Cavity-v0", obs_size=(64, 51)) for _ in range(2)]
    )
    try:
        obs, info = envs.reset(seed=[5, 6])
        assert obs.shape == (2, 51, 64)
        obs, reward, terminated, truncated, info = envs.step(np.array([[100, 0], [0, 100]]))
        assert reward.shape == (2,) and (reward < 0).all()
        assert list(info["evaluations"]) == [1, 1]
    finally:
        envs.close()
