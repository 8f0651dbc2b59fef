"""The large-system scenes (`fault`, `spring_block_chain`, `chain_of_balls`) at small sizes,
against independent references:

- one fault cell with constant friction is the damped Coulomb oscillator, piecewise in closed
  form (each slip phase starts from rest, is a damped oscillation about $-\\operatorname{sign}
  (k u)\\,c/k$ and lasts $\\pi/\\omega_d$; the cell sticks when $|k u| \\le c$ at $v = 0$);
- the spectral kernel against the same periodic kernel summed as a dense matrix (explicit
  Fourier sums, no FFT) and its square root by `eigh`;
- the study's 2x2 fault against a regularised SciPy integration (Radau, $\\operatorname{sign}
  v \\to v/\\sqrt{v^2 + \\varepsilon^2}$) of its mean final slip;
- one block of the Burridge–Knopoff chain against the spring slider's event-driven reference;
- the chain of balls: no penetration, momentum, energy with $e = 1$ and Newton's cradle.

Each scene is compiled once (module-level `filter_jit` with `x0`, `args`, `t1` and the
controller traced).
"""

import sys
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

import nivpjax as nj
from nivpjax import scenes


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
from _references_mechanics import slider_event_driven  # noqa: E402


DATA = Path(__file__).resolve().parent / "data"


def _compiled(scene, max_steps, **kw):
    @eqx.filter_jit
    def solve(x0, args, t1, controller, t_eval):
        return scene.solve(
            0.0,
            t1,
            x0,
            args,
            controller=controller,
            t_eval=t_eval,
            max_steps=max_steps,
            throw=False,
            **kw,
        )

    def call(x0, args, t1, controller, t_eval=None):
        # t1 as an array: `filter_jit` would compile once per Python float.
        return solve(x0, args, jnp.asarray(t1), controller, t_eval)

    return call


def _pid(rtol, atol=None):
    # Arrays, not Python floats: `filter_jit` would compile once per tolerance.
    atol = 1e-3 * rtol if atol is None else atol
    return nj.PIDController(rtol=jnp.asarray(rtol), atol=jnp.asarray(atol))


# --------------------------------------------------------------------------------------------
# One cell: the Coulomb oscillator v' = -k u - e v - c Sign(v), u' = v, k = 1 (normalised),
# e = 2 zeta, c = 0.5 sigma (constant friction), from rest at u0 = -(1 + overshoot) c / k.

ZETA, SIGMA, OVERSHOOT, T_CELL = 0.1, 1.0, 7.0, 12.0


def coulomb_oscillator(u0, k, e, c, ts):
    """Closed form: phases from rest, each a damped oscillation about -sign(k u_a) c / k for
    pi / omega_d; stick when |k u| <= c at v = 0. Returns (v, u, s) at `ts`."""
    omega = np.sqrt(k)
    z = e / (2 * omega)
    wd = omega * np.sqrt(1 - z**2)
    decay = np.exp(-z * omega * np.pi / wd)
    t_a, u_a, s_a = 0.0, u0, 0.0
    v, u, s = np.zeros_like(ts), np.full_like(ts, u0), np.zeros_like(ts)
    while abs(k * u_a) > c:
        centre = np.sign(k * u_a) * c / k
        amp = u_a - centre
        sel = ts >= t_a
        tau = ts[sel] - t_a
        env = np.exp(-z * omega * tau)
        u[sel] = centre + amp * env * (np.cos(wd * tau) + z * omega / wd * np.sin(wd * tau))
        v[sel] = -amp * env * omega**2 / wd * np.sin(wd * tau)
        s[sel] = s_a + np.abs(u[sel] - u_a)
        u_b = centre - amp * decay
        t_a, s_a, u_a = t_a + np.pi / wd, s_a + abs(u_b - u_a), u_b
        # At the phase's end v = 0: the next phase (or the stick) takes over from here.
        u[ts >= t_a], v[ts >= t_a], s[ts >= t_a] = u_a, 0.0, s_a
    return v, u, s, t_a


CELL, CELL_X0, CELL_ARGS = scenes.fault(
    scenes.load_fault_kernel(DATA / "kijs_1x1elem-3x3length.npy"),
    zeta=ZETA,
    sigma=SIGMA,
    delta_mu=0.0,
    overshoot=OVERSHOOT,
)
CELL_SOLVE = _compiled(CELL, 4000)


def test_cell_is_normalised_study_cell():
    # One cell: K = 1 whatever the file's value, E = 2 zeta, u0 = -(1 + overshoot) mu sigma.
    assert float(CELL_ARGS["K"][0, 0]) == pytest.approx(1.0, rel=1e-14)
    assert float(CELL_ARGS["R"][0, 0]) == pytest.approx(1.0, rel=1e-14)
    assert np.allclose(CELL_X0, [0.0, -(1 + OVERSHOOT) * 0.5 * SIGMA, 0.0], rtol=1e-14)


def test_cell_matches_coulomb_oscillator():
    ts = np.linspace(0.0, T_CELL, 241)
    c = 0.5 * SIGMA
    v_ref, u_ref, s_ref, t_stick = coulomb_oscillator(float(CELL_X0[1]), 1.0, 2 * ZETA, c, ts)
    assert 2 * np.pi < t_stick < T_CELL  # three slip phases, then a stick for good
    errors = []
    for rtol in (1e-4, 1e-6):
        sol = CELL_SOLVE(CELL_X0, CELL_ARGS, T_CELL, _pid(rtol), jnp.asarray(ts))
        assert sol.result == nj.RESULTS.successful
        y = np.asarray(sol.y_eval)
        refs = [v_ref, u_ref, s_ref]
        errors.append(max(np.max(np.abs(y[:, k] - ref)) for k, ref in enumerate(refs)))
        # Stuck for good: v = 0 to round-off, u where the closed form leaves it.
        assert abs(float(sol.y_final[0])) < 1e-12
        assert abs(float(sol.y_final[1]) - u_ref[-1]) < {1e-4: 2e-3, 1e-6: 1e-4}[rtol]
        # (measured 6.3e-4, 2.9e-5)
    # Measured 3.4e-3 and 1.7e-4: each friction reversal costs O(h), so the error falls like
    # rtol^(2/3) (4.7x per decade from 1e-3 to 1e-8), not like rtol.
    assert errors[1] < errors[0] / 12
    assert errors[1] < 5e-4


def test_cell_loaded_sticks_until_the_load_breaks_it():
    # Loaded at v_inf = 0.1 from rest at u = 0: stuck (v = 0), u = -v_inf t and the friction
    # carries k v_inf t + e v_inf, which reaches c = 0.5 at t* = (c - e v_inf)/(k v_inf) = 4.8
    # (e = 2 zeta = 0.2); then the cell slips forward. Same executable (v_inf is traced).
    args = dict(CELL_ARGS, v_inf=jnp.asarray(0.1))
    ts = np.linspace(0.0, 6.0, 601)
    sol = CELL_SOLVE(jnp.zeros(3), args, 6.0, _pid(1e-6), jnp.asarray(ts))
    assert sol.result == nj.RESULTS.successful
    y = np.asarray(sol.y_eval)
    stuck = ts < 4.8 - 1e-2
    assert np.max(np.abs(y[stuck, 0])) < 1e-12
    assert np.allclose(y[stuck, 1], -0.1 * ts[stuck], rtol=0, atol=1e-9)
    moving = np.flatnonzero(y[:, 0] > 1e-6)
    assert moving.size and abs(ts[moving[0]] - 4.8) < 3e-2


# --------------------------------------------------------------------------------------------
# The spectral kernel: a periodic 6 x 4 grid on a 1 x 2/3 box, Poisson's ratio 0.25.

NX, NZ, LX, LZ, NU = 6, 4, 1.0, 2.0 / 3.0, 0.25


def periodic_dense(nx, nz, lx, lz, nu, k0):
    """The periodic kernel as a dense matrix, by explicit Fourier sums over all modes."""
    mx = np.fft.fftfreq(nx, 1.0 / nx)
    mz = np.fft.fftfreq(nz, 1.0 / nz)
    kx, kz = np.meshgrid(2 * np.pi * mx / lx, 2 * np.pi * mz / lz)
    lam = (kx**2 / (1 - nu) + kz**2 + k0**2) / (2 * np.sqrt(kx**2 + kz**2 + k0**2))
    p = np.arange(nx * nz)
    x, z = (p % nx) * lx / nx, (p // nx) * lz / nz
    dx, dz = x[:, None] - x[None, :], z[:, None] - z[None, :]
    phase = kx.ravel()[None, None, :] * dx[..., None] + kz.ravel()[None, None, :] * dz[..., None]
    return np.sum(lam.ravel() * np.cos(phase), axis=-1) / (nx * nz)


def _kernel_products(scene, args, u, v):
    # v' = -K u - 2 zeta K^(1/2) v (v_inf = 0; no friction in the dynamics).
    n = u.shape[0]
    x_u = jnp.concatenate([jnp.zeros(n), u, jnp.zeros(n)])
    x_v = jnp.concatenate([v, jnp.zeros(2 * n)])
    Ku = -scene.dynamics(0.0, x_u, args, {})[:n]
    Rv = -scene.dynamics(0.0, x_v, args, {})[:n] / (2 * args["zeta"])
    return np.asarray(Ku), np.asarray(Rv)


def test_spectral_kernel_against_dense_sums():
    scene, x0, args = scenes.fault(
        "spectral", NX, NZ, length=3.0, depth=2.0, poisson=NU, sigma=np.linspace(1, 2, NX * NZ)
    )
    k0 = 2 * np.pi / max(LX, LZ)
    K = periodic_dense(NX, NZ, LX, LZ, NU, k0)
    sigma = np.asarray(args["sigma"])
    # The same kernel passed as a dense matrix (its set-up by one `eigh`).
    _, x0_dense, args_dense = scenes.fault(
        K, NX, NZ, length=3.0, depth=2.0, sigma=np.linspace(1, 2, NX * NZ)
    )
    # The study's normalisation mean(K^-1 sigma) = mean(sigma), in dense algebra.
    K *= np.mean(np.linalg.solve(K, sigma)) / np.mean(sigma)
    lam, Q = np.linalg.eigh(K)
    R = (Q * np.sqrt(lam)) @ Q.T
    rng = np.random.default_rng(0)
    u, v = rng.normal(size=NX * NZ), rng.normal(size=NX * NZ)
    Ku, Rv = _kernel_products(scene, args, jnp.asarray(u), jnp.asarray(v))
    assert np.allclose(Ku, K @ u, rtol=0, atol=1e-12 * np.abs(K @ u).max())
    assert np.allclose(Rv, R @ v, rtol=0, atol=1e-12 * np.abs(R @ v).max())
    # Initial state: u = (1 + 1e-5) u_c, u_c = -K^-1 mu(0) sigma.
    u_c = -np.linalg.solve(K, 0.6 * sigma)
    assert np.allclose(x0[NX * NZ : 2 * NX * NZ], (1 + 1e-5) * u_c, rtol=1e-12, atol=0)
    np.testing.assert_allclose(args_dense["K"], K, rtol=0, atol=1e-12 * np.abs(K).max())
    np.testing.assert_allclose(args_dense["R"], R, rtol=0, atol=1e-12 * np.abs(R).max())
    np.testing.assert_allclose(x0_dense, x0, rtol=1e-11, atol=0)


def test_spectral_kernel_is_half_wavenumber_on_a_mode():
    # Antiplane (nu = 0), no floor to speak of, no normalisation: a slip cos(k.x) carries the
    # stress -(|k|/2) cos(k.x) per unit shear modulus, k = 2 pi (1/Lx, 2/Lz).
    scene, _, args = scenes.fault("spectral", 8, 8, depth=3.0, normalise=False, k_floor=1e-9)
    p = np.arange(64)
    x, z = (p % 8) / 8, (p // 8) / 8
    kx, kz = 2 * np.pi, 4 * np.pi
    u = np.cos(kx * x + kz * z)
    Ku, Rv = _kernel_products(scene, args, jnp.asarray(u), jnp.asarray(u))
    k = np.hypot(kx, kz)
    assert np.allclose(Ku, k / 2 * u, rtol=0, atol=1e-12)
    assert np.allclose(Rv, np.sqrt(k / 2) * u, rtol=0, atol=1e-12)


def test_bad_kernels_raise_before_any_work():
    with pytest.raises(ValueError, match="symmetric"):
        scenes.fault(np.array([[1.0, 0.5], [0.0, 1.0]]), 2, 1)
    with pytest.raises(ValueError, match="positive definite"):
        scenes.fault(-np.eye(4))
    with pytest.raises(ValueError, match="`kernel` must be \\(9, 9\\)"):
        scenes.fault(np.eye(4), 3, 3)
    with pytest.raises(ValueError, match="k_floor"):
        scenes.fault("spectral", 4, 4, k_floor=0.0)
    with pytest.raises(ValueError, match="'spectral' or a square matrix"):
        scenes.fault("fft")


# --------------------------------------------------------------------------------------------
# The study's 2 x 2 fault (3 km patch) against a regularised Radau integration.

FAULT4, FAULT4_X0, FAULT4_ARGS = scenes.fault(
    scenes.load_fault_kernel(DATA / "kijs_2x2elem-3x3length.npy")
)
T_STUDY = 34.641


def regularised_mean_slip(x0, a, t1, eps):
    """SciPy Radau on the fault with sign(v) replaced by v / sqrt(v^2 + eps^2) (and |v| by
    sqrt(v^2 + eps^2) - eps), analytic Jacobian; the mean final slip."""
    a = {k: np.asarray(val) for k, val in a.items()}
    n = a["K"].shape[0]
    E = 2 * a["zeta"] * a["R"]

    def parts(x):
        v, s = x[:n], x[2 * n :]
        w = np.exp(-s / a["Dc"])
        c = (a["mu_res"] + a["delta_mu"] * w) * a["sigma"]
        return v, x[n : 2 * n], w, c, np.sqrt(v * v + eps * eps)

    def rhs(t, x):
        v, u, _, c, q = parts(x)
        return np.concatenate([-a["K"] @ u - E @ v - c * v / q, v, q - eps])

    def jac(t, x):
        v, _, w, c, q = parts(x)
        J = np.zeros((3 * n, 3 * n))
        J[:n, :n] = -E - np.diag(c * eps**2 / q**3)
        J[:n, n : 2 * n] = -a["K"]
        J[:n, 2 * n :] = np.diag(v / q * a["delta_mu"] * w / a["Dc"] * a["sigma"])
        J[n : 2 * n, :n] = np.eye(n)
        J[2 * n :, :n] = np.diag(v / q)
        return J

    sol = solve_ivp(rhs, (0, t1), np.asarray(x0), "Radau", jac=jac, rtol=1e-10, atol=1e-8)
    assert sol.status == 0
    return float(np.mean(sol.y[2 * n :, -1]))


def test_study_2x2_mean_final_slip():
    # The regularised limit: eps = 1e-3, 1e-4 give 2356.910, 2356.818 (creep after arrest
    # grows like eps); eps = 1e-5 is within 1e-2 of the limit.
    ref = regularised_mean_slip(FAULT4_X0, FAULT4_ARGS, T_STUDY, 1e-5)
    solve = _compiled(FAULT4, 4000)
    sol = solve(FAULT4_X0, FAULT4_ARGS, T_STUDY, _pid(1e-6, 1e-6))
    assert sol.result == nj.RESULTS.successful
    n = 4
    slip = float(np.mean(sol.y_final[2 * n :]))
    print("2x2 mean final slip", slip, ref)
    assert abs(slip - ref) < 2e-5 * ref  # measured 4.1e-6 relative
    # Every cell slipped once and is stuck at the end.
    assert np.all(np.asarray(sol.y_final[2 * n :]) > 1000.0)
    assert np.max(np.abs(sol.y_final[:n])) < 1e-10


# --------------------------------------------------------------------------------------------
# Burridge–Knopoff chain.

DRIVEN = dict(mu_static=0.6, mu_kinetic=0.3, slip_scale=1.0, drive_velocity=0.1)
N_CHAIN = 4
CHAIN, _, _ = scenes.spring_block_chain(N_CHAIN)
CHAIN_SOLVE = _compiled(CHAIN, 4000)


def test_identical_blocks_are_the_driven_slider():
    # Identical blocks at the same place move together (the couplings carry nothing): each
    # is the spring slider, against its event-driven reference (DOP853 slip phases,
    # closed-form sticks).
    _, x0, args = scenes.spring_block_chain(N_CHAIN, perturbation=0.0, **DRIVEN)
    sol = CHAIN_SOLVE(x0, args, 30.0, _pid(1e-6, 1e-8))
    assert sol.result == nj.RESULTS.successful
    s = sol.trimmed()
    ts, ys = np.asarray(s.ts), np.asarray(s.ys)
    p = dict(m=1.0, k=1.0, c=0.0, N=1.0, mu_s=0.6, mu_k=0.3, Dc=1.0, V=0.1)
    s_ref, v_ref, switches = slider_event_driven(p, 0.0, 0.0, 30.0, ts)
    assert [m for _, m in switches] == [0, 1, 0, 1, 0, 1, 0, 1]
    # The spring slider's own scene test measures 7.4e-4 on the same reference.
    for i in range(N_CHAIN):
        err = np.max(np.maximum(np.abs(ys[:, i] - s_ref), np.abs(ys[:, N_CHAIN + i] - v_ref)))
        assert err < 1.5e-3


def test_frictionless_chain_is_linear():
    # Without friction and drive the chain is m s'' = kc L s - kp s - c s' (L the free-end
    # Laplacian): against the matrix exponential.
    n, kc, kp, c = N_CHAIN, 2.0, 0.5, 0.1
    _, x0, args = scenes.spring_block_chain(
        n, coupling=kc, stiffness=kp, damping=c, mu_static=0.0, mu_kinetic=0.0, perturbation=0.3
    )
    args = dict(args, V=jnp.asarray(0.0))
    sol = CHAIN_SOLVE(x0, args, 3.0, _pid(1e-6, 1e-8))
    assert sol.result == nj.RESULTS.successful
    L = -2 * np.eye(n) + np.eye(n, k=1) + np.eye(n, k=-1)
    L[0, 0] = L[-1, -1] = -1.0
    A = np.block([[np.zeros((n, n)), np.eye(n)], [kc * L - kp * np.eye(n), -c * np.eye(n)]])
    exact = expm(3.0 * A) @ np.asarray(x0)
    # A sign or a coefficient off in the coupling, the drive spring or the damping is O(1).
    assert np.allclose(sol.y_final, exact, rtol=0, atol=1e-3)


# --------------------------------------------------------------------------------------------
# Chain of balls: 8 unit balls of radius 0.5, the first thrown at 1. One executable: the
# spacing is in x0, the restitution in args.

N_BALLS = 8
BALLS, _, BALL_ARGS = scenes.chain_of_balls(N_BALLS)
BALLS_SOLVE = _compiled(BALLS, 2000)


def _balls(spacing, e, t1):
    _, x0, args = scenes.chain_of_balls(N_BALLS, spacing=spacing, restitution=e)
    sol = BALLS_SOLVE(x0, args, t1, _pid(1e-6, 1e-8))
    assert sol.result == nj.RESULTS.successful
    ys = np.asarray(sol.trimmed().ys)
    q, v = ys[:, :N_BALLS], ys[:, N_BALLS:]
    gaps = np.diff(q, axis=1) - 1.0
    return q, v, gaps


def test_balls_newton_cradle():
    # Spaced by 0.1 with e = 1: one impact at a time, each an exchange of velocities; the
    # last ball leaves at t = 0.7 with all the momentum and energy.
    q, v, gaps = _balls(0.1, 1.0, 1.5)
    assert gaps.min() > -1e-8
    assert np.allclose(v.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.allclose((v**2).sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.allclose(v[-1], np.eye(N_BALLS)[-1], rtol=0, atol=1e-12)
    assert q[-1, -1] == pytest.approx(7 * 1.1 + 0.8, abs=1e-8)


def test_balls_touching_plastic_chain_moves_as_one():
    # All contacts closed at t = 0, e = 0: one body at v0 / n, momentum kept.
    q, v, gaps = _balls(0.0, 0.0, 1.0)
    assert np.abs(gaps).max() < 1e-6  # measured 5.3e-8
    assert np.allclose(v.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.allclose(v[-1], 1.0 / N_BALLS, rtol=0, atol=1e-12)


def test_balls_touching_elastic_chain_keeps_invariants():
    # All contacts closed, e = 1: the simultaneous impact keeps momentum and energy.
    q, v, gaps = _balls(0.0, 1.0, 1.0)
    assert gaps.min() > -1e-8
    assert np.allclose(v.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.allclose((v**2).sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.all(np.diff(v[-1]) >= -1e-12)  # no later impact: the chain has separated
