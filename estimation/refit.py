"""A trained ``tn-match`` run with its motion tables measured again on other trajectories.

The smoothers of ``tn-match`` do most of its work, and their motion tables are measured, not
learned: training measures them on its training trajectories before the first epoch
(:meth:`Estimator.fit_motion`). :func:`refit_motion` measures them again on any trajectories of
the same data set (users who move otherwise than the training users: a deployment's own, or
``mmwsim trajectories --set`` with other speeds) and writes a new run folder with the same
network, so that evaluation, prediction and the online tracker use the new tables. A run saved
by an older version also gains the tables added since. Where only the users' fingerprints are
known, it adapts the run to them instead (:meth:`Estimator.adapt_motion`: tables measured on the
run's own tracks of those fingerprints, weighed beside the measured ones).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import torch

from .checkpoint import MODEL_FORMAT, load_checkpoint
from .data import SequenceSet
from .errors import EstimationError
from .estimator import MODEL_FILE, MODEL_KEYS, Estimator
from .noise import noisy_bits
from .training import RECORDING_FILE, RUN_FILE, read_run_info

__all__ = ["refit_motion"]


def refit_motion(
    run: str | os.PathLike,
    data: SequenceSet,
    out: str | os.PathLike,
    data_info: dict[str, Any] | None = None,
    unlabelled_noise: float | None = None,
    seed: int = 0,
    progress: bool = False,
) -> dict[str, Any]:
    """Write the run folder ``out``: the trained run ``run`` with its motion tables measured on
    the trajectories of ``data`` (:meth:`Estimator.fit_motion`), its network's weights kept.

    Parameters
    ----------
    run : path-like
        A ``tn-match`` run folder (``run.json`` and ``model.pt``); left as it is.
    data : SequenceSet
        Trajectories of at least 3 steps on the grid the network reads.
    out : path-like
        The new run folder: missing or empty, not ``run``. It appears whole (``model.pt`` with
        the new tables and the weights' training record, ``run.json`` with a ``motion``
        entry saying where the tables were measured, ``training.rrd`` where ``run`` has one) or
        not at all; it has no ``checkpoint.pt``, since its tables are not those its network
        was trained with.
    data_info : dict, optional
        Description of ``data`` (``dataset``, ``content_hash``, ``split``), stored under
        ``motion`` in ``run.json``. Where it and the run's own data description both carry a
        content hash they must agree: the tables are measured in the frame of the grid the
        network was trained on.
    unlabelled_noise : float, optional
        Instead, adapt the run to fingerprints drawn at ``data``'s positions with this noise
        (dB) and ``seed`` (:meth:`Estimator.adapt_motion`: tables measured on the run's own
        tracks of them, weighed beside the measured tables, which stay): what a deployment can
        do with fingerprint sequences of users whose positions nobody knows. The positions
        only make the fingerprints.
    seed : int
        Seed of that noise.
    progress : bool
        Show a bar of that tracking (tqdm, on stderr).

    Returns
    -------
    dict
        The ``motion`` entry: ``trajectories``, ``seconds`` and ``data_info``'s keys.
    """
    from mmwsim.files import remove_tree, replace_dir
    from mmwsim.locks import locked_output

    run, out = Path(run), Path(out)
    info = read_run_info(run)
    data_info = dict(data_info or {})
    trained_on = str(info["data"].get("content_hash", ""))
    given = str(data_info.get("content_hash", ""))
    if trained_on and given and trained_on != given:
        raise EstimationError(
            f"{run} was trained on another data set (content hash {trained_on[:12]}, "
            f"{data_info.get('dataset', 'the data')} has {given[:12]}): its tables are measured on the grid it reads"
        )
    if out.resolve() == run.resolve():
        raise EstimationError(f"{out}: is the run itself; choose another --out (the run stays as it is)")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise EstimationError(f"{out}: exists and is not an empty folder; choose another --out")
    state = load_checkpoint(run / MODEL_FILE, MODEL_FORMAT, MODEL_KEYS)
    est = Estimator.from_state(state, str(run / MODEL_FILE))
    start = time.perf_counter()
    if unlabelled_noise is None:
        est.fit_motion(data)
    else:
        bits = noisy_bits(data, float(unlabelled_noise), torch.Generator().manual_seed(int(seed)))
        est.attach(data, sigma=float(unlabelled_noise)).adapt_motion(bits, progress=progress)
        data_info |= {"unlabelled_noise": float(unlabelled_noise), "seed": int(seed)}
    motion = {**data_info, "trajectories": int(data.n), "seconds": round(time.perf_counter() - start, 3)}
    motion["from_run"] = str(run.resolve())
    with locked_output(out, "run") as final:
        tmp = final.with_name(f".{final.name}.partial")
        remove_tree(tmp)
        tmp.mkdir()
        try:
            est.save(tmp / MODEL_FILE, {k: v for k, v in state.items() if k not in ("format", *MODEL_KEYS)})
            (tmp / RUN_FILE).write_text(json.dumps({**info, "motion": motion}, indent=2, sort_keys=True))
            if (run / RECORDING_FILE).is_file():
                shutil.copyfile(run / RECORDING_FILE, tmp / RECORDING_FILE)
            replace_dir(tmp, final)
        finally:
            remove_tree(tmp)
    return motion
