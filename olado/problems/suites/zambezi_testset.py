"""The Zambezi testing set of paper 001 sec. 6 as data (244 problems): the six families at the
horizons of the paper -- zambezi N = 12:12:420, zambezi8 12:12:216, zambezi9 and zambezi10
12:12:72, zambezi11 12:12:432, zambezi12 12:12:252 (122 problems) -- each from two starts: the
balance controls (46)-(47) with simulated states, and the SIF start point (outflow = inflow, every
volume at V0; the project's reading of the paper's start (45), which is the same kind of
"outflow = inflow" trajectory). The inflow record only (``extend=None``: no cyclic extension
beyond the record). Paper 001's Figs. 4-8 on this set: ``python benchmarks/paper.py fig4`` ... ``fig8``.
"""

from __future__ import annotations

#: family -> horizons (paper 001 sec. 6)
GRID = {"zambezi": range(12, 421, 12), "zambezi8": range(12, 217, 12), "zambezi9": range(12, 73, 12),
        "zambezi10": range(12, 73, 12), "zambezi11": range(12, 433, 12), "zambezi12": range(12, 253, 12)}
STARTS = ("balance", "sif")
_SOURCE = "Błaszczyk, Karbowski, Malinowski (paper 001), sec. 6, the Zambezi testing set"

#: every entry of the set: family x horizon x start
ENTRIES = [
    {"name": family, "problem": family, "settings": {"N": N, "start": start, "extend": None},
     "source": _SOURCE, "published_note": "none published (the paper gives profiles only)", "group": family}
    for family, horizons in GRID.items() for N in horizons for start in STARTS
]
