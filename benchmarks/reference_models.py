"""The benchmark scenes written for the reference package `solve_nivp` 0.1.2, with the
settings its notebooks use (notes: /work/notes/reference-semantics.md, sections 5 and 5b).

Each builder returns `solve_ivp_ns` keyword arguments for a tolerance and a function that
maps the reference's state vector to the scene's states `x` (the error is measured on the
scene's states only). Models the reference has no projection for are rewritten with the
projections it has:

- relay, super-twisting: `SignProjection` with the multiplier `w` as an algebraic state
  (row f_w = 0, `w in Sign(s)`), semismooth Newton (its VI solver raises with
  SignProjection, notes §4);
- diode rectifier: the ideal diode i = max(0, (src - v)/R_s) as i = I_max (1 + w)/2 with
  `w in Sign(s)` and an algebraic state s = src - v - R_s i (I_max = 2 V / R_s above any
  current: w is interior exactly when the diode conducts);
- Chua: sat(x) = w with `w in Sign(x - w)` and an algebraic state s = x - w.

DAE variants use the composite (TR-BDF2) scheme: the trapezoidal rule averages algebraic
rows (notes §2) and backward Euler is first order.
"""

import contextlib
import io

import numpy as np
import solve_nivp


def _slices(n):
    return [slice(i, i + 1) for i in range(n)]


def _sign_model(fun, jac, y0, t1, A, y_index, w_index, rtol, atol, h0=1e-3, h_max=None):
    n = len(y0)
    adaptive = dict(h_min=1e-12, skip_error_indices=[y_index, w_index])
    if h_max is not None:
        adaptive["h_max"] = h_max
    return dict(
        fun=fun,
        t_span=(0.0, t1),
        y0=np.asarray(y0, float),
        method="composite",
        projection="sign",
        solver="semismooth_newton",
        projection_opts=dict(y_indices=[y_index], w_indices=[w_index]),
        solver_opts=dict(tol=1e-10, max_iter=100, rhs_jac=jac),
        adaptive_opts=adaptive,
        atol=atol,
        rtol=rtol,
        h0=h0,
        component_slices=_slices(n),
        A=A,
    )


def ball(p, x0, t1, rtol, atol):
    """y = [v, q]; trapezoidal + VI + GeneralMoreau (the notebook's settings)."""
    g, e = p["g"], p["e"]
    popts = dict(
        gap=lambda t, y: np.array([y[1]]),
        u_map=lambda t, y: np.array([y[0]]),
        J_u=lambda t, y: np.array([[1.0, 0.0]]),
        G_apply=lambda t, y, lam: np.array([lam[0], 0.0]),
        e=e,
        gap_tol=0.0,
        lcp_maxit=200,
        lcp_tol=1e-10,
        tc_tol=1e-10,
    )
    kw = dict(
        fun=lambda t, y: np.array([-g, y[0]]),
        t_span=(0.0, t1),
        y0=np.array([x0[1], x0[0]]),
        method="trapezoidal",
        projection="unilateral",
        solver="VI",
        projection_opts=popts,
        solver_opts=dict(tol=1e-7, max_iter=200),
        adaptive_opts=dict(
            h0=1e-3, h_min=1e-12, h_down=0.5, h_up=1.5, method_order=1, use_PI=False
        ),
        atol=atol,
        rtol=rtol,
        h0=1e-3,
        component_slices=_slices(2),
    )
    return kw, lambda y: y[:, ::-1], "trapezoidal + VI, GeneralMoreau (notebook settings)"


def slider(p, x0, t1, rtol, atol, solver="semismooth_newton"):
    """y = [v, s], A = diag(m, 1), Coulomb projection on v (constant friction). The
    notebook runs VI and SSN; SSN is the default here (3-5x faster than its VI on this
    scene: 3.8 s vs 20 s at rtol 1e-3 on a 16 s horizon)."""
    m, k, c, fric = p["m"], p["k"], p["c"], p["mu_k"] * p["N"]

    def con_force(y, t=None, Fk_val=None):
        out = np.zeros_like(y)
        out[0] = fric  # zero on unconstrained entries (the reference acts wherever c != 0)
        return out

    cs = _slices(2)
    kw = dict(
        fun=lambda t, y: np.array([-k * y[1] - c * y[0], y[0]]),
        t_span=(0.0, t1),
        y0=np.array([x0[1], x0[0]]),
        method="composite",
        projection="coulomb",
        solver=solver,
        projection_opts=dict(
            con_force_func=con_force,
            rhok=np.ones(2),
            component_slices=cs,
            constraint_indices=[0],
            jac_func=lambda y, t=None, Fk_val=None: np.zeros((2, 2)),
        ),
        solver_opts=dict(
            tol=1e-10, max_iter=100, rhs_jac=lambda t, y: np.array([[-c, -k], [1.0, 0.0]])
        ),
        atol=atol,
        rtol=rtol,
        h0=0.01,
        component_slices=cs,
        A=np.diag([m, 1.0]),
    )
    return (
        kw,
        lambda y: y[:, ::-1],
        f"composite + {'SSN' if solver == 'semismooth_newton' else solver}, Coulomb projection "
        "(notebook settings)",
    )


def relay(p, x0, t1, rtol, atol):
    """y = [x, w], A = diag(1, 0)."""
    a, f = p["amplitude"], p["frequency"]
    kw = _sign_model(
        lambda t, y: np.array([-y[1] + a * np.sin(2 * np.pi * f * t), 0.0]),
        lambda t, y: np.array([[0.0, -1.0], [0.0, 0.0]]),
        [x0[0], 1.0],
        t1,
        np.diag([1.0, 0.0]),
        0,
        1,
        rtol,
        atol,
        h0=1e-2,
    )
    kw["adaptive_opts"]["skip_error_indices"] = [1]
    return kw, lambda y: y[:, :1], "composite + SSN, SignProjection"


def super_twisting(p, x0, t1, rtol, atol):
    """y = [x1, x2, nu, s, w], s = x2 + c x1 algebraic (the notebook's well-posed variant)."""
    k1, k2, c = p["k1"], p["k2"], p["c"]

    def fun(t, y):
        x1, x2, nu, s, w = y
        u = -k1 * np.sqrt(abs(s)) * w + nu
        return np.array([x2, u + 0.3 * np.sin(5 * t), -k2 * w, x2 + c * x1 - s, 0.0])

    def jac(t, y):
        x1, x2, nu, s, w = y
        ds = -k1 * w * 0.5 / np.sqrt(max(abs(s), 1e-12)) * np.sign(s)
        return np.array(
            [
                [0, 1, 0, 0, 0],
                [0, 0, 1, ds, -k1 * np.sqrt(abs(s))],
                [0, 0, 0, 0, -k2],
                [c, 1, 0, -1, 0],
                [0, 0, 0, 0, 0],
            ],
            float,
        )

    s0 = x0[1] + c * x0[0]
    kw = _sign_model(
        fun,
        jac,
        [x0[0], x0[1], x0[2], s0, np.sign(s0)],
        t1,
        np.diag([1.0, 1.0, 1.0, 0.0, 0.0]),
        3,
        4,
        rtol,
        atol,
    )
    return kw, lambda y: y[:, :3], "composite + SSN, SignProjection (well-posed variant)"


def rectifier(p, x0, t1, rtol, atol, h_max=None):
    """y = [v, s, w]: i = I_max (1 + w)/2, s = src - v - R_s i algebraic, w in Sign(s)."""
    V, om, Rs, RL, C = p["V"], p["omega"], p["R_s"], p["R_L"], p["C"]
    imax = 2 * V / Rs

    def fun(t, y):
        v, s, w = y
        i = imax * (1 + w) / 2
        return np.array([(i - v / RL) / C, V * np.sin(om * t) - v - Rs * i - s, 0.0])

    def jac(t, y):
        return np.array(
            [[-1 / (RL * C), 0, imax / (2 * C)], [-1, -1, -Rs * imax / 2], [0, 0, 0]], float
        )

    kw = _sign_model(
        fun, jac, [x0[0], 0.0, -1.0], t1, np.diag([1.0, 0.0, 0.0]), 1, 2, rtol, atol, 1e-4, h_max
    )
    return kw, lambda y: y[:, :1], "composite + SSN, SignProjection (diode as bounded relay)"


def chua(p, x0, t1, rtol, atol):
    """y = [x, y, z, s, w]: sat(x) = w in Sign(s), s = x - w algebraic."""
    al, be, m0, m1 = p["alpha"], p["beta"], p["m0"], p["m1"]

    def fun(t, u):
        x, y, z, s, w = u
        g = m0 * x + (m1 - m0) * w
        return np.array([al * (y - x - g), x - y + z, -be * y, x - w - s, 0.0])

    def jac(t, u):
        return np.array(
            [
                [-al * (1 + m0), al, 0, 0, -al * (m1 - m0)],
                [1, -1, 1, 0, 0],
                [0, -be, 0, 0, 0],
                [1, 0, 0, -1, -1],
                [0, 0, 0, 0, 0],
            ],
            float,
        )

    w0 = float(np.clip(x0[0], -1, 1))
    kw = _sign_model(
        fun,
        jac,
        [x0[0], x0[1], x0[2], x0[0] - w0, w0],
        t1,
        np.diag([1.0, 1.0, 1.0, 0.0, 0.0]),
        3,
        4,
        rtol,
        atol,
    )
    return kw, lambda y: y[:, :3], "composite + SSN, SignProjection (sat as relay)"


BUILDERS = dict(
    ball=ball,
    slider=slider,
    relay=relay,
    super_twisting=super_twisting,
    rectifier=rectifier,
    chua=chua,
)


def run(kw):
    """One `solve_ivp_ns` call (its prints silenced). Returns (t, y, accepted, rejected,
    iterations) or raises what the reference raises."""
    with contextlib.redirect_stdout(io.StringIO()):
        t, y, h, fk, info, attempts = solve_nivp.solve_ivp_ns(**kw, return_attempts=True)
    acc = np.asarray(attempts["accepted"], bool)
    iters = int(sum(int(i[2]) for i in info))
    return np.asarray(t), np.asarray(y), int(len(t) - 1), int(np.sum(~acc)), iters
