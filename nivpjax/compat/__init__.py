"""Compatibility with the reference package `solve_nivp`: translation and option checking
only; all numerics live in the core. Models written with NumPy run on the host
(`NumpyModelWarning`); a model that cannot run raises `ModelError`."""

from ._host import ModelError as ModelError, NumpyModelWarning as NumpyModelWarning
from .solve_ivp_ns import solve_ivp_ns as solve_ivp_ns
