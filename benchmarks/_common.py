"""Shared helpers for the benchmarks: float64 setup, timing (median of repeats, with
`jax.block_until_ready`), exact solutions of the benchmark problems, markdown tables."""

import os


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import contextlib  # noqa: E402
import signal  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402
from scipy.linalg import expm  # noqa: E402
from scipy.optimize import brentq  # noqa: E402


jax.config.update("jax_enable_x64", True)


# --- timing ------------------------------------------------------------------------------------
def block(x):
    """`jax.block_until_ready` on any pytree (non-JAX leaves pass through)."""
    return jax.block_until_ready(x)


def time_once(fn, *args):
    """Wall time of one call (outputs blocked on) and its output."""
    t0 = time.perf_counter()
    out = block(fn(*args))
    return time.perf_counter() - t0, out


def median_time(fn, *args, repeats=5, number=1, setup=None, reduce=statistics.median):
    """Median over `repeats` of the mean time of `number` back-to-back calls (`reduce`:
    another statistic of the repeats, e.g. `min` on a shared machine).

    `setup()` (optional) is called before each repeat, outside the timed region, and its
    return value is passed as the first argument (used for the reference's stateful solver
    objects, which must be fresh for every solve)."""
    times = []
    for _ in range(repeats):
        pre = () if setup is None else (setup(),)
        t0 = time.perf_counter()
        for _ in range(number):
            out = block(fn(*pre, *args))
        times.append((time.perf_counter() - t0) / number)
    return reduce(times), out


def auto_number(fn, *args, target=0.05, setup=None):
    """Calls per repeat so that one repeat takes about `target` seconds."""
    dt, _ = median_time(fn, *args, repeats=1, number=1, setup=setup)
    return max(1, min(10_000, int(target / max(dt, 1e-7))))


# --- exact solutions ---------------------------------------------------------------------------
G = 9.81


def ball_exact(t_end, v0=1.0, s0=2.0, e=0.8, g=G):
    """Bouncing ball y = [v, s] (s'' = -g, Newton impacts at s = 0 with restitution e):
    piecewise ballistic. Returns the state at `t_end` and the impact times before it."""
    t, v, s = 0.0, v0, s0
    impacts = []
    while True:
        t_hit = (v + np.sqrt(v**2 + 2 * g * s)) / g
        if t + t_hit > t_end:
            dt = t_end - t
            return np.array([v - g * dt, s + v * dt - 0.5 * g * dt**2]), impacts
        t += t_hit
        impacts.append(t)
        v, s = -e * (v - g * t_hit), 0.0


def slider_exact(m=2.0, k=1.0, c=2.0, fric=0.6, v0=0.1):
    """Spring-slider m v' = -k s - c v - fric Sign(v), s' = v from (v0, 0): slides forward,
    then sticks for good (|k s| < fric). Returns (t_stick, s_stick)."""
    M = np.array([[-c / m, -k / m], [1.0, 0.0]])
    b = np.array([-fric / m, 0.0])
    Minv_b = np.linalg.solve(M, b)

    def flow(t):
        return expm(M * t) @ (np.array([v0, 0.0]) + Minv_b) - Minv_b

    t_stick = brentq(lambda t: flow(t)[0], 1e-6, 2.0, xtol=1e-15, rtol=4 * np.finfo(float).eps)
    s_stick = flow(t_stick)[1]
    assert abs(k * s_stick) < fric
    return t_stick, s_stick


def relay_d(t):
    return 0.5 * np.sin(2 * np.pi * t)


def relay_x_reaching(t, x0=0.5):
    """x(t) for x' = -1 + d(t) (before the sliding surface is reached)."""
    return x0 - t + 0.5 / (2 * np.pi) * (1 - np.cos(2 * np.pi * t))


def relay_reaching_time(x0=0.5):
    return brentq(lambda t: relay_x_reaching(t, x0), 1e-6, 2.0, xtol=1e-15)


def relay_exact(t, x0=0.5):
    """Filippov solution of x' = -Sign(x) + d(t), x(0) = x0 > 0 (|d| < 1): (x(t), w(t)) with
    w = 1 before the reaching time and w = d(t) in sliding (x = 0)."""
    t = np.asarray(t, float)
    tr = relay_reaching_time(x0)
    x = np.where(t < tr, relay_x_reaching(t, x0), 0.0)
    w = np.where(t < tr, 1.0, relay_d(t))
    return x, w


# --- output ------------------------------------------------------------------------------------
def fmt_time(s):
    """Seconds, printed in a readable unit."""
    if s is None or not np.isfinite(s):
        return "n/a"
    if s >= 1:
        return f"{s:.2f} s"
    if s >= 1e-3:
        return f"{s * 1e3:.2f} ms"
    return f"{s * 1e6:.1f} µs"


def fmt_num(x, spec=".1e"):
    if x is None:
        return "n/a"
    if isinstance(x, str):
        return x
    if not np.isfinite(x):
        return str(x)
    return format(x, spec)


def markdown_table(headers, rows):
    """A GitHub-flavoured markdown table."""
    cells = [[str(c) for c in r] for r in rows]
    lines = [
        "| " + " | ".join(headers) + " |",
        "|" + "|".join("---" for _ in headers) + "|",
    ]
    lines += ["| " + " | ".join(r) + " |" for r in cells]
    return "\n".join(lines)


def compile_timed(fn, *args, options=None):
    """`jax.jit(fn)` lowered and compiled for `args`: (the jitted function, seconds). The
    time covers tracing (the library's Python-side assembly included) and XLA compilation.
    `options`: XLA compiler options (nivpjax's runs pass `nj.compiler_options()`, which its
    own top-level programs use; the peers compile with XLA's defaults, as their users do).

    Calls then go through the jitted function, which reuses that executable (no second
    compilation) on JAX's C++ dispatch path, as a user's calls do. Calling the AOT
    `Compiled` object instead falls back to Python dispatch for programs with error
    checks (`equinox.error_if`, in nivpjax and diffrax alike): about 0.1 ms more per call,
    measured on a relay solve (0.24 ms against 0.13 ms)."""
    jitted = jax.jit(fn, compiler_options=options)
    t0 = time.perf_counter()
    jitted.lower(*args).compile()
    return jitted, time.perf_counter() - t0


class BufferTiers:
    """Runs of one configuration at the smallest output-buffer size that holds them.

    `build(max_steps)` returns the function to compile, `overflowed(out)` says whether a
    run ran out of buffer (`max_steps` reached). Each size in `tiers` is compiled when a
    run first needs it; `compile_s` is the first (smallest) one's compile time. Output
    buffers are allocated and filled on every call (16384 rows cost about 0.1 ms per call
    on this machine, 100 000 rows several times that), so sizing them to the run, as a
    user sizes `max_steps` for a job, keeps that cost out of the comparison; nivpjax and
    diffrax get the same treatment."""

    def __init__(self, build, tiers, overflowed, *args0, options=None):
        self.build, self.tiers, self.overflowed, self.args0 = build, tiers, overflowed, args0
        self.options = options
        self.fns = {}
        self.compile_s = None

    def _fn(self, max_steps):
        if max_steps not in self.fns:
            fn, seconds = compile_timed(self.build(max_steps), *self.args0, options=self.options)
            self.fns[max_steps] = fn
            self.compile_s = seconds if self.compile_s is None else self.compile_s
        return self.fns[max_steps]

    def __call__(self, *args):
        """`(fn, out, seconds)`: the function of the smallest size that holds this run,
        its output and the wall time of that (first) call."""
        for max_steps in self.tiers:
            fn = self._fn(max_steps)
            seconds, out = time_once(fn, *args)
            if not self.overflowed(out):
                break
        return fn, out, seconds


class TimeLimit(BaseException):
    """Raised by `time_limit` (a BaseException, so that a library's `except Exception`
    does not swallow it)."""


@contextlib.contextmanager
def time_limit(seconds):
    """Interrupt the (pure Python) code inside after `seconds` of wall time (SIGALRM;
    main thread only). Used for the reference package and scipy, which can stall in
    endless tiny steps."""

    def handler(signum, frame):
        raise TimeLimit(f"over {seconds:g} s")

    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
