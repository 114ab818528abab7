"""Measures how many Michelson environment steps per second the native vector environment
runs: obs_size (160, 90), in-process motors, uniformly random actions over the whole action
space (long moves), autoresets included, on every core (``--threads``) for ``--envs``
environments.

    python python/examples/vector_speed.py [--envs N] [--steps N] [--threads N]
"""

import argparse
import os
import time

import gymnasium

import optalign  # noqa: F401  (registers the environments)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=40000, help="environment steps in all")
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    envs = gymnasium.make_vec(
        "optalign/Michelson-v0", num_envs=args.envs, obs_size=(160, 90), threads=args.threads
    )
    envs.action_space.seed(0)
    samples = [envs.action_space.sample() for _ in range(200)]
    envs.reset(seed=0)
    rounds = max(1, args.steps // args.envs)
    started = time.perf_counter()
    for step in range(rounds):
        envs.step(samples[step % len(samples)])
    elapsed = time.perf_counter() - started
    steps = rounds * args.envs
    print(
        f"{steps} steps in {elapsed:.2f} s: {steps / elapsed:.0f} steps/s "
        f"({args.envs} environments on {envs.threads} threads, {os.cpu_count()} cores, "
        "obs 160 x 90, in-process motors)"
    )


if __name__ == "__main__":
    main()
