"""The SymPy back-end: symbolic derivatives, common subexpressions eliminated, one numba-compiled
loop over the stages per function (the measured alternative, docs/autodiff.md)."""

from __future__ import annotations

import numpy as np

from .numba_kernels import NumbaEvaluator, compile_kernel


class SympyBackend:
    """SymPy: symbolic derivatives, common subexpressions eliminated, one numba-compiled loop over
    the stages per function."""

    name = "sympy"

    def __init__(self):
        import sympy   # noqa: PLC0415 - the optional extra
        self.sp = sympy

    def vector(self, name, size):
        return self.sp.Matrix(self.sp.symbols(f"{name}0:{size}", real=True)) if size else self.sp.zeros(0, 1)

    def build(self, model):
        sp = self.sp
        x, u, d, xN = list(model.x), list(model.u), list(model.d), list(model.xN)
        n, m, r, rN = model.n, model.m, model.r, model.rN
        z = x + u
        sigma = sp.Symbol("sigma", real=True)
        p = list(sp.symbols(f"p0:{n}", real=True))
        lam = list(sp.symbols(f"lam0:{r}", real=True)) if r else []
        lamN = list(sp.symbols(f"lamN0:{rN}", real=True)) if rN else []
        f, l, g = [sp.sympify(e) for e in model.f], sp.sympify(model.l), [sp.sympify(e) for e in model.g]
        jac = lambda exprs, vs: [[sp.diff(e, v) for v in vs] for e in exprs]  # noqa: E731
        lag = sigma * l + sum(pi * fi for pi, fi in zip(p, f)) + sum(li * gi for li, gi in zip(lam, g))
        grad = [sp.diff(lag, v) for v in z]
        H = [[sp.diff(grad[i], z[j]) if j >= i else None for j in range(n + m)] for i in range(n + m)]
        Hs = lambda i, j: H[min(i, j)][max(i, j)]  # noqa: E731
        stage_in = [("X", x), ("U", u), ("D", d)]
        specs = {
            "dynamics": (stage_in, [f]),
            "stage_cost": (stage_in, [l]),
            "dynamics_jacobian": (stage_in, [jac(f, x), jac(f, u)]),
            "stage_cost_gradient": (stage_in, [[sp.diff(l, v) for v in x], [sp.diff(l, v) for v in u]]),
            "stage_hessian": (stage_in + [("S", sigma), ("P", p), ("L", lam)],
                              [[[Hs(i, j) for j in range(n)] for i in range(n)],
                               [[Hs(i, n + j) for j in range(m)] for i in range(n)],
                               [[Hs(n + i, n + j) for j in range(m)] for i in range(m)]]),
        }
        if r:
            specs["stage_constraints"] = (stage_in, [g])
            specs["stage_constraints_jacobian"] = (stage_in, [jac(g, x), jac(g, u)])
        F, gN = sp.sympify(model.F), [sp.sympify(e) for e in model.gN]
        specs["final"] = ([("X", xN)], [F, [sp.diff(F, v) for v in xN], gN, jac(gN, xN)])
        flag = sigma * F + sum(li * gi for li, gi in zip(lamN, gN))
        specs["final_hessian"] = ([("X", xN), ("S", sigma), ("L", lamN)], [jac([sp.diff(flag, v) for v in xN], xN)])
        return {name: self._compile(name, ins, outs) for name, (ins, outs) in specs.items()}

    def _compile(self, name, inputs, outputs):
        """Python source of one loop over the stages writing every output entry, compiled by
        numba like the CasADi translation (:func:`compile_kernel`: every argument a (K, size)
        matrix, sigma (K, 1), an output's entries in C order)."""
        from sympy.printing.pycode import PythonCodePrinter   # noqa: PLC0415
        sp = self.sp
        flat, targets, shapes = [], [], []
        for o, out in enumerate(outputs):
            arr = np.array(out, dtype=object)
            shapes.append(arr.shape)
            for j, idx in enumerate(np.ndindex(arr.shape)):
                flat.append(sp.sympify(arr[idx]))
                targets.append(f"o{o}[i, {j}]")
        subs, reduced = sp.cse(flat, symbols=sp.numbered_symbols("t"), optimizations="basic")
        printer = PythonCodePrinter({"standard": "python3", "fully_qualified_modules": True})
        args = [nm for nm, _ in inputs]
        lines = [f"def kernel({', '.join(args + [f'o{o}' for o in range(len(outputs))])}):",
                 f"    for i in range({args[0]}.shape[0]):"]
        for nm, syms in inputs:
            for j, sym in enumerate([syms] if nm == "S" else syms):
                lines.append(f"        {sym} = {nm}[i, {j}]")
        for sym, expr in subs:
            lines.append(f"        {sym} = {printer.doprint(expr)}")
        for tgt, expr in zip(targets, reduced):
            lines.append(f"        {tgt} = {printer.doprint(expr)}")
        if not targets:
            lines.append("        pass")
        kernel = compile_kernel("\n".join(lines) + "\n", len(inputs) + len(outputs))
        return NumbaEvaluator(kernel, shapes, flat=True)
