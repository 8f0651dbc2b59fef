"""`solve_ivp_ns`: the reference package's entry point, on top of `nivpjax.solve`."""

import functools
import inspect

import jax
import jax.numpy as jnp
import numpy as np

from .._cache import CachedJit
from .._controller import ConstantStepSize, PIDController
from .._nonlinear import FixedPointVI, SemismoothNewton
from .._projector import (
    BlockProjector,
    CoulombFriction,
    Identity,
    SecondOrderCone,
    SignResolvent,
    UnilateralContact,
)
from .._solve import solve
from .._stepper import BackwardEuler, Bathe, EmbeddedBETR, Theta, Trapezoidal
from . import _host, _options as opt


METHODS = ("backward_euler", "trapezoidal", "theta", "composite", "embedded_betr")
PROJECTIONS = ("identity", "sign", "coulomb", "unilateral", "soccp")
SOLVERS = ("vi", "semismooth_newton")


def _n_positional(fn) -> int:
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return 1
    if any(p.kind == p.VAR_POSITIONAL for p in params):
        return 3
    return sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)


def _slices_to_indices(component_slices, n):
    out = []
    for s in component_slices:
        if isinstance(s, slice):
            out.append(list(range(n))[s])
        else:
            out.append([int(i) for i in np.atleast_1d(s)])
    return out


def _projector(name, popts, n, component_slices, t0, y0, hosted):
    mapped, no_effect = opt.PROJECTION_OPTS[name]
    opt.check(f"projection_opts for '{name}'", popts, mapped, no_effect)
    if name == "identity":
        return Identity()
    if name == "sign":
        if "y_indices" not in popts or "w_indices" not in popts:
            raise ValueError("projection 'sign' needs projection_opts y_indices and w_indices.")
        # The reference's constructor `tau` is overridden by the solver's rho there too; the
        # stage's own scaling is used (it does not change the solution).
        return SignResolvent(popts["y_indices"], popts["w_indices"])
    if name == "coulomb":
        if "con_force_func" not in popts:
            raise ValueError("projection 'coulomb' needs projection_opts con_force_func.")
        con_force = popts["con_force_func"]
        ci = popts.get("constraint_indices")
        slices = popts.get("component_slices", component_slices)
        if ci is None and slices is not None:
            ci = [i for block in _slices_to_indices(slices, n) for i in block]
        if ci is None:
            raise ValueError(
                "projection 'coulomb' needs `constraint_indices` (or `component_slices`) to "
                "know which components carry friction."
            )
        ci = np.asarray(ci, dtype=int)
        arity = _n_positional(con_force)

        def con_force_ty(t, y):
            call = (y,) if arity == 1 else (y, t) if arity == 2 else (y, t, None)
            return con_force(*call)

        force = _host.adapt(
            con_force_ty, "con_force_func", "(t, y)", (t0, y0), hosted=hosted, source=con_force
        )

        def bound(t, y, args):
            return jnp.asarray(force(t, y))[ci]

        return BlockProjector([(ci, CoulombFriction(bound))])
    if name == "unilateral":
        for key in ("gap", "J_u", "G_apply"):
            if key not in popts:
                raise ValueError(f"projection 'unilateral' needs projection_opts `{key}`.")
        gap = _host.adapt(popts["gap"], "gap", "(t, y)", (t0, y0), hosted=hosted)
        J_u = _host.adapt(popts["J_u"], "J_u", "(t, y)", (t0, y0), hosted=hosted)
        m = jax.eval_shape(lambda t, y: jnp.atleast_1d(gap(t, y)), t0, y0).shape[0]
        G_apply = _host.adapt(
            popts["G_apply"], "G_apply", "(t, y, lam)", (t0, y0, np.zeros(m)), (n,), hosted
        )
        gap_tol = popts.get("gap_tol", 0.0)

        def impulse_map(t, y, args):
            m = jnp.atleast_1d(gap(t, y)).shape[0]
            return jax.jacfwd(lambda lam: jnp.asarray(G_apply(t, y, lam)))(jnp.zeros(m, y.dtype))

        velocity_map = lambda t, y, a: jnp.atleast_2d(J_u(t, y))  # noqa: E731
        rows = _contact_rows(velocity_map, impulse_map, t0, y0)
        common = dict(
            gap=lambda t, y, a: jnp.atleast_1d(gap(t, y)) - gap_tol,
            restitution=popts.get("e", 0.0),
        )
        if rows.all():
            return UnilateralContact(velocity_map=velocity_map, impulse_map=impulse_map, **common)
        # The contact acts on the rows its impulses move (a ball's velocity), as a scene's
        # does: the other rows (positions) are then free rows, interpolated at `t_eval`
        # with their rates instead of linearly.
        idx = np.flatnonzero(rows)
        cols = idx.tolist()  # a list in the closures: static indices, not a traced array
        contact = UnilateralContact(
            velocity_map=lambda t, y, a: velocity_map(t, y, a)[:, cols],
            impulse_map=lambda t, y, a: impulse_map(t, y, a)[cols, :],
            **common,
        )
        return BlockProjector([(idx, contact)])
    # soccp
    blocks = popts.get("blocks", popts.get("constraint_indices"))
    if blocks is None:
        raise ValueError(
            "projection 'soccp' needs `blocks`: a list of index groups (normal index first, "
            "then tangential indices) of multiplier components to project onto the cone."
        )
    blocks = [blocks] if np.ndim(blocks[0]) == 0 else blocks
    mu = popts.get("mu", popts.get("get_mu"))
    if mu is None:
        raise ValueError("projection 'soccp' needs `mu` (float or callable mu(y)).")
    if callable(mu):
        mu = _host.adapt(mu, "mu", "(y)", (y0,), hosted=hosted)
    mu_fn = (lambda t, y, a: mu(y)) if callable(mu) else mu
    return BlockProjector([(np.asarray(b, int), SecondOrderCone(mu_fn)) for b in blocks])


def _maps_at(velocity_map, impulse_map, ts, ys):
    return jax.vmap(lambda t, y: (velocity_map(t, y, None), impulse_map(t, y, None)))(ts, ys)


# Compiled once per model structure (closed-over arrays are run-time values): the probes
# below cost a program call, not a few hundred eager operations, on every drop-in call.
_maps_at_jit = CachedJit(_maps_at)


def _contact_rows(velocity_map, impulse_map, t0, y0, probes=3):
    """The rows a contact can touch: those its impulses move or its velocities read (a
    static mask). The sparsity of `J_u` and of `G_apply`'s impulse map, at `y0` and at
    random states around it (so that an entry zero by coincidence at `y0`, `sin 0`, does
    not hide a row); all rows if any evaluation fails."""
    rng = np.random.default_rng(0)
    scale = 1 + np.abs(y0)
    ys = np.concatenate([y0[None], y0 + rng.standard_normal((probes, y0.size)) * scale])
    ts = np.concatenate([[t0], t0 + rng.standard_normal(probes)])
    try:
        W, B = (np.asarray(a) for a in _maps_at_jit(velocity_map, impulse_map, ts, ys))
    except Exception:  # a map undefined away from y0: no restriction
        return np.ones(y0.size, bool)
    if W.shape[-1] != y0.size or B.shape[1] != y0.size:
        return np.ones(y0.size, bool)
    return np.any(W != 0, axis=(0, 1)) | np.any(B != 0, axis=(0, 2))


def _solver(name, sopts):
    opt.check("solver_opts", sopts, opt.SOLVER_MAPPED, opt.SOLVER_NO_EFFECT)
    tol = float(sopts.get("tol", 1e-10))
    max_iter = int(sopts.get("max_iter", 100))
    if name == "semismooth_newton":
        kw = {}
        if "ls_c1" in sopts:
            kw["sigma"] = float(sopts["ls_c1"])
        if "ls_beta" in sopts:
            kw["beta"] = float(sopts["ls_beta"])
        if "max_backtracks" in sopts:
            kw["max_backtracks"] = int(sopts["max_backtracks"])
        return SemismoothNewton(rtol=tol, atol=tol, max_steps=max_iter, **kw)
    kw = {}
    if "rho0" in sopts:
        kw["alpha0"] = float(sopts["rho0"])
    if "L" in sopts:
        kw["nu"] = float(sopts["L"])
    # The reference's VI tolerance is relative to 1 + |y|.
    return FixedPointVI(rtol=tol, atol=tol, max_steps=max_iter, **kw)


def _stepper(name, solver, iopts):
    allowed = {"theta": {"theta"}, "composite": {"gamma"}}.get(name, set())
    opt.check(f"integrator_opts for method '{name}'", iopts, allowed, opt.INTEGRATOR_NO_EFFECT)
    if name == "backward_euler":
        return BackwardEuler(solver=solver)
    if name == "trapezoidal":
        return Trapezoidal(solver=solver)
    if name == "theta":
        return Theta(theta=float(iopts.get("theta", 0.5)), solver=solver)
    if name == "composite":
        return Bathe(gamma=float(iopts.get("gamma", 0.5)), solver=solver)
    return EmbeddedBETR(solver=solver)


def _in_float64(fn):
    # The reference computes in float64 (`np.array(y0, dtype=float)`), whatever the
    # caller's dtype: so does the drop-in, with x64 on for the call only (it returns NumPy
    # arrays, so no float64 JAX array leaks out).
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapper


def _controller(adaptive, aopts, atol, rtol, h0, n, skip, component_slices, algebraic):
    opt.check("adaptive_opts", aopts, opt.ADAPTIVE_MAPPED, opt.ADAPTIVE_NO_EFFECT)
    h0 = float(aopts.get("h0", h0))
    h_min = aopts.get("h_min", 1e-10)
    if not adaptive:
        return ConstantStepSize(h_min=h_min), h0
    mode = str(aopts.get("mode", "classic")).lower()
    if mode not in ("classic", "ratio"):
        raise ValueError(f"adaptive_opts mode must be 'classic' or 'ratio', got {mode!r}.")
    preset = str(aopts.get("controller", "pi3040")).lower()
    if mode != "classic" and preset not in opt.FILTERS:
        raise ValueError(
            f"adaptive_opts controller={preset!r} in ratio mode is not supported; use one of "
            f"{sorted(opt.FILTERS)}."
        )
    if mode != "classic":
        pcoeff, icoeff = opt.FILTERS[preset]
    elif aopts.get("use_PI", True):
        pcoeff, icoeff = opt.FILTERS["pi3040"]
    else:
        pcoeff, icoeff = opt.FILTERS["elementary"]
    mask = ~algebraic.copy()
    skipped = set(aopts.get("skip_error_indices") or ()) | set(skip or ())
    blocks = (
        _slices_to_indices(component_slices, n) if component_slices else [[i] for i in range(n)]
    )
    for b in skipped:
        if isinstance(b, (bool, np.bool_)) or not isinstance(b, (int, np.integer)):
            raise ValueError(f"`skip_error_indices` entry {b!r} must be an integer index.")
        if not 0 <= int(b) < len(blocks):
            raise ValueError(
                f"`skip_error_indices` entry {b} is out of range: there are {len(blocks)} "
                "components (or component_slices)."
            )
        mask[blocks[int(b)]] = False
    order = aopts.get("method_order", aopts.get("p"))
    controller = PIDController(
        rtol=float(aopts.get("rtol", rtol)),
        atol=float(aopts.get("atol", atol)),
        pcoeff=pcoeff,
        icoeff=icoeff,
        safety=float(aopts.get("safety", 0.9)),
        factormin=min(float(aopts.get("h_down", 0.2)), 1.0),
        factormax=max(float(aopts.get("h_up", 10.0)), 1.0),
        h_min=None if h_min is None else float(h_min),
        h_max=float(aopts.get("h_max", 1e3)),
        error_mask=mask,
        error_order=None if order is None else int(order) + 1,
    )
    return controller, h0


@_in_float64
def solve_ivp_ns(
    fun,
    t_span,
    y0,
    method="composite",
    projection=None,
    solver="VI",
    projection_opts=None,
    solver_opts=None,
    integrator_opts=None,
    adaptive_opts=None,
    adaptive=True,
    atol=1e-6,
    rtol=1e-3,
    h0=1e-2,
    component_slices=None,
    verbose=False,
    A=None,
    skip_error_indices=None,
    return_attempts=False,
    *,
    max_steps=20000,
    throw=True,
    t_eval=None,
):
    r"""Drop-in for `solve_nivp.solve_ivp_ns`: same arguments and return values, computed by
    [`nivpjax.solve`][], in float64 as the reference (whatever `jax_enable_x64` says: x64
    is switched on for the call only, and the results are NumPy arrays).

    `fun(t, y)` and the projection callbacks (`gap`, `J_u`, `G_apply`, `con_force_func`,
    `mu`) are best written with `jax.numpy`. Written with NumPy (`np.array([y[1], -9.81])`)
    they still work: each one JAX cannot trace runs on the host through
    `jax.pure_callback`, with derivatives by central finite differences, and a
    [`nivpjax.compat.NumpyModelWarning`][] says once per model that this is slow and how
    to convert it. A callable that cannot run either way (it writes into its input,
    returns the wrong shape, or fails on NumPy arrays too) raises
    [`nivpjax.compat.ModelError`][] before any work, saying what to change.

    What is the same: method names (`'composite'` is Bathe's scheme with $\gamma = 1/2$, i.e.
    TR-BDF2), projection names and their main options, solver names, tolerances, `h0`, `A`,
    `component_slices`, `skip_error_indices`, `adaptive_opts` (`h_min`, `h_max`, `h_up` as
    the largest growth factor, `h_down` as the smallest shrink factor, `safety`, `use_PI`,
    `method_order`, ratio-mode filter presets), Richardson step doubling for schemes without
    an embedded estimate.

    What differs, on purpose (the physics the options describe, not the reference's bugs):

    - `projection=None` means the identity (the reference raises).
    - `'embedded_betr'` really is the embedded BE/TR pair (the reference runs plain TR).
    - Algebraic rows (zero rows of `A`) are collocated at the end of every stage, never
      averaged, and are always left out of the error norm.
    - `'unilateral'`: contacts are activated from the gap predicted from the step's start
      (Moreau's rule) rather than from the iterate, so backward Euler and `'composite'`
      bounce too; restitution uses the pre-impact velocity as in the reference.
    - `'coulomb'` acts only on `constraint_indices`; `'soccp'` takes `blocks` (normal index
      first, then tangential ones) and `mu`, with the impulses as algebraic unknowns.
    - Defaults of omitted options that differ (tested against the reference's): `h_up`
      10 and `h_down` 0.2 (diffrax's factor bounds; the reference's are 2 and 0.6),
      `max_backtracks` 30 (15), `rho0` 1 (0.9). `use_PI` is Söderlind's PI.3040, the
      previous error raised to $+0.4/k$ as in the reference's ratio mode (its classic mode
      uses $-0.4/k$).
    - Failures raise [`nivpjax.SolveError`][] (`throw=False` returns the partial solution).
    - `h[i]` is the step that produced `y[i]` (`h[0] = h0`); `fk` is a float array of shape
      `(m - 1, n)`, the stage residual (constraint reaction per unit time) after each step;
      `info[i] = (residual_norm, success, iterations)` of that step.

    Extra keyword arguments: `max_steps` (attempted steps), `throw`, and `t_eval`
    (scipy's name): times in `t_span` at which to return the solution, for plots. With it,
    `t` is `t_eval` and `y` the solution there, interpolated as [`nivpjax.solve`][] does
    (third order between steps, impacts and switches inside a step located); `h`, `fk`
    and `info` still describe the steps taken. Without it, `t` and `y` are the accepted
    steps, which for a bouncing ball land just before each impact: a plot of them is flat.
    Unsupported options raise `ValueError` naming them.
    """
    projection_opts = dict(projection_opts or {})
    solver_opts = dict(solver_opts or {})
    integrator_opts = dict(integrator_opts or {})
    adaptive_opts = dict(adaptive_opts or {})
    if not isinstance(method, str) or method.lower() not in METHODS:
        raise ValueError(f"Unknown method {method!r}; expected one of {METHODS}.")
    pname = "identity" if projection is None else str(projection).lower()
    if pname not in PROJECTIONS:
        raise ValueError(f"Unknown projection {projection!r}; expected one of {PROJECTIONS}.")
    if not isinstance(solver, str) or solver.lower() not in SOLVERS:
        raise ValueError(f"Unknown solver {solver!r}; expected 'VI' or 'semismooth_newton'.")
    try:
        t0, t1 = (float(t) for t in t_span)
    except (TypeError, ValueError):
        raise ValueError(f"`t_span` must be a pair (t0, tf), got {t_span!r}.") from None
    if not callable(fun) or _n_positional(fun) < 2:
        raise ValueError("`fun` must accept (t, y).")
    try:
        y0 = np.atleast_1d(np.array(y0, dtype=np.float64))
    except (TypeError, ValueError):
        raise ValueError(f"`y0` must be a 1-D array of real numbers, got {y0!r}.") from None
    if y0.ndim != 1:
        raise ValueError(f"`y0` must be 1-D, got shape {y0.shape}.")
    n = y0.shape[0]

    hosted = {}
    rhs = _host.adapt(fun, "fun", "(t, y)", (t0, y0), (n,), hosted)
    projector = _projector(pname, projection_opts, n, component_slices, t0, y0, hosted)
    _host.warn_once(hosted)
    nl_solver = _solver(solver.lower(), solver_opts)
    stepper = _stepper(method.lower(), nl_solver, integrator_opts)
    algebraic = np.zeros(n, bool) if A is None else np.all(np.asarray(A) == 0, axis=1)
    controller, h_init = _controller(
        adaptive,
        adaptive_opts,
        atol,
        rtol,
        h0,
        n,
        skip_error_indices,
        component_slices,
        algebraic,
    )

    def vector_field(t, y, args):
        return jnp.asarray(rhs(t, y))

    sol = solve(
        vector_field,
        t0,
        t1,
        y0,
        None,
        projector=projector,
        mass_matrix=A,
        stepper=stepper,
        controller=controller,
        h0=h_init,
        t_eval=t_eval,
        max_steps=max_steps,
        save_attempts=return_attempts,
        throw=throw,
        progress=bool(verbose),
    )
    return _outputs(sol, t_eval, return_attempts)


def _outputs(sol, t_eval, return_attempts):
    """The reference's return tuple from a [`nivpjax.Solution`][], as NumPy arrays."""
    # Cut on the host: slicing device arrays to a data-dependent length would compile a new
    # slice program for every step count (most of a repeated call's time).
    rows = int(sol.n_accepted) + 1
    if t_eval is None:
        t = np.asarray(sol.ts)[:rows]
        y = np.asarray(sol.ys)[:rows]
    else:
        t = np.asarray(sol.t_eval)
        y = np.asarray(sol.y_eval)
    h = np.asarray(sol.hs)[:rows]
    fk = np.asarray(sol.multipliers)[1:rows]
    info = [
        (float(r), bool(s), int(i))
        for r, s, i in zip(
            np.asarray(sol.residual_norms)[1:rows],
            np.asarray(sol.nonlinear_success)[1:rows],
            np.asarray(sol.iterations)[1:rows],
        )
    ]
    if not return_attempts:
        return t, y, h, fk, info
    log = sol.attempts
    k = int(sol.n_accepted + sol.n_rejected)
    attempts = None
    if log is not None:
        accepted = np.asarray(log.accepted)[:k]
        ok = np.asarray(log.nonlinear_success)[:k]
        attempts = {
            "t": np.asarray(log.t)[:k],
            "dt": np.asarray(log.h)[:k],
            "accepted": accepted,
            "error": np.asarray(log.error_norm)[:k],
            "status": np.where(accepted, "accept", np.where(ok, "reject", "nonlinear_fail")),
        }
    return t, y, h, fk, info, attempts
