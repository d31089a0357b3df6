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

# as from a terminal: a job started in the background by a non-interactive shell inherits SIGINT ignored (an ignored
# disposition survives exec), and the command rightly keeps it so; the test is of a handler's interrupt
signal.signal(signal.SIGINT, signal.default_int_handler)

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


def _extension_init_interrupted():
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as exc:
        raise ImportError("initialization failed") from exc


def _cleanup_failing_while_interrupted():
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt:
        raise OSError("cleanup failed")  # noqa: B904 - raised while the interrupt unwinds


@pytest.mark.parametrize("fail", [_extension_init_interrupted, _cleanup_failing_while_interrupted])
def test_an_error_raised_from_an_interrupt_is_the_interrupt(capsys, fail):
    """pybind11 turns an interrupt inside an extension's initialiser into ImportError("initialization failed") (seen:
    SIGTERM while gtsam loaded, exit 1 with a traceback); a cleanup that fails while an interrupt unwinds is the
    same. Both: one line, exit 130."""
    from dome_calib import errors

    with pytest.raises(SystemExit) as stop:
        with errors.interrupt_as_one_line("x", imports=()):
            fail()
    assert stop.value.code == errors.EXIT_INTERRUPTED
    assert capsys.readouterr().err == "x: interrupted; rerun the same command to resume\n"


def test_an_error_with_no_interrupt_behind_it_passes_through():
    from dome_calib import errors

    with pytest.raises(ValueError):
        with errors.interrupt_as_one_line("x", imports=()):
            try:
                raise OSError("handled")
            except OSError:
                raise ValueError("raised while handling another error, not an interrupt")  # noqa: B904


_LIBRARY_REPLACING_THE_HANDLER = """
import signal, sys, time
from dome_calib import errors
errors.HANDLER_REPLACING_IMPORTS = ("fakeglog",)
with errors.interrupt_as_one_line("dome-calib", imports=("fakeglog",) if sys.argv[1] == "first" else ()):
    if sys.argv[1] == "late":  # imported midway through a command (run_cli's guard on sys.meta_path)
        sys.meta_path.insert(0, errors._HandlerGuard())
        import fakeglog
    print("loaded", flush=True)
    for _ in range(400):
        time.sleep(0.05)
"""

_FAKE_GLOG = """
import signal
signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as glog's failure handler, which kills the process on SIGTERM
signal.raise_signal(signal.SIGTERM)  # a SIGTERM that comes while the library loads
"""


@pytest.mark.parametrize("when", ["first", "late"])
def test_a_sigterm_while_a_handler_replacing_library_loads_is_an_interrupt(tmp_path, when):
    """Before: a SIGTERM between pycolmap installing glog's handler and ours being put back killed the process with
    glog's C stack dump (exit -15; 5-6 of 40 SIGTERMs sent at random times during a command's start)."""
    (tmp_path / "fakeglog.py").write_text(_FAKE_GLOG)
    env = {**os.environ, "PYTHONPATH": f"{ROOT}:{tmp_path}"}
    proc = subprocess.run([sys.executable, "-c", _LIBRARY_REPLACING_THE_HANDLER, when], capture_output=True,
                          text=True, cwd=tmp_path, env=env, timeout=60)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.splitlines() == ["dome-calib: interrupted; rerun the same command to resume"]
    assert proc.stdout == ""  # the interrupt came where the library finished loading
