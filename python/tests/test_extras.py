"""Without the bluesky extra the package works and imports nothing of Bluesky; with it,
`optalign.bluesky` says what to install when a part is missing."""

import subprocess
import sys
import textwrap

BLOCK_BLUESKY = """
import importlib.abc, sys

class NoBluesky(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("bluesky", "ophyd_async", "ophyd", "event_model"):
            raise ImportError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, NoBluesky())
"""


def _python(code):
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=60
    )


def test_the_package_imports_nothing_of_bluesky():
    done = _python(
        """
        import sys, gymnasium, numpy as np, optalign
        env = gymnasium.make("optalign/Cavity-v0", obs_size=(64, 51))
        env.reset(seed=0)
        env.step(np.array([100, 0]))
        gymnasium.make_vec("optalign/Cavity-v0", num_envs=2, obs_size=(64, 51)).reset(seed=0)
        loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("bluesky", "ophyd_async"))
        print(loaded)
        """
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_without_the_extra_the_rest_works_and_the_bluesky_module_says_what_to_install():
    done = _python(
        BLOCK_BLUESKY
        + """
import numpy as np, gymnasium, optalign
env = gymnasium.make("optalign/Michelson-v0", obs_size=(160, 90))
env.reset(seed=1)
env.step(env.action_space.sample())
print(optalign.run("cavity", policy="random", seed=0)["evaluations_used"])
try:
    import optalign.bluesky
except ImportError as error:
    print(error)
"""
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    assert lines[0] == "50"
    assert "pip install './python[bluesky]'" in lines[1]
