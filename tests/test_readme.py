"""The README's Python example runs as written and does what it says."""

import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def test_python_example_reaches_its_target():
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    scope: dict = {}
    exec(compile(code, str(README), "exec"), scope)
    problem, x, cmd = scope["problem"], scope["x"], scope["cmd"]
    assert cmd.status == "ok"
    ee = np.asarray(problem.kin.ee_position(x)).ravel()
    np.testing.assert_allclose(ee, [0.5, 0.3, 0.6], atol=2e-3)
    assert float(np.asarray(problem.kin.clearance()(x)).min()) >= 0.1 - 1e-6
