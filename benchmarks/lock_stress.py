"""The output folder's lock under stress: several processes take and release the real lock
(datapipe/io/outdir.py, OutLock) in a loop; while holding it each one creates a marker file with
O_CREAT | O_EXCL and removes it before releasing. A marker that already exists is a double holder.

    .venv/bin/python benchmarks/lock_stress.py [--procs 4] [--acquisitions 12000] [--out DIR]

Prints `acquisitions N refused R seconds S double holders D` (the last line). A refused acquire
(another process holds the lock) is tried again. tests/test_outdir_by_record.py runs a small version.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import sys
import tempfile
from pathlib import Path

from harness import ROOT, Stopwatch, parser

sys.path.append(str(ROOT))     # PYTHONPATH first: another checkout can be measured

from datapipe.io.outdir import OutLock, OutputStateError  # noqa: E402

MARKER = "holder.marker"


def hammer(out: str, n: int, start, results) -> None:
    out = Path(out)
    got = refused = double = 0
    start.wait()
    while got < n:
        lock = OutLock(out)
        try:
            lock.acquire()
        except OutputStateError:
            refused += 1
            continue
        try:
            fd = os.open(out / MARKER, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            os.close(fd)
            os.unlink(out / MARKER)
        except FileExistsError:
            double += 1                    # another process holds it too (its marker is there)
        got += 1
        lock.release()
    results.put((got, refused, double))


def stress(out: Path, procs: int, acquisitions: int) -> tuple[int, int, int, float]:
    out.mkdir(parents=True, exist_ok=True)
    ctx = mp.get_context("fork")
    start, results = ctx.Event(), ctx.Queue()
    each = -(-acquisitions // procs)
    ps = [ctx.Process(target=hammer, args=(str(out), each, start, results)) for _ in range(procs)]
    for p in ps:
        p.start()
    with Stopwatch() as clock:
        start.set()
        totals = [results.get() for _ in ps]
        for p in ps:
            p.join()
    return (sum(t[0] for t in totals), sum(t[1] for t in totals), sum(t[2] for t in totals), clock.wall_s)


def main() -> None:
    ap = parser(__doc__, quick="--procs 2 --acquisitions 500")
    ap.add_argument("--procs", type=int, default=4)
    ap.add_argument("--acquisitions", type=int, default=12000)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    if args.quick:
        args.procs, args.acquisitions = 2, 500
    out = args.out or Path(tempfile.mkdtemp(prefix="lock_stress_")) / "OUT"
    got, refused, double, secs = stress(out, args.procs, args.acquisitions)
    print(f"acquisitions {got} refused {refused} seconds {secs:.1f} double holders {double}")


if __name__ == "__main__":
    main()
