"""FQLNK, the full-space quasi Lagrange-Newton-Krylov method of seed 002 (docs/fqlnk.md): layout
(the full-space unknown, c, G, H), bfgs (the damped BFGS (1,1) block), krylov (ILUTP-GMRES),
merit (augmented Lagrangian, Armijo backtracking), solver (options, loop, result)."""
