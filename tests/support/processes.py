"""Child processes that a test stops with Ctrl-C (SIGINT)."""

from __future__ import annotations

import signal


def ctrl_c_default() -> None:
    """Popen's preexec_fn: the child takes SIGINT as Ctrl-C. A suite started as a background job of a
    non-interactive shell (`./run test &`) inherits SIGINT ignored, and Python then never raises
    KeyboardInterrupt: the child would run on and the test would time out, not the product."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
