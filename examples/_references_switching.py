"""Exact references for the switching scenes of `nivpjax.scenes`, written without nivpjax.

Shared by `relay.py`, `super_twisting.py`, `rectifier.py` and `chua.py` in this folder. Every
function is plain NumPy/SciPy: closed forms with switching times found by Brent's method
(relay, rectifiers), and event-driven DOP853 at rtol 1e-12 (super-twisting between the sign
changes of the sliding variable, Chua's circuit on each linear region) so that no reference
step straddles a discontinuity. Also the small helpers the scripts share: timing a solve with
compilation and run separated, and the output folder.
"""

import os
import time

import jax
import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq


OUTPUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "output")


def output_path(name):
    """`examples/output/<name>`, creating the folder (git-ignored) if needed."""
    os.makedirs(OUTPUT, exist_ok=True)
    return os.path.join(OUTPUT, name)


def timed_solve(solve, *inputs):
    """Compile `jax.jit(solve)` for `inputs` and run it, timing both separately.

    **Returns:** `(compiled, output, compile_seconds, run_seconds)`; the run is timed on the
    compiled executable (`jax.block_until_ready`), without tracing or compilation; call
    `compiled` again with new inputs of the same shapes and dtypes.
    """
    t0 = time.perf_counter()
    compiled = jax.jit(solve).lower(*inputs).compile()
    t1 = time.perf_counter()
    out = jax.block_until_ready(compiled(*inputs))
    t2 = time.perf_counter()
    return compiled, out, t1 - t0, t2 - t1


def run_timed(compiled, *inputs):
    """`(output, seconds)` of one call of a compiled executable."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(compiled(*inputs))
    return out, time.perf_counter() - t0


def first_root(g, t0, t1, dt):
    """The first sign change of `g` on a grid of spacing `dt` in `(t0, t1]`, refined by
    Brent's method to machine precision; `None` if there is none."""
    grid = np.append(np.arange(t0, t1, dt), t1)
    values = np.array([g(t) for t in grid])
    idx = np.flatnonzero(np.sign(values[1:]) != np.sign(values[:-1]))
    if idx.size == 0:
        return None
    i = idx[0]
    return brentq(g, grid[i], grid[i + 1], xtol=1e-16, rtol=4 * np.finfo(float).eps)


# ----------------------------------------------------------------------------------------------
# Relay: x' = -sign(x) + a sin(2 pi f t), x0 > 0, |a| < 1.


def relay_exact(t, a, f, x0):
    """The exact state and Filippov selection at the times `t`, and the reaching time $T$.

    Before $T$: $w = 1$ and $x = x_0 - t + a(1 - \\cos 2\\pi f t)/(2\\pi f)$, strictly
    decreasing ($x' \\le -(1 - |a|)$), so $T$ is the unique root, below $x_0/(1 - |a|)$.
    After $T$: sliding, $x = 0$ and $w = d(t) = a \\sin 2\\pi f t$ (which keeps $x' = 0$).

    **Returns:** `(x, w, T)`.
    """
    t = np.asarray(t, dtype=float)
    free = lambda s: x0 - s + a * (1 - np.cos(2 * np.pi * f * s)) / (2 * np.pi * f)
    T = brentq(free, 0.0, x0 / (1 - abs(a)), xtol=1e-16, rtol=4 * np.finfo(float).eps)
    x = np.where(t < T, free(t), 0.0)
    w = np.where(t < T, 1.0, a * np.sin(2 * np.pi * f * t))
    return x, w, T


def forced_relay_exact(ts, x0, A, W, T):
    """The Filippov solution of $x' = -w + A\\sin Wt$, $w \\in \\operatorname{sign}(x)$, at the
    sorted times `ts` (any $A$: with $|A| > 1$ it enters and leaves sliding every half
    period), piece by piece in closed form.

    Off the surface $x' = -s + A\\sin Wt$ with $s = \\operatorname{sign}(x)$; on it, $x = 0$
    while $|A \\sin Wt| \\le 1$ (the equivalent control $w = A\\sin Wt$ inside the set).
    Piece ends are sign changes on a grid of 4000 points per unit time, refined by Brent's
    method to machine precision.

    **Returns:** `x` at `ts`.
    """
    U = lambda t: -A / W * np.cos(W * t)  # noqa: E731  (an antiderivative of the forcing)
    pieces = []  # (start, end, s, x at start); s = 0 for sliding
    t, x = 0.0, x0

    def first_zero(g, t, sign):
        grid = np.linspace(t, T, int((T - t) * 4000) + 2)
        vals = g(grid)
        hit = np.flatnonzero((vals[1:] * sign <= 0) & (grid[1:] > t + 1e-9))
        if not hit.size:
            return T
        i = hit[0]
        return brentq(g, grid[i], grid[i + 1], xtol=1e-15)

    left = False  # just left a sliding piece: leave the surface now
    while t < T - 1e-12:
        if x == 0.0 and not left and abs(A * np.sin(W * t)) < 1:
            end = first_zero(lambda s: 1 - np.abs(A * np.sin(W * s)), t, 1.0)
            pieces.append((t, end, 0.0, 0.0))
            t, left = end, True
            continue
        left = False
        s = np.sign(x) if x != 0.0 else np.sign(A * np.sin(W * (t + 1e-9)))
        x_t, t_a = x, t
        end = first_zero(lambda u: x_t - s * (u - t_a) + U(u) - U(t_a), t, s)
        pieces.append((t, end, s, x))
        t, x = end, 0.0
    out = np.empty(len(ts))
    for i, tq in enumerate(ts):
        for a, b, s, xa in pieces:
            if a - 1e-14 <= tq <= b + 1e-14:
                out[i] = xa - s * (tq - a) + U(tq) - U(a) if s else 0.0
                break
    return out


# ----------------------------------------------------------------------------------------------
# Super-twisting on a double integrator, d(t) = 0.3 sin 5t.


def st_disturbance(t):
    """`(d, d')` of the super-twisting scene's disturbance $d = 0.3\\sin 5t$."""
    return 0.3 * np.sin(5.0 * t), 1.5 * np.cos(5.0 * t)


def super_twisting_reference(x0, k1, k2, c, t_eval, t0=0.0):
    """The exact super-twisting trajectory from `x0` at `t0` at the times `t_eval` (sorted,
    none before `t0`).

    Reaching phase: $w = \\operatorname{sign}\\sigma$ is constant between the zero crossings
    of $\\sigma = x_2 + c x_1$ (they are transversal: $\\sigma' = \\nu + d + c x_2$ is
    continuous and nonzero there), so each segment is a smooth ODE, solved by DOP853 at rtol
    1e-12 up to the next crossing (a terminal event). The crossings accumulate in finite time
    $T^*$ (the twisting around the origin); the loop stops once two crossings are within
    1e-9. Sliding phase ($t \\ge T^*$, $\\sigma \\equiv 0$): $x_1 = x_1(T^*) e^{-c(t - T^*)}$,
    $x_2 = -c x_1$ and, from $\\sigma' = 0$, $\\nu = -d(t) - c x_2$.

    **Returns:** `(states, crossings, T_star)`, `states` of shape `(len(t_eval), 3)`.
    """
    t_eval = np.asarray(t_eval, dtype=float)
    t1 = t_eval[-1]

    def rhs(w):
        def f(t, x):
            s = x[1] + c * x[0]
            u = -k1 * np.sqrt(abs(s)) * w + x[2]
            return [x[1], u + st_disturbance(t)[0], -k2 * w]

        return f

    t, x = t0, np.asarray(x0, dtype=float)
    # On the surface at t0 the sqrt term vanishes: sigma leaves it along its rate.
    w = np.sign(x[1] + c * x[0]) or np.sign(x[2] + st_disturbance(t0)[0] + c * x[1])
    if w == 0:
        raise ValueError("x0 is the sliding state at t0: there is no reaching phase.")
    out = np.empty((t_eval.size, 3))
    crossings = []
    while True:
        event = lambda t, x: x[1] + c * x[0]
        event.terminal, event.direction = True, -w
        sol = solve_ivp(
            rhs(w),
            (t, t1),
            x,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
            events=event,
            dense_output=True,
        )
        inside = (t_eval >= t) & (t_eval <= sol.t[-1])
        if inside.any():
            out[inside] = sol.sol(t_eval[inside]).T
        if sol.status != 1:
            raise RuntimeError("sigma does not reach 0 before the end of `t_eval`.")
        t, x = sol.t_events[0][0], sol.y_events[0][0]
        crossings.append(t)
        w = -w
        if len(crossings) > 1 and crossings[-1] - crossings[-2] < 1e-9:
            break
    after = t_eval >= t
    x1 = x[0] * np.exp(-c * (t_eval[after] - t))
    out[after] = np.stack([x1, -c * x1, -st_disturbance(t_eval[after])[0] + c**2 * x1], 1)
    return out, np.array(crossings), t


# ----------------------------------------------------------------------------------------------
# Rectifiers: C v' = i - v/R_L, i = max(0, (src - v)/R_s), src = V sin wt or |V sin wt|.


class RectifierReference:
    """The exact piecewise solution of the half-wave (`full=False`) or bridge (`full=True`)
    rectifier from $v(0) = 0$.

    Off: $C v' = -v/R_L$, $v = v_0 e^{-(t - t_0)/(R_L C)}$. On: $C v' = (sV\\sin\\omega t -
    v)/R_s - v/R_L$ with $s = \\pm 1$ the sign of the conducting half-wave, i.e.
    $v' = -a v + b\\sin\\omega t$ with $a = 1/(R_s C) + 1/(R_L C)$, $b = sV/(R_s C)$, whose
    solution is $P\\sin\\omega t + Q\\cos\\omega t$ plus a decaying exponential
    ($P = ab/(a^2 + \\omega^2)$, $Q = -\\omega b/(a^2 + \\omega^2)$). The switches are the
    roots of $\\text{src}(t) - v(t)$: conduction starts when the source overtakes the load
    voltage and ends when the current $(\\text{src} - v)/R_s$ returns to 0. Both are
    continuous in $v'$, so the piece boundaries are found by Brent's method to machine
    precision.
    """

    def __init__(self, V, omega, R_s, R_L, C, t1, full):
        self.V, self.omega, self.R_s, self.R_L, self.C = V, omega, R_s, R_L, C
        self.full = full
        self.a = 1 / (R_s * C) + 1 / (R_L * C)
        self.pieces = []  # (t_start, t_end, s (0 when off), v_start)
        t, v, on = 0.0, 0.0, True  # v = src = 0 at t = 0 with the source rising
        dt = 2 * np.pi / omega / 4000
        while t < t1:
            s = (1.0 if np.sin(omega * (t + dt)) > 0 or not full else -1.0) if on else 0.0
            g = lambda tt, p=(t, 0.0, s, v): self.src(tt) - self._piece(p, tt)
            end = first_root(g, t + dt / 10, t1, dt)
            end = t1 if end is None else end
            self.pieces.append((t, end, s, v))
            t, v, on = end, self._piece(self.pieces[-1], end), not on

    def src(self, t):
        """The rectified source: $V\\sin\\omega t$ or $|V\\sin\\omega t|$."""
        e = self.V * np.sin(self.omega * np.asarray(t, dtype=float))
        return np.abs(e) if self.full else e

    def _piece(self, piece, t):
        t0, _, s, v0 = piece
        if s == 0:
            return v0 * np.exp(-(t - t0) / (self.R_L * self.C))
        a, w, b = self.a, self.omega, s * self.V / (self.R_s * self.C)
        P, Q = a * b / (a * a + w * w), -w * b / (a * a + w * w)
        vp = lambda tt: P * np.sin(w * tt) + Q * np.cos(w * tt)
        return vp(t) + (v0 - vp(t0)) * np.exp(-a * (t - t0))

    def v(self, ts):
        """The load voltage at the times `ts`."""
        ts = np.atleast_1d(np.asarray(ts, dtype=float))
        return np.array(
            [next(self._piece(p, t) for p in self.pieces if p[0] <= t <= p[1]) for t in ts]
        )

    def current(self, ts):
        """The total diode current $\\max(0, (\\text{src} - v)/R_s)$ at the times `ts`."""
        return np.maximum(0.0, (self.src(ts) - self.v(ts)) / self.R_s)

    def conduction(self):
        """The conduction intervals, an array of `(start, end)` rows."""
        return np.array([(p[0], p[1]) for p in self.pieces if p[2] != 0])


def rectifier_switch_times(ts, v, i, R_L, C, src):
    """Switching times read from a computed solution: the zero crossings of
    $\\text{src}(t) - v(t)$, with $v$ between accepted points the cubic Hermite interpolant
    of $v_k$ and $v'_k = (\\sum i_k - v_k/R_L)/C$ (from the computed currents `i`)."""
    dv = (i.sum(axis=1) - v / R_L) / C
    g = src(ts) - v
    out = []
    for k in np.flatnonzero((g[1:] > 0) != (g[:-1] > 0)):
        t0, h = ts[k], ts[k + 1] - ts[k]

        def gap(t, k=k, t0=t0, h=h):
            s = (t - t0) / h
            h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
            h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
            vi = h00 * v[k] + h10 * h * dv[k] + h01 * v[k + 1] + h11 * h * dv[k + 1]
            return src(t) - vi

        out.append(brentq(gap, t0, ts[k + 1], xtol=1e-15))
    return np.array(out)


# ----------------------------------------------------------------------------------------------
# Chua's circuit: x' = alpha (y - x - g(x)), y' = x - y + z, z' = -beta y.


def chua_reference(x0, t_eval, alpha, beta, m0, m1):
    """Chua's circuit at the times `t_eval` (sorted), with $g(x) = m_0 x + (m_1 - m_0)
    \\operatorname{clip}(x, -1, 1)$ handled region by region: on $|x| < 1$, $x > 1$ and
    $x < -1$ the field is linear; DOP853 at rtol 1e-13 integrates each region up to a
    terminal event on $x = \\pm 1$ and restarts on the kink, so no step straddles it.

    **Returns:** `(states, kink_times)`.
    """
    t_eval = np.asarray(t_eval, dtype=float)

    def rhs(region):
        def f(t, u):
            sat = u[0] if region == 0 else float(region)
            g = m0 * u[0] + (m1 - m0) * sat
            return [alpha * (u[1] - u[0] - g), u[0] - u[1] + u[2], -beta * u[1]]

        return f

    def boundary(level, direction):
        event = lambda t, u: u[0] - level
        event.terminal, event.direction = True, direction
        return event

    t, u = 0.0, np.asarray(x0, dtype=float)
    region = 0 if abs(u[0]) < 1 else int(np.sign(u[0]))
    out, kinks = np.empty((t_eval.size, 3)), []
    while True:
        if region == 0:
            events = [boundary(1.0, 1), boundary(-1.0, -1)]
        else:
            events = [boundary(float(region), -region)]
        sol = solve_ivp(
            rhs(region),
            (t, t_eval[-1]),
            u,
            method="DOP853",
            rtol=1e-13,
            atol=1e-15,
            events=events,
            dense_output=True,
        )
        inside = (t_eval >= t) & (t_eval <= sol.t[-1])
        if inside.any():
            out[inside] = sol.sol(t_eval[inside]).T
        if sol.status != 1:
            return out, np.array(kinks)
        t = next(te[0] for te in sol.t_events if te.size)
        u = sol.sol(t)
        u[0] = np.round(u[0])  # exactly on the kink
        kinks.append(t)
        region = 0 if region != 0 else int(u[0])
