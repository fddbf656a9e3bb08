"""The event log of a hybrid model's run as arrays for ``bgc simulate --out`` (saved beside the
outputs in the .npz): one row per event, in the order they happened.

The keys hold a double underscore, which no output name may: ``event__t`` (times),
``event__name``, ``event__instance`` (the instance's index in the batch, -1 padded),
``event__x_before`` and ``event__x_after`` (the states, in STATE_NAMES order).

Also what `bgc simulate` says when the runtimes' Zeno guard stops a run (:func:`zeno_text`)."""
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


def zeno_text(exc) -> tuple[str, str]:
    """(the message, a remedy) of a run's SimulationError ``exc``; for the Zeno guard's stop
    the remedy a scene has (its max_events is the module's argument, not the scene's): end
    the run before the Zeno time, where a body coming to rest on a stop piles up impacts."""
    text = str(exc)
    if "Zeno behaviour" not in text or getattr(exc, "t", None) is None:
        return text, ""
    remedy = (f"; a body coming to rest on a stop (restitution below 1) reaches this at its "
              f"Zeno time: end the run before t = {exc.t:.6g} s (the scene's duration, or "
              "--t-end)")
    return text.replace("raise max_events", "in Python, simulate(max_events=...)"), remedy
