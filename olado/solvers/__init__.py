"""How problems are solved: the Solver base class and the solver families (paper 001 sec. 2.2)."""

from .base import Solver, SolverOptions, option
from .registry import SOLVERS, available_solvers, get_solver_class, register

__all__ = ["Solver", "SolverOptions", "option", "SOLVERS", "available_solvers", "get_solver_class", "register"]
