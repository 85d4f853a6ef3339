"""Helpers of the tests that open Zenoh sessions: loopback only."""

import socket


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(pred, timeout, step=0.01):
    """``pred()``'s first truthy value within ``timeout`` s (checked every ``step`` s), else its last."""
    import time

    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        v = pred()
        if v:
            return v
        time.sleep(step)
    return pred()
