"""Simulator speed and fidelity benchmark; the same as `handful bench sim` (see there).

Usage: python benchmarks/sim_speed.py [--repeats 7] [--episodes 8] [--write docs/bench/sim.md]
"""

from app.cli.bench_sim import main

if __name__ == "__main__":
    main()
