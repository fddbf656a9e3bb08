"""bgc.cli.launch.exit_now ends the process without the interpreter's teardown, but only after
what the teardown does that a user could see: the exit status, the other threads' work, the
atexit handlers, the flushed streams."""
import subprocess
import sys

import pytest

_PROG = r"""
import atexit, sys, threading, time
from bgc.cli.launch import exit_now
out = sys.argv[1]
atexit.register(lambda: print("atexit ran"))
def late():
    time.sleep(0.3)
    open(out, "w").write("thread done")
def body():
    threading.Thread(target=late).start()
    sys.stdout.write("unflushed")
    sys.exit(eval(sys.argv[2]))
exit_now(body)
print("not reached")
"""


@pytest.mark.parametrize("code, status", [("None", 0), ("0", 0), ("2", 2), ("'a message'", 1)])
def test_exit_now_keeps_what_the_teardown_did(tmp_path, code, status):
    out = tmp_path / "t.txt"
    p = subprocess.run([sys.executable, "-c", _PROG, str(out), code], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == status, p.stderr
    assert p.stdout.startswith("unflushed") and "atexit ran" in p.stdout
    assert "not reached" not in p.stdout
    assert out.read_text() == "thread done"  # the thread finished before the end
    if status == 1:
        assert "a message" in p.stderr


def test_python_m_bgc_reports_a_user_error_and_its_status(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("bgc: 1\nname: x\nelements:\n  a: {type: Q}\n")
    for entry in ("bgc", "bgc.cli"):
        p = subprocess.run([sys.executable, "-m", entry, "check", str(bad)], capture_output=True,
                           text=True, timeout=300)
        assert p.returncode == 2, p.stderr
        assert f"{bad}:" in p.stderr and "Traceback" not in p.stderr
