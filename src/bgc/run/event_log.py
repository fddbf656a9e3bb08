"""The event log of a hybrid model's run as arrays for ``bgc simulate --out`` (saved beside the
outputs in the .npz): one row per event, in the order they happened.

The keys hold a double underscore, which no output name may: ``event__t`` (times),
``event__name``, ``event__instance`` (the instance's index in the batch, -1 padded),
``event__x_before`` and ``event__x_after`` (the states, in STATE_NAMES order)."""
from __future__ import annotations

import numpy as np


def event_arrays(events, n_states: int) -> dict:
    """The log as arrays (nothing for a run without events)."""
    if not events:
        return {}
    depth = max(len(ev[2]) for ev in events)
    index = np.full((len(events), depth), -1, dtype=np.int64)
    for row, ev in enumerate(events):
        index[row, :len(ev[2])] = ev[2]
    return {"event__t": np.array([float(ev[0]) for ev in events]),
            "event__name": np.array([ev[1] for ev in events]),
            "event__instance": index,
            "event__x_before": np.array([ev[3] for ev in events]).reshape(len(events), n_states),
            "event__x_after": np.array([ev[4] for ev in events]).reshape(len(events), n_states)}

