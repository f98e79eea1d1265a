"""The structure-exploiting SQP method (paper 001 sec. 4.2): the solver and its loop (solver.py), the
per-solve state (state.py), the phases of an iteration (phases.py), the QP step (step.py), the merit
function and line search (merit.py, line_search.py), the residuals (residuals.py) and the Hessian
approximations (hessian.py); see the docstring of solver.py."""
