"""The `solve_ivp_ns` drop-in: the reference's worked examples against exact solutions (and
against the reference itself when it is installed)."""

import importlib
import inspect

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import brentq

import nivpjax as nj
from nivpjax.compat import solve_ivp_ns


G, MASS, E_REST = 9.81, 1.0, 0.8


def ball_opts(xp):
    return dict(
        gap=lambda t, y: xp.array([y[1]]),
        u_map=lambda t, y: xp.array([y[0]]),
        J_u=lambda t, y: xp.array([[1.0, 0.0]]),
        G_apply=lambda t, y, lam: xp.array([lam[0] / MASS, 0.0 * lam[0]]),
        e=E_REST,
    )


def ball_exact(t_end, v0=1.0, s0=2.0):
    t, v, s = 0.0, v0, s0
    while True:
        # time to hit s = 0 from (v, s)
        t_hit = (v + np.sqrt(v**2 + 2 * G * s)) / G
        if t + t_hit > t_end:
            dt = t_end - t
            return np.array([v - G * dt, s + v * dt - 0.5 * G * dt**2])
        t += t_hit
        v, s = -E_REST * (v - G * t_hit), 0.0


@pytest.mark.parametrize("method", ["trapezoidal", "composite", "backward_euler"])
def test_bouncing_ball(method):
    t, y, h, fk, info = solve_ivp_ns(
        lambda t, y: jnp.array([-G, y[0]]),
        (0.0, 3.0),
        np.array([1.0, 2.0]),
        method=method,
        projection="unilateral",
        solver="semismooth_newton",
        projection_opts=ball_opts(jnp) | dict(gap_tol=0.0, lcp_maxit=200),
        solver_opts=dict(tol=1e-10, max_iter=50),
        atol=1e-8,
        rtol=1e-6,
        h0=1e-3,
    )
    assert t[0] == 0.0 and t[-1] == pytest.approx(3.0)
    assert y.shape == (len(t), 2) and fk.shape == (len(t) - 1, 2) and len(info) == len(t) - 1
    assert all(ok for _, ok, _ in info)
    exact = ball_exact(3.0)
    tol = 0.05 if method == "backward_euler" else 0.01
    np.testing.assert_allclose(y[-1], exact, atol=tol)
    assert np.min(y[:, 1]) > -1e-2  # no deep penetration


def slider_exact(t_end, m=2.0, k=1.0, c=2.0, fric=0.6, v0=0.1):
    """m v' = -k s - c v - fric sign(v), s' = v; slides forward, then sticks for good when
    the spring force stays below the friction bound."""
    M = np.array([[-c / m, -k / m], [1.0, 0.0]])
    b = np.array([-fric / m, 0.0])
    # affine flow: y(t) = expm(Mt)(y0 + M^-1 b) - M^-1 b
    Minv_b = np.linalg.solve(M, b)
    flow = lambda t: expm(M * t) @ (np.array([v0, 0.0]) + Minv_b) - Minv_b
    t_stick = brentq(lambda t: flow(t)[0], 1e-6, 2.0)
    s_stick = flow(t_stick)[1]
    assert abs(k * s_stick) < fric
    return t_stick, s_stick


@pytest.mark.parametrize("solver", ["VI", "semismooth_newton"])
def test_spring_slider(solver):
    cs = [slice(0, 1), slice(1, 2)]

    def con_force(y, t=None, Fk_val=None):
        return jnp.array([0.6, 0.0])

    t, y, h, fk, info = solve_ivp_ns(
        lambda t, y: jnp.array([-1.0 * y[1] - 2.0 * y[0], y[0]]),
        (0.0, 1.0),
        np.array([0.1, 0.0]),
        method="composite",
        projection="coulomb",
        solver=solver,
        projection_opts=dict(
            con_force_func=con_force,
            rhok=np.ones(2),
            component_slices=cs,
            constraint_indices=[0],
        ),
        solver_opts=dict(tol=1e-12, max_iter=200),
        atol=1e-9,
        rtol=1e-7,
        h0=0.01,
        component_slices=cs,
        A=np.diag([2.0, 1.0]),
    )
    t_stick, s_stick = slider_exact(1.0)
    assert t_stick < 1.0
    np.testing.assert_allclose(y[-1], [0.0, s_stick], atol=1e-6)
    # In stick the residual of the velocity row is the friction force: k s (per A row).
    assert fk[-1][0] == pytest.approx(1.0 * s_stick, abs=1e-6)
    # Before sticking the velocity is positive (sliding forward).
    assert np.all(y[t < t_stick - 1e-3, 0] > 0)


def relay_reaching_time(x0=0.5):
    x = lambda t: x0 - t + 0.5 / (2 * np.pi) * (1 - np.cos(2 * np.pi * t))
    return brentq(x, 1e-6, 2.0)


@pytest.mark.parametrize("method", ["backward_euler", "composite", "embedded_betr"])
def test_relay_sliding(method):
    d = lambda t: 0.5 * jnp.sin(2 * jnp.pi * t)
    t, y, h, fk, info = solve_ivp_ns(
        lambda t, y: jnp.array([-y[1] + d(t), 0.0]),
        (0.0, 2.0),
        np.array([0.5, 1.0]),
        method=method,
        projection="sign",
        solver="semismooth_newton",
        projection_opts=dict(y_indices=[0], w_indices=[1]),
        solver_opts=dict(tol=1e-12, max_iter=100),
        adaptive_opts=dict(h_min=1e-10, h_max=0.05, skip_error_indices=[1]),
        atol=1e-8,
        rtol=1e-6,
        h0=1e-2,
        component_slices=[slice(0, 1), slice(1, 2)],
        A=np.diag([1.0, 0.0]),
    )
    t_reach = relay_reaching_time()
    after = t > t_reach + 0.02
    # Sliding: x stays on the surface, the selection equals the disturbance (Filippov).
    assert np.max(np.abs(y[after, 0])) < 1e-9
    np.testing.assert_allclose(y[after, 1], 0.5 * np.sin(2 * np.pi * t[after]), atol=1e-8)
    assert np.all(np.abs(y[:, 1]) <= 1 + 1e-12)
    # Reaching phase: x decreases with w = 1.
    before = t < t_reach - 0.02
    assert np.all(y[before, 0] > 0) and np.allclose(y[before, 1], 1.0)


def test_unknown_options_raise():
    f = lambda t, y: -y
    y0 = np.array([1.0])
    with pytest.raises(ValueError, match="Unknown method 'rk45'"):
        solve_ivp_ns(f, (0, 1), y0, method="rk45", projection="identity")
    with pytest.raises(ValueError, match="Unknown projection 'cone'"):
        solve_ivp_ns(f, (0, 1), y0, projection="cone")
    with pytest.raises(ValueError, match="Unknown solver 'newton'"):
        solve_ivp_ns(f, (0, 1), y0, projection="identity", solver="newton")
    with pytest.raises(ValueError, match=r"unsupported solver_opts \['bogus'\]"):
        solve_ivp_ns(f, (0, 1), y0, projection="identity", solver_opts={"bogus": 1})
    with pytest.raises(ValueError, match="unsupported adaptive_opts"):
        solve_ivp_ns(f, (0, 1), y0, adaptive_opts={"controller_magic": 1})
    with pytest.raises(ValueError, match="h211b"):
        solve_ivp_ns(f, (0, 1), y0, adaptive_opts={"mode": "ratio", "controller": "h211b"})
    with pytest.raises(ValueError, match="projection 'sign' needs"):
        solve_ivp_ns(f, (0, 1), y0, projection="sign")


def test_identity_fixed_step_and_attempts():
    f = lambda t, y: -y
    t, y, h, fk, info = solve_ivp_ns(
        f, (0.0, 1.0), np.array([1.0]), method="backward_euler", adaptive=False, h0=0.1
    )
    assert len(t) == 11
    np.testing.assert_allclose(y[-1], [1.1**-10], rtol=1e-8)  # VI tolerance 1e-10 per step
    out = solve_ivp_ns(f, (0.0, 1.0), np.array([1.0]), projection=None, return_attempts=True)
    attempts = out[-1]
    assert attempts["accepted"].sum() == len(out[0]) - 1
    assert isinstance(nj.solve, object)


def test_agrees_with_reference_relay():
    """The same relay model through the reference package (semismooth Newton, BE): both
    reach the sliding surface at the exact time to within the step sizes used."""
    solve_nivp = pytest.importorskip("solve_nivp")
    d = lambda t: 0.5 * np.sin(2 * np.pi * t)
    kwargs = dict(
        method="backward_euler",
        projection="sign",
        solver="semismooth_newton",
        projection_opts=dict(y_indices=[0], w_indices=[1]),
        solver_opts=dict(tol=1e-10, max_iter=100),
        adaptive_opts=dict(h_min=1e-8, h_max=0.05, skip_error_indices=[1]),
        atol=1e-6,
        rtol=1e-3,
        h0=1e-2,
        component_slices=[slice(0, 1), slice(1, 2)],
        A=np.diag([1.0, 0.0]),
    )
    tr, yr, *_ = solve_nivp.solve_ivp_ns(
        lambda t, y: np.array([-y[1] + d(t), 0.0]), (0.0, 1.0), np.array([0.5, 1.0]), **kwargs
    )
    tn, yn, *_ = solve_ivp_ns(
        lambda t, y: jnp.array([-y[1] + 0.5 * jnp.sin(2 * jnp.pi * t), 0.0]),
        (0.0, 1.0),
        np.array([0.5, 1.0]),
        **kwargs,
    )
    t_reach = relay_reaching_time()
    reach = lambda t, y: t[np.argmax(np.abs(y[:, 0]) < 1e-8)]
    assert abs(reach(tr, yr) - t_reach) < 0.05
    assert abs(reach(tn, yn) - t_reach) < 0.05
    np.testing.assert_allclose(yn[-1], yr[-1], atol=1e-6)


class _Captured(Exception):
    pass


def _handed_to_solve(monkeypatch, **options):
    """The keyword arguments the drop-in passes to `nivpjax.solve` for these options."""
    module = importlib.import_module("nivpjax.compat.solve_ivp_ns")
    seen = {}

    def capture(*args, **kwargs):
        seen.update(kwargs)
        raise _Captured

    monkeypatch.setattr(module, "solve", capture)
    with pytest.raises(_Captured):
        solve_ivp_ns(lambda t, y: -y, (0.0, 1.0), np.array([1.0]), **options)
    return seen


# Defaults that differ from the reference's (listed in the drop-in's docstring): option ->
# (ours, the reference's).
DEFAULTS_THAT_DIFFER = {
    "h_up": (10.0, 2.0),
    "h_down": (0.2, 0.6),
    "max_backtracks": (30, 15),
    "rho0": (1.0, 0.9),
}


def _solver_pairs(vi, ref_vi, newton, ref_newton):
    """The solver options as each side holds them: `{option: (ours, the reference's)}`."""
    return {
        "tol": (vi.rtol, ref_vi.tol),
        "tol (atol)": (vi.atol, ref_vi.tol),
        "max_iter": (vi.max_steps, ref_vi.max_iter),
        "rho0": (vi.alpha0, ref_vi.rho0),
        "L": (vi.nu, ref_vi.L),
        "newton tol": (newton.rtol, ref_newton.tol),
        "newton max_iter": (newton.max_steps, ref_newton.max_iter),
        "ls_c1": (newton.sigma, ref_newton.ls_c1),
        "ls_beta": (newton.beta, ref_newton.ls_beta),
        "max_backtracks": (newton.max_backtracks, ref_newton.max_backtracks),
    }


def test_defaults_are_the_reference_ones(monkeypatch):
    """Option by option, what an omitted option means in the drop-in and in the reference
    (read from the reference's own signatures and objects, not written down twice)."""
    ref = pytest.importorskip("solve_nivp")
    # The entry point's own arguments: same names, order and defaults.
    ours = list(inspect.signature(solve_ivp_ns).parameters.values())
    theirs = list(inspect.signature(ref.solve_ivp_ns).parameters.values())
    for mine, other in zip(ours, theirs):
        assert (mine.name, mine.kind, mine.default) == (other.name, other.kind, other.default)
    assert all(p.kind == p.KEYWORD_ONLY for p in ours[len(theirs) :])  # ours: extras only
    # The reference's objects as its solve_ivp_ns builds them from omitted options.
    identity = ref.IdentityProjection()
    ref_vi = ref.ImplicitEquationSolver(method="VI", proj=identity, component_slices=[slice(0, 1)])
    ref_newton = ref.ImplicitEquationSolver(method="semismooth_newton", proj=identity)
    composite = ref.CompositeMethod(solver=ref_vi)
    ref_ctrl = ref.ODESystem(lambda t, y: -y, [1.0], composite, adaptive=True).adaptive_stepper
    k = ref_ctrl.p + 1  # the reference's error order
    assert ref_ctrl.mode == "classic" and ref_ctrl.use_PI

    default = _handed_to_solve(monkeypatch)
    ctrl, stepper, vi = default["controller"], default["stepper"], default["stepper"].solver
    newton = _handed_to_solve(monkeypatch, solver="semismooth_newton")["stepper"].solver
    theta = _handed_to_solve(monkeypatch, method="theta")["stepper"]
    pairs = {
        # adaptive_opts
        "h_min": (ctrl.h_min, ref_ctrl.h_min),
        "h_max": (ctrl.h_max, ref_ctrl.h_max),
        "h_up": (ctrl.factormax, ref_ctrl.h_up),
        "h_down": (ctrl.factormin, ref_ctrl.h_down),
        "safety": (ctrl.safety, ref_ctrl.safety),
        # use_PI: the exponents of the current and the previous error. The reference's
        # classic mode raises the previous error to -0.4/k; ours (and the reference's ratio
        # mode) to +0.4/k, Soderlind's PI.3040: magnitudes compared.
        "use_PI current": ((ctrl.pcoeff + ctrl.icoeff) / k, ref_ctrl._alpha_PI),
        "use_PI previous": (ctrl.pcoeff / k, ref_ctrl._beta_PI),
        "method_order": (stepper.error_order, k),
        # solver_opts
        **_solver_pairs(vi, ref_vi, newton, ref_newton),
        # integrator_opts (the reference's composite scheme has its stage at h/2)
        "gamma": (stepper.gamma, 0.5),
        "theta": (theta.theta, ref.ThetaMethod(solver=ref_vi).theta),
    }
    assert isinstance(stepper, nj.Bathe) and isinstance(vi, nj.FixedPointVI)
    assert default["h0"] == ref_ctrl.h == 1e-2
    for name, (mine, other) in pairs.items():
        expected = DEFAULTS_THAT_DIFFER.get(name, (other, other))
        assert (float(mine), float(other)) == pytest.approx(expected, rel=1e-12), name


def test_given_options_arrive_where_the_reference_reads_them(monkeypatch):
    """Option by option, a value other than the default reaches the field that means what
    the reference's option means (its own objects, built from the same options, give the
    expected values): the translation, not only the defaults."""
    ref = pytest.importorskip("solve_nivp")
    identity = ref.IdentityProjection()
    vi_opts = dict(tol=3e-9, max_iter=77, rho0=0.37, L=0.55)
    newton_opts = dict(tol=2e-9, max_iter=33, ls_c1=3e-4, ls_beta=0.3, max_backtracks=7)
    ref_vi = ref.ImplicitEquationSolver(
        method="VI", proj=identity, component_slices=[slice(0, 1)], **vi_opts
    )
    newton_name = "semismooth_newton"
    ref_newton = ref.ImplicitEquationSolver(method=newton_name, proj=identity, **newton_opts)
    vi = _handed_to_solve(monkeypatch, solver_opts=vi_opts)["stepper"].solver
    seen = _handed_to_solve(monkeypatch, solver=newton_name, solver_opts=newton_opts)
    newton = seen["stepper"].solver
    pairs = _solver_pairs(vi, ref_vi, newton, ref_newton)
    # adaptive_opts: the reference sets its stepper's attributes to the given values; a
    # method_order p makes it control with the error order p + 1 and the PI exponent
    # 0.7 / (p + 1) on the current error.
    aopts = dict(h_up=3.0, h_down=0.4, safety=0.8, h_min=1e-9, h_max=0.5, method_order=3)
    seen = _handed_to_solve(monkeypatch, adaptive_opts=aopts)
    ctrl = seen["controller"]
    k = aopts["method_order"] + 1
    pairs |= {
        "h_up": (ctrl.factormax, aopts["h_up"]),
        "h_down": (ctrl.factormin, aopts["h_down"]),
        "safety": (ctrl.safety, aopts["safety"]),
        "h_min": (ctrl.h_min, aopts["h_min"]),
        "h_max": (ctrl.h_max, aopts["h_max"]),
        "method_order": (ctrl.error_order, k),
        "use_PI current": ((ctrl.pcoeff + ctrl.icoeff) / ctrl.error_order, 0.7 / k),
    }
    theta = _handed_to_solve(monkeypatch, method="theta", integrator_opts=dict(theta=0.6))
    bathe = _handed_to_solve(monkeypatch, integrator_opts=dict(gamma=0.3))
    pairs |= {
        "theta": (theta["stepper"].theta, ref.ThetaMethod(solver=ref_vi, theta=0.6).theta),
        "gamma": (bathe["stepper"].gamma, 0.3),
    }
    for name, (mine, other) in pairs.items():
        assert float(mine) == pytest.approx(float(other), rel=1e-12), name
    # gap_tol: the reference's contact is active where gap <= gap_tol; ours where the
    # translated gap is <= 0. A state between 0 and gap_tol is active in both.
    tol = 1e-3
    contact = _handed_to_solve(
        monkeypatch,
        projection="unilateral",
        projection_opts=ball_opts(jnp) | dict(gap_tol=tol),
    )["projector"]
    contact = contact.blocks[0][1] if isinstance(contact, nj.BlockProjector) else contact
    for height, active in [(0.5 * tol, True), (2 * tol, False), (-0.5 * tol, True)]:
        gap = float(contact.gap(0.0, jnp.array([0.0, height]), None)[0])
        assert (gap <= 0) == active, (height, gap)
