"""CIE 171:2006 analytical test cases, engine level: `python bench/cie171.py` prints, for every
implemented case and point, the expected value (published table or closed form), hirad's
value and the error in %, and each case's wall time: 5.2, 5.3, 5.4, 5.8 here, then 5.6 and 5.7
(bench/cie171_56_57.py, run from here too). The scenes and runners are the tests'
(tests/python/photometry/cie171_scenes.py, cie171_cases.py); the tests' tolerances are 1 % (5.2,
5.3, 5.8), 0.2 % (5.4), 2 % (5.6, 5.7, and 5.8 through the illuminance binding's sensors) and
0.5 % (free-space square)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python" / "photometry"))

import cie171_scenes as cie  # noqa: E402


def row(case: str, point: str, expected: float, got: float, tol: float) -> str:
    err = 100.0 * (got - expected) / expected
    flag = "" if abs(err) <= tol else "  FAIL"
    return f"{case:<24} {point:<22} {expected:>10.2f} {got:>10.2f} {err:>+8.3f}{flag}"


def main() -> int:
    t_all = time.perf_counter()
    print(f"{'case':<24} {'point':<22} {'expected':>10} {'hirad':>10} {'error %':>8}")
    failures = 0

    rows, dt = cie.timed(cie.run_case_52)
    for name, table, closed, got in rows:
        line = row("5.2 point source (lx)", f"{name} (closed {closed:.2f})", table, got, 1.0)
        failures += line.endswith("FAIL")
        print(line)
    print(f"{'':<24} {'wall time':<22} {dt:>10.2f} s")

    for method in ("flat", "hierarchical", "out_of_core"):
        (lumens, got, n), dt = cie.timed(cie.run_case_54, method)
        line = row(f"5.4 flux, {method[:4]} (lm)", f"absorbed ({n} p)", lumens, got, 0.2)
        failures += line.endswith("FAIL")
        print(f"{line}   {dt:.2f} s")

    rows, dt = cie.timed(cie.run_case_53)
    for name, expected, got, _d, _i in rows:
        line = row("5.3 area source (lx)", name, expected, got, 1.0)
        failures += line.endswith("FAIL")
        print(line)
    print(f"{'':<24} {'wall time':<22} {dt:>10.2f} s")

    rows, dt = cie.timed(cie.run_free_square)
    for h, expected, got in rows:
        line = row("free square axis (lx)", f"h = {h:g} m", expected, got, 0.5)
        failures += line.endswith("FAIL")
        print(line)
    print(f"{'':<24} {'wall time':<22} {dt:>10.2f} s")

    for method in ("flat", "hierarchical"):
        for rho in cie.REFLECTANCES_58:
            (expected, got, patches), dt = cie.timed(cie.run_case_58, rho, method)
            line = row(f"5.8 cube mean, {method[:4]} (lx)", f"rho {rho:g} ({patches} p)", expected, got, 1.0)
            failures += line.endswith("FAIL")
            print(f"{line}   {dt:.2f} s")

    for rho in (0.25, 0.5, 0.75):
        (expected, got, sensors), dt = cie.timed(cie.run_case_58_sensors, rho)
        line = row("5.8 cube, sensors (lx)", f"rho {rho:g} ({sensors} s)", expected, got, 2.0)
        failures += line.endswith("FAIL")
        print(f"{line}   {dt:.2f} s")

    print(f"total wall time {time.perf_counter() - t_all:.1f} s, {os.cpu_count()} cores, "
          f"load {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {failures} outside tolerance")
    print()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import cie171_56_57

    return 1 if cie171_56_57.main() or failures else 0


if __name__ == "__main__":
    sys.exit(main())
