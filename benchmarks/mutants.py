"""The curated mutants of `python -m benchmarks.mutation`: one-line edits of the numerics at
lines whose comment or docstring says why the line is what it is.

Each `Mutant` names its file, the exact original text (which must occur exactly once in it:
the harness checks, and `tests/test_mutants.py` too), its replacement, the claim it tests,
and the tests of its area to run (pytest node ids, narrow enough that one run takes seconds
to a minute or two: `-x` stops a killed mutant at its first failure). `area` groups mutants
for the baseline run of the unmutated copy.
"""

from typing import NamedTuple


class Mutant(NamedTuple):
    name: str
    area: str
    file: str
    original: str
    replacement: str
    reason: str
    tests: tuple[str, ...]


P = "nivpjax/_projector/"
N = "nivpjax/_nonlinear/"
S = "nivpjax/_stepper/"
C = "nivpjax/_controller/"
TP = "tests/test_projectors.py::"
TN = "tests/test_nonlinear.py::"
TE = "tests/test_estimates.py::"
TEV = "tests/test_event_prediction.py::"
TS = "tests/test_sensitivities.py::"
TC = "tests/test_compat.py::"
TBF = "tests/test_bowl_friction.py::"

MUTANTS = [
    # ---------------------------------------------------------------- projectors and JVPs
    Mutant(
        "clip_jvp_boundary_strict",
        "projectors",
        P + "box.py",
        "below = z < lower",
        "below = z <= lower",
        "clip's docstring: the boundary is in the set and gets the identity, not the bound's "
        "derivative",
        (TP + "test_clip_kinks_take_identity", TP + "test_clip_jacobian"),
    ),
    Mutant(
        "clip_jvp_bounds_swapped",
        "projectors",
        P + "box.py",
        "dout = jnp.where(below, dlower, jnp.where(above, dupper, dz))",
        "dout = jnp.where(below, dupper, jnp.where(above, dlower, dz))",
        "clip's docstring: d/dl = 1 below the box, d/du = 1 above it",
        (TP + "test_clip_jacobian",),
    ),
    Mutant(
        "nonnegative_switched_strict",
        "projectors",
        P + "box.py",
        "return jnp.any((z0 <= 0) != (z1 <= 0))",
        "return jnp.any((z0 < 0) != (z1 < 0))",
        "NonNegative.switched's docstring: a component became zero or positive (a clip lands "
        "exactly on 0)",
        (
            TP + "test_switched_sees_a_component_landing_on_a_bound",
            "tests/test_scenes_switching.py::test_rectifier_conduction_intervals",
            TS + "test_rectifier_derivative_after_a_step_over_the_turn_off",
        ),
    ),
    Mutant(
        "ball_jvp_boundary_strict",
        "projectors",
        P + "ball.py",
        "    nrm = _safe_norm(w)\n    inside = (nrm <= r) & (r > 0)\n    nrm_safe",
        "    nrm = _safe_norm(w)\n    inside = (nrm < r) & (r > 0)\n    nrm_safe",
        "project_ball's docstring: identity on the closed ball, the boundary |w| = r included",
        (TP + "test_ball_kinks", TP + "test_project_ball_jacobian"),
    ),
    Mutant(
        "ball_jvp_no_tangential_projection",
        "projectors",
        P + "ball.py",
        "(r / nrm_safe) * (dw - what * jnp.dot(what, dw))",
        "(r / nrm_safe) * dw",
        "project_ball's docstring: r/|w| (I - w^ w^T) dw outside the ball",
        (TP + "test_project_ball_jacobian",),
    ),
    Mutant(
        "ball_jvp_no_radius_term",
        "projectors",
        P + "ball.py",
        " + what * dradius",
        "",
        "project_ball's docstring: + w^ dr outside (a state-dependent radius, mu N)",
        (TP + "test_project_ball_jacobian", TP + "test_ball_state_dependent_jacobian"),
    ),
    Mutant(
        "ball_jvp_zero_radius",
        "projectors",
        P + "ball.py",
        "d_out = jnp.where(inside, dw, jnp.where(r > 0, d_out, jnp.zeros_like(dw)))",
        "d_out = jnp.where(inside, dw, d_out)",
        "project_ball's docstring: zero Jacobian when r <= 0 (the set is the point 0)",
        (TP + "test_ball_kinks", TP + "test_project_ball_jacobian"),
    ),
    Mutant(
        "soc_alpha_coefficient",
        "projectors",
        P + "soc.py",
        "alpha = (s + mu * r) / (1.0 + mu**2)",
        "alpha = (s + mu * r) / (1.0 + mu)",
        "project_soc's docstring: alpha = (s + mu |w|) / (1 + mu^2) on the boundary ray",
        (
            TP + "test_output_in_set",
            TP + "test_project_soc_jacobian",
            TP + "test_variational_inequality",
            TP + "test_soc_matches_reference",
        ),
    ),
    Mutant(
        "soc_polar_open",
        "projectors",
        P + "soc.py",
        "polar = (mu * r <= -s) & ~inside",
        "polar = (mu * r < -s) & ~inside",
        "project_soc's docstring: zero Jacobian on the closed polar cone",
        (TP + "test_soc_kinks",),
    ),
    Mutant(
        "soc_inside_without_s_nonnegative",
        "projectors",
        P + "soc.py",
        "inside = (r <= mu * s) & (s >= 0)",
        "inside = r <= mu * s",
        "project_soc's docstring: s >= 0 matters at mu = 0, where K_0 = {w = 0, s >= 0}",
        (TP + "test_soc_non_expansive_at_zero_friction", TP + "test_output_in_set"),
    ),
    Mutant(
        "coulomb_unscaled_clip",
        "projectors",
        P + "coulomb.py",
        "return z - rho * clip(z / rho, -c, c)",
        "return z - rho * clip(z, -c, c)",
        "CoulombFriction's docstring: P(z) = z - rho clip(z / rho, -c, c) (Moreau)",
        (TP + "test_coulomb_is_soft_thresholding",),
    ),
    Mutant(
        "coulomb_isotropic_unscaled",
        "projectors",
        P + "coulomb.py",
        "return z - rho * project_ball(z / rho, c)",
        "return z - project_ball(z, c)",
        "CoulombFriction's docstring: isotropic friction is the ball's Moreau decomposition "
        "with the stage's rho",
        (
            "tests/test_friction_order.py::test_reactions_at_the_steps[tr]",
            "tests/test_scenes_mechanics.py::test_block_on_plane",
        ),
    ),
    Mutant(
        "sign_tau_ignores_rho",
        "projectors",
        P + "sign.py",
        "tau = jnp.broadcast_to(ctx.rho, z.shape)[w] if self.tau is None else self.tau",
        "tau = 1.0 if self.tau is None else self.tau",
        "SignResolvent's docstring: tau=None uses the stage's own scaling tau = rho_w",
        (TP + "test_sign_resolvent_tau_default_uses_rho",),
    ),
    Mutant(
        "lcp_jvp_degenerate_active",
        "projectors",
        P + "lcp.py",
        "    S = p > 0\n    dp",
        "    S = p >= 0\n    dp",
        "lcp_solve's docstring: a degenerate contact (p = 0, Dp + q = 0) is inactive in the JVP",
        (TP + "test_lcp_degenerate_index_is_inactive", TP + "test_lcp_jacobian"),
    ),
    Mutant(
        "lcp_single_contact_unscaled",
        "projectors",
        P + "lcp.py",
        "p0 = jnp.maximum(0.0, -q / jnp.where(diag > 0, diag, 1.0))",
        "p0 = jnp.maximum(0.0, -q)",
        "lcp_solve: one contact, p = max(0, -q/D) is the exact solution",
        (TP + "test_lcp_complementarity", TP + "test_contact_coupled_impulse_map"),
    ),
    Mutant(
        "lcp_active_set_strict_sign",
        "projectors",
        P + "lcp.py",
        "S = p - (D @ p + q) > 0",
        "S = p + (D @ p + q) > 0",
        "lcp_solve's docstring: the active set of semismooth Newton on min(p, Dp + q) = 0",
        (TP + "test_lcp_complementarity",),
    ),
    Mutant(
        "contact_restitution_on_separation",
        "projectors",
        P + "contact.py",
        "q = jnp.where(active, Wt @ z + e * jnp.minimum(u_minus, 0.0), 0.0)",
        "q = jnp.where(active, Wt @ z + e * u_minus, 0.0)",
        "the comment: restitution acts on approach velocities only (a separating contact "
        "gets u+ >= 0)",
        (
            TP + "test_contact_restitution_acts_on_approach_only",
            TP + "test_contact_coupled_impulse_map",
            TP + "test_contact_impact_restitution",
            TP + "test_contact_matches_reference",
        ),
    ),
    Mutant(
        "contact_violation_without_late_velocity",
        "events",
        P + "contact.py",
        "return jnp.max(jnp.maximum(judged, velocity), initial=0.0)",
        "return jnp.max(judged, initial=0.0)",
        "UnilateralContact.violation: a late impact's velocity error (1 + e)|a| dt counts "
        "(measured: a Zeno ball's steps ten times its flights)",
        (
            TEV + "test_zeno_ball_impacts_at_step_boundaries",
            TEV + "test_micro_bounces_do_not_fall_through_the_floor",
        ),
    ),
    Mutant(
        "contact_depth_at_the_states_scale",
        "events",
        P + "contact.py",
        "judged = depth * self._depth_to_state_scale(ctx, dtype)",
        "judged = depth",
        "UnilateralContact._depth_to_state_scale: a penetration is charged like an error in "
        "its gap, atol + rtol R on a bowl (measured at the state's scale, speed included: "
        "a thrown ball's landing 1.35x that deep with backward Euler at rtol 1e-6)",
        ("tests/test_curved_contact.py::test_adaptive_error_falls_with_rtol[thrown-be]",),
    ),
    Mutant(
        "policy_without_tolerances",
        "controllers",
        C + "policy.py",
        "return self.rtol, self.atol",
        "return None",
        "PolicyController.tolerances: its error test charges contacts and holds stages as "
        "PID does (an integral policy reproduces PID step for step on a bouncing ball)",
        ("tests/test_controller_policy.py::test_integral_policy_reproduces_pid",),
    ),
    Mutant(
        "interpolant_turn_at_the_end_as_the_law",
        "events",
        "nivpjax/_loop.py",
        "stop=(stopped | turned, p0, da0)",
        "stop=(stopped, p0, da0)",
        "_persistent: weighed rows at rest at a step's end that moved at its start turned "
        "there; they follow the start's flow, not the cubic with the law's rate of the "
        "turn's far side (measured: 3.1x the steps' error at t_eval on an elliptic bowl)",
        (TBF + "test_t_eval_as_accurate_as_the_steps[bathe-ellipse_slide]",),
    ),
    Mutant(
        "second_order_sliding_start_off_its_surface",
        "events",
        "nivpjax/_held.py",
        "y_eq = on_second_order_surface(model, t0, t0, y_eq, t0 + h, y_eq, y_eq, args, near)",
        "y_eq = y_eq",
        "held_start: a step in a second-order sliding mode starts on the surface's first "
        "derivative with the second-order equivalent control (the trapezoidal rule's w "
        "rang from the stage's value: max_steps on super-twisting at rtol 1e-3)",
        (
            "tests/test_filippov_trust.py::"
            "test_trapezoidal_starts_second_order_sliding_on_its_surface",
        ),
    ),
    Mutant(
        "contact_no_lift_off_prediction",
        "events",
        P + "contact.py",
        "lift_off = jnp.min(lift, initial=jnp.inf)",
        "lift_off = jnp.inf",
        "UnilateralContact.next_event: a resting contact predicts its lift-off (measured: "
        "dv(T)/dg off by 2.2e-3 on a plastic contact; without it the thrown ball's release "
        "from a curved wall is late beyond its bound: Bathe and TR, TR's 3.4e-3 late)",
        (
            TS + "test_plastic_contact_closing_and_opening",
            "tests/test_curved_contact.py::test_adaptive_error_falls_with_rtol[thrown-bathe]",
        ),
    ),
    Mutant(
        "contact_landed_margin",
        "events",
        P + "contact.py",
        "_LANDED = 1e-2",
        "_LANDED = 0.0",
        "the comment: a step that ended within 1% of its size before a contact closes has "
        "landed on it (else a cascade of 5 to 20 rejections)",
        (
            TEV + "test_zeno_ball_impacts_at_step_boundaries",
            TEV + "test_a_step_short_of_a_contact_lands_on_it",
        ),
    ),
    Mutant(
        "contact_event_time_gradient_dropped",
        "events",
        P + "contact.py",
        "tau = jnp.where(closed & impact, tau - jax.lax.stop_gradient(tau), tau)",
        "tau = jnp.where(closed & impact, jax.lax.stop_gradient(tau - tau), tau)",
        "event_time's comment: a gap closed to round-off keeps tau's derivative (how the "
        "landing moves with the data)",
        (
            "tests/test_event_gradients.py::test_gradient_through_an_impact_matches_closed_form",
            TS + "test_plastic_contact_closing_and_opening",
        ),
    ),
    # ------------------------------------------------------------ event prediction kernels
    Mutant(
        "first_root_discriminant",
        "events",
        P + "predict.py",
        "disc = ds**2 - 2 * dds * s",
        "disc = ds**2 - 4 * dds * s",
        "first_root's docstring: roots of s + s' tau + s'' tau^2 / 2 (not the textbook b^2 - 4ac)",
        (TEV + "test_zeno_ball_impacts_at_step_boundaries",),
    ),
    Mutant(
        "secant_crossing_half",
        "events",
        P + "predict.py",
        "tau = h * s0 / jnp.where(approaching, -ds, 1.0)",
        "tau = 0.5 * h * s0 / jnp.where(approaching, -ds, 1.0)",
        "secant_crossing's docstring: the zero of the secant through the two end values",
        (
            TEV + "test_secant_crossing_is_the_zero_of_the_secant",
            TEV + "test_relay_sliding_entry_is_predicted_from_the_rates",
        ),
    ),
    Mutant(
        "hermite_excursion_c2",
        "events",
        P + "predict.py",
        "c2 = -3 * s0 - 2 * m0 + 3 * s1 - m1",
        "c2 = -3 * s0 - m0 + 3 * s1 - m1",
        "hermite_excursion's docstring: the cubic Hermite interpolant of the end values and rates",
        (TEV + "test_hermite_excursion_measures_a_crossing_and_back",),
    ),
    # ------------------------------------------------------------------ nonlinear solvers
    Mutant(
        "ssn_no_watchdog",
        "nonlinear",
        N + "semismooth_newton.py",
        "full_steps: int = eqx.field(static=True, default=3)",
        "full_steps: int = eqx.field(static=True, default=0)",
        "SemismoothNewton's docstring: a monotone line search stalls on stiffly coupled "
        "switching systems (the watchdog's full steps)",
        (
            TN + "test_newton_watchdog_leaves_a_false_minimum_of_the_merit",
            TN + "test_newton_line_search_after_the_watchdog",
            TN + "test_relay_step",
            "tests/test_filippov.py::test_invariant_or_failure_code[bathe-newton]",
            "tests/test_filippov.py::test_invariant_or_failure_code[tr-newton]",
        ),
    ),
    Mutant(
        "ssn_fallback_sign",
        "nonlinear",
        N + "semismooth_newton.py",
        "d = jnp.where(ok, d, -g)",
        "d = jnp.where(ok, d, g)",
        "SemismoothNewton's docstring: a singular Newton system falls back to d = -G(y)",
        (
            TN + "test_singular_newton_system_falls_back_to_the_projection_step",
            TN + "test_relay_step",
            TN + "test_contact_step_resting",
            TN + "test_soc_step_sticking",
            "tests/test_hard_cases.py::test_random_vi[newton]",
        ),
    ),
    Mutant(
        "ssn_armijo_loosened",
        "nonlinear",
        N + "semismooth_newton.py",
        "(1 - 2 * self.sigma * alpha) * m0",
        "(1 + 2 * self.sigma * alpha) * m0",
        "Armijo's sufficient decrease after the watchdog (issue 29's survivor)",
        (TN + "test_newton_line_search_after_the_watchdog",),
    ),
    Mutant(
        "ssn_stops_at_initial_guess",
        "nonlinear",
        N + "semismooth_newton.py",
        "& ((k == 0) | (scaled_error(g, y, rtol, atol, z) > 1))",
        "& (scaled_error(g, y, rtol, atol, z) > 1)",
        "the comment: stopping at the initial guess freezes the state on tiny steps "
        "(issue 29's survivor)",
        (TN + "test_tiny_steps_do_not_freeze_the_state",),
    ),
    Mutant(
        "ssn_backtrack_grows",
        "nonlinear",
        N + "semismooth_newton.py",
        "beta: float = 0.5",
        "beta: float = 1.0",
        "SemismoothNewton: beta is the backtracking factor (a factor 1 never backtracks)",
        (TN + "test_newton_line_search_after_the_watchdog",),
    ),
    Mutant(
        "vi_stops_at_initial_guess",
        "nonlinear",
        N + "fixed_point.py",
        "done = finite & (k > 0) & (scaled_error(natural, y, rtol, atol, argument) <= 1)",
        "done = finite & (scaled_error(natural, y, rtol, atol, argument) <= 1)",
        "the comment: never stop at the initial guess (see SemismoothNewton): move at least once "
        "(with alpha0 < 1 a done first iterate returned the start of a tiny step)",
        (
            TN + "test_vi_moves_from_its_initial_guess_on_a_tiny_step",
            TN + "test_tiny_steps_do_not_freeze_the_state",
            TN + "test_relay_step",
            TN + "test_contact_step_resting",
        ),
    ),
    Mutant(
        "vi_no_final_projection_step",
        "nonlinear",
        N + "fixed_point.py",
        "y_new = jnp.where(done, jnp.where(plain & (alpha >= 1.0), y_bar, y), moved)",
        "y_new = jnp.where(done, y, moved)",
        "the comment: end with the projection step, which solves explicit rows exactly "
        "(else 1e-10 of position per step: micro-bounces of a ball at rest)",
        (
            TN + "test_vi_returns_the_projection_step_that_solves_explicit_rows",
            TN + "test_contact_step_resting",
            TN + "test_relay_step",
            "tests/test_hard_cases.py::test_ball_resting_contact_carries_weight[bathe-vi]",
        ),
    ),
    Mutant(
        "vi_extragradient_unguarded",
        "nonlinear",
        N + "fixed_point.py",
        "extra = ~plain & finite & (L <= self.nu)",
        "extra = ~plain & finite",
        "FixedPointVI's docstring: the extragradient step only if L <= nu, else reject and shrink",
        (
            TN + "test_vi_extragradient_only_at_a_safe_step",
            TN + "test_relay_step",
            TN + "test_soc_step_sliding",
            "tests/test_hard_cases.py::test_random_vi[vi]",
        ),
    ),
    Mutant(
        "vi_kappa_expanding",
        "nonlinear",
        N + "fixed_point.py",
        "kappa: float = 0.7",
        "kappa: float = 1.5",
        "FixedPointVI's docstring: a projection step only when it contracts (plain "
        "projection cycles on saddle stages)",
        (
            TN + "test_relay_step",
            TN + "test_soc_step_sliding",
            TN + "test_soc_step_sticking",
            "tests/test_hard_cases.py::test_random_vi[vi]",
        ),
    ),
    Mutant(
        "vi_step_never_grows",
        "nonlinear",
        N + "fixed_point.py",
        "accept, jnp.where(L < 0.5 * self.nu, grown, alpha), alpha * shrink",
        "accept, alpha, alpha * shrink",
        "FixedPointVI's docstring: alpha grows after an accepted move with L < nu/2",
        (
            TN + "test_vi_step_grows_from_a_small_initial_step",
            TN + "test_relay_step",
            TN + "test_contact_step_resting",
            TN + "test_soc_step_sliding",
            TN + "test_vi_reports_failure_with_small_budget",
        ),
    ),
    Mutant(
        "solve_returns_raw_iterate",
        "nonlinear",
        N + "base.py",
        "return jnp.where(lax.stop_gradient((p != z) | outside), p, y), p",
        "return y, p",
        "NonlinearSolution.value: constrained components lie exactly in their sets, "
        "converged or not (issue 29's survivor)",
        (TN + "test_returned_multipliers_lie_exactly_in_their_sets",),
    ),
    Mutant(
        "solve_projects_free_components",
        "nonlinear",
        N + "base.py",
        "return jnp.where(lax.stop_gradient((p != z) | outside), p, y), p",
        "return p, p",
        "the comment: free components keep the iterate, which satisfies its own equations "
        "more exactly",
        (
            TN + "test_a_successful_value_passes_the_stopping_test",
            TN + "test_tiny_steps_do_not_freeze_the_state",
            TN + "test_relay_step",
            TN + "test_newton_superlinear",
            "tests/test_solve.py::test_order_of_convergence",
        ),
    ),
    Mutant(
        "float32_tolerances_unclamped",
        "nonlinear",
        N + "base.py",
        "floor = 8 * float(jnp.finfo(dtype).eps)",
        "floor = 0.0 * float(jnp.finfo(dtype).eps)",
        "effective_tolerances: a float32 solve asked for 1e-12 would otherwise never converge",
        (
            TN + "test_float32_tolerances_are_clamped_to_its_resolution",
            TN + "test_float32_relay",
            "tests/test_solve.py::test_float32",
        ),
    ),
    # ---------------------------------------------------------- implicit-function gradients
    Mutant(
        "tangent_solve_sign",
        "gradients",
        "nivpjax/_linear/dense.py",
        "x, _ = _linalg.solve(J, b)\n        return x",
        "x, _ = _linalg.solve(J, -b)\n        return x",
        "DenseLU.tangent_solve solves g(x) = b: the implicit function theorem's linear system",
        (TN + "test_gradient_soc_sliding_matches_fd",),
    ),
    Mutant(
        "krylov_tangent_nan_mask_dropped",
        "gradients",
        "nivpjax/_linear/krylov.py",
        "return jnp.where(lax.stop_gradient(converged), precondition(z), jnp.nan)",
        "return precondition(z)",
        "Krylov's docstring: an implicit-function solve short of its tolerance gives NaN, "
        "never a wrong finite derivative",
        (
            "tests/test_linear_large.py::test_unconverged_tangent_solve_gives_nan_not_a_wrong_derivative",
        ),
    ),
    Mutant(
        "krylov_forcing_frozen",
        "nonlinear",
        "nivpjax/_linear/krylov.py",
        "eta = self.gamma * ratio**self.alpha",
        "eta = self.gamma * ratio**0",
        "Krylov's docstring: Eisenstat-Walker forcing terms tighten as the residual falls",
        ("tests/test_linear_large.py::test_forcing_terms_tighten_into_superlinear_convergence",),
    ),
    Mutant(
        "theta_arrest_estimate_dropped",
        "steppers",
        S + "one_leg.py",
        "if self.theta < 1.0:",
        "if self.theta < 0.5:",
        "the theta family's estimate takes held_row_errors' arrest estimate (an arrested "
        "row's value is exact if the slip had ended) for every theta < 1, the trapezoidal "
        "rule included",
        (TE + "test_estimate_of_a_block_coming_to_rest_inside_the_step",),
    ),
    Mutant(
        "gmres_tests_after_the_cycle",
        "nonlinear",
        "nivpjax/_linear/gmres.py",
        "return (j < restart) & (jnp.abs(g[j]) > tol)",
        "return j < restart",
        "gmres's docstring: the cycle stops at the first product that meets its tolerance",
        ("tests/test_gmres.py::test_stops_at_the_product_that_meets_the_tolerance",),
    ),
    Mutant(
        "gmres_gram_schmidt_once",
        "nonlinear",
        "nivpjax/_linear/gmres.py",
        "for _ in range(2):  # classical Gram-Schmidt, twice",
        "for _ in range(1):  # classical Gram-Schmidt, twice",
        "gmres's docstring: Gram-Schmidt twice is as accurate as modified Gram-Schmidt",
        (
            "tests/test_gmres.py::"
            "test_gram_schmidt_twice_keeps_the_residual_true_when_the_basis_is_ill_conditioned",
        ),
    ),
    Mutant(
        "gmres_givens_sign",
        "nonlinear",
        "nivpjax/_linear/gmres.py",
        "g = g.at[j + 1].set(-s_j * g[j]).at[j].set(c_j * g[j])",
        "g = g.at[j + 1].set(s_j * g[j]).at[j].set(c_j * g[j])",
        "the Givens rotation applied to the right-hand side",
        ("tests/test_gmres.py::test_true_residual_meets_the_tolerance",),
    ),
    Mutant(
        "gmres_restart_from_the_old_residual",
        "nonlinear",
        "nivpjax/_linear/gmres.py",
        "r = lax.cond(again, lambda: b - matvec(x), lambda: r)",
        "r = lax.cond(again, lambda: b, lambda: r)",
        "gmres's docstring: a restart recomputes the true residual",
        ("tests/test_gmres.py::test_restarts_recompute_the_residual_and_count_it",),
    ),
    Mutant(
        "linearised_natural_map_without_state_dependence",
        "nonlinear",
        N + "base.py",
        "return lambda v: v - dP(v - rho * dR(v), v)",
        "return lambda v: v - dP(v - rho * dR(v), 0 * v)",
        "linearised_natural_map's docstring: the same map as jax.linearize of G, the "
        "projection's dependence on the state included",
        (
            "tests/test_linear_large.py::"
            "test_linearised_natural_map_from_the_known_argument_is_the_jvp",
        ),
    ),
    Mutant(
        "krylov_cauchy_test_kept",
        "nonlinear",
        "nivpjax/_linear/krylov.py",
        "c = 1.0 / jnp.sqrt(jnp.finfo(b.dtype).eps)",
        "c = 1.0",
        "Krylov._solve's comment: lineax's test on the last update costs an extra iteration",
        ("tests/test_linear_large.py::test_an_exact_preconditioner_solves_in_one_krylov_cycle",),
    ),
    Mutant(
        "tangent_residual_dropped",
        "gradients",
        N + "base.py",
        "z = y - rho * (residual(y) + tangent_only(lambda v: residual_t(v) - residual(v), y))",
        "z = y - rho * residual(y)",
        "NonlinearSolver.solve's docstring: the projected components carry the tangent "
        "residual's element of the generalised Jacobian",
        (
            TS + "test_relay_crossing_carries_the_saltation_term",
            TS + "test_slider_reversals_converge_to_exact_derivative",
            TS + "test_rectifier_converges_to_exact_derivative",
        ),
    ),
    Mutant(
        "relay_without_saltation",
        "gradients",
        "nivpjax/_scene/switching.py",
        "EventLocated(box, OnScene(self.switch, n_states), saltation=True)",
        "EventLocated(box, OnScene(self.switch, n_states), saltation=False)",
        "Relay: the multipliers jump across the surface, whose crossing's saltation term "
        "the derivatives need",
        (
            TS + "test_relay_crossing_carries_the_saltation_term",
            TS + "test_relay_entering_and_leaving_sliding",
        ),
    ),
    # ------------------------------------------------------------- steppers and estimates
    Mutant(
        "theta_leading_term_sign",
        "steppers",
        S + "one_leg.py",
        "e = (theta - 0.5) * h * (f1 - f0)",
        "e = (0.5 - theta) * h * (f1 - f0)",
        "theta_error's docstring: e is the computed minus the exact state, (theta - 1/2) h^2 y''",
        (TE + "test_estimate_tracks_local_error",),
    ),
    Mutant(
        "tr_estimate_constant",
        "steppers",
        S + "one_leg.py",
        "e = e + h**2 / 12 * (df1 - df0)",
        "e = e + h**2 / 6 * (df1 - df0)",
        "theta_error's docstring: the trapezoidal rule's + h^3/12 y'''",
        (TE + "test_estimate_tracks_local_error",),
    ),
    Mutant(
        "early_crossing_never",
        "steppers",
        S + "one_leg.py",
        "return tau < 0.5 * (1 - theta) * h",
        "return tau < 0.0 * h",
        "early_crossing's docstring: a theta step crossing a switch before (1 - theta) h / 2 "
        "is backward Euler's, the nearer (a trapezoidal spiral circled its Zeno point)",
        (
            TE + "test_a_stage_crossing_a_switch_early_is_backward_euler",
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point_with_the_vi_method",
        ),
    ),
    Mutant(
        "early_crossing_at_half_the_old_rate",
        "steppers",
        S + "one_leg.py",
        "return tau < 0.5 * (1 - theta) * h",
        "return tau < (1 - theta) * h",
        "early_crossing's docstring: backward Euler is the nearer only before (1 - theta) h / 2",
        (TE + "test_a_stage_crossing_a_switch_early_is_backward_euler",),
    ),
    Mutant(
        "early_crossing_keeps_the_theta_estimate",
        "steppers",
        S + "one_leg.py",
        "e = jnp.where(crossing, model.to_state(e_crossing), e)",
        "e = e",
        "a step taken as backward Euler's carries backward Euler's estimate",
        (TE + "test_a_stage_crossing_a_switch_early_is_backward_euler",),
    ),
    Mutant(
        "bathe_first_stage_never_crosses_early",
        "steppers",
        S + "bathe.py",
        "theta = jnp.where(crossing, 1.0, 0.5)",
        "theta = jnp.where(crossing, 0.5, 0.5)",
        "Bathe's step: a trapezoidal stage across a switch early in it is backward Euler's",
        (TE + "test_a_stage_crossing_a_switch_early_is_backward_euler",),
    ),
    Mutant(
        "theta_defect_dropped",
        "steppers",
        S + "one_leg.py",
        "    e = jnp.where(jnp.abs(defect) > jnp.abs(e), defect, e)\n",
        "",
        "theta_error's docstring: a scheme averaging the end rates errs by (1 - theta) h |D| "
        "at a jump of the rate",
        (
            TE + "test_theta_estimate_charges_a_switch_inside_the_step",
            TE + "test_estimate_sees_an_equation_row",
            "tests/test_filippov.py::test_invariant_or_failure_code[tr-newton]",
            "tests/test_filippov.py::test_invariant_or_failure_code[theta0.7-newton]",
            "tests/test_hard_cases.py::test_sliding_mode_control_without_chattering[tr]",
        ),
    ),
    Mutant(
        "theta_defect_added",
        "steppers",
        S + "one_leg.py",
        "    e = jnp.where(jnp.abs(defect) > jnp.abs(e), defect, e)\n",
        "    e = e + defect\n",
        "theta_error's docstring: the defect replaces the estimate where larger, not added "
        "(added, it cancelled the trapezoidal estimate near a square-root singularity of "
        "the rate: super-twisting silently wrong at rtol 1e-4 and 1e-6)",
        (TE + "test_theta_estimate_near_a_square_root_singularity",),
    ),
    Mutant(
        "theta_secant_across_switch",
        "steppers",
        S + "one_leg.py",
        "secant = jnp.where(switched, 0.0, (y1 - y0) / h_safe)",
        "secant = (y1 - y0) / h_safe",
        "state_rate's docstring: a jump of the multipliers is not smooth flow; the secant "
        "would explain it away (issue 29's survivor)",
        (
            TE + "test_theta_estimate_charges_a_switch_inside_the_step",
            TE + "test_estimate_tracks_local_error",
            TE + "test_estimate_sees_an_equation_row",
            "tests/test_filippov.py::test_invariant_or_failure_code[tr-newton]",
            "tests/test_filippov.py::test_invariant_or_failure_code[theta0.7-newton]",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[tr-box-1.3-2.0]",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[tr-sign-1.3-2.0]",
        ),
    ),
    Mutant(
        "theta_multiplier_rate_zero",
        "steppers",
        S + "one_leg.py",
        "rate = jnp.where(model.algebraic, secant, model.to_state(F))",
        "rate = jnp.where(model.algebraic, 0.0, model.to_state(F))",
        "state_rate's docstring: multipliers get their secant rate, so a multiplier sliding "
        "along an equivalent control is seen as moving",
        (
            TE + "test_theta_estimate_is_zero_inside_a_sliding_mode",
            TE + "test_estimate_tracks_local_error",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[tr-box-1.3-2.0]",
            "tests/test_hard_cases.py::test_sliding_mode_control_without_chattering[tr]",
        ),
    ),
    Mutant(
        "switch_kink_from_start",
        "steppers",
        S + "one_leg.py",
        "return jnp.where(switched, (1 - theta) * (h - tau) * (f0 - f1), 0.0)",
        "return jnp.where(switched, (1 - theta) * tau * (f0 - f1), 0.0)",
        "switch_kink_error: the scheme errs over the part of the step after the switch "
        "(a normal cone on a differential row reached inside a trapezoidal step: an estimate "
        "of 0 with the factor tau; friction, now weighed, is charged by the defect)",
        (
            TE + "test_theta_estimate_charges_a_face_reached_inside_the_step",
            "tests/test_scenes_mechanics.py::"
            "test_block_comes_to_rest_at_the_tolerance_with_the_trapezoidal_rule",
        ),
    ),
    Mutant(
        "event_in_step_strict",
        "steppers",
        S + "one_leg.py",
        "jnp.where(tau <= h * (1 + jnp.sqrt(jnp.finfo(y1.dtype).eps)), jnp.minimum(tau, h), 0.0)",
        "jnp.where(tau <= h, tau, 0.0)",
        "event_in_step's comment: a landing step's tau is one ulp above h (measured: sliding "
        "time off by 8e-4 at rtol 1e-5, successful)",
        (
            TE + "test_an_event_predicted_at_the_end_of_a_step_up_to_rounding_lies_inside_it",
            "tests/test_scenes_switching.py::test_relay_reaching_time",
            "tests/test_scenes_switching.py::test_relay_filippov_sliding",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[be-box-1.3-2.0]",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[tr-box-1.3-2.0]",
        ),
    ),
    Mutant(
        "be_late_switch_dropped",
        "steppers",
        S + "one_leg.py",
        "return f0_end, tau * (f0 - f0_end)",
        "return f0_end, 0.0 * tau * (f0 - f0_end)",
        "late_switch_error's docstring: rejects a step that crosses a switching surface or "
        "lands on it too early",
        (
            "tests/test_scenes_switching.py::test_relay_reaching_time",
            "tests/test_filippov.py::test_invariant_or_failure_code[be-newton]",
            "tests/test_filippov.py::test_invariant_or_failure_code[be-vi]",
        ),
    ),
    Mutant(
        "be_start_rate_end_only",
        "steppers",
        S + "one_leg.py",
        "base = jnp.where(jnp.abs(d_start) < jnp.abs(d_end), d_start, d_end)",
        "base = d_end",
        "the comment: f0_end is off by O(h) after a landing step's averaged multiplier; the "
        "smaller difference is the right-limit one",
        (
            TE + "test_theta_estimate_is_zero_inside_a_sliding_mode",
            TE + "test_estimate_tracks_local_error",
            TE + "test_estimate_sees_an_equation_row",
            "tests/test_filippov.py::test_invariant_or_failure_code[be-newton]",
            "tests/test_filippov.py::test_invariant_or_failure_code[be-vi]",
        ),
    ),
    Mutant(
        "be_equation_rows_take_end",
        "steppers",
        S + "one_leg.py",
        "f0_end = model.f(t0, jnp.where(model.selection_rows, y1, y0), args)",
        "f0_end = model.f(t0, jnp.where(model.algebraic, y1, y0), args)",
        "backward_euler_error's docstring: equation rows keep their start values (taking the "
        "end's: an estimate 1000x too small on a diode)",
        (TE + "test_estimate_sees_an_equation_row",),
    ),
    Mutant(
        "be_estimate_constant",
        "steppers",
        S + "one_leg.py",
        "return 0.5 * h * (f1 - f0)\n",
        "return 0.25 * h * (f1 - f0)\n",
        "BackwardEuler's docstring: the embedded estimate h/2 (f1 - f0)",
        (TE + "test_estimate_tracks_local_error",),
    ),
    Mutant(
        "friction_weighed_reaction_dropped",
        "steppers",
        S + "one_leg.py",
        "F = jnp.where(model.weighed, f + r, f)",
        "F = f",
        "_effective: on weighed rows F = f + r, the law's reaction at each end (slip weakening)",
        (
            "tests/test_friction_order.py::test_adaptive_as_accurate_as_the_smooth_field[weakening-tr]",
            "tests/test_friction_order.py::test_adaptive_as_accurate_as_the_smooth_field[disk-tr]",
        ),
    ),
    Mutant(
        "friction_reaction_derivative_dropped",
        "steppers",
        S + "one_leg.py",
        "return F, rate, flow_derivative(model, t, y, rate, args) + along(rate)",
        "return F, rate, flow_derivative(model, t, y, rate, args)",
        "_effective's comment: F_dot includes the reaction's derivative along the flow (TR's "
        "estimate was blind to it: 2.2x the smooth field's error)",
        (
            "tests/test_friction_order.py::test_adaptive_as_accurate_as_the_smooth_field[weakening-tr]",
            "tests/test_friction_order.py::test_adaptive_as_accurate_as_the_smooth_field[disk-tr]",
        ),
    ),
    Mutant(
        "bathe_error_constant",
        "steppers",
        S + "bathe.py",
        "return (3 * gamma**2 - 4 * gamma + 2) / (6 * (2 - gamma))",
        "return (3 * gamma**2 - 4 * gamma + 2) / (3 * (2 - gamma))",
        "error_constant's docstring: K = 1/12 at gamma = 1/2",
        (TE + "test_estimate_tracks_local_error",),
    ),
    Mutant(
        "bathe_error_sign",
        "steppers",
        S + "bathe.py",
        "F0 / g - Fg / (g * (1 - g)) + F1 / (1 - g)",
        "F0 / g - Fg / (g * (1 - g)) - F1 / (1 - g)",
        "bathe_error's docstring: the second divided difference on the three nodes",
        (TE + "test_estimate_tracks_local_error",),
    ),
    Mutant(
        "bathe_reaction_at_end_only",
        "steppers",
        S + "bathe.py",
        "smooth = bathe_error(g, h, F0, F_mid, F1)",
        "smooth = bathe_error(g, h, f0, f_mid, F1)",
        "Bathe's docstring: the stages' reactions, taken linear in time, drop out of the "
        "estimate (a body held under a load linear in time has exactly zero estimate; the "
        "holding force at t1 alone: 3.8e-2 for an exact step); replaces "
        "bathe_reaction_constant, equivalent (see EQUIVALENT)",
        (
            TE + "test_bathe_estimate_is_zero_for_a_body_held_under_a_varying_load",
            "tests/test_hard_cases.py::test_stick_slip_under_slowly_growing_load[bathe]",
            "tests/test_friction_order.py::test_second_order_at_fixed_steps[disk-bathe]",
            "tests/test_hard_cases.py::test_ball_resting_contact_carries_weight[bathe]",
        ),
    ),
    Mutant(
        "bathe_split_without_first_stage",
        "steppers",
        S + "bathe.py",
        " + 0.5 * g * h * (f_mid - f0)",
        "",
        "Bathe's docstring: after a restart the estimate charges the rate jump inside the "
        "first stage, gamma h / 2 (f_mid - f0)",
        (
            TE + "test_bathe_estimate_charges_a_switch_inside_its_first_stage",
            "tests/test_scenes_switching.py::test_relay_reaching_time",
            "tests/test_filippov.py::test_invariant_or_failure_code[bathe-newton]",
            "tests/test_scenes_mechanics.py::test_slider_stick_slip",
        ),
    ),
    Mutant(
        "bathe_arrest_estimate_dropped",
        "steppers",
        S + "departure.py",
        "e = jnp.where(arrested, stop_error, e)",
        "e = jnp.where(arrested, e, e)",
        "Bathe's docstring: on a row that came to rest inside the step the estimate is the "
        "projector's (the jump of its rate is no error of its value: the fault's steps "
        "collapsed at every arrest)",
        (TE + "test_estimate_of_a_block_coming_to_rest_inside_the_step",),
    ),
    Mutant(
        "bathe_split_on_f_alone",
        "steppers",
        S + "bathe.py",
        "f0, f_mid, f1 = (jnp.where(model.weighed, a, b) for a, b in zip(F, f))",
        "f0, f_mid, f1 = (jnp.where(model.weighed, b, b) for a, b in zip(F, f))",
        "_split_error's comment: on f alone a row held throughout is charged the change of "
        "its load",
        (TE + "test_estimate_of_a_block_coming_to_rest_inside_the_step",),
    ),
    Mutant(
        "friction_arrest_early_uncharged",
        "projectors",
        P + "coulomb.py",
        "return arrested, jnp.where(early, slip, 0.0)",
        "return arrested, jnp.where(early, 0.0, 0.0)",
        "CoulombFriction.arrest_error's docstring: a row that stopped early is off by the "
        "slip velocity left at the end",
        (TE + "test_arrest_error_is_the_slip_velocity_left_at_the_end",),
    ),
    Mutant(
        "bathe_no_restart_on_switch",
        "steppers",
        S + "bathe.py",
        "restart = impulsive | switched",
        "restart = impulsive",
        "Bathe's docstring: after a change of face the backward difference would "
        "extrapolate across the jump of the rate: restart",
        (
            "tests/test_filippov.py::test_invariant_or_failure_code[bathe-newton]",
            "tests/test_scenes_switching.py::test_relay_filippov_sliding",
            "tests/test_scenes_mechanics.py::test_slider_stick_slip",
        ),
    ),
    Mutant(
        "bathe_late_impact_uncharged",
        "steppers",
        S + "bathe.py",
        "e = jnp.where(late_impact, e + late, e)",
        "e = jnp.where(late_impact, e, e)",
        "the comment: an impact inside the step charges its timing and the stage's holding",
        (
            TEV + "test_bathe_step_charges_an_impact_at_its_second_stage",
            TEV + "test_impact_inside_a_step_charges_timing_and_holding",
        ),
    ),
    Mutant(
        "betr_late_switch_dropped",
        "steppers",
        S + "embedded_betr.py",
        "error = jnp.where(jnp.abs(late) > jnp.abs(error), late, error)",
        "error = jnp.where(jnp.abs(late) > jnp.abs(error), error, error)",
        "the comment: a transient landing has TR - BE ~ 0 (measured: a Filippov spiral's "
        "invariant off by 1.3e-2 at rtol 1e-3)",
        (
            "tests/test_filippov.py::test_invariant_or_failure_code[betr-newton]",
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point[betr-10.0-0.1-1e-09]",
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point[betr-300.0-0.02-1e-09]",
        ),
    ),
    Mutant(
        "richardson_denominator",
        "steppers",
        S + "richardson.py",
        "y_error = (half2.y1 - full.y1) / (2.0**p - 1.0)",
        "y_error = (half2.y1 - full.y1) / 2.0**p",
        "Richardson's docstring: the error of the two half steps is (y_h/2,h/2 - y_h)/(2^p - 1)",
        (
            TE + "test_richardson_estimate_tracks_local_error",
            "tests/test_solve.py::test_adaptive_meets_tolerance",
            TE + "test_estimate_tracks_local_error",
        ),
    ),
    Mutant(
        "multiplier_rho_not_scaled_by_h",
        "steppers",
        "nivpjax/_model.py",
        "alg_rho = self.tau / h_eff",
        "alg_rho = self.tau",
        "AbstractEffect's docstring: multipliers entering the state with weight h are scaled "
        "rho = tau / h (the stage's fixed point does not depend on rho; the VI method's "
        "iterations do: 73 to 141 on a relay stage with rho = tau, 10 to 33 with tau / h)",
        (
            TN + "test_vi_iterations_do_not_grow_as_the_step_shrinks",
            TN + "test_relay_step",
            "tests/test_scenes_switching.py::test_relay_filippov_sliding",
        ),
    ),
    # --------------------------------------------------------------------- controllers
    Mutant(
        "pid_beta2_without_2d",
        "controllers",
        C + "pid.py",
        "beta2 = -(self.pcoeff + 2 * self.dcoeff) / k",
        "beta2 = -(self.pcoeff + self.dcoeff) / k",
        "PIDController's docstring: beta2 = -(p + 2d) (issue 29's survivor)",
        ("tests/test_controller_policy.py",),
    ),
    Mutant(
        "pid_grows_after_rejection",
        "controllers",
        C + "pid.py",
        "factor = jnp.where(accept & ~rejected_before, factor, jnp.minimum(factor, 1.0))",
        "factor = jnp.where(accept, factor, jnp.minimum(factor, 1.0))",
        "the comment: no growth on the step right after a rejection (Hairer & Wanner)",
        ("tests/test_controller_policy.py",),
    ),
    Mutant(
        "pid_ignores_violation",
        "controllers",
        C + "pid.py",
        "err = jnp.maximum(err, info.violation / scale)",
        "err = err + 0 * info.violation",
        "the comment: a constraint crossed inside the step counts as error",
        (
            TEV + "test_micro_bounces_do_not_fall_through_the_floor",
            "tests/test_scenes_mechanics.py::test_ball_impacts_and_apex_ratio",
        ),
    ),
    Mutant(
        "pid_failed_solve_not_shrunk",
        "controllers",
        C + "pid.py",
        "factor = jnp.where(ok, factor, self.nonlinear_factor)",
        "factor = jnp.where(ok, factor, 1.0)",
        "AbstractController's docstring: failed nonlinear solves are rejected and shrunk",
        (
            "tests/test_controller_policy.py::test_pid_error_order_overrides_the_steppers",
            "tests/test_controller_policy.py",
            "tests/test_solve.py::test_h_min_reported",
        ),
    ),
    Mutant(
        "pid_error_order_override_ignored",
        "controllers",
        C + "pid.py",
        "k = info.error_order if self.error_order is None else self.error_order",
        "k = info.error_order",
        "PIDController: error_order overrides the stepper's (the drop-in's method_order)",
        (
            "tests/test_controller_policy.py::test_pid_error_order_overrides_the_steppers",
            TC + "test_defaults_are_the_reference_ones",
            "tests/test_controller_policy.py",
        ),
    ),
    Mutant(
        "pid_initial_step_guess",
        "controllers",
        C + "pid.py",
        "h = jnp.minimum(h, 0.1 * jnp.abs(t1 - t0))",
        "h = jnp.minimum(h, jnp.abs(t1 - t0))",
        "Hairer-Wanner's first guess, capped at a tenth of the interval",
        (
            "tests/test_controller_policy.py::test_pid_first_step_is_hairer_wanners_guess_capped_at_a_tenth_of_the_interval",
            "tests/test_controller_policy.py",
            "tests/test_solve.py::test_attempt_log",
        ),
    ),
    Mutant(
        "norm_counts_masked_rows",
        "controllers",
        "nivpjax/_norms.py",
        "count = jnp.maximum(jnp.sum(mask), 1)",
        "count = mask.size",
        "scaled_rms_norm's docstring: the RMS over the unmasked components",
        (
            "tests/test_controller_policy.py::test_masked_error_norm_is_the_rms_over_the_unmasked_rows",
            "tests/test_controller_policy.py",
            "tests/test_solve.py::test_dae_mass_matrix",
            TE + "test_estimate_sees_an_equation_row",
        ),
    ),
    Mutant(
        "events_land_after_acceptance_from_t0",
        "events",
        C + "events.py",
        "to_event = jnp.where(accept, info.next_event_after_end - info.h, info.next_event)",
        "to_event = jnp.where(accept, info.next_event_after_end, info.next_event)",
        "land_before_event's docstring: after an acceptance the next step starts at t0 + h",
        (
            TEV + "test_zeno_ball_impacts_at_step_boundaries",
            TEV + "test_relay_sliding_entry_is_predicted_from_the_rates",
        ),
    ),
    Mutant(
        "events_retry_crossed_late",
        "events",
        C + "events.py",
        "crossed = ~accept & ok & (info.next_event < info.h * (1 - EVENT_SKIP))",
        "crossed = ~accept & ok & (info.next_event < info.h)",
        "the comment: an attempt that crossed the event in its last EVENT_SKIP is left to the "
        "error-controlled factor (measured: 7936 rejections of one step, VI sliding landing)",
        (
            "tests/test_controller_policy.py::test_a_rejected_attempt_is_retried_shorter",
            "tests/test_filippov.py::test_invariant_or_failure_code[be-vi]",
            "tests/test_scenes_switching.py::test_super_twisting_finite_time_sliding",
        ),
    ),
    Mutant(
        "held_degeneracy_rule_off",
        "events",
        "nivpjax/_held.py",
        "DETERMINED = 1e-3",
        "DETERMINED = 0.0",
        "the comment: a held row takes part only where G depends on the multipliers "
        "(measured: super-twisting ran into max_steps without)",
        ("tests/test_filippov_trust.py::test_second_order_sliding_is_not_checked_as_first_order",),
    ),
    Mutant(
        "held_start_skipped",
        "events",
        "nivpjax/_held.py",
        "return jax.lax.cond(jnp.any(held), start, lambda y0: y0, y0)",
        "return y0",
        "held_start's docstring: a held phase starts from its equivalent control (measured: "
        "max_steps exhausted on a forced relay at rtol 1e-5 with the trapezoidal rule)",
        (
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[tr-box-1.3-2.0]",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[tr-sign-1.3-2.0]",
        ),
    ),
    Mutant(
        "interpolation_end_stage_selection",
        "events",
        "nivpjax/_loop.py",
        "end = held_start(model, t1, h, y1, args)",
        "end = y1",
        "_in_step's comment: the end rates take the held phase's selection, not the stage's "
        "(its average over a step in which a stick begins: a block moving after its stop at "
        "t_eval)",
        ("tests/test_twisting.py::test_t_eval_across_a_stop_inside_a_step",),
    ),
    Mutant(
        "second_order_surface_skipped",
        "events",
        "nivpjax/_loop.py",
        '    return on_second_order_surface(model, t, t0, y0, t1, y1, y, args, p["surface"])\n',
        "    return y\n",
        "on_second_order_surface's docstring: in a second-order sliding mode the state at "
        "t_eval lies on sigma' = 0, which the steps keep (super-twisting's nu = -d - c x2; "
        "the cubic 20x the steps' error with Bathe at rtol 1e-3, 2197x on c = 3, L = 5)",
        ("tests/test_twisting.py::test_t_eval_in_the_second_order_sliding_mode[Bathe]",),
    ),
    Mutant(
        "second_order_surface_without_sigma_step",
        "events",
        "nivpjax/_held.py",
        "y = y - g.T @ mu",
        "y = y",
        "_onto_first_derivative's comment: the rows the surface reads go onto sigma = 0 "
        "first (sqrt|sigma| turns the interpolant's sigma ~ 1e-13 into 1e-6 of sigma': "
        "Bathe's t_eval ratio 14.6 at rtol 1e-6)",
        ("tests/test_twisting.py::test_t_eval_in_the_second_order_sliding_mode[Bathe]",),
    ),
    Mutant(
        "second_order_surface_step_sign",
        "events",
        "nivpjax/_held.py",
        "return y - B @ lam, ok_mu & ok_lam",
        "return y + B @ lam, ok_mu & ok_lam",
        "_onto_first_derivative: a Newton step onto sigma' = 0 along the selections' columns",
        ("tests/test_twisting.py::test_t_eval_in_the_second_order_sliding_mode[Bathe]",),
    ),
    Mutant(
        "come_to_rest_skipped",
        "events",
        "nivpjax/_loop.py",
        "return _stopped_inside(model, t0, y0, moving, r1, r1, rows, t1 - t0, args)",
        "return _stopped_inside(model, t0, y0, moving, r1, r1, rows & False, t1 - t0, args)",
        "_come_to_rest's comment: a row at rest at the end of a step in which a phase begins "
        "follows the flow up to its stop, not a cubic bent to arrive with zero rate",
        ("tests/test_twisting.py::test_t_eval_across_a_stop_inside_a_step",),
    ),
    Mutant(
        "come_to_rest_curvature_sign",
        "events",
        "nivpjax/_loop.py",
        "da0 = h * _rate_change(model, t0, y0, p0, args)",
        "da0 = -h * _rate_change(model, t0, y0, p0, args)",
        "_stopped_inside's users: the flow from the start to second order up to a stop (a "
        "block's position under its constant deceleration; a ball sticking on its wall)",
        (
            "tests/test_twisting.py::test_t_eval_across_a_stop_inside_a_step",
            TBF + "test_t_eval_as_accurate_as_the_steps[bathe]",
        ),
    ),
    Mutant(
        "held_one_sample",
        "events",
        "nivpjax/_held.py",
        "SAMPLES = 8",
        "SAMPLES = 1",
        "the comment: an excursion of the equivalent control must span more than "
        "1/(SAMPLES + 1) of a held step to be seen",
        (
            "tests/test_filippov_trust.py::test_held_step_sees_an_excursion_of_the_equivalent_control_between_its_ends",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[be-box-2.5-3.0]",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[bathe-box-2.5-3.0]",
            "tests/test_filippov_trust.py::test_forced_relay_leaves_sliding[tr-box-2.5-3.0]",
        ),
    ),
    Mutant(
        "loop_last_step_leaves_remainder",
        "controllers",
        "nivpjax/_loop.py",
        "last = s.h >= remaining - h_min",
        "last = s.h >= remaining",
        "the comment: land on t1 rather than leave a remainder below h_min (a step of a few "
        "ulps after fixed steps)",
        (
            "tests/test_solve.py::test_fixed_steps_land_on_t1_without_a_round_off_step",
            "tests/test_solve.py::test_order_of_convergence",
            "tests/test_solve.py::test_t_eval_and_buffers",
            "tests/test_solve.py::test_attempt_log",
        ),
    ),
    Mutant(
        "interpolation_unprojected_rates",
        "controllers",
        "nivpjax/_loop.py",
        'p["m0"], p["m1"] = h * p0, h * p1',
        'p["m0"], p["m1"] = h * r0, h * r1',
        "interpolate's docstring: rows a projector moves take the rates the state has "
        "(zero normal motion at a held face, friction's reaction added), not f's",
        (
            "tests/test_interpolation_order.py::test_sweeping_teval_as_right_as_the_steps",
            "tests/test_scenes_mechanics.py::test_slider_outputs_inside_a_long_stick",
        ),
    ),
    Mutant(
        "theta_departure_uncharged",
        "steppers",
        "nivpjax/_stepper/departure.py",
        "return jnp.where(jnp.abs(left) > jnp.abs(e), left, e)",
        "return e",
        "departure_error: a trapezoidal step ending on a face its row left inside it is "
        "otherwise charged nothing (errors falling like rtol^(1/2) on the sweeping process)",
        ("tests/test_reliability.py::test_departures_from_a_face_keep_the_error_proportional",),
    ),
    Mutant(
        "bathe_departure_sign",
        "steppers",
        "nivpjax/_stepper/departure.py",
        "(y1 - y0) - 0.5 * h * r1 * r1 / span",
        "(y1 - y0) + 0.5 * h * r1 * r1 / span",
        "departure_error: the computed motion minus the exact one since t_d (Bathe's "
        "backward-difference stage moves the row h f1 / c3 off the face)",
        (
            "tests/test_estimates.py::test_departure_error_is_the_computed_minus_the_exact_motion",
            "tests/test_reliability.py::test_departures_from_a_face_keep_the_error_proportional",
        ),
    ),
    Mutant(
        "betr_blind_on_held_rows",
        "steppers",
        "nivpjax/_stepper/embedded_betr.py",
        "        error = _held_rows_error(model, t1, h, y_be, f0, error, args)\n",
        "",
        "EmbeddedBETR's docstring: both stages return a face that holds the row at both "
        "ends of a step (the sweeping process: one step over a departure and return)",
        ("tests/test_interpolation_order.py::test_sweeping_teval_as_right_as_the_steps",),
    ),
    Mutant(
        "coulomb_transient_keeps_stage_derivative",
        "gradients",
        P + "coulomb.py",
        "end = jnp.where(transient, -(force - c * jnp.sign(force)) * delta - own, 0.0)",
        "end = jnp.where(transient, -(force - c * jnp.sign(force)) * delta, 0.0)",
        "CoulombFriction.switch_shift's docstring: a transient landing's end velocity takes "
        "the post-reversal derivative in place of the stage's own, whichever branch the "
        "stage took (a slip landing 1e-19 short kept its own: 0.14 off)",
        (
            "tests/test_reversal_gradients.py::"
            "test_slider_derivative_does_not_depend_on_event_margin",
        ),
    ),
    Mutant(
        "switch_branch_read_at_iterate",
        "gradients",
        "nivpjax/_model.py",
        "return reaction(y, y_base + switch(landed)[0], tangent)",
        "return reaction(y, y_base + switch(y)[0], tangent)",
        "solve_stage's comment: the switch's branch is read at the value the solver returns, "
        "not at the iterate, which may lie on the other side of a switch it landed on",
        (
            "tests/test_reversal_gradients.py::"
            "test_step_ending_anywhere_near_reversal_gives_one_derivative[Trapezoidal]",
        ),
    ),
    Mutant(
        "relay_far_branch_unnormalised",
        "gradients",
        P + "located.py",
        "far = self.projector(w0 + reach * jump / jnp.where(scale > 0, scale, 1.0), ctx)",
        "far = self.projector(w0 + 1e6 * jump, ctx)",
        "EventLocated.switch_shift's comment: the far branch is read along the jump's "
        "direction whatever its size (a selection landed 3.5e-7 off its face: 0.76 off)",
        (TS + "test_relay_crossing_carries_the_saltation_term",),
    ),
    Mutant(
        "interpolation_without_saltation_shift",
        "gradients",
        "nivpjax/_loop.py",
        "    y0 = y0 + model.switch_jump(t0, y0, t1, y1, args)\n",
        "",
        "evaluate's docstring: a step across a switch interpolates from its start moved by "
        "the saltation term (else pre- and post-switch sensitivities blend)",
        (
            TS + "test_output_inside_a_step_across_a_switch_has_the_post_switch_derivative",
            TS + "test_relay_crossing_carries_the_saltation_term",
            "tests/test_adjoint.py",
        ),
    ),
    # ---------------------------------------------------------------------- scene effects
    Mutant(
        "saturation_surface_lower_twice",
        "scenes",
        "nivpjax/_scene/switching.py",
        "return jnp.concatenate([u - self.lower, u - self.upper])",
        "return jnp.concatenate([u - self.lower, u - self.lower])",
        "Saturation: its events are u crossing either bound",
        (
            "tests/test_scenes_switching.py::test_saturation_and_diode_events_are_their_switches",
            "tests/test_scenes_switching.py::test_chua_kinks",
        ),
    ),
    Mutant(
        "saturation_constraint_sign",
        "scenes",
        "nivpjax/_scene/switching.py",
        "return jnp.asarray(self.signal(t, x, args)) - lam",
        "return lam - jnp.asarray(self.signal(t, x, args))",
        "Saturation's docstring: sigma = clip(u, l, h) through the VI <sigma - u, eta - "
        "sigma> >= 0",
        ("tests/test_scenes_switching.py::test_chua_kinks",),
    ),
    Mutant(
        "diode_surface_with_current",
        "scenes",
        "nivpjax/_scene/switching.py",
        "return jnp.atleast_1d(self.voltage(t, x, jnp.zeros(self.n, y.dtype), args))",
        "return jnp.atleast_1d(self.voltage(t, x, y[self.n_states :], args))",
        "_DiodeSurface: the voltage each diode would see without current changes sign at a "
        "switch (with the current it is zero while conducting)",
        (
            "tests/test_scenes_switching.py::test_saturation_and_diode_events_are_their_switches",
            "tests/test_scenes_switching.py::test_rectifier_conduction_intervals",
            TS + "test_rectifier_derivative_after_a_step_over_the_turn_off",
        ),
    ),
    Mutant(
        "contact_impulses_without_inverse_mass",
        "scenes",
        "nivpjax/_scene/contact.py",
        "return self.inverse_mass @ self.normals(t, y, args).T",
        "return self.normals(t, y, args).T",
        "Contact: the impulse map is M^-1 W (a stack of balls of different masses)",
        (
            "tests/test_scenes_mechanics.py::test_contact_impulses_follow_the_inverse_mass",
            "tests/test_scenes_mechanics.py::test_stack_at_rest_carries_weight",
            "tests/test_scenes_mechanics.py::test_stack_drop_ends_stacked",
        ),
    ),
    Mutant(
        "equation_rows_scaled_by_h",
        "scenes",
        "nivpjax/_model.py",
        "alg_rho = jnp.where(self.equation_rows, self.tau, alg_rho)",
        "alg_rho = jnp.where(self.equation_rows, alg_rho, alg_rho)",
        "AbstractEffect's docstring: equation rows (O(1) sensitivity) are scaled rho = tau, "
        "not tau / h",
        (
            TN + "test_vi_iterations_do_not_grow_as_the_step_shrinks",
            "tests/test_scenes_switching.py::test_rectifier_currents",
            TE + "test_estimate_sees_an_equation_row",
        ),
    ),
    # ------------------------------------------------------------------- batched sweep
    Mutant(
        "batched_order_not_inverted",
        "batched",
        "nivpjax/_batched.py",
        "inverse[order] = np.arange(size)",
        "inverse[:] = order",
        "solve_batched's docstring: results come back in the members' original order",
        ("tests/test_batched.py::test_members_match_single_solves_in_original_order",),
    ),
    Mutant(
        "lockstep_waste_unsorted",
        "batched",
        "nivpjax/_batched.py",
        'order = np.arange(size) if cost is None else np.argsort(np.asarray(cost), kind="stable")',
        "order = np.arange(size)",
        "lockstep_waste's docstring: measured with the same chunk_size and cost as the run",
        ("tests/test_batched.py::test_members_match_single_solves_in_original_order",),
    ),
    # ----------------------------------------------------------------------- drop-in
    Mutant(
        "compat_h_down_default",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        'factormin=min(float(aopts.get("h_down", 0.2)), 1.0)',
        'factormin=min(float(aopts.get("h_down", 0.5)), 1.0)',
        "solve_ivp_ns's docstring: h_down's default 0.2 (issue 29's survivor)",
        (TC + "test_defaults_are_the_reference_ones",),
    ),
    Mutant(
        "compat_pi3040_swapped",
        "compat",
        "nivpjax/compat/_options.py",
        '"pi3040": (0.4, 0.3),',
        '"pi3040": (0.3, 0.4),',
        "the comment: presets (beta1, beta2) as beta1 = p + i, beta2 = -p (PI.3040: beta2 = -0.4)",
        (TC + "test_defaults_are_the_reference_ones",),
    ),
    Mutant(
        "compat_use_pi_default_off",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        'elif aopts.get("use_PI", True):',
        'elif aopts.get("use_PI", False):',
        "solve_ivp_ns's docstring: use_PI (default on, as the reference) is PI.3040",
        (TC + "test_defaults_are_the_reference_ones",),
    ),
    Mutant(
        "compat_rho0_to_alpha_max",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        'kw["alpha0"] = float(sopts["rho0"])',
        'kw["alpha_max"] = float(sopts["rho0"])',
        "the drop-in's option translation: the reference's rho0 is the VI's initial step",
        (
            TC + "test_given_options_arrive_where_the_reference_reads_them",
            TC + "test_defaults_are_the_reference_ones",
            TC + "test_spring_slider",
        ),
    ),
    Mutant(
        "compat_gap_tol_sign",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        "gap=lambda t, y, a: jnp.atleast_1d(gap(t, y)) - gap_tol,",
        "gap=lambda t, y, a: jnp.atleast_1d(gap(t, y)) + gap_tol,",
        "the drop-in's option translation: gap_tol shifts the contact (the reference "
        "enforces gap >= gap_tol)",
        (
            TC + "test_bouncing_ball",
            TC + "test_given_options_arrive_where_the_reference_reads_them",
            TC + "test_defaults_are_the_reference_ones",
        ),
    ),
    Mutant(
        "compat_method_order_off_by_one",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        "error_order=None if order is None else int(order) + 1,",
        "error_order=None if order is None else int(order),",
        "the drop-in's option translation: the reference's method_order p controls with "
        "exponent 1/(p + 1)",
        (
            TC + "test_given_options_arrive_where_the_reference_reads_them",
            TC + "test_defaults_are_the_reference_ones",
        ),
    ),
    Mutant(
        "compat_theta_default",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        'Theta(theta=float(iopts.get("theta", 0.5)), solver=solver)',
        'Theta(theta=float(iopts.get("theta", 1.0)), solver=solver)',
        "the drop-in's defaults are the reference's (theta 0.5)",
        (TC + "test_defaults_are_the_reference_ones",),
    ),
    Mutant(
        "compat_solver_tol_default",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        'tol = float(sopts.get("tol", 1e-10))',
        'tol = float(sopts.get("tol", 1e-8))',
        "the drop-in's defaults are the reference's (solver tol 1e-10)",
        (TC + "test_defaults_are_the_reference_ones",),
    ),
    Mutant(
        "compat_vi_L_to_kappa",
        "compat",
        "nivpjax/compat/solve_ivp_ns.py",
        'kw["nu"] = float(sopts["L"])',
        'kw["kappa"] = float(sopts["L"])',
        "the drop-in's option translation: the reference's L is the VI's acceptance threshold nu",
        (
            TC + "test_given_options_arrive_where_the_reference_reads_them",
            TC + "test_defaults_are_the_reference_ones",
        ),
    ),
    # ------------------------------------------- comment audit (issue 29, item 2)
    Mutant(
        "located_start_skip_dropped",
        "events",
        P + "located.py",
        "own = jnp.where(own <= START_SKIP * ctx.h, ahead, own)",
        "own = own",
        "EventLocated.next_event's comment: a switch this close to the start is the start's; "
        "predicting it hid the step's events (measured: a Filippov spiral at its Zeno point "
        "at t = 0.16 instead of 1.08, successful)",
        (
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point[be-300.0-0.02-1e-09]",
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point[be-10.0-0.1-1e-09]",
            "tests/test_filippov.py::test_invariant_or_failure_code[be-newton]",
        ),
    ),
    Mutant(
        "located_secant_when_off_surface",
        "events",
        P + "located.py",
        "return jnp.where(off, ahead, out)",
        "return out",
        "EventLocated.next_event's docstring: a surface approached from one side is predicted "
        "by the quadratic through the end values and rate, not the secant (measured: 46 "
        "attempts against 34 into a relay's sliding)",
        (TEV + "test_relay_sliding_entry_is_predicted_from_the_rates",),
    ),
    Mutant(
        "located_no_hermite_excursion",
        "events",
        P + "located.py",
        "size = jnp.maximum(size, jnp.where(away, excursion, 0.0))",
        "size = size",
        "EventLocated.violation's docstring: a crossing and back inside a step counts "
        "(measured: a diode bridge stepped over a conduction pulse, 9% off, successful)",
        (
            TEV + "test_a_step_does_not_jump_over_a_conduction_pulse",
            TEV + "test_hermite_excursion_measures_a_crossing_and_back",
            "tests/test_scenes_switching.py::test_rectifier_conduction_intervals",
        ),
    ),
    Mutant(
        "located_end_branch_derivative",
        "gradients",
        P + "located.py",
        "return jnp.where(late, moved, out)",
        "return out",
        "EventLocated._start_branch's docstring: a stage crossing a kink in its second half "
        "takes the start branch's derivative (the rectifier's measured 6% predates event "
        "landing: its derivatives are now the same without; pinned at one projector call)",
        (
            TEV + "test_a_late_kink_takes_the_start_branch_derivative",
            TS + "test_rectifier_converges_to_exact_derivative",
            TS + "test_rectifier_derivative_after_a_step_over_the_turn_off",
        ),
    ),
    Mutant(
        "locate_selections_off",
        "events",
        P + "located.py",
        "if isinstance(block, (Box, NonNegative)) and rows.size and selection_rows[rows].all():",
        "if False and isinstance(block, (Box, NonNegative)):",
        "locate_selections' docstring: a relay written by hand gets the scene relay's event "
        "location (measured without: backward Euler reached a spiral's Zeno point at t = 0.22 "
        "instead of 1.08, successful)",
        (
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point[be-300.0-0.02-1e-09]",
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point[be-10.0-0.1-1e-09]",
            "tests/test_filippov.py::test_invariant_or_failure_code[be-newton]",
        ),
    ),
    Mutant(
        "coulomb_missed_breakaway_unchecked",
        "scenes",
        P + "coulomb.py",
        "return jnp.maximum(out, missed)",
        "return out",
        "CoulombFriction.violation's docstring: a step ending stuck under a force beyond the "
        "bound is a missed breakaway (the trapezoidal rule and Bathe check an average force)",
        (
            TP + "test_coulomb_violation_sees_a_missed_breakaway",
            "tests/test_scenes_mechanics.py::test_slider_stick_slip",
            "tests/test_hard_cases.py::test_stick_slip_under_slowly_growing_load[bathe]",
        ),
    ),
    Mutant(
        "weighed_stage_off",
        "steppers",
        "nivpjax/_model.py",
        "        if f_explicit is None or not self.has_weighed:\n            return None, None\n"
        "        if isinstance(theta, float)",
        "        if True:\n            return None, None\n        if isinstance(theta, float)",
        "Model._weighed_start's docstring: friction weighed at both ends of a stage (applied "
        "whole at the end: first order, measured 2.5e-3 off on a driven stick-slip slider)",
        (
            "tests/test_friction_order.py::test_second_order_at_fixed_steps[disk-bathe]",
            "tests/test_friction_order.py::test_adaptive_as_accurate_as_the_smooth_field"
            "[weakening-tr]",
        ),
    ),
    Mutant(
        "equation_rate_secant",
        "steppers",
        S + "one_leg.py",
        "return model.equation_rate(t, y, rate, args, rate)",
        "return rate",
        "Model.equation_rate's docstring: equation rows get their own rate, not the secant "
        "(measured: an estimate 500x too small on the half-wave rectifier)",
        (TE + "test_estimate_sees_an_equation_row",),
    ),
    # --- Issue 33: contacts held closed on curved gaps. ---
    Mutant(
        "contact_stage_normals_at_start",
        "projectors",
        P + "contact.py",
        "Wt, B = self._maps(ctx.t, ctx.y_iter, ctx.args, z.dtype)",
        "Wt, B = self._maps(ctx.t, ctx.y_prev, ctx.args, z.dtype)",
        "UnilateralContact._project: the stage's normals where it ends (with the start's, a "
        "body sliding along a curved wall ends approaching it: an impact per step, a stall)",
        (
            "tests/test_curved_contact.py::test_adaptive_error_falls_with_rtol[bead-bathe]",
            "tests/test_curved_contact.py::test_order_at_fixed_steps[bathe]",
        ),
    ),
    Mutant(
        "contact_end_normals_at_start",
        "projectors",
        P + "contact.py",
        "Wt1, _ = self._maps(ctx.t, ctx.y_iter, ctx.args, dtype)",
        "Wt1, _ = self._maps(ctx.t, ctx.y_prev, ctx.args, dtype)",
        "UnilateralContact._end: the end's normals (the start's read a body sliding along a "
        "curved wall as approaching: Bathe's first stage 'switched', its second restarted as "
        "backward Euler, order 1)",
        (
            "tests/test_curved_contact.py::test_order_at_fixed_steps[bathe]",
            "tests/test_curved_contact.py::test_adaptive_error_falls_with_rtol[bead-bathe]",
        ),
    ),
    Mutant(
        "normal_acceleration_without_curvature",
        "projectors",
        P + "contact.py",
        "return jax.jvp(normal_velocity, (jnp.asarray(y, dtype),), (rate,))[1]",
        "return self._maps(ctx.t, y, ctx.args, dtype)[0] @ ctx.restrict(rate)",
        "_normal_acceleration: the curvature term (dW^T/dt) v, v^2/R on a circular wall (a bead "
        "without gravity is pressed by it alone)",
        (
            "tests/test_curved_contact.py::test_order_at_fixed_steps[bathe]",
            "tests/test_curved_contact.py::test_adaptive_error_falls_with_rtol[bead-bathe]",
        ),
    ),
    Mutant(
        "batched_solve_singular_not_flagged",
        "projectors",
        "nivpjax/_linalg.py",
        "    return jnp.where(nonsingular, X, jnp.nan)",
        "    return X",
        "_looped: NaN where a pivot is zero, so `solve` flags a singular member of a batch",
        (TN + "test_batched_solves_emit_no_batched_lapack_call",),
    ),
    Mutant(
        "batched_solve_shared_matrix_columns",
        "projectors",
        "nivpjax/_linalg.py",
        "return jnp.moveaxis(X.reshape(n, axis_size, m), 1, 0), True",
        "return X.reshape(axis_size, n, m), True",
        "_lapack_batched: a shared matrix's batch of right-hand sides folded into columns and back",
        (TN + "test_batched_solves_emit_no_batched_lapack_call",),
    ),
    Mutant(
        "large_solve_transpose",
        "projectors",
        "nivpjax/_linalg.py",
        "lambda _, r: _lapack(A.T, r[:, None])[:, 0],",
        "lambda _, r: _lapack(A, r[:, None])[:, 0],",
        "_large: reverse mode solves with the transpose of A",
        (TN + "test_batched_solves_emit_no_batched_lapack_call",),
    ),
    Mutant(
        "held_gaps_sign",
        "projectors",
        P + "held_gap.py",
        "mu = _linalg.solve_or_nan(D, -jnp.where(held, gap, 0.0))",
        "mu = _linalg.solve_or_nan(D, jnp.where(held, gap, 0.0))",
        "HeldGaps: g(z) + W^T B mu = 0 on held contacts (the correction onto the gap)",
        (
            "tests/test_curved_contact.py::test_held_on_the_wall_with_its_reaction[bathe]",
            "tests/test_curved_contact.py::test_adaptive_error_falls_with_rtol[bowl-bathe]",
        ),
    ),
    Mutant(
        "frictional_contact_on_normal_part",
        "projectors",
        P + "contact_friction.py",
        "tangential = out - n * jnp.dot(n, out)",
        "tangential = out",
        "FrictionalContact: friction acts on the tangential part of the velocity only (the "
        "normal part is the contact's; equivalent on plastic contacts, whose normal part "
        "after the contact's impulse is zero: an elastic impact shows it)",
        (TBF + "test_friction_at_an_elastic_impact_is_tangential",),
    ),
    Mutant(
        "frictional_contact_bound_halved",
        "projectors",
        P + "contact_friction.py",
        "return out - project_ball(tangential, mu * _safe_norm(out - z))",
        "return out - project_ball(tangential, 0.5 * mu * _safe_norm(out - z))",
        "FrictionalContact: the friction impulse is bounded by mu times the normal impulse",
        (TBF + "test_order_at_fixed_steps[bathe]", TBF + "test_slide_to_stick[bathe]"),
    ),
    Mutant(
        "frictional_contact_stop_not_predicted",
        "projectors",
        P + "contact_friction.py",
        "stop = jnp.where(closed, secant_crossing(s0, s1, ctx.h), jnp.inf)",
        "stop = jnp.full_like(s0, jnp.inf)",
        "FrictionalContact.next_event: the stop predicted along the tangential speed's secant "
        "(Bathe's steps land on it instead of being rejected across it)",
        (TBF + "test_slide_to_stick[bathe]",),
    ),
    Mutant(
        "flat_frictional_contact_not_weighed",
        "projectors",
        P + "contact_friction.py",
        "        return np.ones(n, bool)\n",
        "        return self.contact.weighed_rows(n)\n",
        "FrictionalContact: its rows weighed on a flat gap too (the friction force turns with "
        "a velocity thrown across a slope: order 1 applied at the stage's end)",
        (
            "tests/test_flat_friction.py::test_order_at_fixed_steps[tr]",
            "tests/test_flat_friction.py::test_as_accurate_as_the_law_written_into_f[tr]",
        ),
    ),
    Mutant(
        "friction_anisotropic_mass_accepted",
        "projectors",
        "nivpjax/_scene/contact.py",
        "ok = ok and m[0, 0] > 0 and np.allclose(m, m[0, 0] * np.eye(m.shape[0]), rtol=0, atol=0)",
        "ok = ok and m[0, 0] > 0",
        "Contact(friction=): an anisotropic inverse mass refused (it couples the normal and "
        "tangential impulses, which FrictionalContact solves apart)",
        (TBF + "test_bad_friction_and_axes",),
    ),
    Mutant(
        "law_reaction_point_rounds_away",
        "projectors",
        "nivpjax/_model.py",
        "s = jnp.maximum(1e-6, jnp.sqrt(jnp.finfo(y.dtype).eps)) * jnp.where(h > 0, h, 1.0)",
        "s = 1e-6 * jnp.where(h > 0, h, 1.0)",
        "Model.law_reaction: its JVP's point moved off y where y + s f would round to y "
        "(float32: a resting contact read as open, the friction force lost at the start)",
        ("tests/test_flat_friction.py::test_float32_slide_up_a_slope",),
    ),
    Mutant(
        "persistent_teval_linear",
        "interpolation",
        "nivpjax/_loop.py",
        'y = jnp.where(q["rows"], cubic_hermite(y0, y1, q["m0"], q["m1"], w), y)',
        'y = jnp.where(q["rows"], y, y)',
        "t_eval on a curved contact pressed at both ends: cubic Hermite with the law's rates "
        "(linear velocities: 56x the steps' error)",
        (TBF + "test_t_eval_as_accurate_as_the_steps[bathe]",),
    ),
    Mutant(
        "persistent_teval_start_rate_free",
        "interpolation",
        "nivpjax/_loop.py",
        "p0, p1 = model.to_state(f0 + law0), model.to_state(f1 + law1)",
        "p0, p1 = model.to_state(f0), model.to_state(f1 + law1)",
        "t_eval on a persistent contact: the start's rate includes the law's reaction",
        (TBF + "test_t_eval_as_accurate_as_the_steps[bathe]",),
    ),
    Mutant(
        "moving_gap_accepted",
        "projectors",
        "nivpjax/_scene/curvature.py",
        "return _reads_inputs(closed.jaxpr, consts=False)",
        "return False",
        "Contact refuses a gap that reads the time (the laws take its rate as W^T v: a rising "
        "floor passed through a ball, 'successful')",
        ("tests/test_curved_contact.py::test_a_moving_surface_is_refused",),
    ),
    Mutant(
        "curved_contact_not_weighed",
        "projectors",
        "nivpjax/_scene/contact.py",
        "weighed=bool(self.curved),",
        "weighed=False,",
        "Contact(curved=True): the persistent contact's reaction weighed at both ends of the "
        "trapezoidal stages (applied whole at the stage's end along a turning normal: order 1)",
        (
            "tests/test_curved_contact.py::test_order_at_fixed_steps[tr]",
            "tests/test_curved_contact.py::test_order_at_fixed_steps[bathe]",
        ),
    ),
    Mutant(
        "bathe_weighed_reactions_linear",
        "steppers",
        S + "bathe.py",
        "r_mid = jnp.where(model.weighed, 2 * r_a - law0, r_mid)",
        "r_mid = jnp.where(model.weighed, r0 + g * (r_b - r0), r_mid)",
        "_stage_reactions: the weighed rows' reactions at the three nodes (a line drops out of "
        "the estimate: 7x below the error on the bowl, half the steps of the force in f)",
        (
            "tests/test_curved_contact.py::test_bowl_as_accurate_as_the_force_in_the_field",
            "tests/test_friction_order.py::test_adaptive_as_accurate_as_the_smooth_field[disk-bathe]",
        ),
    ),
    Mutant(
        "law_keeps_impacts",
        "projectors",
        P + "contact.py",
        "            start_active = self.pressed(ctx, z.dtype)",
        "            start_active = start_active",
        "ProjectionContext.law: the law's reaction keeps persistent contacts only (an impact's "
        "holding part read as a force)",
        (
            "tests/test_curved_contact.py::test_law_reaction_is_a_persistent_contacts_force_only",
            "tests/test_curved_contact.py::test_adaptive_error_falls_with_rtol[thrown-tr]",
        ),
    ),
    Mutant(
        "initial_multipliers_first_stage_only",
        "steppers",
        "nivpjax/_model.py",
        "jnp.where(rows & ok, be.value, y)",
        "jnp.where(rows & ok & False, be.value, y)",
        "Model.consistent_initial_state: a reaction acting through the velocity is determined "
        "by a backward Euler stage, not left at its guess (the trapezoidal rule rings)",
        (
            "tests/test_consistent_init.py::test_initial_reaction_is_the_physical_one",
            "tests/test_consistent_init.py::test_relay_started_on_its_surface_takes_the_equivalent_control",
        ),
    ),
    Mutant(
        "step_doubling_pi_sign",
        "controllers",
        C + "step_doubling.py",
        "jnp.where(use_prev, prev, 1.0) ** -beta",
        "jnp.where(use_prev, prev, 1.0) ** beta",
        "StepDoublingController: the reference's PI rule raises E_prev to -beta (its sign, "
        "kept for the baseline)",
        (
            "tests/test_step_doubling.py::test_decisions_on_hand_made_errors",
            "tests/test_step_doubling.py::test_same_steps_as_the_reference",
        ),
    ),
    Mutant(
        "contact_normals_positions_reversed",
        "contact",
        "nivpjax/_scene/contact.py",
        "basis = np.eye(self.n_states, dtype=x.dtype)[list(self.positions)]",
        "basis = np.eye(self.n_states, dtype=x.dtype)[list(self.positions)[::-1]]",
        "_Normals: forward mode along the positions' own unit vectors, in their order "
        "(W^T = dg/dq)",
        (
            "tests/test_curved_contact.py::test_held_on_the_wall_with_its_reaction",
            "tests/test_curved_contact.py::test_bowl_as_accurate_as_the_force_in_the_field",
        ),
    ),
    Mutant(
        "stored_residuals_overlap",
        "gradients",
        "nivpjax/_stored_loop.py",
        "self.sizes[dtype] = offset + a.size",
        "self.sizes[dtype] = offset + 0 * a.size",
        "_Packing: each residual has its own slice of its dtype's row (packing is exact)",
        (
            "tests/test_stored_adjoint.py::test_same_gradient_as_equinox_checkpointed_loop",
            "tests/test_stored_adjoint.py::test_matches_finite_differences",
        ),
    ),
    Mutant(
        "nonlinear_final_test_without_roundoff_floor",
        "nonlinear",
        N + "base.py",
        "converged = scaled_error(G_final, y_nd, rtol, atol, floor) <= 1",
        "converged = scaled_error(G_final, y_nd, rtol, atol) <= 1",
        "scaled_error: G's round-off is a few ulps of the projection's argument; a reaction "
        "the state does not determine (a pushed cone at rtol 1e-8) failed at t0 without it",
        (
            TN + "test_undetermined_reaction_converges_at_round_off",
            "tests/test_consistent_init.py::test_cone_in_slip_starts_at_tight_tolerance",
        ),
    ),
    Mutant(
        "newton_loop_without_roundoff_floor",
        "nonlinear",
        N + "semismooth_newton.py",
        "& ((k == 0) | (scaled_error(g, y, rtol, atol, z) > 1))",
        "& ((k == 0) | (scaled_error(g, y, rtol, atol) > 1))",
        "SemismoothNewton stops at round-off too: without the floor it alternated between "
        "4.5e-13 and 4e4 on the cone's undetermined reaction for all its iterations",
        (
            TN + "test_undetermined_reaction_converges_at_round_off",
            "tests/test_consistent_init.py::test_cone_in_slip_starts_at_tight_tolerance",
        ),
    ),
    Mutant(
        "es_centre_not_evaluated",
        "learning",
        "nivpjax/learn/_estimators.py",
        "([flat[None]] if centre else [])",
        "([flat[None] + sigma * eps[:1]] if centre else [])",
        "es_gradient(centre=True) appends L(theta) itself (the value a training step "
        "descends from)",
        ("tests/test_learn.py::test_es_gradient_quadratic",),
    ),
    Mutant(
        "start_switch_not_shifted",
        "steppers",
        "nivpjax/_model.py",
        "y0_start = jnp.where(self.algebraic, y0_start, y0_start + jump * skipped)",
        "y0_start = jnp.where(self.algebraic, y0_start, y0_start + jump * (skipped - "
        "jax.lax.stop_gradient(skipped)))",
        "Model.start_state: a switch moved to the step's start shifts the differential rows "
        "by skipped (f- - f+) in value (before: zero in value, a margin-sized error per "
        "switch that did not fall with rtol)",
        ("tests/test_filippov_trust.py::test_spiral_through_zeno_point",),
    ),
    Mutant(
        "start_switch_counted_as_violation",
        "projectors",
        P + "located.py",
        "crossed = crossed & ~self._switched_at_start(ctx, s0, ds0)",
        "crossed = crossed",
        "EventLocated.violation: crossing the switch the step's start took is no error "
        "(counted, a step landing 1e-8 of its size short of it was rejected at every size "
        "at rtol 1e-9)",
        ("tests/test_filippov_trust.py::test_spiral_through_zeno_point",),
    ),
    Mutant(
        "end_switch_hides_the_next",
        "projectors",
        P + "located.py",
        "own = jnp.where(own <= end, ahead, own)",
        "own = own",
        "EventLocated.next_event with after_end: a switch inside the attempt or at its end "
        "is past, and its surface's next one sizes the next step (else up to five attempts "
        "per switch of a spiral)",
        (
            "tests/test_event_prediction.py::test_a_switch_crossed_by_an_accepted_step_is_past",
            "tests/test_filippov_trust.py::test_spiral_through_zeno_point",
        ),
    ),
    Mutant(
        "far_branch_not_predicted",
        "projectors",
        P + "located.py",
        "self._switches_at_end(ctx, ds1),",
        "self._switches_at_end(ctx, ds1) & False,",
        "EventLocated._predict: after a switch at the end, the far branch's tangent line "
        "from the next step's start, not the quadratic through the step's values",
        ("tests/test_filippov_trust.py::test_spiral_through_zeno_point",),
    ),
    Mutant(
        "accepted_step_sized_by_the_crossed_event",
        "events",
        C + "events.py",
        "to_event = jnp.where(accept, info.next_event_after_end - info.h, info.next_event)",
        "to_event = info.next_event - jnp.where(accept, info.h, 0.0)",
        "land_before_event: after an acceptance the first event after the attempt's end "
        "sizes the next step; a switch the attempt crossed hid it, and a spiral's steps "
        "crossed one switch each in a cycle that did not approach the origin (reference "
        "controller options)",
        ("tests/test_filippov_trust.py::test_spiral_through_zeno_point",),
    ),
    Mutant(
        "negligible_switches_landed_on",
        "projectors",
        P + "located.py",
        "return (own > ctx.h) & ((own - ctx.h) * per_time <= NEGLIGIBLE)",
        "return (own > ctx.h) & ((own - ctx.h) * per_time <= 0.0)",
        "EventLocated._negligible: switches within a quarter of the tolerance are stepped "
        "over, not resolved down to round-off",
        ("tests/test_filippov_trust.py::test_spiral_through_zeno_point",),
    ),
    Mutant(
        "vi_without_anderson",
        "nonlinear",
        N + "fixed_point.py",
        "return y_a, R_a, y_bar_a, allowed & (count >= 2) & ok & better",
        "return y_a, R_a, y_bar_a, allowed & (count >= 2) & ok & better & False",
        "FixedPointVI: Anderson's extrapolation passes a rotation-dominated stage (a "
        "spiral's step into its Zeno point), where the moves contract at 1 - mu/L",
        ("tests/test_filippov_trust.py::test_spiral_through_zeno_point_with_the_vi_method",),
    ),
    Mutant(
        "vi_anderson_unconstrained",
        "nonlinear",
        N + "fixed_point.py",
        "rhs = jnp.zeros(m + 1, Ys.dtype).at[m].set(1.0)",
        "rhs = jnp.zeros(m + 1, Ys.dtype).at[m].set(0.0)",
        "_anderson: the coefficients sum to one (else the extrapolation is 0)",
        ("tests/test_filippov_trust.py::test_spiral_through_zeno_point_with_the_vi_method",),
    ),
    Mutant(
        "violation_scale_counts_the_multipliers",
        "controllers",
        "nivpjax/_norms.py",
        "y0 = jnp.abs(y0) if mask is None else jnp.where(mask, jnp.abs(y0), 0.0)",
        "y0 = jnp.abs(y0)",
        "violation_scale: over the rows the error norm judges (a relay's |w| = 1 set the "
        "scale of a small state to rtol, and its crossed switches went unseen)",
        ("tests/test_filippov_trust.py::test_a_relay_on_a_small_state_is_judged_on_its_state",),
    ),
    Mutant(
        "vi_stops_above_the_residual_round_off",
        "nonlinear",
        N + "fixed_point.py",
        "floor = jnp.abs(argument) + alpha * rho * noise / jnp.minimum(1.0, alpha)",
        "floor = jnp.abs(argument)",
        "FixedPointVI stops, once stalled, at the round-off of rho R's terms: a selection "
        "row scaled by 1/h cannot fall below eps |x| / h",
        (
            "tests/test_filippov_trust.py::test_a_tiny_stage_on_the_sliding_surface_converges_at_round_off"
            + "[FixedPointVI]",
        ),
    ),
    Mutant(
        "final_check_above_the_residual_round_off",
        "nonlinear",
        N + "base.py",
        "floor = jnp.abs(lax.stop_gradient(z)) + rho * residual_scale(residual, y_nd)",
        "floor = jnp.abs(lax.stop_gradient(z))",
        "AbstractNonlinearSolver.solve's final check counts the round-off of rho R's terms",
        (
            "tests/test_filippov_trust.py::test_a_tiny_stage_on_the_sliding_surface_converges_at_round_off"
            + "[FixedPointVI]",
        ),
    ),
]

# Equivalent mutants, excluded from the list and the score (standard practice: a mutant no
# test can kill measures nothing). Each was run and survived; the reason says why no test
# can fail. Listed on docs/development/mutation.md.
EQUIVALENT = {
    "interpolation_second_order_sliding_stage_rates": (
        "nivpjax/_loop.py",
        "f0, f1 = model.f(t0, ends0, args), model.f(t1, ends1, args)  ->  "
        "f0, f1 = model.f(t0, y0, args), model.f(t1, y1, args)",
        "since `_held.on_second_order_surface` moves the state at t_eval onto sigma' = 0 "
        "in a second-order sliding mode, the end rates of the rows it moves (super-"
        "twisting's nu, the only rate the stage's ringing selection changes) no longer "
        "reach the output, and the rows it does not move (x1, x2) have rates that do not "
        "depend on w on the surface (k1 sqrt|sigma| = 0). Survived "
        "test_t_eval_as_right_as_the_steps (38 s). Kept: the cubic it feeds is what the "
        "output falls back to where the second-order control leaves its set inside the "
        "step, and there the phase's rates are the right ones.",
    ),
    "second_order_newton_moves_selections": (
        "nivpjax/_held.py",
        "return jnp.where(model.algebraic, 0.0, _rate(model, tt, yy, args))  ->  "
        "return _rate(model, tt, yy, args)",
        "the rows `second_order_ends` moves are those whose first-order constraint hardly "
        "depends on them (`_linearisation`'s `on` false: d sigma'/dw below 1e-3 of its "
        "reach, super-twisting's k1 sqrt|sigma| = 0 on the surface), so a rate given to "
        "the selections enters sigma'' through d sigma'/dw only: nothing on super-twisting. "
        "Survived test_t_eval_as_right_as_the_steps (356 s, loaded machine). Kept: with "
        "the selections held, sigma'' is the second derivative the docstring states.",
    ),
    "tangent_solve_jacobian_at_b": (
        N + "base.py",
        "J = jax.jacfwd(g)(jnp.zeros_like(b))  ->  J = jax.jacfwd(g)(b)",
        "g is the linearisation of G at the solution, linear: its Jacobian is the same at "
        "every point, and the primal value g(b) that jacfwd computes on the way is unused, "
        "so JAX drops it and the program stays linear in b (reverse mode transposes it "
        "unchanged). Survived the reverse-mode gradient tests (15 s). The comment's reason "
        "(keep b out of everything but the solve) is a clarity choice, now said so.",
    ),
    "bathe_reaction_constant": (
        S + "bathe.py",
        "r0 = (2 * r_a - g * r_b) / (2 - g)  ->  r0 = r_a",
        "r_mid = r0 + g (r_b - r0) puts the three reactions on a line in time whatever r0 "
        "is, and bathe_error (the second divided difference on the nodes 0, gamma, 1) is "
        "zero on any line: the estimate is f's up to rounding (~1e-19 against 1e-7 on the "
        "super-twisting run). Survived its area tests (28 s). The lines are kept: removing "
        "them changes the estimate at rounding level, which tipped the super-twisting test "
        "into max_steps.",
    ),
    "frictional_contact_no_stop_violation": (
        P + "contact_friction.py",
        "through = closed & (s1 < 0)  ->  through = closed & (s1 < -jnp.inf)",
        "redundant with the stop's secant prediction (next_event) on the slide: the "
        "predicted stops end steps, so no accepted step crosses one. With the violation "
        "removed, Bathe's runs at rtol 1e-3 to 1e-6 took the same steps to the same errors "
        "and stick times (measured by patching it out); survived test_slide_to_stick "
        "(Bathe, TR, 220 s). Kept as the charge for a stop the secant misses.",
    ),
    "batched_pad_short": (
        "nivpjax/_batched.py",
        "min(chunk_size, size)  ->  max(chunk_size, size)",
        "one chunk of all the members instead of several: the members are independent "
        "under vmap, so every result is the same; only the memory and the lock-step cost "
        "change, which no result shows. Survived the batched tests (6 s).",
    ),
}
