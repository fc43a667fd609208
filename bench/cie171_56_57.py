"""CIE 171:2006 test cases 5.6 (light reflection over diffuse surfaces, scenario 2) and 5.7
(diffuse reflections with internal obstructions): `python bench/cie171_56_57.py` prints, for
each case, method (flat, hierarchical) and point, the published value (Table 17; the corrected
Table 19), the closed form at the sensor (Lambert's contour integral to the visible part of
S2), hirad's value (all in % of E / (E_2 rho)) and the errors in %, and each run's wall time.
The scenes and runners are the tests' (tests/python/photometry/cie171_cases.py; geometry and
sources in its docstring); the tests' tolerances are 2 % against the table and 1 % against
the closed form; J and K of 5.7 (0 in the table) within 0.01 absolute."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python" / "photometry"))

import cie171_cases as cases  # noqa: E402


def main() -> int:
    t_all = time.perf_counter()
    print(f"{'case':<22} {'point':<6} {'expected':>9} {'closed':>9} {'hirad':>9} {'err tab %':>10} {'err cf %':>9}")
    failures = 0
    for case, label in (("5.6", "5.6 scen. 2"), ("5.7", "5.7 obstruction")):
        for method in ("flat", "hierarchical"):
            t = time.perf_counter()
            r = cases.run(case, method)
            dt = time.perf_counter() - t
            for name, expected, closed, got in zip(r.names, r.expected, r.closed, r.hirad):
                if expected == 0:
                    bad = abs(got) > 0.01
                    et, ec = "(0)", "(0)"
                else:
                    e_t, e_c = 100 * (got - expected) / expected, 100 * (got - closed) / closed
                    bad = abs(e_t) > 2.0 or abs(e_c) > 1.0
                    et, ec = f"{e_t:+.3f}", f"{e_c:+.3f}"
                failures += bad
                print(f"{label + ', ' + method[:4]:<22} {name:<6} {expected:>9.3f} {closed:>9.3f} {got:>9.3f} "
                      f"{et:>10} {ec:>9}{'  FAIL' if bad else ''}")
            print(f"{'':<22} {'time':<6} {dt:>9.2f} s  ({r.patches} patches, E_2 on S2 "
                  f"{r.s2_illuminance.min():.3f}..{r.s2_illuminance.max():.3f} lx)")
    print(f"total wall time {time.perf_counter() - t_all:.1f} s, {os.cpu_count()} cores, "
          f"load {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {failures} outside tolerance")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
