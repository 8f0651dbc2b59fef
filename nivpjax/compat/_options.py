"""The reference's option names, sorted into what we map, what we accept without effect
(performance knobs of a scipy implementation that have no meaning here), and the rest."""

# solver_opts
SOLVER_MAPPED = {"tol", "max_iter", "rho0", "L", "nu", "lam", "ls_c1", "ls_beta", "max_backtracks"}
SOLVER_NO_EFFECT = {
    # Jacobians come from autodiff and projector custom JVPs.
    "rhs_jac",
    "fun_jacobian",
    "jacobian",
    "use_autodiff",
    "autodiff_mode",
    # Dense LU is always used; sparse/iterative knobs do not apply.
    "sparse",
    "sparse_threshold",
    "linear_solver",
    "precond_reuse_steps",
    "ilu_drop_tol",
    "ilu_fill_factor",
    "gmres_tol",
    "gmres_maxiter",
    "gmres_restart",
    "splu_permc_spec",
    "ilu_permc_spec",
    "linear_tol_strategy",
    "eisenstat_c",
    "eisenstat_exp",
    # Globalisation is always on (watchdog Armijo); the VI step is always adaptive.
    "globalization",
    "ls_min_alpha",
    "adaptive_lam",
    "lam_update_strategy",
    "Lmin",
    "delta",
    "vi_strict_block_lipschitz",
    "vi_max_block_adjust_iters",
    "use_broyden",
}

# adaptive_opts
ADAPTIVE_MAPPED = {
    "h_min",
    "h_max",
    "h_up",
    "h_down",
    "safety",
    "use_PI",
    "atol",
    "rtol",
    "method_order",
    "p",
    "skip_error_indices",
    "h0",
    "mode",
    "controller",
}
ADAPTIVE_NO_EFFECT = {"verbose", "r_min", "r_max", "reject_reboot_thresh"}

# Digital-filter presets (beta1, beta2) of the reference's ratio mode, as PID coefficients
# beta1 = p + i, beta2 = -p.
FILTERS = {
    "elementary": (0.0, 1.0),
    "pi3040": (0.4, 0.3),
    "pi3333": (1 / 3, 1 / 3),
    "pi4020": (0.2, 0.4),
    "h211pi": (-1 / 6, 1 / 3),
}

# projection_opts per projection
PROJECTION_OPTS = {
    "identity": (set(), set()),
    "sign": ({"y_indices", "w_indices", "tau"}, {"component_slices"}),
    "coulomb": (
        {"con_force_func", "constraint_indices", "component_slices"},
        {"rhok", "jac_func", "conf_jacobian_mode", "use_numba"},
    ),
    "unilateral": (
        {"gap", "u_map", "J_u", "G_apply", "e", "gap_tol"},
        {"lcp_maxit", "lcp_tol", "tc_tol", "component_slices"},
    ),
    "soccp": ({"blocks", "mu", "get_mu", "constraint_indices"}, {"component_slices"}),
}

INTEGRATOR_MAPPED = {"theta", "gamma"}
INTEGRATOR_NO_EFFECT = set()


def check(kind: str, opts: dict, mapped: set, no_effect: set):
    unknown = sorted(set(opts) - mapped - no_effect)
    if unknown:
        raise ValueError(
            f"solve_ivp_ns: unsupported {kind} {unknown}. Supported: {sorted(mapped)}; "
            f"accepted without effect: {sorted(no_effect)}."
        )
