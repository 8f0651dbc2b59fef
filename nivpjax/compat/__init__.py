"""Compatibility with the reference package `solve_nivp`: translation and option checking
only; all numerics live in the core."""

from .solve_ivp_ns import solve_ivp_ns as solve_ivp_ns
