"""Track a user from beamformed fingerprints and plan a path inside the corridor of the estimate.

Library use end to end, small enough to run in seconds: a coarse data set of the default scene,
trajectories with a spatial hold-out region, a short transformer training, the estimate of one
held-out trajectory from fingerprints sampled with fresh noise, and Informed RRT* inside the
corridor around that estimate.

Run: python examples/track_and_plan.py [OUT_DIR]
"""

import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

import estimation
import mmwsim
import planning
from mmwsim.trajectories import generate_for_dataset

folder = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp())
folder.mkdir(parents=True, exist_ok=True)
torch.set_num_threads(1)

# 1. A coarse data set (receivers every 10 m) and user trajectories stored in it.
store = folder / "coarse.zarr"
mmwsim.generate_dataset("default", store, spacing=10.0, n_rays=1_000_000, progress=False, resume=True)
ds = mmwsim.Dataset.open(store)
scene = ds.scene()
counts = {"pedestrian": 200, "vehicle": 200, "hybrid": 50}
trajectories = generate_for_dataset(ds, counts, length=7, seed=0, scene=scene, vehicles_on_streets=True)
mmwsim.write_trajectories(ds, mmwsim.split(trajectories, seed=0, holdout_region=(250, 250, 350, 350)))
print(ds)

# 2. Fingerprints: bits of (beam, delay bin) drawn with fresh 6 dB noise at every call.
rng = np.random.default_rng(0)
test = mmwsim.read_trajectories(ds, "test")
held_out = np.flatnonzero(test.holdout)
travel = np.linalg.norm(np.diff(test.positions[held_out], axis=1), axis=-1).sum(axis=1)
pick = held_out[np.argmax(travel)]  # the held-out trajectory that travels farthest
true = test.positions[pick]  # (7, 2) metres
bits = ds.fingerprints(ds.nearest(true), rng)  # (7 steps, 32 beams, 81 bins) uint8
print(f"trajectory {test.ids[pick]}: fingerprints {bits.shape}, {int(bits.sum())} bits set")

# 3. A short training of the transformer on the train / validation splits.
sets, info = estimation.load_splits(store, ("train", "validation"), dataset=ds)
# tn-match: the transformer over the grid's fingerprint-match candidates (it reads the data set's
# grid, so it also tracks users in the region no training trajectory visited).
config = estimation.TrainConfig(model="tn-match", epochs=2, epoch_size=256, max_length=7, seed=0)
summary = estimation.train(
    sets["train"],
    sets["validation"],
    config,
    folder / "tn-match",
    data_info=info,
    progress=False,
    log=lambda s: None,
)
print(f"trained tn-match: {summary['epochs']} epochs, validation RMSE {summary['best_val_rmse']:.1f} m")

# 4. The trained model on the held-out trajectory (a batch of one sequence).
model = estimation.Estimator.load(folder / "tn-match").attach(ds)
estimate = model.predict(torch.from_numpy(bits[None]).float())[0].numpy().astype(np.float64)  # (7, 2)
rmse = estimation.trajectory_rmse(estimate[None], true[None])[0]
print(f"estimate RMSE {rmse:.1f} m")

# 5. Informed RRT* from the estimated first to the estimated last position, inside the corridor.
space = planning.AgentSpace(scene, radius=0.5, corridor=planning.Corridor.from_array(estimate, 20.0))
start, goal = space.nearest_free_point(estimate[0]), space.nearest_free_point(estimate[-1])
if start is None or goal is None or np.allclose(start, goal):
    print("the corridor leaves no room to plan in")
else:
    result = planning.plan(space, start, goal, planner="irrtstar", iterations=500, seed=0)
    optimum = planning.shortest_path(space, start, goal)
    if result.solved and optimum is not None:
        print(f"{result.label}: {result.length:.1f} m, optimum in the corridor {optimum.length:.1f} m")
    else:
        print(f"{result.label}: no path between the estimated ends within the corridor")
