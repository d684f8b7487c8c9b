"""``aeromanip fly`` / ``aeromanip sitl``: bad input is one line naming the option, value
and what is allowed (exit 2), before anything is built or connected."""

import pytest

from aeromanip.cli import main


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["fly", "flight", "--link", "http://x"], "--link: 'http://x' is not a MAVLink link"),
        (["fly", "flight", "--link", "udpin:127.0.0.1:14540", "--stream-hz", "5"], "--stream-hz"),
        (["fly", "flight-cog", "--link", "udpin:127.0.0.1:14540", "--check"], "--variant"),
        (["fly", "flight", "--link", "udpin:127.0.0.1:1", "--set", "duration=-1"], "duration"),
        (["sitl", "flight", "--link", "udpout:127.0.0.1:14540", "--state-hz", "10"], "--state-hz"),
        (["sitl", "flight", "--link", "serial:/dev/ttyS0"], "serial:DEVICE:BAUD"),
    ],
)
def test_bad_input_is_one_line(argv, needle, capsys, tmp_path):
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def test_check_connects_to_nothing(capsys, tmp_path):
    argv = ["fly", "flight", "--link", "udpin:127.0.0.1:14540", "--check"]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 0
    assert "1560 steps at 2 Hz" in capsys.readouterr().out
