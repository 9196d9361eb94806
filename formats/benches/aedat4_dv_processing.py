"""iniVation's dv-processing reading the AEDAT 4 files `bench_read` wrote (NEUSPIKE_BENCH_DUMP),
streaming (batch by batch, the events dropped) and collecting (all events into one store), in
million events per second, best of 5 runs, one thread.

    python -m venv /tmp/dv && /tmp/dv/bin/pip install dv-processing==2.0.4
    NEUSPIKE_BENCH_DUMP=/tmp/b cargo bench -p neuspike-formats --bench bench_read -- aedat4
    /tmp/dv/bin/python formats/benches/aedat4_dv_processing.py /tmp/b/aedat4_*.aedat4
"""

import sys
import time

import dv_processing as dv


def stream(path):
    r = dv.io.MonoCameraRecording(path)
    n = 0
    while r.isRunning():
        b = r.getNextEventBatch()
        if b is not None:
            n += b.size()
    return n


def collect(path):
    r = dv.io.MonoCameraRecording(path)
    store = dv.EventStore()
    while r.isRunning():
        b = r.getNextEventBatch()
        if b is not None:
            store.add(b)
    return store.size()


for path in sys.argv[1:]:
    for name, f in [("stream", stream), ("collect", collect)]:
        best = float("inf")
        for _ in range(5):
            t = time.perf_counter()
            n = f(path)
            best = min(best, time.perf_counter() - t)
        print(f"{path} {name}: {n} events, {n / best / 1e6:.1f} M events/s")
