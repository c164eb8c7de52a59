"""A drawing in a forked child beside the caller (octofuse.outputs.aside)."""

from __future__ import annotations

import os
import signal

import pytest

from octofuse.outputs.aside import drawn_aside


def _no_child_left():
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)


def test_the_child_draws_while_the_body_runs(tmp_path):
    """The body goes on while the child works: the child waits for a file the body writes,
    so a child run after the body (or instead of it) would never finish its own file."""
    ready, drawn = tmp_path / "ready", tmp_path / "drawn.png"

    def draw():
        import time

        for _ in range(2000):
            if ready.exists():
                drawn.write_text("figure")
                return
            time.sleep(0.005)
        raise TimeoutError("the body never ran beside the drawing")

    with drawn_aside(draw, drawn.name):
        ready.write_text("")
    assert drawn.read_text() == "figure"
    _no_child_left()


def test_on_one_core_the_drawing_comes_first_in_the_callers_process():
    """``--threads 1`` means one core: no child then, the drawing done before the body."""
    order = []
    with drawn_aside(lambda: order.append(("draw", os.getpid())), "a.png", cores=1):
        order.append(("body", os.getpid()))
    assert order == [("draw", os.getpid()), ("body", os.getpid())]
    _no_child_left()


@pytest.mark.parametrize("cores", [1, 2])
@pytest.mark.parametrize("kind", [ValueError, TypeError, PermissionError])
def test_a_failed_drawing_raises_its_own_error_in_either_process(kind, cores):
    """The caller gets the drawing's error as it is, whichever process drew: its kind decides
    what the command line makes of it (a bug's TypeError an internal error, a file's
    PermissionError bad input); from a child, its traceback comes along as a note."""

    def draw():
        raise kind("no axes to draw")

    with pytest.raises(kind) as raised:
        with drawn_aside(draw, "kl_over_time.png", cores=cores):
            pass
    assert type(raised.value) is kind and raised.value.args == ("no axes to draw",)
    notes = getattr(raised.value, "__notes__", [])
    if cores == 2:
        assert len(notes) == 1 and "drawing kl_over_time.png in a child process" in notes[0]
        assert "in draw" in notes[0] and f"{kind.__name__}: no axes to draw" in notes[0]
    else:
        assert notes == []
    _no_child_left()


class Unpicklable(Exception):
    def __init__(self, a, b):  # unpickling rebuilds it with one argument: fails
        super().__init__(f"{a} {b}")


def test_an_error_that_does_not_pickle_comes_back_as_a_runtime_error():
    def draw():
        raise Unpicklable("no", "axes")

    with pytest.raises(RuntimeError) as raised:
        with drawn_aside(draw, "a.png"):
            pass
    assert raised.value.args == ("Unpicklable: no axes",)
    _no_child_left()


def test_a_drawing_process_killed_is_an_error_not_a_crash():
    with pytest.raises(OSError, match=r"cannot write a\.png: its drawing process ended with -9"):
        with drawn_aside(lambda: os.kill(os.getpid(), signal.SIGKILL), "a.png"):
            pass
    _no_child_left()


@pytest.mark.parametrize("end, code", [("killed", -9), ("exited", 1)])
def test_an_error_half_handed_over_is_an_error_naming_the_files(monkeypatch, end, code):
    """The child ended while writing its error: what it wrote is not read as an error."""
    import pickle

    from octofuse.outputs import aside

    def half_handed_over(fd, e):
        os.write(fd, pickle.dumps((e, "its traceback"))[:20])
        if end == "killed":
            os.kill(os.getpid(), signal.SIGKILL)

    def draw():
        raise ValueError("no axes to draw")

    monkeypatch.setattr(aside, "_hand_over", half_handed_over)
    said = rf"^cannot write a\.png: its drawing process ended with {code}$"
    with pytest.raises(OSError, match=said):
        with drawn_aside(draw, "a.png"):
            pass
    _no_child_left()


def test_the_bodys_error_wins_and_the_child_is_waited_for():
    def draw():
        raise ValueError("the drawing's error")

    with pytest.raises(KeyError, match="the body's error"):
        with drawn_aside(draw, "a.png"):
            raise KeyError("the body's error")
    _no_child_left()


@pytest.mark.slow
def test_the_child_leaves_the_callers_exit_and_buffers_alone(tmp_path):
    """The child ends with os._exit: the parent's atexit handlers run once (in the parent) and
    text buffered before the fork is written once."""
    import subprocess
    import sys

    code = (
        "import atexit, sys; from octofuse.outputs.aside import drawn_aside\n"
        "atexit.register(lambda: print('exit handler'))\n"
        "sys.stdout.write('buffered ')\n"
        f"with drawn_aside(lambda: open({str(tmp_path / 'f')!r}, 'w').write('x'), 'f'):\n"
        "    pass\n"
        "print('done')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["buffered", "done", "exit", "handler"]
    assert (tmp_path / "f").read_text() == "x"
