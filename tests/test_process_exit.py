"""Ending a CLI process without the native teardown (osgd.contract.process_exit) keeps what a normal exit does."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from osgd.contract.process_exit import exit_status

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str, cwd: Path) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter, its stdout and stderr pipes (block-buffered)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          cwd=cwd, check=False, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})


@pytest.mark.parametrize(("code", "status"), [(None, 0), (0, 0), (3, 3), (130, 130), ("bad input", 1)])
def test_the_status_is_the_one_sys_exit_gives(code: object, status: int) -> None:
    assert exit_status(code) == status


def test_exit_runs_atexit_handlers_waits_for_threads_and_flushes_the_streams(tmp_path: Path) -> None:
    result = _python("""
        import atexit, logging, threading, time
        from osgd.contract.process_exit import exit_process
        logging.basicConfig(filename="run.log", level=logging.INFO)
        atexit.register(lambda: print("atexit ran"))
        def late():
            time.sleep(0.3)
            print("thread finished")
        threading.Thread(target=late).start()
        print("work done")            # buffered: stdout is a pipe
        logging.info("logged line")   # the log file's handler is flushed by logging's atexit handler
        exit_process(5)
        print("never")
    """, tmp_path)
    assert result.returncode == 5, result.stderr
    assert result.stdout.splitlines() == ["work done", "thread finished", "atexit ran"]
    assert "logged line" in (tmp_path / "run.log").read_text()


def test_a_message_goes_to_stderr_with_status_1(tmp_path: Path) -> None:
    result = _python("from osgd.contract.process_exit import exit_process; exit_process('error: the data dir is gone')",
                     tmp_path)
    assert result.returncode == 1
    assert result.stderr.strip() == "error: the data dir is gone"


@pytest.mark.parametrize(("arguments", "status"), [(["--help"], 0), (["no-such-command"], 2)])
@pytest.mark.parametrize("cli", ["osgd", "togcrf"])
def test_both_commands_end_with_clicks_status(cli: str, arguments: list[str], status: int, tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-m", cli, *arguments], capture_output=True, text=True,
                            cwd=tmp_path, check=False)
    assert result.returncode == status, result.stderr
    assert (result.stdout if status == 0 else result.stderr).strip(), "the output was lost on the way out"


def test_a_command_s_system_exit_sets_the_status_and_other_errors_keep_their_traceback(tmp_path: Path) -> None:
    ended = _python("""
        import sys
        from osgd.contract.process_exit import run_then_exit
        run_then_exit(lambda: sys.exit(4))
    """, tmp_path)
    returned = _python("from osgd.contract.process_exit import run_then_exit; run_then_exit(lambda: print('done'))",
                       tmp_path)
    raised = _python("from osgd.contract.process_exit import run_then_exit; run_then_exit(lambda: 1 / 0)", tmp_path)
    assert ended.returncode == 4
    assert (returned.returncode, returned.stdout) == (0, "done\n")
    assert raised.returncode == 1 and "ZeroDivisionError" in raised.stderr and "Traceback" in raised.stderr
