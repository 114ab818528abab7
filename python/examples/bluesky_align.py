"""A Bluesky session on a simulated optalign rig: a scan of a Michelson beam across the
camera with a live table, then an alignment of the cavity as a plan.

    pip install './python[bluesky]'
    python python/examples/bluesky_align.py
"""

import bluesky.plans as bp
from bluesky import RunEngine
from bluesky.callbacks import LiveTable

from optalign.bluesky import align, simulated_rig

RE = RunEngine({})  # first: the rig's devices connect in its event loop

# Mirror 1's first axis swept over 6,000 steps; the camera reads the strongest beam.
with simulated_rig("michelson", seed=3, obs_size=(320, 180)) as rig:
    axis, camera = rig.controller.axes[0], rig.camera
    table = LiveTable([axis.position.name, camera.x.name, camera.y.name, camera.beams.name])
    RE(bp.scan([camera], axis, -3000, 3000, 5), table)


# One alignment run: an event per evaluation, the hidden error apart in the "truth"
# stream. "random" keeps this example quick; policy="vision" aligns from the images alone
# (give it full frames: leave out obs_size), "bo" reads the simulator's hidden objective.
errors = []


def report(name, doc):
    if name == "event" and "truth-error" in doc["data"]:
        errors.append(doc["data"]["truth-error"])
    if name == "stop":
        print(f"{len(errors)} evaluations, best true error {min(errors):.1f} steps")
        print("outcome:", doc["reason"])


with simulated_rig("cavity", seed=0, obs_size=(320, 256)) as rig:
    RE(align("cavity", rig, policy="random"), report)
