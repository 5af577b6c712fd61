"""What the per-game profiles' watcher costs at rest (docs/performance.md, "At rest").

``neurotouch_hid.service.games.ProcessScanner`` lists ``/proc`` at every poll (``games.POLL_S``) and reads
each process's ``comm`` to notice an exec (a game a wrapper starts late); a process is read in full
only when new, young or renamed. This scans this machine's processes as the driver would, with a
map of one Steam app and one executable that do not run: a first scan (every process read), then
``--scans`` scans at rest, timed in CPU (``time.process_time``) and wall; and the same scans with
the ``comm`` read left out (what a scan cost before it), for the difference. Needs no root.

Run: ``python3 benchmarks/bench_games_scan.py [--scans 200]``; prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import psutil

from neurotouch_hid.service import games


def _per_scan(scanner: games.ProcessScanner, game_map: games.GameMap, scans: int) -> tuple[float, float]:
    """CPU and wall time per scan (ms) over ``scans`` scans."""
    cpu, wall = time.process_time(), time.perf_counter()
    for _ in range(scans):
        scanner.games(game_map)
    return (time.process_time() - cpu) * 1000 / scans, (time.perf_counter() - wall) * 1000 / scans


def measure(scans: int = 200) -> dict:
    game_map = games.GameMap({4_000_000_000: "mouse"}, {"no-such-game-here": "mouse"})
    scanner = games.ProcessScanner()
    cpu = time.process_time()
    scanner.games(game_map)
    first_ms = (time.process_time() - cpu) * 1000
    rest_cpu, rest_wall = _per_scan(scanner, game_map, scans)
    read = games._comm_bytes
    games._comm_bytes = lambda pid: scanner._seen[pid].comm if pid in scanner._seen else read(pid)
    try:
        listing_cpu, _ = _per_scan(scanner, game_map, scans)
    finally:
        games._comm_bytes = read
    return {
        "processes": len(psutil.pids()),
        "first_scan_cpu_ms": round(first_ms, 2),
        "scan_cpu_ms": round(rest_cpu, 3),
        "scan_wall_ms": round(rest_wall, 3),
        "scan_cpu_ms_without_comm": round(listing_cpu, 3),
        "cpu_share_at_poll_s": round(rest_cpu / 1000 / games.POLL_S, 5),
        "load_1min": round(os.getloadavg()[0], 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=200)
    print(json.dumps(measure(parser.parse_args().scans)))


if __name__ == "__main__":
    main()
