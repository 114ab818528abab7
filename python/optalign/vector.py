"""Native vector environments of the Michelson and the cavity: N simulated rigs stepped in
Rust in one call, the GIL released and the rigs spread over the cores.

``gymnasium.make_vec("optalign/Michelson-v0", num_envs=8, obs_size=(160, 90))`` makes one.
Each sub-environment is the single environment's episode, step for step: environment
``i`` reset with seed ``s`` gives exactly the observations, rewards, terminations and
truncations of ``gymnasium.make(...).reset(seed=s)`` under the same actions. Episodes that
end are reset on the next step (Gymnasium's next-step autoreset), with a seed drawn from
the sub-environment's own generator as the single environment draws it.
"""

from __future__ import annotations

import json
import os
from typing import List, Optional, Sequence, Tuple, Union

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import _native
from .envs import (
    MAX_REJECTIONS_IN_ROW,
    CavityEnv,
    MichelsonEnv,
    _size,
    command_space,
    split_commands,
    whole_steps,
)


class _AlignmentVectorEnv(VectorEnv):
    """``num_envs`` episodes of one task with absolute commands (Michelson, cavity).

    Options as the single environment's: ``obs_size``, ``scenario``, ``motors``,
    ``privileged_info`` and ``done_action``; ``threads`` spreads a step over that many
    threads (default: one per core)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}
    task = ""
    axis_names: Tuple[str, ...] = ()

    def __init__(
        self,
        num_envs: int,
        obs_size: Optional[Tuple[int, int]] = None,
        scenario: Optional[str] = None,
        motors: str = "in-process",
        privileged_info: bool = False,
        done_action: bool = False,
        threads: Optional[int] = None,
    ):
        if obs_size is not None:
            obs_size = _size(obs_size)
        scenario = None if scenario is None else os.fspath(scenario)
        self._native = _native.VectorEpisodes(
            self.task, int(num_envs), scenario, motors, obs_size, threads
        )
        self.num_envs = int(num_envs)
        self._shape = tuple(self._native.frame_shape())
        self.limits = json.loads(self._native.limits_json())
        self.budget = self._native.budget()
        self.privileged_info = bool(privileged_info)
        self.done_action = bool(done_action)
        self.single_action_space = command_space(self.limits, self.task, self.done_action)
        self.single_observation_space = spaces.Box(0, 255, self._shape, dtype=np.uint8)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._generators: List[Optional[np.random.Generator]] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    @property
    def threads(self) -> int:
        """Threads a step is spread over."""
        return self._native.threads()

    def reset(
        self,
        *,
        seed: Union[int, Sequence[Optional[int]], None] = None,
        options: Optional[dict] = None,
    ):
        """Resets every sub-environment: ``seed`` an int (environment ``i`` gets ``seed +
        i``, as Gymnasium's vector environments do), a list of seeds (or ``None`` each), or
        ``None`` (each draws one from its generator)."""
        if seed is None:
            seeds: List[Optional[int]] = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{self.num_envs} environments take {self.num_envs} seeds, got {len(seeds)}")
        if seed is not None:
            self._np_random, self._np_random_seed = seeding.np_random(seeds[0])
        episode_seeds = [self._episode_seed(i, s) for i, s in enumerate(seeds)]
        image, states = self._native.reset(episode_seeds)
        self._autoreset[:] = False
        observations, _, _, _, info = self._batch(image, states, None)
        info["seed"] = np.array(episode_seeds, dtype=np.uint64)
        info["_seed"] = np.ones(self.num_envs, dtype=bool)
        return observations, info

    def step(self, actions):
        values = np.asarray(actions, dtype=np.float64)
        width = self.single_action_space.shape[0]
        if values.shape != (self.num_envs, width):
            raise ValueError(
                f"{self.num_envs} environments take actions of shape ({self.num_envs}, {width}), "
                f"got {values.shape}"
            )
        commands, done = split_commands(
            whole_steps(values, "the actions"), len(self.axis_names), self.done_action
        )
        resets = [
            self._episode_seed(i, None) if self._autoreset[i] else None
            for i in range(self.num_envs)
        ]
        image, states = self._native.step(
            commands.ravel().tolist(), done.tolist(), resets
        )
        restarted = self._autoreset.copy()
        observations, rewards, terminated, truncated, info = self._batch(
            image, states, done & ~restarted
        )
        rewards[restarted] = 0.0
        terminated &= ~restarted
        truncated &= ~restarted
        self._autoreset = terminated | truncated
        return observations, rewards, terminated, truncated, info

    def close_extras(self, **kwargs):
        self._native = None

    def _episode_seed(self, index: int, seed: Optional[int]) -> int:
        """The seed episode ``index`` starts with, drawn as the single environment draws
        it: ``seed`` itself (which also seeds the environment's generator), or the next
        draw of its generator."""
        if seed is not None:
            if int(seed) < 0:
                raise ValueError(f"seed must be >= 0, got {seed}")
            self._generators[index], _ = seeding.np_random(int(seed))
            return int(seed)
        if self._generators[index] is None:
            self._generators[index], _ = seeding.np_random()
        return int(self._generators[index].integers(2**63))

    def _batch(self, image, states, declared_done):
        errors, success, evaluations, rejections = (np.array(c) for c in zip(*states))
        observations = np.frombuffer(image, dtype=np.uint8).reshape((self.num_envs,) + self._shape)
        rewards = -errors.astype(np.float64)
        success = success.astype(bool)
        terminated = success.copy() if declared_done is None else (declared_done | success)
        truncated = ~terminated & (
            (evaluations >= self.budget) | (rejections >= MAX_REJECTIONS_IN_ROW)
        )
        every = np.ones(self.num_envs, dtype=bool)
        info = {
            "evaluations": evaluations,
            "_evaluations": every,
            "remaining": self.budget - evaluations,
            "_remaining": every,
        }
        if self.privileged_info:
            info.update(
                true_error=errors.astype(np.float64),
                _true_error=every,
                success=success,
                _success=every,
            )
        return observations, rewards, terminated, truncated, info


class MichelsonVectorEnv(_AlignmentVectorEnv):
    """``num_envs`` Michelson environments (``optalign/Michelson-v0``) stepped natively."""

    task = "michelson"
    axis_names = MichelsonEnv.axis_names


class CavityVectorEnv(_AlignmentVectorEnv):
    """``num_envs`` cavity environments (``optalign/Cavity-v0``) stepped natively."""

    task = "cavity"
    axis_names = CavityEnv.axis_names
