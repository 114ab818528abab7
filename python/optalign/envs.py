"""The Gymnasium environments of the three alignment tasks, on the simulated rigs of
``optalign bench``.

Observations are camera images (``uint8``, deeper frames scaled to 8 bits, height x width; ``obs_size=(width, height)``
shrinks them), plus the camera's station for the relay. The reward after each step is
minus the true error (Michelson: px, cavity: motor steps, relay: px from the centre of C8,
``dark_error`` while no light reaches C8). An episode terminates when the agent declares
done or the state meets the task's success rule, and is truncated when the evaluation
budget is spent (or after ten rejected actions in a row, as ``optalign run`` ends a run).
``info`` holds the evaluations used and left; the true error and state only with
``privileged_info=True``.
"""

from __future__ import annotations

import json
import os
from typing import Any, Optional, Tuple

import gymnasium
import numpy as np
from gymnasium import spaces

from . import _native

#: Rejected actions in a row that end an episode, as in ``optalign run``.
MAX_REJECTIONS_IN_ROW = 10

#: The error the relay's reward counts while no light reaches C8, px: more than any lit
#: spot on the default 640 x 480 sensor can be off.
DEFAULT_DARK_ERROR = 1000.0

ENV_IDS = {
    "optalign/Michelson-v0": "optalign.envs:MichelsonEnv",
    "optalign/Cavity-v0": "optalign.envs:CavityEnv",
    "optalign/Relay-v0": "optalign.envs:RelayEnv",
}

#: The native vector environments (``gymnasium.make_vec`` picks them by default).
VECTOR_IDS = {
    "optalign/Michelson-v0": "optalign.vector:MichelsonVectorEnv",
    "optalign/Cavity-v0": "optalign.vector:CavityVectorEnv",
}


def register_envs() -> None:
    """Registers the three environments with Gymnasium (once)."""
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id, entry_point=entry_point, vector_entry_point=VECTOR_IDS.get(env_id)
            )


class _AlignmentEnv(gymnasium.Env):
    """What the three environments share: the episode, seeding, reward and info."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        task: str,
        obs_size: Optional[Tuple[int, int]] = None,
        scenario: Optional[str] = None,
        motors: str = "in-process",
        privileged_info: bool = False,
        render_mode: Optional[str] = None,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if obs_size is not None:
            obs_size = _size(obs_size)
        scenario = None if scenario is None else os.fspath(scenario)
        self._episode = _native.Episode(task, scenario, motors, obs_size)
        self._shape = tuple(self._episode.frame_shape())
        self.limits = json.loads(self._episode.limits_json())
        self.budget = self._episode.budget()
        self.privileged_info = bool(privileged_info)
        self.render_mode = render_mode
        self._image = np.zeros(self._shape, dtype=np.uint8)
        self.image_space = spaces.Box(0, 255, self._shape, dtype=np.uint8)

    # -- Gymnasium API ------------------------------------------------------------------

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        """Starts the episode of ``seed``: the same hidden misalignment as seed ``seed`` of
        ``optalign bench``. Without a seed, one is drawn from the environment's generator
        (``info["seed"]`` says which)."""
        super().reset(seed=seed)
        episode_seed = int(seed) if seed is not None else int(self.np_random.integers(2**63))
        if episode_seed < 0:
            raise ValueError(f"seed must be >= 0, got {episode_seed}")
        self._image = self._frame(self._episode.reset(episode_seed))
        info = self._info(self._episode.evaluations())
        info["seed"] = episode_seed
        return self._observation(), info

    def step(self, action):
        image, rejected, (error, success, evaluations, rejections) = self._act(action)
        if image is not None:
            self._image = self._frame(image)
        reward = -self._reward_error(error)
        terminated = (self._declared_done(action) and rejected is None) or success
        truncated = not terminated and (
            evaluations >= self.budget or rejections >= MAX_REJECTIONS_IN_ROW
        )
        info = self._info(evaluations)
        if rejected is not None:
            info["rejected"] = rejected
        return self._observation(), reward, terminated, truncated, info

    def render(self):
        if self.render_mode == "rgb_array":
            return np.repeat(self._image[:, :, None], 3, axis=2)
        return None

    # -- for the subclasses ---------------------------------------------------------------

    def _act(self, action) -> Tuple[Any, Optional[str], tuple]:
        """Carries out ``action``: (the next image or None, the reason it was rejected or
        None, (true error, success, evaluations, rejections in a row))."""
        raise NotImplementedError

    def _declared_done(self, action) -> bool:
        raise NotImplementedError

    def _observation(self):
        return self._image

    def _reward_error(self, error: Optional[float]) -> float:
        """The error the reward counts."""
        return float(error)

    def _frame(self, pixels) -> np.ndarray:
        return np.frombuffer(pixels, dtype=np.uint8).reshape(self._shape)

    def _info(self, evaluations: int) -> dict:
        info = {"evaluations": evaluations, "remaining": self.budget - evaluations}
        if self.privileged_info:
            truth = json.loads(self._episode.truth_json())
            info["true_error"] = self._episode.error()
            info["success"] = self._episode.success()
            info["state"] = truth
        return info


def _size(obs_size) -> Tuple[int, int]:
    try:
        width, height = (int(side) for side in obs_size)
    except (TypeError, ValueError):
        raise ValueError(f"obs_size must be (width, height), got {obs_size!r}") from None
    if width < 1 or height < 1:
        raise ValueError(f"obs_size must be positive (width, height), got {obs_size!r}")
    return width, height


def _whole_steps(action, size: int, what: str) -> np.ndarray:
    values = np.asarray(action, dtype=np.float64).reshape(-1)
    if values.shape != (size,):
        raise ValueError(f"{what} takes {size} values, got {np.asarray(action).shape}")
    return whole_steps(values, what)


def whole_steps(values: np.ndarray, what: str) -> np.ndarray:
    """Float or integer actions rounded to whole steps; non-finite ones refused."""
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{what} must be finite numbers of steps, got {values.tolist()}")
    return np.rint(values).astype(np.int64)


def command_space(limits: dict, task: str, done_action: bool) -> spaces.Box:
    """The absolute command of the Michelson or the cavity: one setting per axis within
    the task's ranges, and with ``done_action`` a last entry 0/1."""
    ranges = limits[task]["ranges"]
    low = [r["min"] for r in ranges]
    high = [r["max"] for r in ranges]
    if done_action:
        low, high = low + [0], high + [1]
    return spaces.Box(np.array(low, dtype=np.int32), np.array(high, dtype=np.int32), dtype=np.int32)


def split_commands(values: np.ndarray, axes: int, done_action: bool):
    """Whole-step actions, one row per environment, as (commands, done flags)."""
    if not done_action:
        return values, np.zeros(len(values), dtype=bool)
    flags = values[:, axes]
    if not np.all((flags == 0) | (flags == 1)):
        raise ValueError(f"the done entry must be 0 or 1, got {flags.tolist()}")
    return values[:, :axes], flags == 1


class _AbsoluteEnv(_AlignmentEnv):
    """Michelson and cavity: the action is the absolute command, one setting per axis,
    within the task's ranges; with ``done_action=True`` a last entry 0/1 declares done."""

    axis_names: Tuple[str, ...] = ()

    def __init__(self, task: str, done_action: bool = False, **kwargs):
        super().__init__(task, **kwargs)
        self.done_action = bool(done_action)
        self.action_space = command_space(self.limits, task, self.done_action)
        self.observation_space = self.image_space

    def _act(self, action):
        values = _whole_steps(
            action, self.action_space.shape[0], f"the {self.__class__.__name__} action"
        )
        commands, done = split_commands(values[None, :], len(self.axis_names), self.done_action)
        return self._episode.act_command([int(v) for v in commands[0]], bool(done[0]))

    def _declared_done(self, action) -> bool:
        return bool(self.done_action and np.rint(np.asarray(action).reshape(-1)[-1]) >= 1)


class MichelsonEnv(_AbsoluteEnv):
    """``optalign/Michelson-v0``: overlap two beams at the image centre. Action: absolute
    settings of mirror 1 (axis 1, axis 2) and mirror 2 (axis 1, axis 2), steps. Reward:
    minus the summed distance of both true beam centres from the image centre, px."""

    axis_names = ("mirror_1_axis_1", "mirror_1_axis_2", "mirror_2_axis_1", "mirror_2_axis_2")

    def __init__(self, **kwargs):
        super().__init__("michelson", **kwargs)


class CavityEnv(_AbsoluteEnv):
    """``optalign/Cavity-v0``: put the dim secondary beam on the bright primary. Action:
    absolute settings (x, y), steps. Reward: minus the true distance from the aligned
    setting, steps."""

    axis_names = ("x", "y")

    def __init__(self, **kwargs):
        super().__init__("cavity", **kwargs)


class RelayEnv(_AlignmentEnv):
    """``optalign/Relay-v0``: get the beam through four mirrors to a centred spot at C8.

    Action, a ``Dict``: ``kind`` 0 = tilt ``mirror`` (0 = M1 .. 3 = M4) by ``tilt`` =
    (vertical, horizontal) steps, 1 = move the camera to ``station`` (0 = C1 .. 7 = C8),
    2 = declare done (accepted only at C8). Tilts beyond ``max_step`` raise; a tilt that
    would take an axis's cumulative command beyond ``max_cumulative``, or done away from C8,
    is rejected without spending an evaluation (``info["rejected"]`` says why).
    Observation, a ``Dict``: ``image`` and ``station``. Reward: minus the true distance of
    the spot from the centre of C8, px (``dark_error`` while no light reaches C8).
    """

    TILT, MEASURE, DONE = 0, 1, 2

    def __init__(self, dark_error: float = DEFAULT_DARK_ERROR, **kwargs):
        super().__init__("relay", **kwargs)
        self.dark_error = float(dark_error)
        step = self.limits["relay"]["max_step"]
        self.action_space = spaces.Dict(
            {
                "kind": spaces.Discrete(3),
                "mirror": spaces.Discrete(4),
                "tilt": spaces.Box(-step, step, (2,), dtype=np.int32),
                "station": spaces.Discrete(8),
            }
        )
        self.observation_space = spaces.Dict(
            {"image": self.image_space, "station": spaces.Discrete(8)}
        )

    def _act(self, action):
        try:
            kind = int(action["kind"])
        except (TypeError, KeyError, IndexError):
            raise ValueError(
                "a relay action is a dict with 'kind' (0 tilt, 1 camera move, 2 done) and "
                f"'mirror'/'tilt' or 'station', got {action!r}"
            ) from None
        if kind == self.TILT:
            vertical, horizontal = _whole_steps(action["tilt"], 2, "tilt")
            return self._episode.act_tilt(int(action["mirror"]), int(vertical), int(horizontal))
        if kind == self.MEASURE:
            return self._episode.act_measure(int(action["station"]))
        if kind == self.DONE:
            return self._episode.act_done()
        raise ValueError(f"kind must be 0 (tilt), 1 (camera move) or 2 (done), got {kind}")

    def _declared_done(self, action) -> bool:
        return int(action["kind"]) == self.DONE

    def _observation(self):
        return {"image": self._image, "station": self._episode.station()}

    def _reward_error(self, error: Optional[float]) -> float:
        return self.dark_error if error is None else float(error)
