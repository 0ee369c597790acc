"""Trace the exact specular paths from the default scene's transmitter to a few receivers.

Run: python examples/trace_paths.py
"""

import numpy as np

import mmwsim

scene = mmwsim.load_scene("default")
receivers = np.array([[200.0, 100.0, 1.5], [300.0, 203.0, 1.5], [100.0, 203.0, 1.5]])
assert scene.outdoors(receivers).all()

# One Tracer shoots its candidate rays once; .trace() then solves any set of receivers exactly.
tracer = mmwsim.Tracer(scene, scene.transmitter.array, max_reflections=3, n_rays=2_000_000)
paths = tracer.trace(receivers)
names = [o.name for o in scene.objects]
offsets = paths.offsets()
gain = paths.gain_db()  # isotropic, vertically polarised at both ends
for i, rx in enumerate(receivers):
    print(f"receiver at {rx.tolist()}: {offsets[i + 1] - offsets[i]} paths")
    for p in range(offsets[i], offsets[i + 1]):
        via = " > ".join(names[o] for o in paths.objects[p] if o >= 0) or "line of sight"
        print(f"  {paths.delay[p] * 1e9:8.2f} ns  {gain[p]:7.2f} dB  {via}")
