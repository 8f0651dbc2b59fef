"""Bad input: every public entry point rejects it before any work, with a message naming the
argument, the value received and what was expected (STYLE.md §5); runtime failures are
reported with what failed, where and with which step size.

"Before any work" is checked with a tripwire vector field: `solve` may trace it once, for the
shape check, and raises `WorkStarted` on any further call, i.e. as soon as the compiled loop
starts being traced. So each rejection test costs no compilation, and a missing check shows up
as `WorkStarted` rather than as a slow run.
"""

import math
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nivpjax as nj
from nivpjax.compat import solve_ivp_ns


Y0 = np.array([1.0, 2.0])
NAN, INF = float("nan"), float("inf")


class WorkStarted(AssertionError):
    """The solver went past input validation (it traced the vector field a second time)."""


def tripwire(n_args=3):
    """A vector field $-y$ that may be called once (the shape check) and then trips."""
    calls = [0]

    def check():
        calls[0] += 1
        if calls[0] > 1:
            raise WorkStarted("the solver started work before rejecting the input")

    if n_args == 3:

        def vector_field(t, y, args):
            check()
            return -y

    else:

        def vector_field(t, y):
            check()
            return -y

    return vector_field


def run_solve(*, vector_field=None, t0=0.0, t1=1.0, y0=Y0, args=None, **kwargs):
    if vector_field is None:
        vector_field = tripwire()
    return nj.solve(vector_field, t0, t1, y0, args, **kwargs)


def run_compat(*, fun=None, t_span=(0.0, 1.0), y0=Y0, **kwargs):
    if fun is None:
        fun = tripwire(n_args=2)
    return solve_ivp_ns(fun, t_span, y0, **kwargs)


def test_tripwire_detects_work():
    # Valid input goes past validation: the tripwire must fire (else the tests below prove
    # nothing about "before any work").
    with pytest.raises(WorkStarted):
        run_solve()
    with pytest.raises(WorkStarted):
        run_compat()


# --------------------------------------------------------------------------------------------
# nivpjax.solve: the state and the vector field
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        pytest.param(
            dict(vector_field=lambda t, y, a: jnp.zeros(3)),
            ValueError,
            r"`vector_field\(t, y, args\)` must return an array of the same shape as `y0` "
            r"\(2,\), got \(3,\)",
            id="f-output-shape",
        ),
        pytest.param(
            dict(vector_field=lambda t, y, a: jnp.sum(y)),
            ValueError,
            r"`vector_field\(t, y, args\)` must return .* same shape as `y0` \(2,\), got \(\)",
            id="f-output-scalar",
        ),
        pytest.param(
            dict(vector_field=lambda t, y, a: (y, y)),
            ValueError,
            r"`vector_field\(t, y, args\)` must return .* same shape as `y0` \(2,\), got tuple",
            id="f-output-tuple",
        ),
        pytest.param(
            dict(vector_field="f"),
            TypeError,
            r"`vector_field` must be callable f\(t, y, args\), got 'f'",
            id="f-not-callable",
        ),
        pytest.param(
            dict(y0=np.ones((2, 1))),
            ValueError,
            r"`y0` must be a 1-D array of shape \(n,\), got shape \(2, 1\)",
            id="y0-2d",
        ),
        pytest.param(
            dict(y0=np.array(1.0)),
            ValueError,
            r"`y0` must be a 1-D array of shape \(n,\), got shape \(\)",
            id="y0-0d",
        ),
        pytest.param(dict(y0=1.0), TypeError, r"`y0` must be an array, got float", id="y0-float"),
        pytest.param(
            dict(y0=np.zeros(0)),
            ValueError,
            r"`y0` must have at least one component",
            id="y0-empty",
        ),
        pytest.param(
            dict(y0=np.array([1, 2], np.int32)),
            TypeError,
            r"`y0` must have a floating dtype \(float32 or float64\), got int32",
            id="y0-int",
        ),
        pytest.param(
            dict(y0=np.array([1.0, NAN])),
            ValueError,
            r"`y0` contains NaN or inf at components \[1\]",
            id="y0-nan",
        ),
        pytest.param(
            dict(y0=np.array([-INF, 1.0])),
            ValueError,
            r"`y0` contains NaN or inf at components \[0\]",
            id="y0-inf",
        ),
        pytest.param(
            dict(vector_field=lambda t, y: -y),
            TypeError,
            r"`vector_field` must accept \(t, y, args\) .*takes 2 positional arguments but 3",
            id="f-signature",
        ),
    ],
)
def test_solve_rejects_bad_state_or_vector_field(kwargs, error, match):
    with pytest.raises(error, match=match):
        run_solve(**kwargs)


# --------------------------------------------------------------------------------------------
# nivpjax.solve: the interval, the mass matrix, the options
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        pytest.param(
            dict(t0=1.0, t1=1.0),
            ValueError,
            r"`t1` must be greater than `t0`, got t0=1\.0, t1=1\.0",
            id="t1-equal",
        ),
        pytest.param(
            dict(t0=1.0, t1=0.5),
            ValueError,
            r"`t1` must be greater than `t0`, got t0=1\.0, t1=0\.5",
            id="t1-smaller",
        ),
        pytest.param(dict(t0=NAN), ValueError, r"`t0` must be finite, got nan", id="t0-nan"),
        pytest.param(dict(t0=-INF), ValueError, r"`t0` must be finite, got -inf", id="t0-inf"),
        pytest.param(dict(t1=INF), ValueError, r"`t1` must be finite, got inf", id="t1-inf"),
        pytest.param(dict(t1=NAN), ValueError, r"`t1` must be finite, got nan", id="t1-nan"),
        pytest.param(
            dict(t0=np.zeros(2)),
            ValueError,
            r"`t0` must be a scalar, got shape \(2,\)",
            id="t0-vector",
        ),
        pytest.param(
            dict(t1="1.0"), TypeError, r"`t1` must be a real number, got '1\.0'", id="t1-str"
        ),
        pytest.param(
            dict(t1=1.0 + 1.0j), TypeError, r"`t1` must be a real number", id="t1-complex"
        ),
        pytest.param(
            dict(mass_matrix=np.eye(3)),
            ValueError,
            r"`mass_matrix` must have shape \(n, n\) = \(2, 2\) to match `y0`, got \(3, 3\)",
            id="mass-shape",
        ),
        pytest.param(
            dict(mass_matrix=np.ones(2)),
            ValueError,
            r"`mass_matrix` must have shape \(n, n\) = \(2, 2\) to match `y0`, got \(2,\)",
            id="mass-1d",
        ),
        pytest.param(
            dict(mass_matrix=np.array([[1.0, 0.0], [0.0, NAN]])),
            ValueError,
            r"`mass_matrix` contains NaN or inf",
            id="mass-nan",
        ),
        pytest.param(
            dict(mass_matrix="identity"),
            TypeError,
            r"`mass_matrix` must be a numeric \(n, n\) array, got 'identity'",
            id="mass-str",
        ),
        pytest.param(dict(h0=0.0), ValueError, r"`h0` must be positive, got 0\.0", id="h0-zero"),
        pytest.param(
            dict(h0=-0.1), ValueError, r"`h0` must be positive, got -0\.1", id="h0-negative"
        ),
        pytest.param(dict(h0=NAN), ValueError, r"`h0` must be finite, got nan", id="h0-nan"),
        pytest.param(
            dict(h0=np.array([0.1, 0.2])),
            ValueError,
            r"`h0` must be a scalar, got shape \(2,\)",
            id="h0-vector",
        ),
        pytest.param(
            dict(max_steps=0),
            ValueError,
            r"`max_steps` must be a positive int, got 0",
            id="max-steps-zero",
        ),
        pytest.param(
            dict(max_steps=-5),
            ValueError,
            r"`max_steps` must be a positive int, got -5",
            id="max-steps-negative",
        ),
        pytest.param(
            dict(max_steps=10.0),
            ValueError,
            r"`max_steps` must be a positive int, got 10\.0",
            id="max-steps-float",
        ),
        pytest.param(
            dict(max_steps="10"),
            ValueError,
            r"`max_steps` must be a positive int, got '10'",
            id="max-steps-str",
        ),
        pytest.param(
            dict(max_steps=True),
            ValueError,
            r"`max_steps` must be a positive int, got True",
            id="max-steps-bool",
        ),
        pytest.param(
            dict(error_estimate="adaptive"),
            ValueError,
            r"`error_estimate` must be one of 'auto', 'embedded', 'richardson', got 'adaptive'",
            id="error-estimate",
        ),
        pytest.param(
            dict(adjoint="backsolve"),
            ValueError,
            r"`adjoint` must be 'checkpointed' or 'forward', got 'backsolve'",
            id="adjoint",
        ),
        pytest.param(
            dict(tau=0.0),
            ValueError,
            r"`tau` must be a positive finite scalar or an array of shape \(2,\), got 0\.0",
            id="tau-zero",
        ),
        pytest.param(dict(tau=-1.0), ValueError, r"`tau` must be a positive .*got -1\.0"),
        pytest.param(dict(tau=NAN), ValueError, r"`tau` must be a positive .*got nan"),
        pytest.param(dict(tau=INF), ValueError, r"`tau` must be a positive .*got inf"),
        pytest.param(
            dict(tau=np.ones(3)),
            ValueError,
            r"`tau` must be .*an array of shape \(2,\), got array\(\[1\., 1\., 1\.\]\)",
            id="tau-shape",
        ),
        pytest.param(
            dict(tau=np.array([1.0, 0.0])),
            ValueError,
            r"`tau` must be a positive .*got array\(\[1\., 0\.\]\)",
            id="tau-zero-component",
        ),
        pytest.param(
            dict(tau="1"),
            TypeError,
            r"`tau` must be a positive number or array, got '1'",
            id="tau-str",
        ),
        pytest.param(
            dict(tau=1j),
            TypeError,
            r"`tau` must be a positive number or array, got 1j",
            id="tau-complex",
        ),
        pytest.param(
            dict(equation_rows=np.ones(3, bool)),
            ValueError,
            r"`equation_rows` must be a boolean array of shape \(2,\), got \(3,\)",
            id="equation-rows-shape",
        ),
        pytest.param(
            dict(t_eval=[0.5, 0.2]),
            ValueError,
            r"`t_eval` must be sorted in increasing order",
            id="t-eval-unsorted",
        ),
        pytest.param(
            dict(t_eval=[0.0, 1.5]),
            ValueError,
            r"`t_eval` must lie within \[t0, t1\] = \[0\.0, 1\.0\], got values in \[0\.0, 1\.5\]",
            id="t-eval-above",
        ),
        pytest.param(
            dict(t_eval=[-0.1, 0.5]),
            ValueError,
            r"`t_eval` must lie within \[t0, t1\] = \[0\.0, 1\.0\], got values in "
            r"\[-0\.1, 0\.5\]",
            id="t-eval-below",
        ),
        pytest.param(
            dict(t_eval=np.zeros((2, 1))),
            ValueError,
            r"`t_eval` must be 1-D, got shape \(2, 1\)",
            id="t-eval-2d",
        ),
        pytest.param(
            dict(t_eval=[0.0, NAN]),
            ValueError,
            r"`t_eval` contains NaN or inf",
            id="t-eval-nan",
        ),
        pytest.param(
            dict(t_eval=[0.0, INF]),
            ValueError,
            r"`t_eval` contains NaN or inf",
            id="t-eval-inf",
        ),
        pytest.param(
            # A NumPy integer is a valid `max_steps`: the solve goes on to reject `t_eval`.
            dict(max_steps=np.int64(10), t_eval=[2.0]),
            ValueError,
            r"`t_eval` must lie within \[t0, t1\]",
            id="max-steps-numpy-int-accepted",
        ),
        pytest.param(
            dict(t_eval=["a"]),
            (TypeError, ValueError),
            r"`t_eval`",
            id="t-eval-str",
        ),
    ],
)
def test_solve_rejects_bad_interval_or_option(kwargs, error, match):
    with pytest.raises(error, match=match):
        run_solve(**kwargs)


def test_solve_rejects_traced_mass_matrix():
    # The algebraic rows are read from the mass matrix at trace time.
    with pytest.raises(TypeError, match=r"`mass_matrix` must be a concrete array"):
        jax.jit(lambda m: run_solve(mass_matrix=m).y_final)(jnp.eye(2))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(projector=lambda z, ctx: z), r"`projector` must be an AbstractProjector, got <func"),
        (dict(projector="sign"), r"`projector` must be an AbstractProjector, got 'sign'"),
        (dict(projector=nj.NonNegative), r"`projector` must be an AbstractProjector, got <class"),
        (dict(stepper="bathe"), r"`stepper` must be an AbstractStepper .*got 'bathe'"),
        (dict(stepper=nj.Bathe), r"`stepper` must be an AbstractStepper .*got <class"),
        (dict(stepper=nj.SemismoothNewton()), r"`stepper` must be an AbstractStepper"),
        (dict(controller="pid"), r"`controller` must be an AbstractController, got 'pid'"),
        (dict(controller=nj.PIDController), r"`controller` must be an AbstractController"),
    ],
    ids=lambda v: v if isinstance(v, str) else None,
)
def test_solve_rejects_wrong_component_types(kwargs, match):
    with pytest.raises(TypeError, match=match):
        run_solve(**kwargs)


class PlainEuler(nj.AbstractStepper):
    """A user's stepper without an embedded error estimate (`error_order` 0)."""

    solver: nj.AbstractNonlinearSolver = eqx.field(default_factory=nj.SemismoothNewton)

    @property
    def order(self):
        return 1

    def step(self, model, t0, h, y0, args):
        return nj.BackwardEuler(self.solver).step(model, t0, h, y0, args)


def test_solve_rejects_embedded_estimate_without_one():
    match = r"PlainEuler has no embedded error estimate; use error_estimate='richardson'"
    with pytest.raises(ValueError, match=match):
        run_solve(stepper=PlainEuler(), error_estimate="embedded")


@pytest.mark.parametrize(
    "stepper", [nj.Bathe(), nj.BackwardEuler(), nj.Trapezoidal(), nj.Theta(0.75)], ids=repr
)
def test_builtin_steppers_have_embedded_estimates(stepper):
    # Every built-in stepper carries an embedded estimate, so "auto" never pays for step
    # doubling; its order is one above the propagated solution's.
    assert stepper.error_order == stepper.order + 1


# A bad controller setting is rejected either by the controller's constructor or by `solve`
# (which checks the bounds against `h0` and the state); `stage` says which, and in both cases
# it happens before any work. The controllers are built inside the test (`make`), so that a
# constructor that rejects its input does not break collection.
@pytest.mark.parametrize(
    "make, kwargs, stage, match",
    [
        pytest.param(
            lambda: nj.PIDController(h_min=-1.0),
            {},
            "solve",
            r"`h_min` must be finite and non-negative, got -1\.0",
            id="pid",
        ),
        pytest.param(
            lambda: nj.ConstantStepSize(h_min=-1.0),
            dict(h0=0.1),
            "solve",
            r"`h_min` must be finite and non-negative, got -1\.0",
            id="constant",
        ),
        pytest.param(
            lambda: nj.ConstantStepSize(h_min=NAN),
            dict(h0=0.1),
            "solve",
            r"`h_min` must be finite and non-negative, got nan",
            id="constant-h-min-nan",
        ),
        pytest.param(
            lambda: nj.PIDController(h_max=0.0),
            {},
            "solve",
            r"`h_max` must be finite and positive, got 0\.0",
            id="h-max-0",
        ),
        pytest.param(
            lambda: nj.PIDController(h_max=NAN),
            {},
            "constructor",
            r"`h_max` must be finite, got nan",
            id="h-max-nan",
        ),
        pytest.param(
            lambda: nj.PIDController(h_max=INF),
            {},
            "constructor",
            r"`h_max` must be finite, got inf",
            id="h-max-inf",
        ),
        pytest.param(
            lambda: nj.PIDController(error_mask=np.ones(3, bool)),
            {},
            "solve",
            r"`error_mask` must be a boolean array of shape \(2,\), got \(3,\)",
            id="error-mask-length",
        ),
        pytest.param(
            lambda: nj.PIDController(error_mask=np.ones((2, 2), bool)),
            {},
            "solve",
            r"`error_mask` must be a boolean array of shape \(2,\), got \(2, 2\)",
            id="error-mask-2d",
        ),
        pytest.param(
            lambda: nj.PIDController(h_min=NAN),
            {},
            "constructor",
            r"`h_min` must be finite, got nan",
            id="h-min-nan",
        ),
        pytest.param(
            lambda: nj.PIDController(h_min=INF),
            {},
            "constructor",
            r"`h_min` must be finite, got inf",
            id="h-min-inf",
        ),
        pytest.param(
            nj.ConstantStepSize,
            {},
            "solve",
            r"ConstantStepSize needs an initial step `h0`",
            id="constant-without-h0",
        ),
    ],
)
def test_solve_rejects_bad_controller_settings(make, kwargs, stage, match):
    if stage == "constructor":
        with pytest.raises(ValueError, match=match):
            make()
    else:
        controller = make()
        with pytest.raises(ValueError, match=match):
            run_solve(controller=controller, **kwargs)


# --------------------------------------------------------------------------------------------
# Controllers, steppers and nonlinear solvers: constructors
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["rtol", "atol"])
@pytest.mark.parametrize("value", [0.0, -1e-3, NAN, INF], ids=str)
def test_pid_rejects_bad_tolerance(name, value):
    with pytest.raises(ValueError, match=rf"`{name}` must be positive and finite, got {value}"):
        nj.PIDController(**{name: value})


def test_pid_rejects_h_min_above_h_max():
    match = r"`h_min` must not exceed `h_max`, got h_min=0\.5, h_max=0\.1"
    with pytest.raises(ValueError, match=match):
        nj.PIDController(h_min=0.5, h_max=0.1)


FACTORMIN = r"`factormin` must satisfy 0 < factormin <= 1, got "
FACTORMAX = r"`factormax` must be >= 1, got "


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(factormin=0.0), FACTORMIN + r"0\.0"),
        (dict(factormin=-0.1), FACTORMIN + r"-0\.1"),
        (dict(factormin=1.5), FACTORMIN + r"1\.5"),
        (dict(factormin=NAN), FACTORMIN + r"nan"),
        (dict(factormax=0.5), FACTORMAX + r"0\.5"),
        (dict(factormax=NAN), FACTORMAX + r"nan"),
    ],
    ids=str,
)
def test_pid_rejects_bad_factor_bounds(kwargs, match):
    # The message names the argument, the bound and the value received.
    with pytest.raises(ValueError, match=match):
        nj.PIDController(**kwargs)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        pytest.param(
            dict(rtol="1e-3"),
            TypeError,
            r"`rtol` must be a real number, got '1e-3'",
            id="rtol-str",
        ),
        pytest.param(
            dict(safety=0.0),
            ValueError,
            r"`safety` must be positive and finite, got 0\.0",
            id="safety-zero",
        ),
        pytest.param(
            dict(nonlinear_factor=1.5),
            ValueError,
            r"`nonlinear_factor` must lie in \(0, 1\), got 1\.5",
            id="nonlinear-factor",
        ),
        pytest.param(
            dict(nonlinear_factor=0.0),
            ValueError,
            r"`nonlinear_factor` must lie in \(0, 1\), got 0\.0",
            id="nonlinear-factor-zero",
        ),
        pytest.param(
            dict(error_order=0),
            ValueError,
            r"`error_order` must be an int >= 1, got 0",
            id="error-order-zero",
        ),
        pytest.param(
            dict(error_order=1.5),
            ValueError,
            r"`error_order` must be an int >= 1, got 1\.5",
            id="error-order-float",
        ),
        pytest.param(
            dict(h_min="0.1"),
            TypeError,
            r"`h_min` must be a real number, got '0\.1'",
            id="h-min-str",
        ),
    ],
)
def test_pid_rejects_other_bad_settings(kwargs, error, match):
    # Rejected by the constructor itself, so before any solve.
    with pytest.raises(error, match=match):
        nj.PIDController(**kwargs)


@pytest.mark.parametrize("theta", [0.4, 0.0, 1.1, -1.0, NAN], ids=str)
def test_theta_rejects_out_of_range(theta):
    with pytest.raises(ValueError, match=rf"`theta` must lie in \[1/2, 1\], got {theta}"):
        nj.Theta(theta)


@pytest.mark.parametrize("gamma", [0.0, 1.0, -0.5, 1.5, NAN], ids=str)
def test_bathe_rejects_out_of_range(gamma):
    with pytest.raises(ValueError, match=rf"`gamma` must lie in \(0, 1\), got {gamma}"):
        nj.Bathe(gamma)


def test_embedded_betr_rejects_unknown_propagate():
    match = r"`propagate` must be 'backward_euler' or 'trapezoidal', got 'x'"
    with pytest.raises(ValueError, match=match):
        nj.EmbeddedBETR(propagate="x")


@pytest.mark.parametrize("cls", [nj.SemismoothNewton, nj.FixedPointVI])
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(max_steps=0), r"`max_steps` must be a positive int, got 0"),
        (dict(max_steps=2.0), r"`max_steps` must be a positive int, got 2\.0"),
        (dict(max_steps=True), r"`max_steps` must be a positive int, got True"),
        (dict(rtol=-1.0), r"`rtol` must be finite and non-negative, got -1\.0"),
        (dict(atol=NAN), r"`atol` must be finite and non-negative, got nan"),
        (dict(atol=INF), r"`atol` must be finite and non-negative, got inf"),
    ],
    ids=str,
)
def test_nonlinear_solver_rejects_bad_settings(cls, kwargs, match):
    # Rejected by the constructor itself, so before any solve.
    with pytest.raises(ValueError, match=match):
        cls(**kwargs)


@pytest.mark.parametrize(
    "make",
    [
        pytest.param(lambda: nj.PIDController(rtol=np.float32(1e-3)), id="pid-rtol-float32"),
        pytest.param(lambda: nj.PIDController(h_min=np.float64(1e-6)), id="pid-h-min-float64"),
        pytest.param(lambda: nj.SemismoothNewton(rtol=np.float64(1e-6)), id="newton-rtol-f64"),
        pytest.param(
            lambda: nj.SemismoothNewton(max_steps=np.int64(10)),
            id="newton-max-steps-int64",
        ),
        pytest.param(
            lambda: nj.FixedPointVI(rtol=np.float32(1e-6)),
            id="fixed-point-rtol-float32",
        ),
        pytest.param(
            lambda: nj.PIDController(error_order=np.int64(2)),
            id="pid-error-order-int64",
        ),
    ],
)
@pytest.mark.filterwarnings("ignore:A JAX array is being set as static")
def test_constructors_accept_numpy_scalars(make):
    # A NumPy scalar is as good a number as a Python one. (`max_steps` and `error_order` are
    # static fields: equinox warns about a NumPy scalar there, so a fix should store int().)
    make()


# --------------------------------------------------------------------------------------------
# Projectors: constructors, and their indices against the state
# --------------------------------------------------------------------------------------------


def test_sign_resolvent_rejects_index_length_mismatch():
    match = r"`s_index` and `w_index` must have the same length, got 2 and 1"
    with pytest.raises(ValueError, match=match):
        nj.SignResolvent((0, 1), (2,))


@pytest.mark.parametrize("tau", [0.0, -1.0, NAN], ids=str)
def test_sign_resolvent_rejects_non_positive_tau(tau):
    with pytest.raises(ValueError, match=rf"`tau` must be positive, got {tau}"):
        nj.SignResolvent(0, 1, tau=tau)


def test_sign_resolvent_rejects_non_integer_indices():
    with pytest.raises(TypeError, match=r"indices must be integers, got 0\.5"):
        nj.SignResolvent(0.5, 1)


@pytest.mark.parametrize(
    "blocks, error, match",
    [
        pytest.param(
            [((0, 1), nj.NonNegative()), ((1, 2), nj.NonNegative())],
            ValueError,
            r"block indices overlap at \[1\]",
            id="overlap",
        ),
        pytest.param(
            [((0,), "relu")],
            TypeError,
            r"each block's projector must be an AbstractProjector, got 'relu'",
            id="not-a-projector",
        ),
        pytest.param(
            [((0,), nj.NonNegative)],
            TypeError,
            r"each block's projector must be an AbstractProjector, got <class",
            id="projector-class",
        ),
        pytest.param(
            [((0,),)],
            TypeError,
            r"`blocks` must be a sequence of `\(indices, projector\)` pairs, got \(\(0,\),\)",
            id="one-element-entry",
        ),
        pytest.param(
            [((0,), nj.NonNegative(), 1)],
            TypeError,
            r"`blocks` must be a sequence of `\(indices, projector\)` pairs",
            id="three-element-entry",
        ),
        pytest.param(
            [nj.NonNegative()],
            TypeError,
            r"`blocks` must be a sequence of `\(indices, projector\)` pairs, got NonNegative",
            id="bare-projector-entry",
        ),
        pytest.param(
            nj.NonNegative(),
            TypeError,
            r"`blocks` must be a list of `\(indices, projector\)` pairs, got NonNegative",
            id="blocks-not-a-sequence",
        ),
        pytest.param(
            {0: nj.NonNegative()},
            TypeError,
            r"`blocks` must be a list of `\(indices, projector\)` pairs, got dict",
            id="blocks-dict",
        ),
        pytest.param(
            [(("a",), nj.NonNegative())],
            TypeError,
            r"block indices must be integers, got \('a',\)",
            id="string-indices",
        ),
        pytest.param(
            [((0.5,), nj.NonNegative())],
            TypeError,
            r"block indices must be integers, got \(0\.5,\) \(dtype float64\)",
            id="float-indices",
        ),
        pytest.param(
            [((True,), nj.NonNegative())],
            TypeError,
            r"block indices must be integers, got \(True,\) \(dtype bool\)",
            id="bool-indices",
        ),
        pytest.param(
            [((0, 0), nj.NonNegative())],
            ValueError,
            r"block indices repeat within a block: \[0, 0\]",
            id="repeated-index-in-block",
        ),
    ],
)
def test_block_projector_rejects_bad_blocks(blocks, error, match):
    with pytest.raises(error, match=match):
        nj.BlockProjector(blocks)


@pytest.mark.parametrize(
    "make, match",
    [
        pytest.param(
            lambda: nj.BlockProjector([((5,), nj.NonNegative())]),
            r"BlockProjector indices \[5\] are out of range for a state of size 2",
            id="block",
        ),
        pytest.param(
            lambda: nj.BlockProjector([((0, -3), nj.NonNegative())]),
            r"BlockProjector indices \[-3\] are out of range for a state of size 2",
            id="block-negative",
        ),
        pytest.param(
            lambda: nj.SignResolvent(0, 7),
            r"SignResolvent indices \[7\] are out of range for a state of size 2",
            id="sign",
        ),
    ],
)
def test_solve_rejects_projector_indices_out_of_range(make, match):
    # The projector itself is valid; only against `y0` (n = 2) are its indices out of range.
    projector = make()
    with pytest.raises(ValueError, match=match):
        run_solve(projector=projector)


# --------------------------------------------------------------------------------------------
# nivpjax.compat.solve_ivp_ns
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(method="rk45"), r"Unknown method 'rk45'; expected one of \(.*'composite'"),
        (dict(method=3), r"Unknown method 3; expected one of"),
        (dict(projection="cone"), r"Unknown projection 'cone'; expected one of \(.*'soccp'"),
        (dict(solver="newton"), r"Unknown solver 'newton'; expected 'VI' or 'semismooth_newton'"),
        (
            dict(solver_opts={"bogus": 1, "also_bogus": 2}),
            r"unsupported solver_opts \['also_bogus', 'bogus'\]\. Supported: \[.*'tol'",
        ),
        (
            dict(adaptive_opts={"controller_magic": 1}),
            r"unsupported adaptive_opts \['controller_magic'\]\. Supported: \[.*'h_min'",
        ),
        (
            dict(integrator_opts={"alpha": 1}),
            r"unsupported integrator_opts for method 'composite' \['alpha'\]\. "
            r"Supported: \['gamma'\]",
        ),
        (
            dict(projection_opts={"tau": 1}),
            r"unsupported projection_opts for 'identity' \['tau'\]",
        ),
        (
            dict(
                projection="sign",
                projection_opts={"y_indices": [0], "w_indices": [1], "zeta": 1},
            ),
            r"unsupported projection_opts for 'sign' \['zeta'\]\. Supported: \[.*'w_indices'",
        ),
        (
            dict(projection="unilateral", projection_opts={"restitution": 0.5}),
            r"unsupported projection_opts for 'unilateral' \['restitution'\]",
        ),
        (
            dict(adaptive_opts={"mode": "ratio", "controller": "h211b"}),
            r"controller='h211b' in ratio mode is not supported; use one of \[.*'pi3040'",
        ),
    ],
    ids=str,
)
def test_compat_rejects_unknown_names_and_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        run_compat(**kwargs)


@pytest.mark.parametrize(
    "projection, popts, match",
    [
        ("sign", {}, r"projection 'sign' needs projection_opts y_indices and w_indices"),
        ("sign", {"y_indices": [0]}, r"projection 'sign' needs .*w_indices"),
        ("coulomb", {}, r"projection 'coulomb' needs projection_opts con_force_func"),
        (
            "coulomb",
            {"con_force_func": lambda y: y},
            r"projection 'coulomb' needs `constraint_indices` \(or `component_slices`\)",
        ),
        ("unilateral", {}, r"projection 'unilateral' needs projection_opts `gap`"),
        ("unilateral", {"gap": lambda t, y: y[:1]}, r"needs projection_opts `J_u`"),
        (
            "unilateral",
            {"gap": lambda t, y: y[:1], "J_u": lambda t, y: jnp.eye(2)[:1]},
            r"needs projection_opts `G_apply`",
        ),
        ("soccp", {}, r"projection 'soccp' needs `blocks`"),
        ("soccp", {"blocks": [0, 1]}, r"projection 'soccp' needs `mu`"),
    ],
    # Stable ids (no function reprs with addresses), so that xdist workers agree.
    ids=lambda v: "-".join(sorted(v)) if isinstance(v, dict) else str(v)[:40],
)
def test_compat_rejects_missing_projection_options(projection, popts, match):
    with pytest.raises(ValueError, match=match):
        run_compat(projection=projection, projection_opts=popts)


@pytest.mark.parametrize(
    "t_span, match",
    [
        ((1.0,), r"`t_span` must be a pair \(t0, tf\), got \(1\.0,\)"),
        ((0.0, 1.0, 2.0), r"`t_span` must be a pair \(t0, tf\), got \(0\.0, 1\.0, 2\.0\)"),
        (None, r"`t_span` must be a pair \(t0, tf\), got None"),
        (("a", 1.0), r"`t_span` must be a pair \(t0, tf\), got \('a', 1\.0\)"),
        ((1.0, 0.0), r"`t1` must be greater than `t0`, got t0=1\.0, t1=0\.0"),
        ((1.0, 1.0), r"`t1` must be greater than `t0`, got t0=1\.0, t1=1\.0"),
        ((0.0, NAN), r"`t1` must be finite, got nan"),
    ],
    ids=str,
)
def test_compat_rejects_bad_t_span(t_span, match):
    with pytest.raises(ValueError, match=match):
        run_compat(t_span=t_span)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        pytest.param(dict(fun=lambda y: -y), r"`fun` must accept \(t, y\)", id="fun-arity"),
        pytest.param(
            dict(method="theta", integrator_opts={"theta": 0.2}),
            r"`theta` must lie in \[1/2, 1\], got 0\.2",
            id="theta",
        ),
        pytest.param(
            dict(integrator_opts={"gamma": 1.0}),
            r"`gamma` must lie in \(0, 1\), got 1\.0",
            id="gamma",
        ),
        pytest.param(
            dict(adaptive_opts={"rtol": 0.0}),
            r"`rtol` must be positive and finite, got 0\.0",
            id="rtol",
        ),
        pytest.param(
            dict(adaptive_opts={"h_min": -1.0}),
            r"`h_min` must be finite and non-negative, got -1\.0",
            id="h-min",
        ),
        pytest.param(
            dict(max_steps=0), r"`max_steps` must be a positive int, got 0", id="max-steps"
        ),
        pytest.param(
            dict(y0=np.array([1.0, NAN])),
            r"`y0` contains NaN or inf at components \[1\]",
            id="y0-nan",
        ),
        pytest.param(
            dict(A=np.eye(3)),
            r"`mass_matrix` must have shape \(n, n\) = \(2, 2\)",
            id="mass-matrix",
        ),
        pytest.param(
            dict(method="theta", integrator_opts={"gamma": 0.3}),
            r"unsupported integrator_opts for method 'theta' \['gamma'\]\. "
            r"Supported: \['theta'\]",
            id="option-of-another-method",
        ),
        pytest.param(
            dict(method="backward_euler", integrator_opts={"theta": 0.6}),
            r"unsupported integrator_opts for method 'backward_euler' \['theta'\]\. "
            r"Supported: \[\]",
            id="option-of-method-without-options",
        ),
        pytest.param(
            dict(adaptive_opts={"mode": "bogus"}),
            r"adaptive_opts mode must be 'classic' or 'ratio', got 'bogus'",
            id="adaptive-mode",
        ),
        pytest.param(
            dict(skip_error_indices=[5]),
            r"`skip_error_indices` entry 5 is out of range: there are 2 components",
            id="skip-error-indices",
        ),
        pytest.param(
            dict(skip_error_indices=[-1]),
            r"`skip_error_indices` entry -1 is out of range: there are 2 components",
            id="skip-error-indices-negative",
        ),
        pytest.param(
            dict(skip_error_indices=[1.5]),
            r"`skip_error_indices` entry 1\.5",
            id="skip-error-indices-float",
        ),
    ],
)
def test_compat_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        run_compat(**kwargs)


# --------------------------------------------------------------------------------------------
# Runtime failures: SolveError with throw=True, result codes with throw=False, and equinox
# runtime errors inside jit. Tiny problems, a handful of steps, one compilation per setting.
# --------------------------------------------------------------------------------------------


def decay(t, y, args):
    return -y


FIXED = dict(stepper=nj.BackwardEuler(), controller=nj.ConstantStepSize(), h0=0.1, max_steps=3)
SOLVE_ERROR_MESSAGE = (
    r"nivpjax\.solve failed at t = (?P<t>\S+) after (?P<acc>\d+) accepted and (?P<rej>\d+) "
    r"rejected steps \(last attempted step size (?P<h>\S+)\): "
)


def test_max_steps_reached():
    # 3 fixed steps of 0.1 end at t = 0.3 < t1 = 1.
    sol = nj.solve(decay, 0.0, 1.0, Y0, throw=False, **FIXED)
    assert sol.result == nj.RESULTS.time_max_steps_reached
    assert float(sol.t_final) == pytest.approx(0.3, abs=1e-12)
    with pytest.raises(nj.SolveError) as info:
        nj.solve(decay, 0.0, 1.0, Y0, **FIXED)
    message = str(info.value)
    match = re.match(SOLVE_ERROR_MESSAGE, message)
    assert match is not None, message
    assert float(match["t"]) == pytest.approx(0.3, abs=1e-9)
    assert (int(match["acc"]), int(match["rej"])) == (3, 0)
    assert float(match["h"]) == pytest.approx(0.1, rel=1e-2)
    assert "maximum number of time steps" in message and "`max_steps`" in message


def jump(t, y, args):
    # Zero up to t = args, then a right-hand side no tolerance can follow.
    return jnp.where(t < args, 0.0, 1e6 * t) * jnp.ones_like(y)


# Backward Euler (Richardson error estimate) with a step floor of 1e-3. h0 equals the floor,
# and the jump time is passed as an array, so every test below shares one compilation.
JUMP = dict(
    stepper=nj.BackwardEuler(),
    controller=nj.PIDController(rtol=1e-10, atol=1e-12, h_min=1e-3),
    h0=1e-3,
    max_steps=200,
)


def solve_jump(t_jump, **kwargs):
    return nj.solve(jump, 0.0, 1.0, np.array([0.0]), jnp.asarray(t_jump), **JUMP, **kwargs)


def test_h_min_reached():
    sol = solve_jump(0.5, throw=False)
    assert sol.result == nj.RESULTS.h_min_reached
    assert 0.49 < float(sol.t_final) <= 0.5
    with pytest.raises(nj.SolveError) as info:
        solve_jump(0.5)
    message = str(info.value)
    match = re.match(SOLVE_ERROR_MESSAGE, message)
    assert match is not None, message
    assert float(match["t"]) == pytest.approx(float(sol.t_final), rel=1e-9)
    assert int(match["rej"]) >= 1
    assert math.isfinite(float(match["h"])) and float(match["h"]) >= 1e-3
    assert "fell below `h_min`" in message


def test_h_min_reached_on_first_step_reports_step_size():
    # The jump lies inside the very first step, which is already at the floor: there is no
    # accepted step, and the message gives the size of the failed attempt.
    sol = solve_jump(5e-4, throw=False)
    assert sol.result == nj.RESULTS.h_min_reached and int(sol.n_accepted) == 0
    assert float(sol.h_last) == pytest.approx(1e-3, rel=1e-9)
    with pytest.raises(nj.SolveError, match=r"last attempted step size 0\.001\)"):
        solve_jump(5e-4)


def test_h_min_reached_near_t1():
    # Within 2 h_min of t1 each attempt is stretched to land on t1 (h_try = t1 - t > h_min);
    # the floor is judged by the proposed step, so the run still ends at h_min, not max_steps.
    sol = solve_jump(0.9995, throw=False)
    assert sol.result == nj.RESULTS.h_min_reached
    assert 0.99 < float(sol.t_final) <= 0.9995 and int(sol.n_rejected) >= 1
    with pytest.raises(nj.SolveError, match=r"fell below `h_min`"):
        solve_jump(0.9995)


@eqx.filter_jit
def _fixed_step_final_state(y0, t1):
    return nj.solve(decay, 0.0, t1, y0, **FIXED).y_final


def fixed_step_final_state(y0, t1):
    # Arrays, so that filter_jit traces them: the checks then run inside the program.
    return _fixed_step_final_state(jnp.asarray(y0), jnp.asarray(t1))


def test_jit_throw_raises_runtime_errors():
    # A successful run first: the checks below must not fire on good input.
    y = fixed_step_final_state(jnp.asarray(Y0), 0.2)
    np.testing.assert_allclose(y, Y0 / 1.1**2, rtol=1e-12)  # two backward Euler steps
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"maximum number of time steps.*`max_steps`"):
        fixed_step_final_state(jnp.asarray(Y0), 1.0)
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"`y0` contains NaN or inf"):
        fixed_step_final_state(jnp.array([1.0, NAN]), 0.2)
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"`t1` must be greater than `t0`"):
        fixed_step_final_state(jnp.asarray(Y0), 0.0)
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"`t1` must be greater than `t0`"):
        fixed_step_final_state(jnp.asarray(Y0), -1.0)


@eqx.filter_jit
def _fixed_step_quiet(y0, t1):
    return nj.solve(decay, 0.0, t1, y0, throw=False, **FIXED)


def test_traced_bad_inputs_are_failure_codes():
    # With throw=False the in-program checks of traced inputs are result codes (no host
    # callback: JAX's persistent cache stores the program, see test_cache), and the run
    # stops at once; a good run is unaffected.
    good = _fixed_step_quiet(jnp.asarray(Y0), jnp.asarray(0.2))
    assert good.result == nj.RESULTS.successful
    bad_y0 = _fixed_step_quiet(jnp.array([1.0, NAN]), jnp.asarray(0.2))
    assert bad_y0.result == nj.RESULTS.nonfinite_y0
    for t1 in (0.0, -1.0):
        sol = _fixed_step_quiet(jnp.asarray(Y0), jnp.asarray(t1))
        assert sol.result == nj.RESULTS.empty_span
        assert int(sol.n_accepted) == 0


def test_plain_jax_jit_throw_raises():
    # Under plain `jax.jit` the equinox error surfaces as whatever JAX makes of a failed
    # callback (JaxRuntimeError on the first call, ValueError from the C++ fast path later),
    # so only the message is checked.
    run = jax.jit(lambda y0: nj.solve(decay, 0.0, 1.0, y0, **FIXED).y_final)
    with pytest.raises(Exception, match=r"maximum number of time steps.*`max_steps`"):
        run(jnp.asarray(Y0))


def test_compat_max_steps_reached():
    kwargs = dict(method="backward_euler", adaptive=False, h0=0.1, max_steps=3)
    t, y, h, fk, info = solve_ivp_ns(lambda t, y: -y, (0.0, 1.0), Y0, throw=False, **kwargs)
    np.testing.assert_allclose(t, [0.0, 0.1, 0.2, 0.3], atol=1e-12)
    with pytest.raises(nj.SolveError, match=r"failed at t = 0\.3 .*maximum number of time"):
        solve_ivp_ns(lambda t, y: -y, (0.0, 1.0), Y0, **kwargs)


# --------------------------------------------------------------------------------------------
# Effects: a relay's bounds
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(lower=1.0, upper=-1.0), ValueError, "`lower` must be below `upper`"),
        (dict(lower=0.5, upper=0.5), ValueError, "`lower` must be below `upper`"),
        (dict(n=2, lower=[0.0, 1.0], upper=1.0), ValueError, r"components \[1\]"),
        (dict(n=2, lower=[-1.0, -1.0, -1.0]), ValueError, r"shape \(2,\).*got shape \(3,\)"),
        (dict(lower=np.zeros((1, 1))), ValueError, "must be a scalar or have shape"),
        (dict(upper=np.inf), ValueError, "`upper` must be finite"),
        (dict(lower="a"), TypeError, "`lower` must be a number"),
        (dict(upper=lambda t, y, a: 1.0), TypeError, "`upper` must be a number"),
        (dict(lower=1j), TypeError, "`lower` must be real"),
    ],
)
def test_relay_rejects_bad_bounds(kwargs, error, match):
    with pytest.raises(error, match=match):
        nj.Relay("w", lambda t, x, a: x[:1], **kwargs)


def test_relay_accepts_bounds_per_component_and_traced_bounds():
    relay = nj.Relay("w", lambda t, x, a: x[:2], n=2, lower=np.array([-1.0, 0.0]), upper=2.0)
    assert relay.size == 2
    # Traced bounds (a sweep over them) are the caller's to check: no error at trace time.
    jax.vmap(lambda b: nj.Relay("w", lambda t, x, a: x[:1], lower=-b, upper=b).upper)(
        jnp.array([0.5, 1.0])
    )
