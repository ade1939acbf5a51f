"""Progress on stderr: a bar on a terminal, plain lines in a log."""

import io

from rose_usd import progress as progress_module


def test_off_a_terminal_progress_is_whole_lines(monkeypatch):
    """A log gets a line when the work starts, one per LOG_EVERY_S and one when it ends (none
    just before it); no carriage returns (a tqdm bar's redraws would fill the file)."""
    log = io.StringIO()  # not a terminal
    monkeypatch.setattr(progress_module.sys, "stderr", log)
    monkeypatch.setattr(progress_module, "LOG_EVERY_S", 0.0)
    monkeypatch.delenv("ROSE_USD_QUIET", raising=False)
    assert list(progress_module.progress(range(3), "segment", total=3)) == [0, 1, 2]
    lines = log.getvalue().splitlines()
    assert "\r" not in log.getvalue()
    assert lines[0] == "segment: 0/3 frames"
    assert lines[1].startswith("segment: 1/3 frames, ")
    assert lines[-1].startswith("segment: 3/3 frames in ") and lines[-1].endswith(" s")
    assert len(lines) == 4  # start, 1/3, 2/3, end: the last item's periodic line is the end's


def test_quiet_prints_nothing(monkeypatch):
    log = io.StringIO()
    monkeypatch.setattr(progress_module.sys, "stderr", log)
    monkeypatch.setenv("ROSE_USD_QUIET", "1")
    assert list(progress_module.progress(range(2), "scene", total=2)) == [0, 1]
    assert log.getvalue() == ""


def test_a_loop_left_early_still_gets_its_end_line(monkeypatch):
    """A rest check stops once the objects settle: its log showed "newton: 0/600 steps" and never
    an end. Left early (a break, or an error in the loop) it ends with the count reached."""
    log = io.StringIO()
    monkeypatch.setattr(progress_module.sys, "stderr", log)
    monkeypatch.delenv("ROSE_USD_QUIET", raising=False)
    for step in progress_module.progress(range(600), "newton", total=600, unit="step"):
        if step == 149:
            break
    lines = log.getvalue().splitlines()
    assert lines[0] == "newton: 0/600 steps" and lines[-1].startswith("newton: stopped at 150/600 steps after "), lines
    log.truncate(0)
    log.seek(0)
    try:
        for _ in progress_module.progress(range(3), "segment", total=3):
            raise ValueError("a stage's error")
    except ValueError:
        pass
    lines = log.getvalue().splitlines()
    assert (
        lines[0] == "segment: 0/3 frames"
        and lines[1].startswith("segment: stopped at 1/3 frames after ")
        and len(lines) == 2
    )
