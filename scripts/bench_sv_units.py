"""Micro-benchmark (issue 26 item 2): one SV's CPU per tick serving the 12 fed PID slots of
the default two-PUMA cell, on an arena laid out as ``kalictl start`` does, no processes.

An SV is built without its process shell (``ServoWorker.__new__`` and the attributes
``on_configure`` sets), and each tick SIO's part is imitated: every slot fed (busy 0),
``done`` zeroed, the tick written.  Then ``ServoWorker.serve`` is timed.  Run from the
repository root: ``python scripts/bench_sv_units.py``.

On the same loaded 2-vCPU VM (min / median): per-slot ctypes steps, no units, 44.3 / 45.3
us; units compiled with numba, 6.2 / 6.4 us; units in C (``csrc/servo.c``, the one compiled
technology left), 4.9-5.1 / 5.1-5.3 us.
"""

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import numpy as np

from kali_daemons.core import atomic
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo.level import ServoLevel
from kali_daemons.servo.sv.daemon import ServoWorker
from kali_daemons.tools import launcher
from tests.conftest import make_config, unique_name

name = unique_name("bench")
cfg = make_config(name)
arena = launcher._create(cfg, name, True)
arena.close()
inst = Instance.attach(name)
try:
    lv = ServoLevel(inst)
    lv.initialise()
    w = ServoWorker.__new__(ServoWorker)
    w.inst, w.name, w.index, w.me = inst, "sv.0", 0, 1

    class Sem:
        def release(self):
            pass

    w.done_sem = Sem()
    w.level = lv
    n = lv.n
    w.order = list(range(n))
    w.busy = lv.slots["busy"]
    w.n_algos = len(lv.registry)
    w.configured = [0] * n
    w.cas = atomic.CompareExchange32()
    c = lv.ctrl
    w._fed, w._tick = c["fed"], c["tick"]
    w._exec_last = c["sv_exec_last_ns"][0:1]
    w._exec_max = c["sv_exec_max_ns"][0:1]
    w._servos = c["sv_servos"][0:1]
    w._exec_hist = c["sv_exec_hist"][0]
    w._fed_tick = c["sv_fed_tick"][0:1]
    w._setup_units(1)
    rng = np.random.default_rng(1)
    lv.slots["position"] = rng.normal(0, 0.1, n)
    lv.slots["demand"] = lv.slots["position"] + rng.normal(0, 0.001, n)
    c["fed"] = n

    serve = w.serve
    busy = lv.slots["busy"]
    times = []
    for tick in range(20000):
        busy[:] = 0
        c["done"] = 0
        c["tick"] = tick
        t0 = time.perf_counter_ns()
        serve(tick)
        times.append(time.perf_counter_ns() - t0)
    assert (lv.slots["ran_tick"] == 19999).all(), lv.slots["ran_tick"]
    assert int(c["done"]) == n
    t = times[2000:]
    print(
        f"serve: {n} slots, min {min(t) / 1000:.1f} us, "
        f"median {statistics.median(t) / 1000:.1f} us, p90 {np.percentile(t, 90) / 1000:.1f} us"
    )
    lv.close()
    del lv, busy, c
finally:
    inst.close()
    launcher._stop(name)
