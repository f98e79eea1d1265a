"""The working set of the active-set method and the factorizations of its equality-constrained
QPs (paper 001 sec. 4.2.2-4.2.3): every working set is the LQ-DOCP of the stage QP (14) with the
working set's constraints as equality rows, factored by the block Riccati recursion
(:class:`~olado.linalg.riccati.RiccatiFactorization`, Arnold's elimination with equality rows) in
O(N) and solved in O(N) per right-hand side.

Rows live in padded stage arrays E (N, cap, n), F (N, cap, m) -- the base rows (the QP's own
rows, fixed entries) in the first slots of each stage, the working set's constraints after them
-- and in a list of final rows (on x_N). A change of the working set writes or clears one slot
(removal moves the stage's last row into the freed slot). One factorization object is refactored
in place (the stage row counts written into its ``data.ne``), and only from the highest stage
whose rows changed since its last factorization downwards: the backward sweep's factors of the
later stages stay valid (``RiccatiFactorization.refactor(from_stage=k)``), so a change at stage k
costs O(k), not O(N). A new object is built when the number of final rows changes or the plain
recursion (no rows at all) no longer fits. A factorization keeps a copy of the slot map it was
computed with (solves and multipliers refer to it; valid until the next factorization) and its
count of *dropped* rows: rows the recursion found linearly dependent on the others (together
with x_0 = x0) -- a constraint whose addition raises this count is dependent on the working set
(Goldfarb and Idnani's case z = 0).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...linalg.riccati import RiccatiFactorization


@dataclasses.dataclass
class Factor:
    """A factorization of the EQP of one working set: the Riccati object, the slot map it was
    computed with (constraint ids per stage slot, -1 empty; ids of the final rows) and the number
    of rows the recursion dropped as dependent."""

    fact: RiccatiFactorization
    slots: np.ndarray
    final: np.ndarray
    drops: int

    def slot_of(self, cid, stage, N):
        """(stage or N, slot) of the constraint ``cid`` in this factorization."""
        if stage == N:
            return N, int(np.nonzero(self.final == cid)[0][0])
        return stage, int(np.nonzero(self.slots[stage] == cid)[0][0])

    def offsets(self, off):
        """The offsets e (N, cap), eN of the rows (``off``: per id, with a trailing 0 for -1)."""
        return off[self.slots], off[self.final]

    def multipliers(self, nu, n_ids):
        """The Riccati multipliers nu (N+1, *) of the rows, scattered over the constraint ids
        (0 for ids not in this working set)."""
        out = np.zeros(n_ids + 1)
        cap = self.slots.shape[1]
        out[self.slots] = nu[:-1, :cap]
        if self.final.size:
            out[self.final] = nu[-1, :self.final.size]
        out[-1] = 0.0
        return out[:-1]


def dropped_rows(fact):
    """Rows the recursion dropped as linearly dependent: the rows that reached x_0 (fixed by x0)
    and the dependent passed-back rows of every stage (RiccatiFactorization's nc, rank, ng)."""
    if fact.unconstrained:
        return 0
    N = fact.N
    return int(fact.ng[0] + np.sum(fact.nc - fact.rank - fact.ng[:N]))


class WorkingSet:
    """The working set's rows in padded stage arrays and the two alternating factorizations
    (module docstring)."""

    def __init__(self, qp, cons):
        self.qp, self.cons = qp, cons
        N, n, m = qp.N, qp.n, qp.m
        self.N = N
        base = cons.base_ids()
        stages = np.array([cons.stage(c) for c in base], dtype=np.int64)
        nb = np.bincount(stages[stages < N], minlength=N) if base else np.zeros(N, dtype=np.int64)
        # an independent row set at one stage has at most n + m rows, plus one trial row
        self.cap = cap = int(nb.max(initial=0)) + n + m + 1
        self.E = np.zeros((N, cap, n))
        self.F = np.zeros((N, cap, m))
        self.slots = np.full((N, cap), -1, dtype=np.int64)
        self.counts = np.zeros(N, dtype=np.int64)
        self.final = []
        self.members = set()
        self.dirty = N              # highest stage changed since the last factorization (N: all)
        for c in base:
            self._insert(c)
        self.base = frozenset(base)
        self._ineq = np.zeros(2 * cons.nw, dtype=bool)   # the working set's inequality sides
        self.Q, self.S, self.R = (np.ascontiguousarray(a, dtype=float) for a in (qp.Q, qp.S, qp.R))
        self.A, self.B = qp.A, qp.B
        self.fact = None            # the Riccati object, refactored in place
        self._EN, self._EN_ids = None, None   # the final rows (rebuilt when they change)
        self.factorizations = 0

    # ------------------------------------------------------------------ membership
    def _insert(self, cid):
        k, e, f = self.cons.row(cid)
        self.dirty = max(self.dirty, k)
        if k == self.N:
            self.final.append(cid)
        else:
            s = self.counts[k]
            self.slots[k, s] = cid
            self.E[k, s] = e
            self.F[k, s] = f
            self.counts[k] = s + 1
        self.members.add(cid)

    def add_many(self, ids):
        """Put the inequality sides ``ids`` into the working set at once (an initial working set);
        sides beyond a stage's capacity (cap - 1 rows: more cannot be linearly independent) are
        left out. Returns the ids added."""
        ids = np.asarray([c for c in np.asarray(ids, dtype=np.int64) if int(c) not in self.members], dtype=np.int64)
        if not ids.size:
            return ids
        N = self.N
        k, E, F = self.cons.rows(ids)
        stage = k < N
        order = np.argsort(k[stage], kind="stable")
        ks, idk = k[stage][order], ids[stage][order]
        Ek, Fk = E[stage][order], F[stage][order]
        slot = self.counts[ks] + np.arange(ks.size) - np.searchsorted(ks, ks, side="left")
        fit = slot < self.cap - 1
        ks, idk, Ek, Fk, slot = ks[fit], idk[fit], Ek[fit], Fk[fit], slot[fit]
        self.slots[ks, slot] = idk
        self.E[ks, slot] = Ek
        self.F[ks, slot] = Fk
        self.counts += np.bincount(ks, minlength=N)
        fin = ids[~stage]
        self.final.extend(int(c) for c in fin)
        added = np.concatenate([idk, fin])
        self.members.update(int(c) for c in added)
        self._ineq[added] = True
        if added.size:
            self.dirty = max(self.dirty, int(np.max(np.concatenate([ks, np.full(fin.size, N)]))))
        return added

    def reset(self):
        """Back to the base rows only."""
        for c in self.inequalities():
            self.remove(int(c))

    def add(self, cid):
        """Put the constraint ``cid`` into the working set."""
        if cid in self.members:
            raise ValueError(f"constraint {cid} is already in the working set")
        self._insert(cid)
        self._ineq[cid] = True

    def remove(self, cid):
        """Take the constraint ``cid`` out of the working set (never a base row)."""
        if cid in self.base:
            raise ValueError(f"constraint {cid} is a base row")
        k = self.cons.stage(cid)
        self.dirty = max(self.dirty, k)
        if k == self.N:
            self.final.remove(cid)
        else:
            s = int(np.nonzero(self.slots[k] == cid)[0][0])
            last = self.counts[k] - 1
            if s != last:
                self.slots[k, s] = self.slots[k, last]
                self.E[k, s] = self.E[k, last]
                self.F[k, s] = self.F[k, last]
            self.slots[k, last] = -1
            self.E[k, last] = 0.0
            self.F[k, last] = 0.0
            self.counts[k] = last
        self.members.discard(cid)
        self._ineq[cid] = False

    def inequalities(self):
        """The ids of the working set's inequality constraints (not base rows), as an array."""
        return np.nonzero(self._ineq)[0]

    def size(self):
        """The number of inequality constraints in the working set."""
        return len(self.members) - len(self.base)

    # ------------------------------------------------------------------ factorizations
    def factorize(self):
        """Factor the EQP of the present working set (module docstring); raises
        NotPositiveDefiniteError when a reduced Hessian is not positive definite (the next
        factorization is then a full one). The previous Factor's solves are invalid after this."""
        cons, N = self.cons, self.N
        final = np.array(self.final, dtype=np.int64)
        if self._EN_ids != self.final:
            self._EN = np.array([cons.row(c)[1] for c in self.final]).reshape(len(self.final), self.qp.n)
            self._EN_ids = list(self.final)
        EN = self._EN
        rows = bool(self.counts.any()) or final.size > 0
        fact = self.fact
        fits = (fact is not None and fact.data.neN == final.size
                and (not fact.unconstrained if rows else fact.unconstrained))
        dirty, self.dirty = self.dirty, N
        if fits:
            if rows:
                fact.data.ne[:] = self.counts
                if fact.data.EN is not EN:
                    fact.data.EN[:] = EN
            fact.refactor(from_stage=dirty if dirty < N else None)
        elif rows:
            self.fact = None
            fact = RiccatiFactorization(self.Q, self.S, self.R, self.A, self.B, E=self.E, F=self.F,
                                        n_eq=self.counts.copy(), EN=EN)
        else:
            self.fact = None
            fact = RiccatiFactorization(self.Q, self.S, self.R, self.A, self.B)
        self.fact, self.dirty = fact, -1
        self.factorizations += 1
        return Factor(fact, self.slots.copy(), final, dropped_rows(fact))
