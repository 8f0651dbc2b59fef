"""A text progress meter driven from inside the compiled loop (off by default)."""

import sys
import time

import jax
import numpy as np


class _Meter:
    def __init__(self, t0, t1, every=0.25):
        self.t0, self.t1, self.every = float(t0), float(t1), every
        self.last = 0.0

    def __call__(self, t):
        now = time.monotonic()
        t = np.asarray(t)
        frac = float(np.min((t - self.t0) / (self.t1 - self.t0))) if t.size else 1.0
        if now - self.last >= self.every or frac >= 1.0:
            self.last = now
            bar = "#" * int(30 * frac)
            sys.stderr.write(f"\rnivpjax: [{bar:<30}] {100 * frac:5.1f}%")
            if frac >= 1.0:
                sys.stderr.write("\n")
            sys.stderr.flush()


def progress_callback(t0, t1):
    """A function `update(t)` to call inside the loop; prints the fraction of `[t0, t1]`
    done (the slowest member under `vmap`) at most four times a second."""
    meter = _Meter(t0, t1)

    def update(t):
        jax.debug.callback(meter, t)

    return update
