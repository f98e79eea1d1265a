#!/usr/bin/env python3
"""Extract the numbers of the CUTEr ZAMB2 family into ``olado/problems/data/zambezi.json``.

The Zambezi reservoir benchmark of paper 001 sec. 5 (eqs. (40)-(47), Table 1) takes "the
historical data about natural inflows to reservoirs and all values of problem parameters ... from
the appropriate CUTER test problem files" ZAMB2.SIF, ZAMB2-8.SIF ... ZAMB2-11.SIF (E. Arnold
1996; reference: Arnold, Tatjewski, Wolochowicz, JOTA 81(1994) 221-248). The SIF files are not
part of this repository; this script reads them from ``../shared/data/cuter`` relative to the
repository root (override with ``--sif-dir``) and writes only the numbers.

What is read (a targeted reader, not a general SIF decoder):

* the raw ``RE``/``IE`` parameter lines of the data section (before ``VARIABLES``): inflows
  ``IN1j, IN2j, IN4j`` (j = 0..431, month j of the record starting January 1930), ``IN3``,
  evaporation ``E1j, E4j`` (j = 0..11, calendar month), the scalar parameters (NY, YEAR, PHI,
  VE, PSI, V10.., V1REF.., Q1REF, F2REF, Q3REF, Q4REF, PHI3, ALFA, SC);
* the ``XP`` element parameters A, B, C of the element uses FE1..FE4 (final energy), FA1..FA4
  (evaporation area) and F0E1, F0E3, F0E4 (water level in the energy terms);
* the ``XL``/``XU`` bounds of the volumes, outflows and spillages, including the month pattern
  of the lower bound of F2 (built in the SIF by a ``DO k ... DI k 12`` loop).

The record data, element parameters and bounds must be identical in all five files (the script
checks this); the per-family scalars are stored per family. ``zambezi12`` is not a SIF file: it
is ZAMB2-10 with PSI = 0 and start year 1945 (paper 001 sec. 5, "the influence of the reference
control trajectory Q_ref on the cost function was omitted").

Usage::

    python tools/extract_zambezi.py [--sif-dir DIR] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile

FILES = {
    "zambezi": "ZAMB2.SIF",
    "zambezi8": "ZAMB2-8.SIF",
    "zambezi9": "ZAMB2-9.SIF",
    "zambezi10": "ZAMB2-10.SIF",
    "zambezi11": "ZAMB2-11.SIF",
}
SCALARS = ["NY", "YEAR", "PHI", "VE", "PSI", "V10", "V20", "V30", "V40",
           "V1REF", "V2REF", "V3REF", "V4REF", "Q1REF", "F2REF", "Q3REF", "Q4REF",
           "PHI3", "ALFA", "SC"]
RECORD_MONTHS = 432          # January 1930 .. December 1965
FIRST_YEAR = 1930
SECTIONS = {"VARIABLES", "GROUPS", "CONSTANTS", "BOUNDS", "START POINT", "ELEMENT TYPE",
            "ELEMENT USES", "GROUP TYPE", "GROUP USES", "OBJECT BOUND", "ENDATA", "RANGES"}

# Derived-parameter statements every file must contain (their meaning is applied in
# olado/problems/zambezi.py; the script only checks that they are there, unchanged).
EXPECTED_DERIVED = [
    ("R*", "ALFA", "ALFA", "SC"), ("R*", "PHI", "PHI", "SC"), ("R*", "PSI", "PSI", "SC"),
    ("R*", "VE", "VE", "SC"), ("RD", "SPSI", "PSI", "1.0"), ("RD", "SPHI", "PHI", "1.0"),
    ("R*", "SPHI3", "PHI", "PHI3"), ("RD", "SPHI3", "SPHI3", "1.0"),
    ("RM", "MVE", "VE", "-1.0"), ("RM", "MALFA", "ALFA", "-1.0"),
]


def _number(text):
    return float(text.replace("D", "E").replace("d", "e"))


def _data_lines(path):
    """The SIF data section (up to the first ENDATA) without comments, split into sections."""
    sections, current = {"HEADER": []}, "HEADER"
    with open(path, encoding="ascii", errors="replace") as fh:
        for raw in fh:
            line = raw.rstrip("\n")
            if not line.strip() or line.lstrip().startswith("*"):
                continue
            line = line.split("$", 1)[0].rstrip()   # '$-PARAMETER' comments
            key = line.strip()
            if not line.startswith(" ") and key.split("  ")[0].strip() in SECTIONS | {"NAME"}:
                head = key.split("  ")[0].strip()
                if head == "ENDATA":
                    break
                if head == "NAME":
                    continue
                current = head
                sections[current] = []
                continue
            sections[current].append(line.split())
    return sections


def parse_sif(path):
    """Read one ZAMB2 SIF file; return dict(scalars, record, evaporation, elements, bounds)."""
    sec = _data_lines(path)
    params, derived = {}, []
    for f in sec["HEADER"]:
        if f[0] in ("RE", "IE") and len(f) == 3:
            params[f[1]] = _number(f[2])
        elif f[0] in ("R*", "RD", "RM"):
            derived.append(tuple(f))
    for d in EXPECTED_DERIVED:
        if d not in derived:
            raise ValueError(f"{path}: expected derived-parameter statement {' '.join(d)!r}")
    scalars = {k: params[k] for k in SCALARS}
    scalars["NY"], scalars["YEAR"] = int(scalars["NY"]), int(scalars["YEAR"])
    record = {f"IN{i}": [params[f"IN{i}{j}"] for j in range(RECORD_MONTHS)] for i in (1, 2, 4)}
    record["IN3"] = params["IN3"]
    evaporation = {f"E{i}": [params[f"E{i}{j}"] for j in range(12)] for i in (1, 4)}

    # element parameters: XP NAME(k) A value
    elements = {}
    for f in sec["ELEMENT USES"]:
        if f[0] == "XP":
            name = re.sub(r"\(k\)$", "", f[1])
            elements.setdefault(name, {})[f[2]] = _number(f[3])
    elem = {"FE": {}, "FA": {}, "FHQ": {}}
    for i in (1, 2, 3, 4):
        elem["FE"][str(i)] = elements[f"FE{i}"]
        elem["FA"][str(i)] = elements[f"FA{i}"]
    for i in (1, 3, 4):
        elem["FHQ"][str(i)] = elements[f"F0E{i}"]

    # bounds: stationary XL/XU on V*(k), Q*(k), F*(k); the F2 lower bound month pattern
    lower, upper, f2_month = {}, {}, {}
    loop = None   # (lo_offset, hi_offset) of an inner 'DO kk k+a k+b' loop
    for f in sec["BOUNDS"]:
        if f[0] == "DO" and f[1] == "kk":
            off = lambda s: 0 if s == "k" else int(s.split("+")[1])  # noqa: E731
            loop = (off(f[2]), off(f[3]))
        elif f[0] == "OD" and len(f) > 1 and f[1] == "kk":
            loop = None
        elif f[0] in ("XL", "XU"):
            var, val = f[2], _number(f[3])
            m = re.fullmatch(r"([VQF][1-4])\((k|kk|k\+\d+)\)", var)
            if m is None:
                raise ValueError(f"{path}: unexpected bound statement {' '.join(f)!r}")
            name, idx = m.groups()
            if idx == "k":
                if name == "F2" and f[0] == "XL":
                    raise ValueError(f"{path}: unexpected stationary lower bound of F2")
                (lower if f[0] == "XL" else upper)[name] = val
            else:
                if not (name == "F2" and f[0] == "XL"):
                    raise ValueError(f"{path}: unexpected stage-pattern bound {' '.join(f)!r}")
                months = range(loop[0], loop[1] + 1) if idx == "kk" else [int(idx[2:])]
                for mo in months:
                    if mo in f2_month:
                        raise ValueError(f"{path}: F2 lower bound of month {mo} set twice")
                    f2_month[mo] = val
    if sorted(f2_month) != list(range(12)):
        raise ValueError(f"{path}: F2 lower-bound pattern does not cover 12 months: {f2_month}")
    bounds = {}
    for name in ("V1", "V2", "V3", "V4", "Q1", "Q3", "Q4", "F1", "F2", "F3", "F4"):
        bounds[name] = [lower.get(name), upper.get(name)]   # None: unbounded (SIF 'FR DEFAULT')
    bounds["F2_lower_by_month"] = [f2_month[j] for j in range(12)]
    return dict(scalars=scalars, record=record, evaporation=evaporation, elements=elem,
                bounds=bounds)


def build(sif_dir):
    parsed = {fam: parse_sif(os.path.join(sif_dir, fn)) for fam, fn in FILES.items()}
    ref = parsed["zambezi10"]
    for fam, p in parsed.items():
        for key in ("record", "evaporation", "elements", "bounds"):
            if p[key] != ref[key]:
                raise ValueError(f"{FILES[fam]}: '{key}' differs from ZAMB2-10.SIF; the JSON "
                                 "layout assumes the family shares them")
    families = {}
    for fam, p in parsed.items():
        s = dict(p["scalars"])
        s["file"] = FILES[fam]
        s["max_N"] = 12 * (FIRST_YEAR + RECORD_MONTHS // 12 - s["YEAR"])
        families[fam] = s
    z12 = dict(families["zambezi10"])
    z12.update(file=None, derived_from="ZAMB2-10.SIF", PSI=0.0, YEAR=1945, NY=2,
               max_N=12 * (1966 - 1945),
               note="paper 001 sec. 5: zambezi10 with the reference outflow term removed "
                    "(PSI = 0), Franke and Arnold (1997); start year 1945 (Fig. 3: 1945-1946)")
    families["zambezi12"] = z12
    return {
        "source": ("CUTEr test problems ZAMB2.SIF, ZAMB2-8.SIF, ZAMB2-9.SIF, ZAMB2-10.SIF, "
                   "ZAMB2-11.SIF (optimal control of the Zambezi hydropower system; SIF files by "
                   "E. Arnold, 1/3/1996). Reference: E. Arnold, P. Tatjewski, P. Wolochowicz, "
                   "Two methods for large-scale nonlinear optimization and their comparison on a "
                   "case study of hydropower optimization, JOTA 81(1994)2, 221-248. Extracted by "
                   "tools/extract_zambezi.py; used in paper 001 sec. 5."),
        "units_and_indexing": (
            "Inflows IN1, IN2, IN4: list index j = (YEAR-1930)*12 + month (month 0 = January), "
            "j = 0..431 (1930-1965). IN3: constant local inflow of reservoir 3. E1, E4: "
            "evaporation coefficients by calendar month 0..11 (E1 is used for reservoirs 1, 2, 3 "
            "and E4 for reservoir 4, as in the SIF group uses). Elements: FE(V)=A V^2+B V+C "
            "(final energy), FA(V)=A V^2+B V+C (evaporation area), FHQ: level h(V)=A V^2+B V+C "
            "in Q*(h(V(k))+h(V(k+1))). Bounds: [lower, upper], null = unbounded; volume bounds "
            "apply to V(1..N) in the SIF (V(0) is fixed). F2_lower_by_month: lower bound of "
            "F2(k) for k mod 12. Scalars are the raw SIF values before the SIF multiplies ALFA, "
            "PHI, PSI, VE by SC."),
        "first_year": FIRST_YEAR,
        "record_months": RECORD_MONTHS,
        "record": ref["record"],
        "evaporation": ref["evaporation"],
        "elements": ref["elements"],
        "bounds": ref["bounds"],
        "families": families,
    }


def write_json_atomic(obj, path):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(obj, fh, indent=1)
            fh.write("\n")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def main(argv=None):
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sif-dir", default=os.path.join(root, "..", "shared", "data", "cuter"))
    ap.add_argument("--out", default=os.path.join(root, "olado", "problems", "data",
                                                  "zambezi.json"))
    args = ap.parse_args(argv)
    if not os.path.isdir(args.sif_dir):
        print(f"SIF folder not found: {args.sif_dir}", file=sys.stderr)
        return 1
    data = build(args.sif_dir)
    write_json_atomic(data, args.out)
    print(f"wrote {args.out}: {len(data['families'])} families, "
          f"{data['record_months']} months of inflows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
