"""SIGTERM as Ctrl-C, for the command line."""

import contextlib
import signal
import threading


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Inside it, SIGTERM (what ``timeout`` and job schedulers send) raises ``KeyboardInterrupt``
    as Ctrl-C does: a stopped benchmark still reports what it measured, and a stopped conversion
    removes its temporary file (OUT is left as it was). Outside the main thread it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
