"""Issue 37: stopping the way schedulers stop things. SIGTERM gives one line and exit 130 even after pycolmap (whose
glog replaces the handler at the C level) is imported inside the run; pool workers end when their parent is killed
(SIGKILL, SIGHUP, SIGTERM) instead of running on for ever."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_IMPORT_INSIDE = """
import sys, time
from pathlib import Path
from dome_calib.errors import interrupt_as_one_line
with interrupt_as_one_line("dome-calib"):
    import dome_calib.pipeline.full  # as the calibrate command does: pycolmap loads inside the block
    Path(sys.argv[1]).write_text("ready")
    time.sleep(60)
"""


def test_sigterm_after_pycolmap_loaded_is_one_line_and_exit_130(tmp_path):
    marker = tmp_path / "ready"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", _IMPORT_INSIDE, str(marker)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert marker.exists(), proc.communicate()[1]
    proc.send_signal(signal.SIGTERM)  # `timeout` and batch schedulers send SIGTERM to the process
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        "dome-calib: interrupted; rerun the same command to resume"], err


def test_a_stage_restores_the_handler_a_library_replaced(tmp_path):
    from dome_calib import errors
    from dome_calib.pipeline.workstate import WorkState

    with errors.interrupt_as_one_line("x"):
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as a library loaded during a stage would
        with WorkState.open(tmp_path / "w", {"k": 1}) as state:
            state.time("s", lambda: None)
        assert signal.getsignal(signal.SIGTERM) is errors._terminate_as_interrupt


_POOL = """
import os, signal, sys, time
from pathlib import Path
# SIGHUP's default action, whatever the test runner passed on (a runner started under nohup ignores it, and a process
# that ignores SIGHUP is not killed by it: there would be nothing to test)
signal.signal(signal.SIGHUP, signal.SIG_DFL)
from dome_calib.executor.local import LocalProcessExecutor
pool = LocalProcessExecutor(2)
futures = [pool.submit(time.sleep, 120) for _ in range(2)]  # both workers busy
time.sleep(1.0)
pids = sorted(p.pid for p in pool._processes())
Path(sys.argv[1]).write_text(" ".join(map(str, pids)))
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in state  # a zombie has ended (its parent, init, reaps it)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGHUP, signal.SIGTERM], ids=["SIGKILL", "SIGHUP", "SIGTERM"])
def test_pool_workers_end_when_their_parent_is_killed(tmp_path, sig):
    marker = tmp_path / "pids"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", _POOL, str(marker)], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    pids = [int(p) for p in marker.read_text().split()]
    assert pids and all(_alive(p) for p in pids)
    try:
        os.kill(proc.pid, sig)  # the parent only (a scheduler's kill), not its process group
        proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in pids if _alive(p)], "workers still running after their parent died"
    finally:
        for p in pids:
            if _alive(p):
                os.kill(p, signal.SIGKILL)


_LOST_IN_A_CALLBACK = """
import signal, sys, time, weakref
from dome_calib.errors import interrupt_as_one_line

class Resource:
    def __del__(self):
        signal.raise_signal(getattr(signal, sys.argv[1]))

class Key:
    pass

with interrupt_as_one_line("dome-calib"):
    if sys.argv[2] == "weakref":  # as an import lock's weakref callback, when the signal comes during an import
        key = Key()
        ref = weakref.ref(key, lambda _: signal.raise_signal(getattr(signal, sys.argv[1])))
        del key
    else:  # a finaliser
        Resource()
    for _ in range(400):  # 20 s: the run goes on as if no signal had come
        time.sleep(0.05)
print("went on")
"""


@pytest.mark.parametrize("where", ["weakref", "finaliser"])
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_an_interrupt_raised_inside_a_callback_is_not_lost(sig, where):
    """A handler's KeyboardInterrupt raised inside a weakref callback or a ``__del__`` is "ignored" by Python
    (printed and dropped). Seen in CI: SIGTERM while ``reconstruct`` was still importing, raised inside an import
    lock's callback; the run went on and blocked on its input. Before: exit 0 after 20 s, "Exception ignored" on
    stderr."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", _LOST_IN_A_CALLBACK, sig, where], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=60)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.splitlines() == ["dome-calib: interrupted; rerun the same command to resume"]
    assert proc.stdout == ""
    assert time.monotonic() - start < 15


def test_the_hook_is_put_back_and_other_unraisables_pass_through():
    from dome_calib import errors

    seen = []
    before = sys.unraisablehook
    sys.unraisablehook = seen.append
    try:
        with errors.interrupt_as_one_line("x"):
            with errors.interrupt_as_one_line("x", imports=()):  # nested: one hook
                assert sys.unraisablehook is errors._interrupt_never_swallowed
            assert sys.unraisablehook is errors._interrupt_never_swallowed

            class Failing:
                def __del__(self):
                    raise ValueError("a finaliser's own error")

            Failing()
        assert sys.unraisablehook == seen.append
        assert [type(u.exc_value) for u in seen] == [ValueError]
    finally:
        sys.unraisablehook = before
