"""A timed-out benchmark worker takes its own child processes with it (run_all.run_in_own_group).

The Monte Carlo sections run pools of processes; when subprocess.run's timeout killed
only the worker, its pool was orphaned and kept loading the cores under the next
section's timings (seen in a make bench run: two orphans at 30 % CPU each).
"""

from __future__ import annotations

import os
import sys
import time

from benchmarks.run_all import run_in_own_group

CHILD = (
    "import subprocess, sys, time;"
    "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']);"
    "print(p.pid, flush=True); time.sleep(60)"
)


def test_timeout_kills_the_whole_group(tmp_path):
    out = tmp_path / "pid"
    code = CHILD.replace("print(p.pid, flush=True)", f"open({str(out)!r}, 'w').write(str(p.pid))")
    assert run_in_own_group([sys.executable, "-c", code], timeout=3.0) is None
    pid = int(out.read_text())
    for _ in range(50):  # the kernel reaps the orphan shortly after SIGKILL
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    raise AssertionError(f"grandchild {pid} survived its worker's timeout")


def test_a_finished_worker_returns_its_output():
    r = run_in_own_group([sys.executable, "-c", "print('hi')"], timeout=30.0)
    assert r is not None and r.returncode == 0 and r.stdout.strip() == "hi"
