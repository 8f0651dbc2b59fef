"""Projectors and their kernels.

Properties of the true projections (in the set, idempotent, non-expansive, variational
inequality), custom-JVP Jacobians against central finite differences (forward and reverse
mode, including derivatives through state-dependent bounds), the documented element of the
generalised Jacobian at kinks, `vmap`/`jit` consistency, the sign resolvent's fixed points,
the LCP kernel, unilateral-contact physics, and agreement with the reference package
`solve_nivp` where the two share semantics.
"""

import itertools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from helpers import ALL_PROJECTORS, fd_jacobian, tree_allclose
from hypothesis import assume, given, settings, strategies as st
from hypothesis.extra import numpy as hnp

import nivpjax as nv


SETTINGS = settings(max_examples=40, deadline=None)
KINK = 1e-4  # finite-difference samples closer than this to a kink are skipped
FD_RTOL, FD_ATOL = 1e-6, 1e-6  # central differences with eps=1e-6: error ~1e-10


def floats(lo=-3.0, hi=3.0):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False, allow_subnormal=False)


def vectors(n, lo=-3.0, hi=3.0):
    return hnp.arrays(np.float64, (n,), elements=floats(lo, hi))


def context(z, *, y_iter=None, y_prev=None, rho=None, args=None, h=1.0):
    """A context for `z` with the given fields (the others as in `nv.default_context`)."""
    z = jnp.asarray(z)
    return nv.ProjectionContext(
        t=jnp.zeros((), z.dtype),
        h=jnp.asarray(h, z.dtype),
        y_prev=z if y_prev is None else jnp.asarray(y_prev, z.dtype),
        y_iter=z if y_iter is None else jnp.asarray(y_iter, z.dtype),
        rho=jnp.ones_like(z) if rho is None else jnp.broadcast_to(jnp.asarray(rho), z.shape),
        args=args,
    )


def jacobian_fns(f, argnums):
    """`f` and `(jacfwd(f), jacrev(f))` with respect to `argnums`, each jitted once (one
    compilation per input shape)."""
    both = lambda *args: (jax.jacfwd(f, argnums)(*args), jax.jacrev(f, argnums)(*args))
    return jax.jit(f), jax.jit(both)


def assert_jacobians_match_fd(fns, args, argnums):
    f, jacobians = fns
    fwd, rev = jacobians(*args)
    for k, i in enumerate(argnums):
        fd = fd_jacobian(f, args, i)
        np.testing.assert_allclose(fwd[k], fd, rtol=FD_RTOL, atol=FD_ATOL)
        np.testing.assert_allclose(rev[k], fd, rtol=FD_RTOL, atol=FD_ATOL)


def lcp_enumerate(D, q):
    """Independent LCP reference: try every active set (fine for m <= 6). For a P-matrix
    exactly one active set gives a solution."""
    m = len(q)
    for size in range(m + 1):
        for S in itertools.combinations(range(m), size):
            S = list(S)
            p = np.zeros(m)
            if S:
                p[S] = np.linalg.solve(D[np.ix_(S, S)], -q[S])
            w = D @ p + q
            if np.all(p >= -1e-12) and np.all(w >= -1e-12):
                return p
    raise AssertionError("no solution found: D is not a P-matrix")


# ---------------------------------------------------------------------------------------
# Fixed data for state-dependent sets and contacts.

Y_ITER = jnp.array([0.3, -0.7, 1.2, 0.4, -0.1, 0.9, -1.3])  # an iterate for bounds


def box_lower(t, y, a):
    return -a * (1.0 + y[:3] ** 2)


def box_upper(t, y, a):
    return a * (0.2 + jnp.abs(y[3:6]))


BOX_STATE = nv.Box(lower=box_lower, upper=box_upper)
BALL_STATE = nv.Ball(radius=lambda t, y, a: a * (1.0 + y[0] ** 2))
SOC_STATE = nv.SecondOrderCone(mu=lambda t, y, a: a * (1.0 + y[0] ** 2))

# Three contacts on a state (position, 4 velocities); unit impulse map, so the projection is
# Euclidean onto {v : W_A^T v + e u^-_A >= 0}. With Y_PREV3 and h = 0.01 the predicted gaps
# are (-0.1047, -0.198, 1.099): contacts 0 and 1 are active, contact 2 is not.
WT3 = np.array(
    [
        [0.0, 1.0, 0.2, 0.0, 0.1],
        [0.0, 0.0, 1.0, -0.3, 0.0],
        [0.0, 0.5, 0.0, 1.0, 0.0],
    ]
)
E3 = 0.5
Y_PREV3 = jnp.array([0.1, -1.0, 0.5, 0.3, -0.4])
ACTIVE3 = np.array([True, True, False])
CONTACT3 = nv.UnilateralContact(
    gap=lambda t, y, a: jnp.stack([y[0] - 0.2, y[0] - 0.3, y[0] + 1.0]),
    velocity_map=lambda t, y, a: jnp.asarray(WT3),
    restitution=E3,
)

# Two coupled contacts at the ends of a bar, state (x1, x2, v1, v2, omega): u_1 = v1 + 0.5
# omega, u_2 = v2 - 0.4 omega, impulse map B = M^{-1} W with M = diag(., ., 2, 0.5, 0.8).
# Restitution per contact through args.
WT2 = np.array([[0.0, 0.0, 1.0, 0.0, 0.5], [0.0, 0.0, 0.0, 1.0, -0.4]])
MASS2 = np.array([1.0, 1.0, 2.0, 0.5, 0.8])
B2 = WT2.T / MASS2[:, None]
D2 = WT2 @ B2
Y_PREV2 = jnp.array([0.0, -0.001, -1.0, -0.5, 0.3])
CONTACT2 = nv.UnilateralContact(
    gap=lambda t, y, a: y[:2],
    velocity_map=lambda t, y, a: jnp.asarray(WT2),
    impulse_map=lambda t, y, a: jnp.asarray(B2),
    restitution=lambda t, y, a: a,
)


def contact2(z, e):
    return CONTACT2(z, context(z, y_prev=Y_PREV2, h=0.01, args=e))


# ---------------------------------------------------------------------------------------
# True projections onto closed convex sets: apply (jitted, z -> P(z)) and a violation
# measure (0 inside the set).


class SetCase(NamedTuple):
    dim: int
    apply: Any
    violation: Any


def _fixed_case(projector, dim):
    return jax.jit(lambda z: projector(z, nv.default_context(z)))


_CATALOGUE = dict((name, (proj, dim)) for name, proj, dim in ALL_PROJECTORS)
_box_l, _box_u = np.array([-1.0, 0.0, 2.0]), np.array([1.0, 0.5, 2.0])
_bs_l, _bs_u = np.asarray(box_lower(0, Y_ITER, 0.8)), np.asarray(box_upper(0, Y_ITER, 0.8))
_ball_r = 0.9 * (1.0 + 0.3**2)
_soc_mu = 1.3 * (1.0 + 0.3**2)


def _soc_violation(p, mu):
    return max(np.linalg.norm(p[1:]) - mu * p[0], 0.0)


def _block_violation(p):
    return max(-p[0], np.linalg.norm(p[1:3]) - 1.0, _soc_violation(p[3:6], 0.7), 0.0)


SETS = {
    "identity": SetCase(3, _fixed_case(*_CATALOGUE["identity"]), lambda p: 0.0),
    "nonnegative": SetCase(3, _fixed_case(*_CATALOGUE["nonnegative"]), lambda p: -min(p.min(), 0)),
    "box": SetCase(
        3,
        _fixed_case(*_CATALOGUE["box"]),
        lambda p: max(np.max(_box_l - p), np.max(p - _box_u), 0.0),
    ),
    "box_state": SetCase(
        3,
        jax.jit(lambda z: BOX_STATE(z, context(z, y_iter=Y_ITER, args=0.8))),
        lambda p: max(np.max(_bs_l - p), np.max(p - _bs_u), 0.0),
    ),
    "ball": SetCase(
        2, _fixed_case(*_CATALOGUE["ball"]), lambda p: max(np.linalg.norm(p) - 1.5, 0.0)
    ),
    "ball_state": SetCase(
        3,
        jax.jit(lambda z: BALL_STATE(z, context(z, y_iter=Y_ITER, args=0.9))),
        lambda p: max(np.linalg.norm(p) - _ball_r, 0.0),
    ),
    "soc": SetCase(3, _fixed_case(*_CATALOGUE["soc"]), lambda p: _soc_violation(p, 0.7)),
    "soc_state": SetCase(
        2,
        jax.jit(lambda z: SOC_STATE(z, context(z, y_iter=Y_ITER, args=1.3))),
        lambda p: _soc_violation(p, _soc_mu),
    ),
    "contact": SetCase(
        5,
        jax.jit(lambda z: CONTACT3(z, context(z, y_prev=Y_PREV3, h=0.01))),
        lambda p: max(-np.min((WT3 @ p + E3 * (WT3 @ np.asarray(Y_PREV3)))[ACTIVE3]), 0.0),
    ),
    "block": SetCase(7, _fixed_case(*_CATALOGUE["block"]), _block_violation),
}


@pytest.mark.parametrize("name", list(SETS))
@SETTINGS
@given(data=st.data())
def test_output_in_set(name, data):
    case = SETS[name]
    z = data.draw(vectors(case.dim, -4, 4))
    p = np.asarray(case.apply(z))
    assert case.violation(p) <= 1e-12 * (1 + np.max(np.abs(z)))


@pytest.mark.parametrize("name", list(SETS))
@SETTINGS
@given(data=st.data())
def test_idempotent(name, data):
    case = SETS[name]
    z = data.draw(vectors(case.dim, -4, 4))
    p = case.apply(z)
    np.testing.assert_allclose(case.apply(p), p, rtol=0, atol=1e-12 * (1 + np.max(np.abs(z))))


@pytest.mark.parametrize("name", list(SETS))
@SETTINGS
@given(data=st.data())
def test_non_expansive(name, data):
    case = SETS[name]
    x = data.draw(vectors(case.dim, -4, 4))
    y = data.draw(vectors(case.dim, -4, 4))
    dp = np.linalg.norm(case.apply(x) - case.apply(y))
    assert dp <= np.linalg.norm(x - y) * (1 + 1e-12) + 1e-12


@pytest.mark.parametrize("name", list(SETS))
@SETTINGS
@given(data=st.data())
def test_variational_inequality(name, data):
    # <z - P(z), x - P(z)> <= 0 for every x in the set; x = P(x') samples the set (membership
    # of P(x') is checked by test_output_in_set).
    case = SETS[name]
    z = data.draw(vectors(case.dim, -4, 4))
    x = np.asarray(case.apply(data.draw(vectors(case.dim, -4, 4))))
    p = np.asarray(case.apply(z))
    assert np.dot(z - p, x - p) <= 1e-10 * (1 + np.max(np.abs(z))) ** 2


COULOMB = nv.CoulombFriction(bound=lambda t, y, a: a)


def coulomb(z, rho, c):
    return COULOMB(z, context(z, rho=rho, args=c))


_coulomb_fns = jacobian_fns(coulomb, (0, 1, 2))


@SETTINGS
@given(x=vectors(3, -4, 4), y=vectors(3, -4, 4), rho=vectors(3, 0.1, 2), c=vectors(3, 0, 2))
def test_coulomb_firmly_non_expansive(x, y, rho, c):
    # A proximal map (soft thresholding) is firmly non-expansive:
    # |P(x) - P(y)|^2 <= <P(x) - P(y), x - y>.
    f = _coulomb_fns[0]
    dp = np.asarray(f(x, rho, c) - f(y, rho, c))
    assert dp @ dp <= dp @ (x - y) + 1e-12


@SETTINGS
@given(z=vectors(3, -4, 4), rho=vectors(3, 0.1, 2), c=vectors(3, 0, 2))
def test_coulomb_is_soft_thresholding(z, rho, c):
    # Independent closed form: the prox of rho*c*|.| is sign(z) max(|z| - rho c, 0).
    expected = np.sign(z) * np.maximum(np.abs(z) - rho * c, 0.0)
    np.testing.assert_allclose(_coulomb_fns[0](z, rho, c), expected, rtol=1e-14, atol=1e-14)


# ---------------------------------------------------------------------------------------
# Jacobians (jacfwd and jacrev) against central finite differences away from kinks.

_clip_fns = jacobian_fns(nv.clip, (0, 1, 2))


@SETTINGS
@given(z=vectors(3), a=vectors(3), b=vectors(3))
def test_clip_jacobian(z, a, b):
    lower, upper = np.minimum(a, b), np.maximum(a, b)
    assume(np.all(upper - lower > KINK))  # lower == upper is a kink in the bounds
    assume(np.all(np.abs(z - lower) > KINK) and np.all(np.abs(z - upper) > KINK))
    assert_jacobians_match_fd(_clip_fns, (z, lower, upper), (0, 1, 2))


_ball_fns = jacobian_fns(nv.project_ball, (0, 1))


@SETTINGS
@given(w=vectors(3), radius=floats(-1, 3))
def test_project_ball_jacobian(w, radius):
    nrm = np.linalg.norm(w)
    assume(abs(radius) > 1e-3 and nrm > 0.05 and abs(nrm - radius) > 1e-3)
    assert_jacobians_match_fd(_ball_fns, (w, radius), (0, 1))


def _soc_flat(s, w, mu):
    s_out, w_out = nv.project_soc(s, w, mu)
    return jnp.concatenate([s_out[None], w_out])


_soc_fns = jacobian_fns(_soc_flat, (0, 1, 2))
_soc_flat_jit = _soc_fns[0]


def _away_from_soc_kinks(s, w, mu):
    r, scale = np.linalg.norm(w), np.sqrt(1 + mu**2)
    return r > 0.05 and abs(r - mu * s) > 1e-3 * scale and abs(mu * r + s) > 1e-3 * scale


@SETTINGS
@given(s=floats(), w=vectors(2), mu=floats(0.1, 3))
def test_project_soc_jacobian(s, w, mu):
    assume(_away_from_soc_kinks(s, w, mu))
    assert_jacobians_match_fd(_soc_fns, (s, w, mu), (0, 1, 2))


_box_state_fns = jacobian_fns(lambda z, y, a: BOX_STATE(z, context(z, y_iter=y, args=a)), (0, 1, 2))


@SETTINGS
@given(z=vectors(3), y=vectors(7), a=floats(0.1, 2))
def test_box_state_dependent_jacobian(z, y, a):
    # Bounds are callables of ctx.y_iter and args: derivatives w.r.t. z, the iterate and a.
    assume(np.all(np.abs(y[3:6]) > KINK))
    lower, upper = np.asarray(box_lower(0, y, a)), np.asarray(box_upper(0, y, a))
    assume(np.all(np.abs(z - lower) > KINK) and np.all(np.abs(z - upper) > KINK))
    assert_jacobians_match_fd(_box_state_fns, (z, y, a), (0, 1, 2))


_ball_state_fns = jacobian_fns(
    lambda z, y, a: BALL_STATE(z, context(z, y_iter=y, args=a)), (0, 1, 2)
)


@SETTINGS
@given(z=vectors(2), y=vectors(3, -1, 1), a=floats(0.1, 2))
def test_ball_state_dependent_jacobian(z, y, a):
    radius, nrm = a * (1 + y[0] ** 2), np.linalg.norm(z)
    assume(nrm > 0.05 and abs(nrm - radius) > 1e-3)
    assert_jacobians_match_fd(_ball_state_fns, (z, y, a), (0, 1, 2))


_soc_state_fns = jacobian_fns(lambda z, y, a: SOC_STATE(z, context(z, y_iter=y, args=a)), (0, 1, 2))


@SETTINGS
@given(z=vectors(3), y=vectors(2, -1, 1), a=floats(0.1, 2))
def test_soc_state_dependent_jacobian(z, y, a):
    assume(_away_from_soc_kinks(z[0], z[1:], a * (1 + y[0] ** 2)))
    assert_jacobians_match_fd(_soc_state_fns, (z, y, a), (0, 1, 2))


@SETTINGS
@given(z=vectors(3, -4, 4), rho=vectors(3, 0.1, 2), c=vectors(3, 0.05, 2))
def test_coulomb_jacobian(z, rho, c):
    # Derivatives w.r.t. z, the stage scaling rho and the friction bound c.
    assume(np.all(np.abs(np.abs(z) - rho * c) > KINK))
    assert_jacobians_match_fd(_coulomb_fns, (z, rho, c), (0, 1, 2))


SIGN2 = nv.SignResolvent(s_index=(0, 1), w_index=(2, 3))  # tau from ctx.rho
_sign_fns = jacobian_fns(lambda z, rho: SIGN2(z, context(z, rho=rho)), (0, 1))


@SETTINGS
@given(z=vectors(5), rho=vectors(5, 0.1, 3))
def test_sign_resolvent_jacobian(z, rho):
    assume(np.all(np.abs(np.abs(z[2:4] + rho[2:4] * z[0:2]) - 1) > KINK))
    assert_jacobians_match_fd(_sign_fns, (z, rho), (0, 1))


_contact2_fns = jacobian_fns(contact2, (0, 1))
_lcp = jax.jit(nv.lcp_solve)
_lcp_fns = jacobian_fns(nv.lcp_solve, (0, 1))


def _contact2_lcp(z, e):
    u_minus = WT2 @ np.asarray(Y_PREV2)
    q = WT2 @ z + e * u_minus
    p = lcp_enumerate(D2, q)
    return p, D2 @ p + q


@SETTINGS
@given(z=vectors(5), e=vectors(2, 0, 1))
def test_contact_jacobian(z, e):
    # Derivatives w.r.t. the candidate and the restitution coefficients (through args).
    p, w = _contact2_lcp(z, e)
    assume(np.min(p + w) > KINK)  # strict complementarity: the LCP is not degenerate
    assert_jacobians_match_fd(_contact2_fns, (z, e), (0, 1))


CUSTOM_WITH_JAC = nv.CustomProjector(
    project=lambda z, ctx: jnp.clip(z, -ctx.args, ctx.args),
    jacobian=lambda z, ctx: jnp.diag((jnp.abs(z) <= ctx.args).astype(z.dtype)),
)
CUSTOM_AUTO = nv.CustomProjector(project=lambda z, ctx: nv.clip(z, -ctx.args, ctx.args))
_custom_fns = {
    "with_jacobian": jacobian_fns(
        lambda z, a: CUSTOM_WITH_JAC(z, nv.default_context(z, a)), (0, 1)
    ),
    "autodiff": jacobian_fns(lambda z, a: CUSTOM_AUTO(z, nv.default_context(z, a)), (0, 1)),
}


@pytest.mark.parametrize("kind", list(_custom_fns))
@SETTINGS
@given(z=vectors(3), a=floats(0.1, 2))
def test_custom_projector_jacobian(kind, z, a):
    assume(np.all(np.abs(np.abs(z) - a) > KINK))
    assert_jacobians_match_fd(_custom_fns[kind], (z, a), (0, 1))


def test_custom_projector_uses_user_jacobian():
    # The user's matrix replaces d/dz (here deliberately 2 I, not the true derivative I),
    # while the derivative w.r.t. the context still comes from autodiff of `project`.
    proj = nv.CustomProjector(
        project=lambda z, ctx: z * ctx.args, jacobian=lambda z, ctx: 2.0 * jnp.eye(z.shape[0])
    )
    f = lambda z, a: proj(z, nv.default_context(z, a))
    z, a = jnp.array([1.0, -2.0]), jnp.array(3.0)
    for jac in (jax.jacfwd, jax.jacrev):
        dz, da = jac(f, (0, 1))(z, a)
        np.testing.assert_array_equal(dz, 2.0 * np.eye(2))
        np.testing.assert_array_equal(da, z)


_block = _CATALOGUE["block"][0]
_block_jac = jax.jit(jax.jacfwd(lambda z: _block(z, nv.default_context(z))))
_block_parts = [
    (
        np.asarray(indices),
        jax.jit(lambda v, p=proj: p(v, nv.default_context(v))),
        jax.jit(jax.jacfwd(lambda v, p=proj: p(v, nv.default_context(v)))),
    )
    for indices, proj in _block.blocks
]


@SETTINGS
@given(z=vectors(7))
def test_block_projector_is_blockwise(z):
    # Output and Jacobian are those of the blocks' projectors (each FD-checked above); the
    # component in no block passes through with derivative 1.
    expected_out, expected_jac = np.array(z), np.zeros((7, 7))
    for idx, apply, jac in _block_parts:
        expected_out[idx] = apply(z[idx])
        expected_jac[np.ix_(idx, idx)] = jac(z[idx])
    expected_jac[6, 6] = 1.0
    np.testing.assert_allclose(SETS["block"].apply(z), expected_out, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(_block_jac(z), expected_jac, rtol=1e-14, atol=1e-14)


def test_block_projector_restricts_rho():
    block = nv.BlockProjector([((1, 3), COULOMB)])
    z = jnp.array([5.0, 2.0, -7.0, -3.0])
    rho = jnp.array([10.0, 0.5, 10.0, 2.0])
    c = jnp.array([1.0, 1.0])
    got = block(z, context(z, rho=rho, args=c))
    # soft thresholds 0.5*1 on z[1] and 2*1 on z[3]; z[0], z[2] untouched
    np.testing.assert_array_equal(got, [5.0, 1.5, -7.0, -1.0])


def test_empty_block_projector_is_identity():
    z = jnp.array([1.0, -2.0, 3.0])
    ctx = nv.default_context(z)
    np.testing.assert_array_equal(nv.BlockProjector([])(z, ctx), z)
    np.testing.assert_array_equal(jax.jacfwd(lambda v: nv.BlockProjector([])(v, ctx))(z), np.eye(3))


def test_bad_construction():
    with pytest.raises(TypeError, match="sequence of `\\(indices, projector\\)` pairs"):
        nv.BlockProjector([(0,)])
    with pytest.raises(TypeError, match="must be an AbstractProjector"):
        nv.BlockProjector([((0,), lambda z, ctx: z)])
    with pytest.raises(ValueError, match="overlap at \\[1\\]"):
        nv.BlockProjector([((0, 1), nv.NonNegative()), ((1, 2), nv.NonNegative())])
    with pytest.raises(ValueError, match="same length"):
        nv.SignResolvent(s_index=(0, 1), w_index=2)
    with pytest.raises(ValueError, match="`tau` must be positive"):
        nv.SignResolvent(s_index=0, w_index=1, tau=0.0)


# ---------------------------------------------------------------------------------------
# The documented element of the generalised Jacobian at kinks.


def test_clip_kinks_take_identity():
    jacobians = _clip_fns[1]
    # On a bound (and on a degenerate interval lower == upper) the point is in the set:
    # d/dz = 1 (plain jnp.clip would give 1/2) and the bounds get derivative 0.
    z, lower, upper = (
        jnp.array([-1.0, 1.0, 2.0]),
        jnp.array([-1.0, -1.0, 2.0]),
        jnp.array([1.0, 1.0, 2.0]),
    )
    for dz, dlower, dupper in jacobians(z, lower, upper):
        np.testing.assert_array_equal(dz, np.eye(3))
        np.testing.assert_array_equal(dlower, np.zeros((3, 3)))
        np.testing.assert_array_equal(dupper, np.zeros((3, 3)))
    # Strictly outside: the derivative is w.r.t. the violated bound only.
    z, lower, upper = jnp.array([3.0, -3.0, 0.5]), -jnp.ones(3), jnp.ones(3)
    for dz, dlower, dupper in jacobians(z, lower, upper):
        np.testing.assert_array_equal(dz, np.diag([0.0, 0.0, 1.0]))
        np.testing.assert_array_equal(dlower, np.diag([0.0, 1.0, 0.0]))
        np.testing.assert_array_equal(dupper, np.diag([1.0, 0.0, 0.0]))


def test_nonnegative_and_box_kinks_take_identity():
    z = jnp.array([0.0, 0.0, 2.0])  # on the box's lower bounds and its interval [2, 2]
    for name in ("nonnegative", "box"):
        proj = _CATALOGUE[name][0]
        f = lambda v: proj(v, nv.default_context(v))
        np.testing.assert_array_equal(f(z), z)
        for jac in (jax.jacfwd(f)(z), jax.jacrev(f)(z)):
            np.testing.assert_array_equal(jac, np.eye(3))


def test_ball_kinks():
    jacobians = _ball_fns[1]
    w = jnp.array([3.0, 4.0, 0.0])
    # On the boundary |w| = r, and at the centre: identity.
    for point in (w, jnp.zeros(3)):
        for dw, dr in jacobians(point, 5.0):
            np.testing.assert_array_equal(dw, np.eye(3))
            np.testing.assert_array_equal(dr, np.zeros(3))
    # Radius <= 0: the set is {0}, output 0, zero Jacobian.
    for radius in (0.0, -1.0):
        np.testing.assert_array_equal(_ball_fns[0](w, radius), np.zeros(3))
        for dw, dr in jacobians(w, radius):
            np.testing.assert_array_equal(dw, np.zeros((3, 3)))
            np.testing.assert_array_equal(dr, np.zeros(3))


SOC_KINKS = [
    (0.0, [0.0, 0.0], 0.7, "identity"),  # apex
    (2.0, [0.0, 0.0], 0.7, "identity"),  # on the axis, inside
    (1.0, [3.0, 4.0], 5.0, "identity"),  # on the cone's boundary |w| = mu s
    (2.0, [0.1, 0.0], 0.7, "identity"),  # strictly inside
    (-1.0, [0.0, 0.0], 0.7, "zero"),  # on the axis, in the polar cone
    (-2.0, [0.1, 0.0], 0.5, "zero"),  # strictly in the polar cone
    (-2.5, [3.0, 4.0], 0.5, "zero"),  # on the polar cone's boundary mu |w| = -s
]


@pytest.mark.parametrize(
    "s, w, mu, expected, mode",
    [(*case, "jacfwd") for case in SOC_KINKS] + [(*case, "jacrev") for case in SOC_KINKS],
)
def test_soc_kinks(s, w, mu, expected, mode):
    w = jnp.asarray(w)
    out = _soc_flat(s, w, mu)
    z = np.concatenate([[s], w])
    np.testing.assert_array_equal(out, z if expected == "identity" else np.zeros(3))
    jac = _soc_fns[1](s, w, mu)[0 if mode == "jacfwd" else 1]
    full = np.concatenate([np.asarray(jac[0])[:, None], np.asarray(jac[1])], axis=1)
    np.testing.assert_array_equal(full, np.eye(3) if expected == "identity" else 0.0)
    np.testing.assert_array_equal(jac[2], np.zeros(3))


def test_soc_non_expansive_at_zero_friction():
    # K_0 is the ray {w = 0, s >= 0} (the limit mu -> 0+; a friction cone with mu = 0 is a
    # frictionless normal force s >= 0). Any projection is non-expansive, in particular
    # continuous in w at w = 0.
    a = np.asarray(_soc_flat_jit(-1.0, jnp.array([0.0, 0.0]), 0.0))
    b = np.asarray(_soc_flat_jit(-1.0, jnp.array([1e-12, 0.0]), 0.0))
    assert np.linalg.norm(a - b) <= 1e-12
    np.testing.assert_array_equal(a, np.zeros(3))


def test_coulomb_stick_slip_boundary_takes_stick_branch():
    # |z| = rho c exactly: output 0 and dP/dz = 0 (the stick branch, clip's identity).
    z, rho, c = jnp.array([1.0, -1.0, 0.3]), jnp.array([0.5, 0.5, 1.0]), jnp.array([2.0, 2.0, 0.3])
    np.testing.assert_array_equal(_coulomb_fns[0](z, rho, c), np.zeros(3))
    for dz, _, _ in _coulomb_fns[1](z, rho, c):
        np.testing.assert_array_equal(dz, np.zeros((3, 3)))


def test_sign_resolvent_kink_takes_identity():
    # w + tau s = 1 exactly: w_new = 1, dw_new/dw = 1, dw_new/ds = tau.
    sign = nv.SignResolvent(s_index=0, w_index=1, tau=2.0)
    f = lambda z: sign(z, nv.default_context(z))
    z = jnp.array([0.25, 0.5])
    np.testing.assert_array_equal(f(z), [0.25, 1.0])
    for jac in (jax.jacfwd(f)(z), jax.jacrev(f)(z)):
        np.testing.assert_array_equal(jac, [[1.0, 0.0], [2.0, 1.0]])


def test_lcp_degenerate_index_is_inactive():
    # q_1 = 0 with p_1 = 0 and (Dp + q)_1 = 0: no impulse reacts (dp_1 = 0).
    D = jnp.array([[2.0, 0.5], [0.5, 1.0]])
    q = jnp.array([-1.0, -0.25])  # p = (0.5, 0), w_1 = 0.5 * 0.5 - 0.25 = 0
    np.testing.assert_array_equal(_lcp_fns[0](D, q), [0.5, 0.0])
    for _, dq in _lcp_fns[1](D, q):
        np.testing.assert_array_equal(dq, [[-0.5, 0.0], [0.0, 0.0]])


# ---------------------------------------------------------------------------------------
# vmap and jit agree with single eager calls (values and Jacobians).

MAPPED = {  # (f(z, a), dim); "block" and the *_state cases cover ALL_PROJECTORS' kernels
    "block": (lambda z, a: _block(z, nv.default_context(z)), 7),
    "box_state": (lambda z, a: BOX_STATE(z, context(z, y_iter=Y_ITER, args=a)), 3),
    "ball_state": (lambda z, a: BALL_STATE(z, context(z, y_iter=Y_ITER, args=a)), 3),
    "soc_state": (lambda z, a: SOC_STATE(z, context(z, y_iter=Y_ITER, args=a)), 2),
    "coulomb": (lambda z, a: coulomb(z, jnp.full(3, 0.7), jnp.full(3, a)), 3),
    "sign": (lambda z, a: SIGN2(z, context(z, rho=jnp.full(5, a))), 5),
    "contact3": (lambda z, a: CONTACT3(z, context(z, y_prev=Y_PREV3, h=0.01)), 5),
    "contact2": (lambda z, a: contact2(z, jnp.full(2, a)), 5),
    "custom_with_jacobian": (lambda z, a: CUSTOM_WITH_JAC(z, nv.default_context(z, a)), 3),
    "custom_autodiff": (lambda z, a: CUSTOM_AUTO(z, nv.default_context(z, a)), 3),
}


@pytest.mark.parametrize("name", list(MAPPED))
def test_vmap_and_jit_match_single_calls(name, getkey):
    f, dim = MAPPED[name]
    with_jac = lambda z, a: (f(z, a), jax.jacfwd(f)(z, a))
    zs = 2.0 * jr.normal(getkey(), (4, dim))
    zs = jnp.concatenate([zs, jnp.zeros((1, dim))])  # a kink for most sets
    args = jr.uniform(getkey(), (5,), minval=0.2, maxval=1.0)
    tol = dict(rtol=1e-13, atol=1e-13)
    single = jax.jit(with_jac)
    singles = [single(z, a) for z, a in zip(zs, args)]
    # jit against one eager (un-jitted, un-batched) call
    assert tree_allclose(f(zs[0], args[0]), singles[0][0], **tol)
    # vmap (values and Jacobians) against the single calls
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *singles)
    assert tree_allclose(jax.jit(jax.vmap(with_jac))(zs, args), stacked, **tol)


def test_lcp_vmap_matches_single_calls(getkey):
    G = jr.normal(getkey(), (6, 3, 3))
    Ds = G @ jnp.swapaxes(G, 1, 2) / 3 + 0.2 * jnp.eye(3)
    qs = 2.0 * jr.normal(getkey(), (6, 3))
    single = jnp.stack([_lcp(D, q) for D, q in zip(Ds, qs)])
    assert tree_allclose(jax.jit(jax.vmap(nv.lcp_solve))(Ds, qs), single, rtol=1e-13, atol=1e-13)


# ---------------------------------------------------------------------------------------
# SignResolvent: fixed points are exactly w in sign(s).

SIGN1 = nv.SignResolvent(s_index=0, w_index=1)
_sign1 = jax.jit(lambda z, tau: SIGN1(z, context(z, rho=tau)))


@SETTINGS
@given(
    s=st.one_of(st.just(0.0), floats(1e-3, 3), floats(-3, -1e-3)),
    w=st.one_of(st.sampled_from([-1.0, 1.0]), floats(-1, 1), floats(-3, 3)),
    tau=floats(0.01, 10),
)
def test_sign_resolvent_fixed_points(s, w, tau):
    out = np.asarray(_sign1(jnp.array([s, w]), tau))
    in_sign = (s > 0 and w == 1.0) or (s < 0 and w == -1.0) or (s == 0 and abs(w) <= 1)
    assert (out[1] == w) == in_sign
    assert -1.0 <= out[1] <= 1.0
    assert out[0] == s


def test_sign_resolvent_tau_default_uses_rho():
    z = jnp.array([0.3, -0.2, 0.1, 0.4, 7.0])
    rho = jnp.array([9.0, 9.0, 0.5, 2.0, 9.0])
    got = SIGN2(z, context(z, rho=rho))
    expected = [0.3, -0.2, 0.1 + 0.5 * 0.3, 0.4 - 2.0 * 0.2, 7.0]
    np.testing.assert_allclose(got, expected, rtol=1e-15)
    explicit = nv.SignResolvent(s_index=(0, 1), w_index=(2, 3), tau=0.5)
    np.testing.assert_allclose(
        explicit(z, context(z, rho=rho)), [0.3, -0.2, 0.25, 0.3, 7.0], rtol=1e-15
    )


# ---------------------------------------------------------------------------------------
# lcp_solve on random P-matrices.


@st.composite
def lcp_problems(draw):
    m = draw(st.integers(1, 6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    G = rng.normal(size=(m, m))
    D = G @ G.T / m + 0.2 * np.eye(m)
    if draw(st.booleans()):  # positive definite but not symmetric: still a P-matrix
        K = rng.normal(size=(m, m))
        D = D + 0.5 * (K - K.T)
    q = draw(vectors(m, -5, 5))
    return D, q


@settings(max_examples=50, deadline=None)
@given(problem=lcp_problems())
def test_lcp_complementarity(problem):
    D, q = problem
    p = np.asarray(_lcp(D, q))
    w = D @ p + q
    assert p.min() >= -1e-10 and w.min() >= -1e-10
    assert np.max(np.abs(np.minimum(p, w))) <= 1e-10
    np.testing.assert_allclose(p, lcp_enumerate(D, q), rtol=1e-9, atol=1e-10)


@SETTINGS
@given(problem=lcp_problems())
def test_lcp_jacobian(problem):
    D, q = problem
    p = lcp_enumerate(D, q)
    assume(np.min(p + D @ p + q) > KINK)
    assert_jacobians_match_fd(_lcp_fns, (D, q), (0, 1))


# ---------------------------------------------------------------------------------------
# UnilateralContact physics.

GRAVITY, H = 9.81, 0.01


def _floor(restitution, flat=False):
    # A ball above a floor: state (height, vertical velocity); gap and velocity map of one
    # contact as a scalar and as a (1, 2) matrix, or (flat) as a vector.
    return nv.UnilateralContact(
        gap=lambda t, y, a: y[0],
        velocity_map=lambda t, y, a: jnp.array([0.0, 1.0] if flat else [[0.0, 1.0]]),
        restitution=restitution,
    )


@pytest.mark.parametrize("flat", [False, True])
def test_contact_resting_ball_has_exactly_zero_velocity(flat):
    y_prev = jnp.array([0.0, 0.0])
    z = jnp.array([0.0, -GRAVITY * H])  # one gravity-driven step, candidate pushes in
    out = _floor(0.0, flat)(z, context(z, y_prev=y_prev, h=H))
    assert float(out[1]) == 0.0
    assert float(out[0]) == 0.0


@pytest.mark.parametrize("e", [0.0, 0.5, 0.8, 1.0])
def test_contact_impact_restitution(e):
    u_minus = -2.0
    y_prev = jnp.array([0.001, u_minus])  # predicted gap 0.001 - 0.01 < 0: active
    z = jnp.array([0.001, u_minus - GRAVITY * H])
    out = _floor(e)(z, context(z, y_prev=y_prev, h=H))
    np.testing.assert_allclose(out[1], -e * u_minus, rtol=1e-14, atol=1e-15)
    assert float(out[0]) == 0.001


def test_switched_sees_a_component_landing_on_a_bound():
    # The faces of a box are its bounds and its interior; a clip lands a component exactly
    # on a bound (a diode's current turning off is 0.0): that is a change of face, and so
    # are leaving a bound and moving between bounds. Staying on one is not.
    box, orthant = nv.Box(-1.0, 1.0), nv.NonNegative()
    cases = [
        (orthant, [1.0], [0.0], True),
        (orthant, [0.0], [0.5], True),
        (orthant, [0.0], [0.0], False),
        (orthant, [0.3], [0.5], False),
        (box, [0.2], [1.0], True),
        (box, [-1.0], [1.0], True),
        (box, [1.0], [1.0], False),
        (box, [0.2], [-0.5], False),
    ]
    for projector, before, after, switched in cases:
        z = jnp.asarray(after)
        ctx = context(z, y_prev=before, y_iter=after)
        assert bool(projector.switched(ctx)) == switched, (projector, before, after)


@pytest.mark.parametrize("e", [0.5, 1.0])
def test_contact_restitution_acts_on_approach_only(e):
    # A contact penetrated at the stage start but separating (u- = +1; active: its gap stays
    # closed over the lookahead) whose candidate velocity points into the floor: Newton's
    # law restores nothing of a separating velocity, so the velocity after is exactly 0
    # (u+ >= -e u- would let the body move further in).
    y_prev = jnp.array([-0.1, 1.0])
    z = jnp.array([-0.1, -3.0])
    out = _floor(e)(z, context(z, y_prev=y_prev, h=H))
    assert float(out[1]) == 0.0


_floor_fns = jacobian_fns(lambda z, y_prev: _floor(0.5)(z, context(z, y_prev=y_prev, h=H)), 0)


def test_contact_inactive_when_predicted_gap_positive():
    # Positive predicted gap (above the floor, or at it but leaving): the identity, even
    # though the candidate velocity points into the floor.
    z = jnp.array([0.0, -3.0])
    for y_prev in ([0.5, -1.0], [0.0, 1.0]):
        y_prev = jnp.asarray(y_prev)
        np.testing.assert_array_equal(_floor_fns[0](z, y_prev), z)
        for jac in _floor_fns[1](z, y_prev):
            np.testing.assert_array_equal(jac, np.eye(2))


def test_contact_grazing_is_identity():
    # Resting contact (gap 0, u^- = 0) and zero candidate velocity: q = 0, p = 0. The point is
    # feasible, so the Jacobian is the identity.
    z = y_prev = jnp.array([0.0, 0.0])
    np.testing.assert_array_equal(_floor_fns[0](z, y_prev), z)
    for jac in _floor_fns[1](z, y_prev):
        np.testing.assert_array_equal(jac, np.eye(2))


_contact2 = jax.jit(contact2)


@SETTINGS
@given(z=vectors(5), x=vectors(5), e=vectors(2, 0, 1))
def test_contact_coupled_impulse_map(z, x, e):
    # Two coupled contacts, B = M^{-1} W: P(z) = z + B p with p the (independently
    # enumerated) LCP solution; P(z) satisfies Newton's law and is the projection in the
    # M-metric: <M (z - P z), P x - P z> <= 0 and |P x - P z|_M <= |x - z|_M.
    p_ref, _ = _contact2_lcp(z, e)
    pz, px = np.asarray(_contact2(z, e)), np.asarray(_contact2(x, e))
    np.testing.assert_allclose(pz, z + B2 @ p_ref, rtol=1e-12, atol=1e-12)
    u_plus, u_minus = WT2 @ pz, WT2 @ np.asarray(Y_PREV2)
    assert np.all(u_plus + e * u_minus >= -1e-12)
    np.testing.assert_allclose(p_ref * (u_plus + e * u_minus), 0.0, atol=1e-12)
    assert (MASS2 * (z - pz)) @ (px - pz) <= 1e-10
    m_norm = lambda v: np.sqrt(v @ (MASS2 * v))
    assert m_norm(px - pz) <= m_norm(x - z) * (1 + 1e-12) + 1e-12


# ---------------------------------------------------------------------------------------
# Agreement with the reference package solve_nivp.


def _report(record_property, name, worst):
    print(f"{name}: max discrepancy vs solve_nivp = {worst:.3e}")
    record_property(f"{name}_max_discrepancy", worst)


def test_sign_matches_reference(record_property):
    """`SignProjection.project(current, candidate, rhok=tau)` sets w = clip(w_c + tau s_c, -1,
    1) from the candidate's entries and ignores `current`: the same map as
    `nv.SignResolvent(tau=tau)` applied to the candidate."""
    ref = pytest.importorskip("solve_nivp.projections")
    rng = np.random.default_rng(0)
    s_idx, w_idx = [0, 3], [1, 4]
    worst = 0.0
    for _ in range(60):
        cand, cur = rng.normal(scale=2.0, size=5), rng.normal(size=5)
        tau = float(rng.uniform(0.05, 5.0))
        expected = ref.SignProjection(s_idx, w_idx).project(cur, cand.copy(), rhok=tau)
        got = nv.SignResolvent(s_idx, w_idx, tau=tau)(jnp.asarray(cand), nv.default_context(cand))
        worst = max(worst, float(np.max(np.abs(np.asarray(got) - expected))))
    _report(record_property, "sign", worst)
    assert worst <= 1e-14


def test_coulomb_matches_reference_at_fixed_points(record_property):
    """The two maps differ away from fixed points, but have the same fixed points.

    Reference: `CoulombProjection.project(y, y - rho R, rho)` projects (v, z~) with
    v = y - rho R and z~ = |y| - rho c (|current_state|, not |candidate|) onto the cone
    {z >= |v|} and keeps v. For y > 0 in its ray region the result is y - rho (R + c)/2, half
    the step of nivpjax's soft threshold P(y - rho R) = y - rho (R + c), so the outputs do
    not correspond one-to-one. Fixed points do: both maps fix y exactly when
    0 in R + c Sign(y) (slip y != 0, R = -c sign(y); stick y = 0, |R| <= c). Checked both
    ways on constructed fixed points and on perturbed (non-fixed) ones."""
    ref = pytest.importorskip("solve_nivp.projections")
    rng = np.random.default_rng(1)
    n = 4
    worst_fixed = 0.0
    for _ in range(60):
        c = rng.uniform(0.0, 2.0, n) * (rng.uniform(size=n) > 0.2)  # some c = 0
        rho = rng.uniform(0.05, 2.0, n)
        y = rng.normal(size=n) * (rng.uniform(size=n) > 0.4)  # some stick (y = 0)
        R = np.where(y != 0, -c * np.sign(y), rng.uniform(-1, 1, n) * c)
        fixed = True
        if rng.uniform() < 0.5:
            R = R + rng.choice([-1.0, 1.0], n) * rng.uniform(0.1, 1.0, n)
            fixed = False
        proj = ref.CoulombProjection(
            lambda y_, t, F, c=c: c, rhok=None, constraint_indices=np.arange(n), use_numba=False
        )
        res_ref = np.abs(proj.project(y, y - rho * R, rho) - y)
        res_nv = np.abs(np.asarray(_coulomb_fns[0](y - rho * R, rho, c)) - y)
        if fixed:
            worst_fixed = max(worst_fixed, float(res_ref.max()), float(res_nv.max()))
        else:
            # A perturbed slip component is fixed for neither map; a perturbed stick one
            # stays fixed for both while |R| <= c: compare componentwise fixedness.
            np.testing.assert_array_equal(res_ref <= 1e-12, res_nv <= 1e-12)
    _report(record_property, "coulomb_fixed_point_residual", worst_fixed)
    assert worst_fixed <= 1e-12


def test_coulomb_matches_reference_implicit_euler_limit(record_property):
    """Iterating y <- P(y, y - rho R(y)) for one implicit-Euler step of m v' in f - c Sign(v),
    R(v) = m (v - v_n)/h - f, converges for both maps to the same step result, the closed
    form soft(v_n + h f/m, h c/m); with rho = h/m nivpjax reaches it in one application."""
    ref = pytest.importorskip("solve_nivp.projections")
    rng = np.random.default_rng(2)
    n, m, h = 3, 1.5, 0.1
    rho = 0.5 * h / m * np.ones(n)
    worst = 0.0
    for _ in range(10):
        vn, f, c = rng.normal(size=n), 10 * rng.normal(size=n), rng.uniform(0.1, 10.0, n)
        R = lambda v: m * (v - vn) / h - f
        a = vn + h * f / m
        exact = np.sign(a) * np.maximum(np.abs(a) - h * c / m, 0.0)
        proj = ref.CoulombProjection(
            lambda y_, t, F, c=c: c, rhok=None, constraint_indices=np.arange(n), use_numba=False
        )
        v_ref, v_nv = vn.copy(), vn.copy()
        for _ in range(200):
            v_ref = proj.project(v_ref, v_ref - rho * R(v_ref), rho)
            v_nv = np.asarray(_coulomb_fns[0](v_nv - rho * R(v_nv), rho, c))
        one_step = np.asarray(_coulomb_fns[0](vn - (h / m) * R(vn), h / m * np.ones(n), c))
        np.testing.assert_allclose(one_step, exact, rtol=1e-13, atol=1e-13)
        worst = max(worst, float(np.max(np.abs(v_ref - v_nv))))
        np.testing.assert_allclose(v_nv, exact, rtol=1e-12, atol=1e-12)
    _report(record_property, "coulomb_implicit_euler", worst)
    assert worst <= 1e-8


def test_soc_matches_reference(record_property):
    """`MuScaledSOCProjection._proj_mu_scaled_soc(z, mu)` projects z = (s, w) onto
    {s >= 0, |w| <= mu s}: the same set, ordering (s first) and mu as
    `nv.project_soc(z[0], z[1:], mu)`. (The reference's `project()` calls it with
    mu' = 1/mu on [N, T]; that is `project_soc(N, T, 1/mu)` here.) mu > 0 only: at mu = 0
    neither is a projection (see test_soc_non_expansive_at_zero_friction)."""
    ref = pytest.importorskip("solve_nivp.projections")
    kernel = ref.MuScaledSOCProjection._proj_mu_scaled_soc
    rng = np.random.default_rng(3)
    special = [([0.0, 0.0, 0.0], 0.7), ([1.0, 3.0, 4.0], 5.0), ([-2.5, 3.0, 4.0], 0.5)]
    samples = special + [
        (rng.normal(scale=2.0, size=k + 1), float(rng.uniform(0.05, 4.0)))
        for k in rng.integers(1, 4, size=150)
    ]
    worst = 0.0
    for z, mu in samples:
        z = np.asarray(z)
        got = np.asarray(_soc_flat_jit(z[0], z[1:], mu))
        worst = max(worst, float(np.max(np.abs(got - kernel(z, mu)))))
    _report(record_property, "soc", worst)
    assert worst <= 1e-12


def _moreau_reference(ref, Wt, B, e):
    return ref.GeneralMoreauVIProjection(
        gap=lambda t, y: y[: Wt.shape[0]],
        u_map=lambda t, y: Wt @ y,
        J_u=lambda t, y: Wt,
        G_apply=lambda t, y, lam: B @ lam,
        e=e,
        lcp_maxit=500,
        lcp_tol=1e-14,
    )


@pytest.mark.parametrize("case", ["single", "coupled"])
def test_contact_matches_reference(case, record_property):
    """`GeneralMoreauVIProjection.project(y_k, ybar, prev_state=y_prev)` with u = W^T y,
    G(lam) = B lam, solves 0 <= lam perp W^T (ybar + B lam) + e W^T y_prev >= 0 on its active
    set {min(gap(ybar), gap(y_k)) <= 0} and returns ybar + B lam: the same LCP as
    `UnilateralContact` on its active set {gap(y_prev) + h/2 u^- <= 0}. All positions are
    set to -0.01 (penetrating) so that both active sets are all contacts, and only
    approaching pre-impact velocities u^- <= 0 are sampled: nivpjax applies restitution to
    approach velocities only (e min(u^-, 0)), the reference to any u^-, which lets a
    separating penetrated contact pull inwards. The reference's projected-Jacobi LCP is run
    to 1e-14 (it converges: D is diagonally dominant)."""
    ref = pytest.importorskip("solve_nivp.projections")
    if case == "single":
        # state (height, horizontal velocity, vertical velocity), unit impulse map
        Wt = np.array([[0.0, 0.0, 1.0]])
        B = Wt.T.copy()
        m = 1
    else:
        Wt, B, m = WT2, B2, 2
    contact = nv.UnilateralContact(
        gap=lambda t, y, a: y[:m],
        velocity_map=lambda t, y, a: jnp.asarray(Wt),
        impulse_map=lambda t, y, a: jnp.asarray(B),
        restitution=lambda t, y, a: a,
    )
    apply = jax.jit(
        lambda z, y_iter, y_prev, e: contact(
            z, context(z, y_iter=y_iter, y_prev=y_prev, h=H, args=e)
        )
    )
    rng = np.random.default_rng(4)
    n = Wt.shape[1]
    worst, used = 0.0, 0
    for _ in range(120):
        y_prev, y_k, ybar = (rng.normal(scale=1.5, size=n) for _ in range(3))
        for y in (y_prev, y_k, ybar):
            y[:m] = -0.01
        if np.any(Wt @ y_prev > 0.0):
            continue
        used += 1
        e = rng.uniform(0.0, 1.0, m)
        # a size-1 array e fails inside the reference (`float(e)` of a 1-d array): pass a
        # scalar for one contact
        e_ref = float(e[0]) if m == 1 else e
        expected = _moreau_reference(ref, Wt, B, e_ref).project(y_k, ybar, prev_state=y_prev)
        got = np.asarray(apply(ybar, y_k, y_prev, e))
        worst = max(worst, float(np.max(np.abs(got - expected))))
    assert used >= 10
    _report(record_property, f"contact_{case}", worst)
    assert worst <= 1e-8


def test_coulomb_violation_sees_a_missed_breakaway():
    # A step that ends stuck (v1 = 0) while the applied force there exceeds the bound c
    # missed a breakaway: the body would gain h (|F| - c) of velocity in one step, which
    # the violation reports in velocity units (a scheme checking the stick against an
    # average force over the step lets a growing load past the static bound). Within the
    # bound, or still slipping, nothing; a reversal counts its smaller speed.
    friction = nv.CoulombFriction(bound=2.0)
    h = 0.1

    def violation(v0, v1, force):
        ctx = nv.ProjectionContext(
            t=jnp.asarray(1.0),
            h=jnp.asarray(h),
            y_prev=jnp.array([v0]),
            y_iter=jnp.array([v1]),
            rho=jnp.ones(1),
            args=None,
            rate=jnp.array([force]),
        )
        return float(friction.violation(ctx))

    np.testing.assert_allclose(violation(0.0, 0.0, 3.5), h * 1.5, rtol=1e-14)
    np.testing.assert_allclose(violation(0.3, 0.0, -2.5), h * 0.5, rtol=1e-14)
    assert violation(0.0, 0.0, 1.9) == 0.0
    assert violation(0.3, 0.2, 3.5) == 0.0
    np.testing.assert_allclose(violation(0.3, -0.2, 0.0), 0.2, rtol=1e-14)
