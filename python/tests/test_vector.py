"""The native vector environments: each sub-environment is the single environment's
episode step for step (autoresets included), whatever the threads, and bad actions are
refused before anything moves."""

import gymnasium
import numpy as np
import pytest

import optalign  # noqa: F401  (registers the environments)
from optalign.vector import MichelsonVectorEnv


def _small_moves(seed, steps, envs, axes):
    """Random commands of a few hundred steps: the suite's unoptimised build steps the
    simulated firmware slowly, and long moves test nothing more."""
    generator = np.random.default_rng(seed)
    for _ in range(steps):
        yield generator.integers(-400, 400, size=(envs, axes))


def _single_episodes(env_id, seeds, actions, **kwargs):
    """What single environments give under ``actions[t][i]``, with Gymnasium's next-step
    autoreset done by hand (a reset without a seed, from the environment's generator)."""
    envs = [gymnasium.make(env_id, **kwargs).unwrapped for _ in seeds]
    firsts = [env.reset(seed=seed)[0] for env, seed in zip(envs, seeds)]
    ended = [False] * len(envs)
    steps = []
    for row in actions:
        out = []
        for i, env in enumerate(envs):
            if ended[i]:
                obs, _ = env.reset()
                out.append((obs, 0.0, False, False, 0))
                ended[i] = False
                continue
            obs, reward, terminated, truncated, info = env.step(row[i])
            ended[i] = terminated or truncated
            out.append((obs, reward, terminated, truncated, info["evaluations"]))
        steps.append(out)
    return firsts, steps


def _compare(vector, seeds, actions, firsts, steps):
    obs, info = vector.reset(seed=list(seeds))
    for i, first in enumerate(firsts):
        np.testing.assert_array_equal(obs[i], first)
    assert list(info["seed"]) == list(seeds)
    for t, (row, expected) in enumerate(zip(actions, steps)):
        obs, rewards, terminated, truncated, info = vector.step(row)
        for i, (e_obs, e_reward, e_term, e_trunc, e_evals) in enumerate(expected):
            np.testing.assert_array_equal(obs[i], e_obs, err_msg=f"step {t}, env {i}")
            assert (rewards[i], terminated[i], truncated[i]) == (e_reward, e_term, e_trunc), (t, i)
            if e_evals:
                assert info["evaluations"][i] == e_evals


def test_each_michelson_in_the_batch_is_the_single_environment_with_its_seed(tmp_path):
    scenario = tmp_path / "short.toml"
    scenario.write_text("[tasks.michelson]\nbudget = 4\n")
    kwargs = dict(obs_size=(160, 90), scenario=scenario)
    seeds = [3, 4, 5]
    vector = gymnasium.make_vec("optalign/Michelson-v0", num_envs=3, **kwargs)
    assert isinstance(vector, MichelsonVectorEnv)
    # 11 steps: past the budget of 4 twice, so every environment truncates and autoresets.
    actions = list(_small_moves(7, 11, 3, 4))
    firsts, steps = _single_episodes("optalign/Michelson-v0", seeds, actions, **kwargs)
    assert any(s[3] for row in steps for s in row), "the episodes reach their truncation"
    _compare(vector, seeds, actions, firsts, steps)


def test_environments_that_declare_done_terminate_and_restart_like_single_ones():
    seeds = [0, 9]
    kwargs = dict(obs_size=(160, 90), done_action=True)
    vector = gymnasium.make_vec("optalign/Michelson-v0", num_envs=2, threads=2, **kwargs)
    actions = [
        np.array([[100 * t, -50 * t, 0, 20, int(t == 3)], [-30 * t, 70, 10, 0, 0]])
        for t in range(6)
    ]
    firsts, steps = _single_episodes("optalign/Michelson-v0", seeds, actions, **kwargs)
    assert steps[3][0][2] and not steps[3][1][2], "env 0 declares done at step 3"
    _compare(vector, seeds, actions, firsts, steps)


def test_the_threads_change_nothing_but_the_speed():
    results = []
    for threads in (1, 2):
        vector = MichelsonVectorEnv(num_envs=4, obs_size=(160, 90), threads=threads)
        assert vector.threads == threads
        obs, _ = vector.reset(seed=20)
        frames = [obs]
        for action in _small_moves(1, 4, 4, 4):
            obs, rewards, _, _, _ = vector.step(action)
            frames.append(obs.copy())
            frames.append(rewards)
        results.append(frames)
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)


def test_privileged_information_and_spaces_follow_the_single_environment():
    vector = MichelsonVectorEnv(num_envs=2, obs_size=(160, 90), privileged_info=True)
    single = gymnasium.make("optalign/Michelson-v0", obs_size=(160, 90))
    assert vector.single_action_space == single.action_space
    assert vector.single_observation_space == single.observation_space
    assert vector.observation_space.shape == (2, 90, 160)
    vector.reset(seed=0)
    _, rewards, _, _, info = vector.step(np.array([[500, -500, 300, 0], [0, 0, 0, 0]]))
    np.testing.assert_array_equal(rewards, -info["true_error"])
    assert info["evaluations"].tolist() == [1, 1] and info["remaining"].tolist() == [59, 59]


def test_bad_actions_are_refused_before_any_environment_moves():
    vector = MichelsonVectorEnv(num_envs=2, obs_size=(160, 90))
    vector.reset(seed=0)
    with pytest.raises(ValueError, match=r"environment 1: .*mirror_1_axis_1=9000 is outside"):
        vector.step(np.array([[10, 0, 0, 0], [9000, 0, 0, 0]]))
    with pytest.raises(ValueError, match=r"shape \(2, 4\)"):
        vector.step(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="finite"):
        vector.step(np.array([[np.nan, 0, 0, 0], [0, 0, 0, 0]]))
    _, _, _, _, info = vector.step(np.zeros((2, 4)))
    assert info["evaluations"].tolist() == [1, 1], "the refused steps spent nothing"
    with pytest.raises(ValueError, match="num_envs must be 1 to"):
        MichelsonVectorEnv(num_envs=0)
    with pytest.raises(ValueError, match="AsyncVectorEnv"):
        optalign._native.VectorEpisodes("relay", 2)
