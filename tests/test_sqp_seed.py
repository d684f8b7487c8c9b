"""The sqp backend's seed options (issue 14): checked before anything is built."""

import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.sqp import SqpBackend


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"seed": "acados"}, "solver_options.seed: 'acados' is not one of ['ipopt', 'none']"),
        ({"seed_ratio": 0.5}, "solver_options.seed_ratio: 0.5 is not a finite number >= 1"),
        ({"seed_ratio": float("nan")}, "solver_options.seed_ratio: nan is not a finite"),
    ],
)
def test_bad_seed_options_are_one_clear_line(options, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        SqpBackend.checked_options(options)


def test_seed_defaults():
    opts = SqpBackend.checked_options({})
    assert opts["seed"] == "ipopt" and opts["seed_ratio"] == 3.0
