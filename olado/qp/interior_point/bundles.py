"""The bundles of arrays the interior-point QP's kernels take, each declared once here: the
kernels receive them as plain tuples and read them by these field names
(:func:`olado.linalg.codegen.as_bundle`); the Python side builds them from the same classes.

A change of a bundle's fields (their order included) changes the compiled kernels that read it (kernels.py,
kkt_map.py), whose numba caches do not see this file: delete their caches
(olado/qp/interior_point/__pycache__/*.nbi, *.nbc) after such a change.
"""

from __future__ import annotations

import collections

#: the fields of a point (an iterate or a direction), and the bundle of its arrays the kernels
#: take: states X (N+1, n), controls U (N, m), dynamics and equality multipliers lam (N+1, n),
#: nu (N+1, n_nu), and the slacks tl, tu and multipliers zl, zu of the finite box sides (flat over
#: the boxes, 0 on infinite sides)
PointArrays = collections.namedtuple("PointArrays", "X U lam nu tl tu zl zu")
#: the multiplier fields of a point (the dual step length moves them)
DUAL_FIELDS = ("lam", "nu", "zl", "zu")
#: the complementarity pairs of a point (the slacks w and multipliers lambda of (18)-(20), per
#: side of the boxes): what the elementwise kernels read of an iterate or a direction
Slacks = collections.namedtuple("Slacks", "tl tu zl zu")
#: the equations of the Newton system (22) / the KKT conditions (16)-(20), and the bundle of
#: their arrays: stationarity rx (N+1, n), ru (N, m), dynamics dyn (N, n), initial state x0r (n,),
#: equality rows rE (N, ne), rEN (neN,) and the box sides rl, rup (flat); also the bundle of
#: offsets of the residual kernel (kkt_map._kkt_map)
Residuals = collections.namedtuple("Residuals", "rx ru dyn x0r rE rEN rl rup")
#: the stage data of the residual kernel (kkt_map._kkt_map): the symmetric stage Hessians
#: H (N, n+m, n+m) and QN (n, n), AB = [A B] (N, n, n+m), the equality rows EF = [E F]
#: (N, ne, n+m), EFt its transpose and eqm (N, ne) their mask, EN (neN, n), the stage rows
#: C (N, nc, n+m), Ct its transpose, CN (ncN, n), and the finite sides fl, fu of the boxes
KKTData = collections.namedtuple("KKTData", "H QN AB EF EFt eqm EN C Ct CN fl fu")
