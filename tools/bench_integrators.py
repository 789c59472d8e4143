"""Time one integrator step for banks of 1, 16, 1 000 and 100 000 springs (not a test).

Prints µs per step and million spring-steps per second for every method, on the path the
integrator picks by itself (pure Python up to ``small_bank_limit`` springs, numpy above) and, with
``--both``, on the other path too, which shows where the crossover lies.

Goals: ≤ 10 µs per RK4 step for one spring (the 1 kHz loop), ≥ 30 M spring-steps/s at
100 000 springs. Timings are the best of several repeats; other load on the machine only slows them.

    python tools/bench_integrators.py [--both] [--sizes 1 16 1000 100000] [--methods rk4 euler]
"""

from __future__ import annotations

import argparse
import timeit

import numpy as np

from hilsim.dynamics.integrators import INTEGRATORS, make_integrator
from hilsim.dynamics.springs import Spring


def time_step(method: str, n: int, *, vectorized: bool | None, held_target: bool) -> float:
    """Best-of-repeats seconds for one ``step`` of an n-spring bank."""
    rng = np.random.default_rng(0)
    spring = Spring(m=1.0, c=rng.uniform(0.1, 1.0, n), k=rng.uniform(5.0, 20.0, n))
    integrator = make_integrator(method, spring, vectorized=vectorized)
    x = rng.uniform(-1.0, 1.0, n)
    v = np.zeros(n)
    target = (np.zeros(n), np.zeros(n)) if held_target else None
    h = 1e-3

    def one() -> None:
        integrator.step(x, v, h, 0.0, target)

    number = max(5, min(20_000, 2_000_000 // n))
    return min(timeit.repeat(one, number=number, repeat=7)) / number


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 16, 1000, 100_000])
    parser.add_argument(
        "--methods", nargs="+", default=list(INTEGRATORS), choices=list(INTEGRATORS)
    )
    parser.add_argument("--both", action="store_true", help="also time the path not chosen")
    parser.add_argument(
        "--target", action="store_true", help="pass a held (u, du) target, as the loop does"
    )
    args = parser.parse_args(argv)

    print(f"{'method':<20} {'n':>7} {'path':<11} {'µs/step':>10} {'M spring-steps/s':>17}")
    for method in args.methods:
        for n in args.sizes:
            auto = make_integrator(method, Spring(m=1.0, c=0.1, k=1.0 + np.zeros(n))).vectorized
            paths = [auto, not auto] if args.both else [auto]
            for vectorized in paths:
                seconds = time_step(method, n, vectorized=vectorized, held_target=args.target)
                label = "numpy" if vectorized else "python"
                if args.both and vectorized != auto:
                    label += " (alt)"
                print(
                    f"{method:<20} {n:>7} {label:<11} {seconds * 1e6:>10.2f} "
                    f"{n / seconds / 1e6:>17.2f}"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
