"""One run per output folder: the lock file names its holder, a second run is refused naming
it, a lock that a killed run left behind is taken over with one note, and SIGTERM releases the lock
(the console-script entry point turns it into an interrupt, as Ctrl-C: exit 130, the resume hint)."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from gicore.error_policy import EXIT_INTERRUPTED, UserError
from gicore.fileio import FolderHeld, exclusive_run

ROOT = Path(__file__).resolve().parents[2]

#: Holds the lock of the folder argv[1] (exclusive_run alone), says so, sleeps.
HOLD = """
import sys, time
from pathlib import Path
from gicore.fileio import exclusive_run
with exclusive_run(Path(sys.argv[1])):
    print("locked", flush=True)
    time.sleep(60)
"""

#: A console script (through gicore.error_policy.run, as every entry point) that holds the lock of argv[1].
SCRIPT = """
import time
from pathlib import Path
import typer
from gicore.error_policy import run
from gicore.fileio import exclusive_run
app = typer.Typer(add_completion=False)
@app.command()
def hold(out: Path) -> None:
    with exclusive_run(out):
        print("locked", flush=True)
        time.sleep(60)
run(app, prog_name="hold", resume="run it again")
"""


def start(code: str, folder: Path) -> subprocess.Popen:
    """``code`` as a process holding ``folder``'s lock; returns once it says so."""
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(folder)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "locked", proc.communicate(timeout=120)
    return proc


def test_the_lock_names_its_holder_and_a_second_run_is_refused_naming_it(tmp_path: Path) -> None:
    folder = tmp_path / "out"
    with exclusive_run(folder):
        assert (folder / ".lock").read_text() == f"{os.getpid()}\n"
        with pytest.raises(FolderHeld) as caught, exclusive_run(folder):
            pass
        assert isinstance(caught.value, UserError) and caught.value.holder == os.getpid()
        assert str(caught.value) == (
            f"another run holds {folder} (process {os.getpid()}): wait for it to finish or choose another --out"
        )
        assert str(pickle.loads(pickle.dumps(caught.value))) == str(caught.value)
    assert not folder.exists()  # created by the run, left empty: removed


def test_a_lock_left_by_a_killed_run_is_taken_over_with_one_note(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "out"
    holder = start(HOLD, folder)
    holder.kill()  # kill -9: no clean-up, the lock file stays (the kernel drops the flock itself)
    holder.communicate(timeout=120)
    assert (folder / ".lock").read_text() == f"{holder.pid}\n"
    with exclusive_run(folder):
        assert (folder / ".lock").read_text() == f"{os.getpid()}\n"
    err = capfd.readouterr().err
    assert err == f"note: taking over the lock of {folder} left by process {holder.pid}, which is gone\n"
    assert not (folder / ".lock").exists()
    with exclusive_run(folder):  # a lock released properly leaves nothing to take over
        pass
    assert capfd.readouterr().err == ""


def test_sigterm_ends_a_command_as_an_interrupt_and_releases_the_lock(tmp_path: Path) -> None:
    folder = tmp_path / "out"
    proc = start(SCRIPT, folder)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == EXIT_INTERRUPTED == 130, err  # ended by the signal, not after its 60 s sleep
    assert err.strip() == "interrupted: run it again"
    assert not folder.exists()  # the lock removed, and the folder the run created with it


def test_a_run_leaves_no_folder_it_created_and_left_empty(tmp_path: Path) -> None:
    with exclusive_run(tmp_path / "store" / ".prebake" / "scene"):
        assert (tmp_path / "store" / ".prebake" / "scene" / ".lock").is_file()
    assert list(tmp_path.iterdir()) == []
    with exclusive_run(tmp_path / "store" / ".prebake" / "scene"):
        (tmp_path / "store" / "index.sqlite").touch()  # what the run stored stays, and the folders that hold it
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == ["index.sqlite"]
