"""Exact references for the mechanical scenes of `nivpjax.scenes`, written without nivpjax.

Shared by the example scripts in this folder and by `tests/test_scenes_mechanics.py`. Every
reference is plain NumPy/SciPy: closed forms where the motion is piecewise polynomial or
harmonic, and an event-driven integration (DOP853 at rtol 1e-12, events located by root
finding) where the slip phase of the spring slider has slip-weakening friction. Two small
utilities for the examples (timing a compiled call, the output folder) close the file.
"""

import os
import time

import numpy as np
from scipy.integrate import solve_ivp


# ----------------------------------------------------------------------------------------------
# Bouncing ball: q'' = -g in flight, v+ = -e v- at q = 0.


def ball_impacts(height, velocity, e, g, n=400):
    """Impact times, pre-impact speeds and the accumulation (Zeno) time of a ball released at
    `height` with upward `velocity`.

    The first impact is at $t_1 = (v_0 + u_1)/g$ with speed $u_1 = \\sqrt{v_0^2 + 2gH}$; the
    $k$-th rebound leaves at $e^k u_1$ and flies $2 e^k u_1/g$, so the impacts accumulate at
    $t_\\infty = t_1 + 2 e u_1 / (g(1 - e))$.

    **Returns:** `(t_impacts, speeds_in, t_inf)`, arrays of length `n`.
    """
    u1 = np.sqrt(velocity**2 + 2 * g * height)
    t1 = (velocity + u1) / g
    k = np.arange(n)
    speeds_in = u1 * e**k
    flights = 2 * u1 * e ** (k + 1) / g
    t_impacts = t1 + np.concatenate([[0.0], np.cumsum(flights[:-1])])
    t_inf = t1 + 2 * e * u1 / (g * (1 - e))
    return t_impacts, speeds_in, t_inf


def ball_state(t, height, velocity, e, g):
    """The exact state `(q, v)` of the bouncing ball at the times `t` (array); at rest after
    the accumulation time."""
    t = np.asarray(t, dtype=float)
    t_imp, speeds, t_inf = ball_impacts(height, velocity, e, g)
    k = np.searchsorted(t_imp, t, side="right")  # impacts at or before t
    before = k == 0
    j = np.maximum(k - 1, 0)
    tau = t - t_imp[j]
    w = e * speeds[j]  # take-off speed after impact j
    q = np.where(before, height + velocity * t - 0.5 * g * t**2, w * tau - 0.5 * g * tau**2)
    v = np.where(before, velocity - g * t, w - g * tau)
    rest = t >= t_inf
    return np.where(rest, 0.0, q), np.where(rest, 0.0, v)


# ----------------------------------------------------------------------------------------------
# Spring slider: m s'' = k (V t - s) - c s' - mu(s) N Sign(s').


def slider_constant_friction(s0, v0, m, k, mu, normal, t_end):
    """Exact piecewise-harmonic motion of the undriven, undamped slider with constant
    friction $F = \\mu N$: while slipping with sign $\\sigma$, $s$ oscillates about
    $s_c = -\\sigma F/k$ with $\\omega = \\sqrt{k/m}$; when $v = 0$ it sticks for good if
    $|k s| \\le F$, otherwise it slips back (half a period).

    **Returns:** `(phases, t_stick)`: `phases` a list of `(t_start, s_start, v_start, sigma)`
    (sigma 0 for the final stick) and the time it sticks (`inf` if not before `t_end`).
    """
    omega = np.sqrt(k / m)
    force = mu * normal
    t, s, v = 0.0, float(s0), float(v0)
    phases = []
    while t < t_end:
        if v == 0.0:
            if abs(k * s) <= force:
                phases.append((t, s, 0.0, 0))
                return phases, t
            sigma = -np.sign(s)
        else:
            sigma = np.sign(v)
        phases.append((t, s, v, sigma))
        centre = -sigma * force / k
        a, b = s - centre, v / omega
        # s - centre = R cos(omega tau - phi): v vanishes again at omega tau = phi (mod pi).
        phi = np.arctan2(b, a)
        tau = (phi if phi > 0 else phi + np.pi) / omega
        s = centre + np.hypot(a, b) * np.cos(omega * tau - phi)
        t, v = t + tau, 0.0
    return phases, np.inf


def slider_constant_friction_state(t, phases, m, k, mu, normal):
    """Evaluate `slider_constant_friction`'s phases at the times `t`."""
    t = np.asarray(t, dtype=float)
    omega = np.sqrt(k / m)
    starts = np.array([p[0] for p in phases])
    i = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(phases) - 1)
    s_out, v_out = np.empty_like(t), np.empty_like(t)
    for j, (t0, s0, v0, sigma) in enumerate(phases):
        sel = i == j
        tau = t[sel] - t0
        if sigma == 0:
            s_out[sel], v_out[sel] = s0, 0.0
            continue
        centre = -sigma * mu * normal / k
        s_out[sel] = centre + (s0 - centre) * np.cos(omega * tau) + v0 / omega * np.sin(omega * tau)
        v_out[sel] = -omega * (s0 - centre) * np.sin(omega * tau) + v0 * np.cos(omega * tau)
    return s_out, v_out


def slider_event_driven(p, s0, v0, t_end, t_eval):
    """Event-driven reference for the full spring-slider law (drive, damping, slip-weakening
    $\\mu(s) = \\mu_k + (\\mu_s - \\mu_k) e^{-|s|/D_c}$), `p` the scene's `args` as floats.

    Stick phases are exact: $s$ stays put until the spring force $k(Vt - s)$ exceeds
    $\\mu(s) N$, a time found in closed form. Slip phases integrate the smooth ODE with DOP853
    (rtol 1e-12, atol 1e-14) until $v = 0$ (located by the integrator's root finder); there
    the block sticks if $|k(Vt - s)| \\le \\mu(s) N$ and otherwise slips on.

    **Returns:** `(s, v)` at `t_eval` and the list of `(t, mode)` switches (mode +1/-1 slip
    direction, 0 stick).
    """
    m, k, c, N, V = p["m"], p["k"], p["c"], p["N"], p["V"]

    def mu(s):
        return p["mu_k"] + (p["mu_s"] - p["mu_k"]) * np.exp(-abs(s) / p["Dc"])

    t_eval = np.asarray(t_eval, dtype=float)
    s_out, v_out = np.full_like(t_eval, np.nan), np.full_like(t_eval, np.nan)
    t, s, v = 0.0, float(s0), float(v0)
    switches = []
    while t < t_end:
        if v == 0.0:
            spring = k * (V * t - s)
            if abs(spring) <= mu(s) * N:
                # Stick until the spring force reaches the static bound (never if V = 0).
                if V == 0.0:
                    t_next = np.inf
                else:
                    t_next = (s + np.sign(V) * mu(s) * N / k) / V
                    t_next = max(t_next, t)
                switches.append((t, 0))
                sel = (t_eval >= t) & (t_eval <= t_next)
                s_out[sel], v_out[sel] = s, 0.0
                t = t_next
                sigma = np.sign(V)
            else:
                sigma = np.sign(spring)
        else:
            sigma = np.sign(v)
        if t >= t_end:
            break
        switches.append((t, int(sigma)))

        def rhs(t_, x, sigma=sigma):
            return [x[1], (k * (V * t_ - x[0]) - c * x[1] - sigma * mu(x[0]) * N) / m]

        def stop(t_, x, sigma=sigma):
            return x[1]

        stop.terminal = True
        stop.direction = -sigma
        # From v = 0 the event function starts at zero; `direction` skips that root.
        sel = (t_eval >= t) & (t_eval <= t_end)
        sol = solve_ivp(
            rhs,
            (t, t_end),
            [s, v],
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
            events=stop,
            dense_output=True,
        )
        t_stop = sol.t_events[0][0] if sol.t_events[0].size else t_end
        sel = sel & (t_eval <= t_stop)
        if np.any(sel):
            x = sol.sol(t_eval[sel])
            s_out[sel], v_out[sel] = x[0], x[1]
        if sol.t_events[0].size:
            s, v = sol.y_events[0][0][0], 0.0
        else:
            s, v = sol.y[0, -1], sol.y[1, -1]
        t = t_stop
    return s_out, v_out, switches


# ----------------------------------------------------------------------------------------------
# Block on a plane: isotropic Coulomb friction, constant deceleration mu g.


def block_state(t, velocity, mu, g):
    """Exact position and velocity (2-D) of the block sliding from the origin: it moves along
    $\\hat v_0$ with speed $|v_0| - \\mu g t$ until $t^* = |v_0|/(\\mu g)$, then rests at
    distance $|v_0|^2/(2\\mu g)$.

    **Returns:** `(p, v, t_stop)` with `p`, `v` of shape `t.shape + (2,)`."""
    t = np.asarray(t, dtype=float)
    v0 = np.asarray(velocity, dtype=float)
    speed = np.linalg.norm(v0)
    direction = v0 / speed
    t_stop = speed / (mu * g)
    tc = np.minimum(t, t_stop)[..., None]
    p = direction * (speed * tc - 0.5 * mu * g * tc**2)
    v = direction * (speed - mu * g * tc)
    return p, v, t_stop


def pushed_block_state(t, velocity, mu, g, amp, omega):
    """Position and velocity (2-D) of the block pushed by $F = A(\\cos\\omega t,
    \\sin\\omega t)$ while it slips: $p' = v$, $v' = F - \\mu g\\,v/|v|$, from the origin,
    DOP853 at rtol 1e-13. Valid while the speed stays positive: a stop is an event, and a
    run that reaches one raises (the family's grid keeps the block slipping).

    **Returns:** `(p, v, min_speed)`, `p`, `v` of shape `t.shape + (2,)`, and the least
    speed over `[0, max(t)]`."""
    t = np.asarray(t, dtype=float)
    t_end = max(float(t.max()), 1e-12)

    def rhs(s, z):
        v = z[2:]
        force = amp * np.array([np.cos(omega * s), np.sin(omega * s)])
        return np.concatenate([v, force - mu * g * v / np.hypot(*v)])

    def stop(s, z):
        return np.hypot(*z[2:]) - 1e-3

    stop.terminal = True
    z0 = [0.0, 0.0, float(velocity[0]), float(velocity[1])]
    sol = solve_ivp(
        rhs,
        (0.0, t_end),
        z0,
        events=stop,
        method="DOP853",
        rtol=1e-13,
        atol=1e-14,
        dense_output=True,
    )
    if sol.t_events[0].size:
        raise ValueError(f"the pushed block stops near t = {sol.t_events[0][0]:.4g}")
    z = sol.sol(t.ravel()).T.reshape(t.shape + (4,))
    fine = sol.sol(np.linspace(0.0, t_end, 4001))
    return z[..., :2], z[..., 2:], float(np.min(np.hypot(*fine[2:])))


# ----------------------------------------------------------------------------------------------
# Ball stack: a dropped column with equal spacing and plastic impacts.


def stack_drop_state(t, n, radius, spacing, g):
    """Exact heights and velocities of the column of `n` unit balls released at rest with
    ball 0 on the floor and gaps `spacing` between the others, restitution 0.

    All the balls above the last stopped one fall together, so their gaps stay `spacing`;
    ball $i$ lands plastically on the (resting) column below after falling $i d$, at
    $t_i = \\sqrt{2 i d/g}$, and stays at $r(2i + 1)$.

    **Returns:** `(q, v, t_land)`, `q` and `v` of shape `t.shape + (n,)`.
    """
    t = np.asarray(t, dtype=float)[..., None]
    i = np.arange(n)
    t_land = np.sqrt(2 * i * spacing / g)
    start = radius + i * (2 * radius + spacing)
    flying = t < t_land
    q = np.where(flying, start - 0.5 * g * t**2, radius * (2 * i + 1))
    v = np.where(flying, -g * t, 0.0)
    return q, v, t_land


def stack_contact_forces(net_force):
    """Contact forces from the net contact force on each ball (bottom first): contact $i$
    (floor for $i = 0$, ball $i-1$ on ball $i$ otherwise) pushes ball $i$ up and ball $i-1$
    down, so the net force on ball $i$ is $\\lambda_i - \\lambda_{i+1}$ and
    $\\lambda_i = \\sum_{j \\ge i} F_j$."""
    net_force = np.asarray(net_force)
    return np.cumsum(net_force[..., ::-1], axis=-1)[..., ::-1]


# ----------------------------------------------------------------------------------------------
# A ball in a circular bowl (R = 1, plastic): on the wall a pendulum, phi'' = -g sin(phi), pressed
# by N = phi'^2 + g cos(phi); released where N = 0, a parabola inside, landing with the normal
# velocity removed, the pendulum again.


def _on_wall(phi, om):
    return np.stack([np.sin(phi), -np.cos(phi), om * np.cos(phi), om * np.sin(phi)], -1)


def _bowl_pendulum(phi0, om0, t0, t1, g):
    # Until t1 or the release (N reaching zero from above): (dense solution, end time).
    def normal(t, s):
        return s[1] ** 2 + g * np.cos(s[0])

    normal.terminal, normal.direction = True, -1
    sol = solve_ivp(
        lambda t, s: [s[1], -g * np.sin(s[0])],
        (t0, t1),
        [phi0, om0],
        method="DOP853",
        rtol=1e-13,
        atol=1e-13,
        dense_output=True,
        events=normal,
    )
    released = len(sol.t_events[0]) > 0
    return sol.sol, (sol.t_events[0][0] if released else t1), released


def bowl_pieces(v0, g, t_end):
    """The phases of a ball thrown from the bottom of a unit bowl at speed `v0`, as a list of
    `(t_start, t_end, state)` with `state(t) -> (q1, q2, v1, v2)`: on the wall, in flight
    (released where the normal force vanishes), on the wall again after a plastic landing
    (located by root finding on |q| = 1), and so on until `t_end`."""
    from scipy.optimize import brentq

    pieces, t0, phi, om = [], 0.0, 0.0, float(v0)
    down = np.array([0.0, -g])
    while t0 < t_end:
        wall, t_r, released = _bowl_pendulum(phi, om, t0, t_end, g)
        pieces.append((t0, t_r, lambda t, wall=wall: _on_wall(*wall(t))))
        if not released:
            break
        q_r, v_r = _on_wall(*wall(t_r))[:2], _on_wall(*wall(t_r))[2:]

        def flight(t, q_r=q_r, v_r=v_r, t_r=t_r):
            s = t - t_r
            return np.concatenate([q_r + v_r * s + 0.5 * down * s * s, v_r + down * s])

        inside = lambda t: 1.0 - np.sum(flight(t)[:2] ** 2)  # noqa: E731
        grid = t_r + np.linspace(1e-9, 2 * (abs(v0) + 1) / max(g, 1e-12), 20001)
        k = int(np.argmax([inside(t) < 0 for t in grid]))
        t_l = brentq(inside, grid[k - 1], grid[k], xtol=1e-15)
        pieces.append((t_r, min(t_l, t_end), flight))
        q, v = flight(t_l)[:2], flight(t_l)[2:]
        v = v - (v @ q) * q  # plastic: the normal velocity removed
        t0, phi = t_l, np.arctan2(q[0], -q[1])
        om = v @ np.array([np.cos(phi), np.sin(phi)])
    return pieces


def bowl_state(t, v0, g, t_end=None):
    """The state of the ball of `bowl_pieces` at the times `t` (an array)."""
    t = np.atleast_1d(np.asarray(t, float))
    pieces = bowl_pieces(v0, g, float(t.max()) if t_end is None else t_end)
    out = np.empty((t.size, 4))
    for i, ti in enumerate(t):
        for a, b, state in pieces:
            if ti <= b or (a, b, state) == pieces[-1]:
                out[i] = state(ti)
                break
    return out


# ----------------------------------------------------------------------------------------------
# A ball sliding on a circular wall of radius R with Coulomb friction mu (2-D, never leaving it):
# phi'' = -(g/R) sin(phi) - mu sign(phi') (phi'^2 + (g/R) cos(phi)) while it slides; at phi' = 0 it
# sticks for good where |tan(phi)| <= mu and turns back otherwise.


def friction_bowl_pieces(phi0, om0, mu, g, R, t_end):
    """The slide phases of the ball, as `(pieces, t_stick)`: `pieces` a list of
    `(t_start, t_end, dense)` with `dense(t) -> (phi, phi')`, `t_stick` the time it sticks
    (`inf` if not before `t_end`); DOP853 at rtol 1e-12, each stop located as an event."""
    pieces, t0, phi, om = [], 0.0, float(phi0), float(om0)
    while t0 < t_end:
        sigma = np.sign(om) if om != 0 else -np.sign(np.sin(phi))
        if om == 0 and abs(np.tan(phi)) <= mu:
            return pieces, t0

        def rhs(t, s, sigma=sigma):
            return [s[1], -(g / R) * np.sin(s[0]) - mu * sigma * (s[1] ** 2 + g / R * np.cos(s[0]))]

        def stop(t, s):
            return s[1]

        stop.terminal, stop.direction = True, -sigma
        sol = solve_ivp(
            rhs,
            (t0, t_end),
            [phi, om],
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
            dense_output=True,
            events=stop,
        )
        stopped = len(sol.t_events[0]) > 0
        t1 = sol.t_events[0][0] if stopped else t_end
        pieces.append((t0, t1, sol.sol))
        if not stopped:
            break
        t0, phi, om = t1, float(sol.sol(t1)[0]), 0.0
    return pieces, np.inf


def friction_bowl_state(t, phi0, om0, mu, g, R):
    """`(q1, q2, v1, v2)` of the sliding ball at the times `t` (array), at rest after its
    stick; and the stick time."""
    t = np.atleast_1d(np.asarray(t, float))
    pieces, t_stick = friction_bowl_pieces(phi0, om0, mu, g, R, float(t.max()))
    out = np.empty((t.size, 4))
    for i, ti in enumerate(t):
        a, b, dense = next((p for p in pieces if ti <= p[1]), pieces[-1])
        phi, om = dense(min(ti, b))
        om = 0.0 if ti >= t_stick else om
        out[i] = [R * np.sin(phi), -R * np.cos(phi), R * om * np.cos(phi), R * om * np.sin(phi)]
    return out, t_stick


# ----------------------------------------------------------------------------------------------
# A ball on the wall of an elliptic bowl (x/a)^2 + (y/b)^2 = 1, frictionless, pressed onto it:
# q = (a sin s, -b cos s), the constrained Lagrangian in the angle parameter s,
# |q_s|^2 s'' + (q_s . q_ss) s'^2 = -g y_s.


def ellipse_bowl_state(t, s0, sd0, a, b, g):
    r"""`(q1, q2, v1, v2)` at the times `t` (array) of a ball on the wall of the elliptic bowl
    from parameter `s0` at rate `sd0`; DOP853 at rtol 1e-12. Also the normal force
    $N = \kappa |v|^2 + g\,n_y$ per unit mass (it must stay positive: on the wall)."""

    def rhs(t, z):
        s, sd = z
        qs = np.array([a * np.cos(s), b * np.sin(s)])
        qss = np.array([-a * np.sin(s), b * np.cos(s)])
        return [sd, -(qs @ qss * sd**2 + g * qs[1]) / (qs @ qs)]

    t = np.atleast_1d(np.asarray(t, float))
    t_end = max(float(t.max()), 1e-12)
    kw = dict(method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True)
    s, sd = solve_ivp(rhs, (0.0, t_end), [s0, sd0], **kw).sol(t)
    q = np.stack([a * np.sin(s), -b * np.cos(s)], -1)
    qs = np.stack([a * np.cos(s), b * np.sin(s)], -1)
    qss = np.stack([-a * np.sin(s), b * np.cos(s)], -1)
    v = qs * sd[:, None]
    acc = qss * sd[:, None] ** 2 + qs * np.array([rhs(0, z)[1] for z in zip(s, sd)])[:, None]
    inward = -np.stack([q[:, 0] / a**2, q[:, 1] / b**2], -1)
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    normal = np.sum((acc + np.array([0.0, g])) * inward, axis=1)
    return np.concatenate([q, v], 1), normal


def ellipse_friction_bowl_state(t, s0, sd0, a, b, g, mu):
    r"""`(q1, q2, v1, v2)` at the times `t` (array) of a ball sliding with Coulomb friction
    `mu` on the wall of the elliptic bowl $(x/a)^2 + (y/b)^2 \le 1$, from parameter `s0` at
    rate `sd0`, never leaving it; and the time it sticks for good (`inf` if not before
    `t.max()`). With $q = (a \sin s, -b \cos s)$, $n$ the wall's inward unit normal and
    $\sigma$ the sign of $s'$, sliding is

    $$ |q_s|^2 s'' + (q_s \cdot q_{ss}) s'^2 = -g\,y_s - \mu\,\sigma N |q_s|,
    \qquad N = (q_{ss} \cdot n)\,s'^2 + g\,n_y $$

    (the normal force per unit mass: the normal part of the acceleration plus gravity's,
    independent of $s''$). Where $s' = 0$ the ball stays for good if gravity's tangential
    part is within the cone, $|y_s|/|q_s| \le \mu\,n_y$, and slides back otherwise. DOP853 at
    rtol 1e-12, each stop located as an event. With `a == b` it is `friction_bowl_state`."""

    def frame(s):
        qs = np.array([a * np.cos(s), b * np.sin(s)])
        qss = np.array([-a * np.sin(s), b * np.cos(s)])
        n = -np.array([np.sin(s) / a, -np.cos(s) / b])  # -(x/a^2, y/b^2) on the wall
        return qs, qss, n / np.linalg.norm(n)

    t = np.atleast_1d(np.asarray(t, float))
    t_end = max(float(t.max()), 1e-12)
    pieces, t0, s, sd, t_stick = [], 0.0, float(s0), float(sd0), np.inf
    while t0 < t_end:
        qs, _, n = frame(s)
        if sd == 0 and abs(qs[1]) / np.linalg.norm(qs) <= mu * n[1]:
            t_stick = t0
            break
        sigma = np.sign(sd) if sd != 0 else -np.sign(qs[1])

        def rhs(_, z, sigma=sigma):
            qs, qss, n = frame(z[0])
            normal = (qss @ n) * z[1] ** 2 + g * n[1]
            force = -g * qs[1] - mu * sigma * normal * np.linalg.norm(qs)
            return [z[1], (force - (qs @ qss) * z[1] ** 2) / (qs @ qs)]

        def stop(_, z):
            return z[1]

        stop.terminal, stop.direction = True, -sigma
        kw = dict(method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True, events=stop)
        sol = solve_ivp(rhs, (t0, t_end), [s, sd], **kw)
        stopped = len(sol.t_events[0]) > 0
        t1 = sol.t_events[0][0] if stopped else t_end
        pieces.append((t0, t1, sol.sol))
        if not stopped:
            break
        t0, s, sd = t1, float(sol.sol(t1)[0]), 0.0
    out = np.empty((t.size, 4))
    for i, ti in enumerate(t):
        if not pieces or ti >= t_stick:
            sj, sdj = (s, 0.0) if pieces or ti >= t_stick else (s0, sd0)
        else:
            _, t1, dense = next((p for p in pieces if ti <= p[1]), pieces[-1])
            sj, sdj = dense(min(ti, t1))
        qs, _, _ = frame(sj)
        out[i] = [a * np.sin(sj), -b * np.cos(sj), *(qs * sdj)]
    return out, t_stick


# ----------------------------------------------------------------------------------------------
# A block on an inclined plane of angle alpha (a flat contact), thrown in the plane with velocity
# (u, w) along (up-slope, across), gravity g (1 + amp sin(omega t)) pressing it. Sliding, in the
# speed and direction of its velocity (psi from up-slope):
# sigma' = -g L (sin(alpha) cos(psi) + mu cos(alpha)), psi' = g L sin(alpha) sin(psi) / sigma,
# L the load; at sigma = 0 it sticks for good where tan(alpha) <= mu, and slides down the fall
# line from rest otherwise.


def incline_slide_state(t, velocity, mu, alpha, g, amp=0.0, omega=0.0):
    r"""`(q, v)` in world coordinates (6,) at the times `t` (array) of the block: the plane
    through the origin with unit normal $(-\sin\alpha, 0, \cos\alpha)$, up-slope
    $(\cos\alpha, 0, \sin\alpha)$, across $(0, 1, 0)$; and the time it stops (`inf` if it
    does not before `t.max()`). DOP853 at rtol 1e-12, the stop located as an event."""
    t = np.atleast_1d(np.asarray(t, float))
    t_end = max(float(t.max()), 1e-12)
    sa, ca = np.sin(alpha), np.cos(alpha)
    load = lambda s: 1.0 + amp * np.sin(omega * s)  # noqa: E731

    def rhs(s, z):
        _, _, sigma, psi = z
        a = g * load(s)
        return [
            sigma * np.cos(psi),
            sigma * np.sin(psi),
            -a * (sa * np.cos(psi) + mu * ca),
            a * sa * np.sin(psi) / sigma,
        ]

    def stop(s, z):
        # A speed of 1e-10, not 0: psi' ~ 1/sigma is singular at the stop, and scipy 1.17's
        # DOP853 stepped past sigma = 0 without reporting the event (states of 1e74). The
        # stop time moves by 1e-10 over the deceleration, far inside the tests' 1e-4.
        return z[2] - 1e-10

    stop.terminal, stop.direction = True, -1
    kw = dict(method="DOP853", rtol=1e-12, atol=1e-14, dense_output=True)
    z0 = [0.0, 0.0, float(np.hypot(*velocity)), float(np.arctan2(velocity[1], velocity[0]))]
    slide = solve_ivp(rhs, (0.0, t_end), z0, events=stop, **kw)
    t_stop = slide.t_events[0][0] if len(slide.t_events[0]) else np.inf
    back = None
    if t_stop < t_end and np.tan(alpha) > mu:
        down = lambda s, z: [z[1], -g * load(s) * (sa - mu * ca)]  # noqa: E731
        end = slide.sol(t_stop)
        back = (end, solve_ivp(down, (t_stop, t_end), [0.0, 0.0], **kw).sol)
    out = np.empty((t.size, 6))
    for i, ti in enumerate(t):
        x, y, sigma, psi = slide.sol(min(ti, t_stop))
        u, w = sigma * np.cos(psi), sigma * np.sin(psi)
        if ti >= t_stop:
            u = w = 0.0
            if back is not None:
                (x, y, _, _), sol = back
                ds, u = sol(ti)
                x += ds
        out[i] = [x * ca, y, x * sa, u * ca, w, u * sa]
    return out, t_stop


# ----------------------------------------------------------------------------------------------
# Example utilities.


def output_path(name):
    """`examples/output/<name>`, creating the (git-ignored) folder."""
    folder = os.path.join(os.path.dirname(os.path.abspath(__file__)), "output")
    os.makedirs(folder, exist_ok=True)
    return os.path.join(folder, name)


def timed(fn, *args):
    """`(fn(*args), seconds)`, waiting for asynchronous JAX results."""
    import jax

    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - start
