"""Output files: readable by others (the umask decides), atomic, no temporaries left behind."""

from __future__ import annotations

import os
import stat
import subprocess
import sys

import pytest

from tpos_cli.report.files import remove_stale_temporaries, staged, write_atomic


@pytest.fixture
def umask022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_mode_follows_the_umask(tmp_path, umask022):
    p = tmp_path / "report.pdf"
    write_atomic(p, lambda t: t.write_bytes(b"x"))
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    os.umask(0o077)
    write_atomic(p, lambda t: t.write_bytes(b"y"))
    assert stat.S_IMODE(p.stat().st_mode) == 0o600 and p.read_bytes() == b"y"


def test_failure_leaves_old_files_and_no_temporaries(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.pdf"
    a.write_text("old")

    with pytest.raises(RuntimeError), staged([a, b]) as tmps:
        tmps[a].write_text("new")
        raise RuntimeError("boom")
    assert a.read_text() == "old" and not b.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_stale_temporaries_of_dead_writers_are_removed(tmp_path):
    # a killed writer's temporary (its PID gone), an old-version mkstemp name, a live writer's file
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    stale = tmp_path / f".report.pdf.{pid}-0a1b2c3d.tmp"
    old_style = tmp_path / ".accuracy.json.k3j_x9a2.tmp"
    live = tmp_path / f".report.pdf.{os.getppid()}-deadbeef.tmp"
    other = tmp_path / ".notes.txt.123-abcd.tmp"
    for p in (stale, old_style, live, other):
        p.write_text("")
    removed = remove_stale_temporaries(tmp_path, ["report.pdf", "accuracy.json"])
    assert sorted(p.name for p in removed) == sorted([stale.name, old_style.name])
    assert live.exists() and other.exists()


def test_sigterm_mid_write_leaves_nothing(tmp_path):
    # a real process writing through `staged` is killed with SIGTERM: the CLI's handler turns it
    # into KeyboardInterrupt, the temporary is removed, the old output stays
    (tmp_path / "out.bin").write_text("old")
    code = (
        "import sys, time; from pathlib import Path\n"
        "from tpos_cli.report.files import staged, terminate_as_interrupt\n"
        f"p = Path({str(tmp_path / 'out.bin')!r})\n"
        "with terminate_as_interrupt():\n"
        "    try:\n"
        "        with staged([p]) as t:\n"
        "            t[p].write_text('partial'); print('ready', flush=True); time.sleep(30)\n"
        "    except KeyboardInterrupt:\n"
        "        sys.exit(130)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    proc.terminate()
    assert proc.wait(timeout=20) == 130
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"] and (tmp_path / "out.bin").read_text() == "old"


def test_interrupt_right_after_a_temporary_is_created_leaves_nothing(tmp_path, monkeypatch):
    # a SIGTERM (KeyboardInterrupt) landing between a temporary's creation and its registration
    # once left it behind (found by test_report_killed_mid_run_then_run_again)
    from tpos_cli.report import files

    real, calls = files._create, []

    def create_then_interrupt(tmp):
        real(tmp)
        calls.append(tmp)
        if len(calls) == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(files, "_create", create_then_interrupt)
    with pytest.raises(KeyboardInterrupt), staged([tmp_path / "a.json", tmp_path / "b.pdf", tmp_path / "c.parquet"]):
        pass
    assert len(calls) == 2 and list(tmp_path.iterdir()) == []


def _read_only_os_open(monkeypatch):
    import errno

    real_open = os.open

    def ro_open(path, flags, *a, **k):
        if str(path).endswith(".tmp") and flags & os.O_CREAT:
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real_open(path, flags, *a, **k)

    monkeypatch.setattr(os, "open", ro_open)


def test_read_only_directory_is_a_one_line_error_naming_the_output(tmp_path, monkeypatch):
    """On a read-only file system the temporary's creation and its clean-up both raised EROFS:
    `tpos report`/`export` ended in "tpos: internal error: OSError ..." (exit 1)."""
    from tpos_cli.errors import TposError

    _read_only_os_open(monkeypatch)
    with pytest.raises(TposError) as exc:
        write_atomic(tmp_path / "x.gpx", lambda p: p.write_text("x"))
    assert str(exc.value) == f"cannot write {tmp_path / 'x.gpx'}: Read-only file system"
    assert type(exc.value).exit_code == 1
    assert list(tmp_path.iterdir()) == []


def test_full_disk_while_writing_names_the_output(tmp_path):
    import errno

    from tpos_cli.errors import TposError

    def write(p):
        raise OSError(errno.ENOSPC, "No space left on device", str(p))

    with pytest.raises(TposError, match=r"cannot write .*a\.csv: No space left on device"):
        write_atomic(tmp_path / "a.csv", write)
    assert list(tmp_path.iterdir()) == []


def test_other_errors_of_the_writer_are_not_renamed(tmp_path):
    def write(p):
        raise FileNotFoundError(2, "No such file", "/elsewhere/input.parquet")

    with pytest.raises(FileNotFoundError):
        write_atomic(tmp_path / "a.csv", write)


def test_a_target_that_is_not_a_regular_file_is_refused(tmp_path):
    """A FIFO (as a device, which only root could name) is not replaced by a regular file; a
    directory neither; nothing is written and the other targets are untouched."""
    from tpos_cli.errors import InvalidInputError

    fifo, other = tmp_path / "out.pdf", tmp_path / "summary.txt"
    os.mkfifo(fifo)
    other.write_text("old")
    for target in (fifo, tmp_path):
        with pytest.raises(InvalidInputError, match="exists and is not a regular file"):
            with staged([other, target]) as tmps:
                for t in tmps.values():
                    t.write_text("new")
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    assert other.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.pdf", "summary.txt"]
    link = tmp_path / "link.pdf"
    link.symlink_to(other)
    with staged([link]) as tmps:  # a link is replaced, its target left alone
        tmps[link].write_text("new")
    assert not link.is_symlink() and link.read_text() == "new" and other.read_text() == "old"


def test_a_link_to_a_fifo_or_directory_is_refused_and_left_alone(tmp_path):
    """audit (session 11): a link to a FIFO (as `/dev/stdout` is a link to the terminal or pipe) was
    replaced by a regular file (as root, `tpos export RUN -o /dev/stdout` would have replaced the
    system's link); a dangling link is still replaced."""
    from tpos_cli.errors import InvalidInputError

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for name, target in (("stdout", fifo), ("dirlink", tmp_path)):
        link = tmp_path / name
        link.symlink_to(target)
        with pytest.raises(InvalidInputError, match="exists and is not a regular file .a link to a device"):
            write_atomic(link, lambda p: p.write_text("new"))
        assert link.is_symlink() and link.readlink() == target
    dangling = tmp_path / "dangling.pdf"
    dangling.symlink_to(tmp_path / "nowhere")
    write_atomic(dangling, lambda p: p.write_text("new"))
    assert not dangling.is_symlink() and dangling.read_text() == "new"
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
