"""A text progress meter driven from inside the compiled loop (off by default)."""

import sys
import time

import jax
import numpy as np


class _Meter:
    def __init__(self, every=0.25):
        self.every = every
        self.last = 0.0
        self.done = False

    def __call__(self, t, t0, t1):
        now = time.monotonic()
        t, t0, t1 = np.asarray(t), np.asarray(t0), np.asarray(t1)
        frac = float(np.min((t - t0) / (t1 - t0)))
        if frac >= 1.0 and self.done:
            return
        if now - self.last >= self.every or frac >= 1.0:
            self.last = now
            bar = "#" * int(30 * frac)
            sys.stderr.write(f"\rnivpjax: [{bar:<30}] {100 * frac:5.1f}%")
            if frac >= 1.0:
                self.done = True
                sys.stderr.write("\n")
            sys.stderr.flush()


def progress_callback(t0, t1):
    """A function `update(t)` to call inside the loop; prints the fraction of `[t0, t1]`
    done (the slowest member under `vmap`) at most four times a second."""
    meter = _Meter()

    def update(t):
        jax.debug.callback(meter, t, t0, t1)

    return update
