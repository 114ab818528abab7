"""Measures how many Michelson environment steps per second one core runs: obs_size
(160, 90), in-process motors, uniformly random actions over the whole action space (the
hardest case: long moves), resets included.

    python python/examples/step_speed.py [--steps N]
"""

import argparse
import os
import time

import gymnasium
import numpy as np

import optalign  # noqa: F401  (registers the environments)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    env = gymnasium.make("optalign/Michelson-v0", obs_size=(160, 90))
    env.action_space.seed(0)
    sample = [env.action_space.sample() for _ in range(1000)]
    env.reset(seed=0)
    episodes, started = 1, time.perf_counter()
    for step in range(args.steps):
        _, _, terminated, truncated, _ = env.step(sample[step % len(sample)])
        if terminated or truncated:
            env.reset(seed=episodes)
            episodes += 1
    elapsed = time.perf_counter() - started
    print(
        f"{args.steps} steps in {elapsed:.2f} s on one core: {args.steps / elapsed:.0f} steps/s "
        f"({episodes} episodes, obs 160 x 90, in-process motors)"
    )


if __name__ == "__main__":
    main()
