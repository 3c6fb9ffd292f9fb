"""Progress goes to stderr, only for steps long enough to look stuck, and never with progress off."""

import time

from slr_ray.progress import bar, phase


def test_a_long_phase_is_named_then_timed_on_stderr(capsys):
    with phase("embree: preparing 5 points", after=0.02):
        time.sleep(0.2)
    out, err = capsys.readouterr()
    assert out == ""
    assert "embree: preparing 5 points ..." in err and "embree: preparing 5 points: 0." in err


def test_a_short_phase_and_a_quiet_one_say_nothing(capsys):
    with phase("quick", after=5.0):
        pass
    with phase("quiet", progress=False, after=0.0):
        time.sleep(0.05)
    assert capsys.readouterr() == ("", "")


def test_a_quiet_bar_still_iterates_and_says_nothing(capsys):
    assert list(bar(range(3), "scans", "scan", progress=False)) == [0, 1, 2]
    b = bar(total=2, progress=False)
    b.update(2)
    b.close()
    assert capsys.readouterr() == ("", "")
    assert list(bar(range(2), "scans", "scan")) == [0, 1]
    out, err = capsys.readouterr()
    assert out == "" and "scans" in err


def test_a_bar_closed_outside_a_terminal_leaves_its_last_state_not_a_line_of_blanks(capsys):
    # was: a streamed scan's bar ended its stderr with spaces and '\r' (a blank line in a log)
    b = bar(total=4, desc="1 scan", unit="pt")
    b.update(4)
    b.close()
    err = capsys.readouterr().err
    assert err.endswith("\n") and "4/4" in err.splitlines()[-1]
    assert all(line.strip() for line in err.replace("\r", "\n").split("\n")[1:-1])
