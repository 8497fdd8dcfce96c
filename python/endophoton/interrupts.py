"""Ctrl-C on the command line: SIGINT cancels the running work instead of ending the process, so
that ``run`` prints its partial result and ``sweep`` writes what it finished (exit status 130)."""
from __future__ import annotations

import contextlib
import signal

__all__ = ["sigint_cancels"]


@contextlib.contextmanager
def sigint_cancels():
    """While open, Ctrl-C (SIGINT) cancels the CancelToken it yields instead of raising
    KeyboardInterrupt (the engine runs signal handlers at every progress tick, so a run stops
    within ~0.1 s). Kept open while the outputs are written, so that a second Ctrl-C cannot cut
    the writing of what the first one kept."""
    from .run import CancelToken

    token = CancelToken()
    previous = signal.signal(signal.SIGINT, lambda signum, frame: token.cancel())
    try:
        yield token
    finally:
        signal.signal(signal.SIGINT, previous)
