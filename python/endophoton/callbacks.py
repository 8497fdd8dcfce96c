"""The return values of the user's callbacks, checked by type (one rule for every callback).

Two kinds of callback reach the package:

- a *progress* callback (``ep.run(progress=...)``, ``ep.sweep(progress=...)``, a cluster run's)
  answers whether the run goes on: ``None`` or ``True`` continue, ``False`` stops (numpy's bool
  counts as a bool). Anything else, e.g. the string ``"continue"``, is a TypeError naming the
  callback and the value's type: a truthy string must not pass as "go on" nor abort the process.
- a *notification* (``on_run``, ``on_beta``, ``on_chunks``, ``on_chunk``, ``on_finished``) is told
  something and answers nothing: its value is ignored (``kept.setdefault(i, result)`` is a fine
  on_run), but a bool is refused by name, TypeError: ``False`` would read as "stop", which a
  notification cannot do (cancel= or a progress callback stops a run).

The engine's binding (native/bindings/run.cpp) applies the progress rule once more to whatever
callable reaches it directly, so no return value can end the process (it used to abort it).
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

__all__ = ["progress_verdict", "checked_progress", "notification_done", "checked_notification"]


def _kind(value: Any) -> str:
    return type(value).__name__


def progress_verdict(name: str, value: Any) -> bool:
    """Whether a run goes on after progress callback ``name`` returned ``value``: None or True
    -> True, False -> False; any other value is a TypeError naming ``name``."""
    if value is None:
        return True
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise TypeError(
        f"{name} returned {_kind(value)} {_short(value)}: a progress callback must return None or True "
        "(go on) or False (stop)"
    )


def checked_progress(name: str, fn: Callable | None) -> Callable | None:
    """``fn`` (a progress callback, or None) wrapped so that its value is :func:`progress_verdict`'s
    bool: what the engine and the cluster loop get."""
    if fn is None:
        return None

    def progress(*args):
        return progress_verdict(name, fn(*args))

    progress.__wrapped__ = fn
    return progress


def notification_done(name: str, value: Any) -> None:
    """A notification callback ``name`` returned ``value``: ignored, but a bool (numpy's too) is a
    TypeError naming it (a notification cannot answer go on or stop)."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(
            f"{name} returned {_kind(value)} {_short(value)}: a notification cannot stop or continue anything "
            "(its value is ignored): to stop, use cancel= or a progress callback returning False"
        )


def checked_notification(name: str, fn: Callable | None) -> Callable | None:
    """``fn`` (a notification callback, or None) wrapped so that a returned bool is refused."""
    if fn is None:
        return None

    def notify(*args):
        notification_done(name, fn(*args))

    notify.__wrapped__ = fn
    return notify


def _short(value: Any) -> str:
    """``repr(value)``, at most 60 characters (a callback may return anything, however large)."""
    try:
        text = repr(value)
    except Exception:  # a hostile __repr__ must not hide the message
        return "(unprintable)"
    return text if len(text) <= 60 else text[:57] + "..."
